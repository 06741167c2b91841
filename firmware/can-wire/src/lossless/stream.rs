//! The sender's state for one scan in the lossless coding: points in, segments of data
//! frames out, and the scan CRC over the headers and the segments' CRCs.

use super::bits::{Out, Writer};
use super::block::{put_block, width, Block, History};
use super::code;
use super::{segment_points, BLOCK_POINTS, MAX_VALUE, SEGMENT_POINTS, WIDTH_BITS};
use crate::crc::ScanCrc;
use crate::encoder::FrameSink;
use crate::Error;
use core::cell::Cell;

/// One scan being coded.
#[derive(Debug, Clone)]
pub struct ScanStream {
    w: Writer,
    seq_low: u8,
    point_count: u16,
    intensity: bool,
    /// Points taken before the block being gathered (its `gathered` points not counted).
    pushed: u16,
    /// Points of the segments ended so far (sent whole).
    sent: u16,
    /// Codes that are no range among the points taken before the current run (the run
    /// counts its own), and range codes among the points sent.
    nonrange: u16,
    valid_sent: u16,
    /// Points the block being gathered still takes (0: the next point is an anchor):
    /// the run's one test per pass for the block's, the segment's and the scan's end.
    block_left: usize,
    /// Points of the segment after the block being gathered.
    segment_left: usize,
    /// The block being gathered: the distance channel's values (and room for the
    /// residuals of either channel), the intensity channel's values (into `d` once the
    /// distances are written: the scan stream stays as small as it was).
    d: Block,
    i: [u32; BLOCK_POINTS],
    /// Its points so far.
    gathered: usize,
    hd: History,
    hi: History,
    /// Headers, then each segment's CRC.
    crc: ScanCrc,
}

/// The codes of `points` into `d` (and `i` if `INTENSITY`). The code counts what is no
/// range itself: the common case, a range, costs no test here.
#[inline(always)]
fn gather<const INTENSITY: bool, T, F>(points: &[T], code: &F, d: &mut [u32], i: &mut [u32])
where
    F: Fn(&T) -> (u32, u16),
{
    for ((p, d), i) in points.iter().zip(d.iter_mut()).zip(i.iter_mut()) {
        let (dc, ic) = code(p);
        *d = dc;
        if INTENSITY {
            *i = u32::from(ic);
        }
    }
}

impl ScanStream {
    /// A scan of `point_count` points with sequence `seq`, whose header frames were
    /// `a` and `b`, sent in data frames of `full_len` bytes.
    pub fn new(
        seq: u16,
        point_count: u16,
        intensity: bool,
        full_len: usize,
        a: &[u8],
        b: &[u8],
    ) -> ScanStream {
        ScanStream {
            w: Writer::new(full_len),
            seq_low: (seq & 0xF) as u8,
            point_count,
            intensity,
            pushed: 0,
            sent: 0,
            nonrange: 0,
            valid_sent: 0,
            block_left: 0,
            segment_left: 0,
            d: Block::default(),
            i: [0; BLOCK_POINTS],
            gathered: 0,
            hd: History::default(),
            hi: History::default(),
            crc: ScanCrc::new(a, b),
        }
    }

    /// Points taken so far.
    pub fn pushed(&self) -> u16 {
        // At most the scan's points: no wrap.
        self.pushed.wrapping_add(self.gathered as u16)
    }

    /// Points in segments sent whole: the trailer's `points_sent`.
    pub fn sent(&self) -> u16 {
        self.sent
    }

    /// Range codes among the points sent: the trailer's `points_valid`.
    pub fn valid_sent(&self) -> u16 {
        self.valid_sent
    }

    /// Stream bytes written so far (segments and their CRCs, framing bytes not counted).
    pub fn stream_bytes(&self) -> u32 {
        self.w.stream_bytes()
    }

    /// Whether every point of the scan was taken.
    pub fn is_full(&self) -> bool {
        self.pushed() >= self.point_count
    }

    /// The scan CRC, finished with the trailer's first six bytes.
    pub fn crc(&self, trailer_head: &[u8]) -> u16 {
        self.crc.finish(trailer_head)
    }

    /// Take the next point: its distance code and intensity code (0 without the
    /// channel). Frames that fill go into `out`. The same as [`ScanStream::push_run`]
    /// of one point.
    pub fn push<S: FrameSink + ?Sized>(
        &mut self,
        distance: u32,
        intensity: u16,
        out: &mut Out<'_, S>,
    ) -> Result<(), Error> {
        if self.is_full() {
            return Err(Error::TooManyPoints);
        }
        let misses = Cell::new(0u32);
        let code = |p: &(u32, u16)| {
            misses.set(misses.get().wrapping_add(u32::from(!code::is_range(p.0))));
            *p
        };
        self.push_run(&[(distance.min(MAX_VALUE), intensity)], code, &misses, out);
        Ok(())
    }

    /// Take `points` in order, each turned by `code` into its distance code (at most
    /// [`MAX_VALUE`]: the caller's guarantee, not checked per point) and intensity code,
    /// like [`ScanStream::push`] for each but a block at a time; `code` adds 1 to
    /// `misses` for each distance code it returns that is no range (below
    /// [`code::RANGE_BASE`]), so the common case costs no test. Stops when the scan is
    /// full or after a frame the sink had no slot for. Returns the points taken and how
    /// many of them were no range.
    #[inline(always)]
    pub fn push_run<T, F, S>(
        &mut self,
        points: &[T],
        code: F,
        misses: &Cell<u32>,
        out: &mut Out<'_, S>,
    ) -> (usize, usize)
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        // The counters stay below the scan's points (at most 4096), `misses` grows by at
        // most `taken`, `gathered + block_left <= BLOCK_POINTS` and `segment_left` is
        // what the segment has left: nothing here wraps.
        let base = misses.get();
        let mut taken = 0usize;
        let mut rest = points;
        while !rest.is_empty() && out.lost == 0 {
            if self.block_left == 0 {
                // The next point begins a segment, if the scan has one left.
                if self.pushed >= self.point_count {
                    break;
                }
                let Some((first, later)) = rest.split_first() else {
                    break;
                };
                let (d, i) = code(first);
                self.begin_segment(d.min(MAX_VALUE), u32::from(i), out);
                if self.block_left == 0 {
                    self.end_segment(misses.get().wrapping_sub(base), out);
                }
                rest = later;
                taken = taken.wrapping_add(1);
                continue;
            }
            let room = self.block_left.min(rest.len());
            let (now, later) = rest.split_at(room);
            let at = self.gathered;
            let end = at.wrapping_add(room);
            let (Some(dd), Some(ii)) = (self.d.v.get_mut(at..end), self.i.get_mut(at..end)) else {
                break;
            };
            // Without the intensity channel the loop neither computes nor stores any.
            if self.intensity {
                gather::<true, _, _>(now, &code, dd, ii);
            } else {
                gather::<false, _, _>(now, &code, dd, ii);
            }
            self.gathered = end;
            self.block_left = self.block_left.wrapping_sub(room);
            taken = taken.wrapping_add(room);
            rest = later;
            if self.block_left == 0 {
                self.put_blocks(out);
                if self.segment_left == 0 {
                    self.end_segment(misses.get().wrapping_sub(base), out);
                } else {
                    self.next_block();
                }
            }
        }
        // The run's full frames (classic CAN gathers them): every frame due is in the
        // sink when the run returns.
        self.w.flush(out);
        let missed = misses.get().wrapping_sub(base);
        self.nonrange = self.nonrange.wrapping_add(missed as u16);
        (taken, missed as usize)
    }

    /// The next block of the segment: at most [`BLOCK_POINTS`] of the points it has left.
    #[inline(always)]
    fn next_block(&mut self) {
        self.block_left = self.segment_left.min(BLOCK_POINTS);
        self.segment_left = self.segment_left.wrapping_sub(self.block_left);
    }

    /// Begin a segment with its first point, the anchor `d` (and `i`).
    #[cold]
    fn begin_segment<S: FrameSink + ?Sized>(&mut self, d: u32, i: u32, out: &mut Out<'_, S>) {
        let index = usize::from(self.pushed) / SEGMENT_POINTS;
        // The anchor is one of the segment's points (at least one: the scan is not full).
        self.pushed = self.pushed.wrapping_add(1);
        self.segment_left = segment_points(usize::from(self.point_count), index).saturating_sub(1);
        self.next_block();
        self.w.begin_segment(self.seq_low, index as u8, out);
        self.w.put(
            width(d) | d << WIDTH_BITS,
            WIDTH_BITS.wrapping_add(width(d)),
            out,
        );
        self.hd = History::anchor(d);
        if self.intensity {
            self.w.put(
                width(i) | i << WIDTH_BITS,
                WIDTH_BITS.wrapping_add(width(i)),
                out,
            );
            self.hi = History::anchor(i);
        }
        self.gathered = 0;
    }

    fn put_blocks<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        let n = self.gathered;
        put_block(&mut self.d, n, &mut self.hd, &mut self.w, out);
        if self.intensity {
            self.d.v = self.i;
            put_block(&mut self.d, n, &mut self.hi, &mut self.w, out);
        }
        // At most the scan's points: no wrap.
        self.pushed = self.pushed.wrapping_add(n as u16);
        self.gathered = 0;
    }

    /// End the segment; `missed` codes that are no range among the run's points so far.
    fn end_segment<S: FrameSink + ?Sized>(&mut self, missed: u32, out: &mut Out<'_, S>) {
        if self.gathered > 0 {
            self.put_blocks(out);
        }
        let crc = self.w.end_segment(out);
        self.crc.bytes(&crc.to_le_bytes());
        self.sent = self.pushed;
        // At most `pushed` points are no range: no wrap.
        self.valid_sent = self
            .pushed
            .wrapping_sub(self.nonrange.wrapping_add(missed as u16));
        self.block_left = 0;
        self.segment_left = 0;
    }
}
