//! The sender's state for one scan in the lossless coding: points in, segments of data
//! frames out, and the scan CRC over the headers and the segments' CRCs.

use super::bits::{Out, Writer};
use super::block::{put_block, width, History, Scratch};
use super::code;
use super::{segment_points, BLOCK_POINTS, MAX_VALUE, SEGMENT_POINTS, WIDTH_BITS};
use crate::crc::ScanCrc;
use crate::encoder::FrameSink;
use crate::Error;

/// One scan being coded.
#[derive(Debug, Clone)]
pub struct ScanStream {
    w: Writer,
    seq_low: u8,
    point_count: u16,
    intensity: bool,
    /// Points taken so far.
    pushed: u16,
    /// Points of the segments ended so far (sent whole).
    sent: u16,
    /// Range codes among the points taken, and among those sent.
    valid: u16,
    valid_sent: u16,
    /// Position of the next point in its segment (0: the next point is an anchor).
    in_segment: usize,
    /// Points in the segment being coded.
    segment_len: usize,
    /// The block being gathered.
    d: [u32; BLOCK_POINTS],
    i: [u32; BLOCK_POINTS],
    gathered: usize,
    hd: History,
    hi: History,
    scratch: Scratch,
    /// Headers, then each segment's CRC.
    crc: ScanCrc,
}

/// The codes of `points` into `d` (and `i` if `INTENSITY`); returns how many are ranges.
#[inline(always)]
fn gather<const INTENSITY: bool, T, F>(
    points: &[T],
    code: &F,
    d: &mut [u32],
    i: &mut [u32],
) -> usize
where
    F: Fn(&T) -> (u32, u16),
{
    let mut valid = 0usize;
    for ((p, d), i) in points.iter().zip(d.iter_mut()).zip(i.iter_mut()) {
        let (dc, ic) = code(p);
        *d = dc;
        if INTENSITY {
            *i = u32::from(ic);
        }
        // At most the run's length: no wrap.
        valid = valid.wrapping_add(usize::from(dc >= code::RANGE_BASE));
    }
    valid
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
            valid: 0,
            valid_sent: 0,
            in_segment: 0,
            segment_len: 0,
            d: [0; BLOCK_POINTS],
            i: [0; BLOCK_POINTS],
            gathered: 0,
            hd: History::default(),
            hi: History::default(),
            scratch: Scratch::default(),
            crc: ScanCrc::new(a, b),
        }
    }

    /// Points taken so far.
    pub fn pushed(&self) -> u16 {
        self.pushed
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
        self.pushed >= self.point_count
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
        if self.pushed >= self.point_count {
            return Err(Error::TooManyPoints);
        }
        self.push_run(&[(distance.min(MAX_VALUE), intensity)], |p| *p, out);
        Ok(())
    }

    /// Take `points` in order, each turned by `code` into its distance code (at most
    /// [`MAX_VALUE`]: the caller's guarantee, not checked per point) and intensity code, like [`ScanStream::push`] for each but a block
    /// at a time. Stops when the scan is full or after a frame the sink had no slot for.
    /// Returns the points taken and how many of them were no range.
    #[inline(always)]
    pub fn push_run<T, F, S>(
        &mut self,
        points: &[T],
        code: F,
        out: &mut Out<'_, S>,
    ) -> (usize, usize)
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        // The counters stay below the scan's points (at most 4096), `ranges <= taken`,
        // `gathered < BLOCK_POINTS` and `in_segment < segment_len` at the top of the
        // loop (a full block or segment is sent at once): nothing here wraps.
        let (mut taken, mut ranges) = (0usize, 0usize);
        let mut rest = points;
        while !rest.is_empty() && self.pushed < self.point_count && out.lost == 0 {
            if self.in_segment == 0 {
                let Some((first, later)) = rest.split_first() else {
                    break;
                };
                let (d, i) = code(first);
                let d = d.min(MAX_VALUE);
                ranges = ranges.wrapping_add(usize::from(code::is_range(d)));
                self.valid = self.valid.wrapping_add(u16::from(code::is_range(d)));
                self.pushed = self.pushed.wrapping_add(1);
                self.begin_segment(d, u32::from(i), out);
                if self.in_segment >= self.segment_len {
                    self.end_segment(out);
                }
                rest = later;
                taken = taken.wrapping_add(1);
                continue;
            }
            let left = usize::from(self.point_count.wrapping_sub(self.pushed));
            let room = BLOCK_POINTS
                .wrapping_sub(self.gathered)
                .min(self.segment_len.wrapping_sub(self.in_segment))
                .min(rest.len())
                .min(left);
            let (now, later) = rest.split_at(room);
            let at = self.gathered;
            let end = at.wrapping_add(room);
            let (Some(dd), Some(ii)) = (self.d.get_mut(at..end), self.i.get_mut(at..end)) else {
                break;
            };
            // Without the intensity channel the loop neither computes nor stores any.
            let valid = if self.intensity {
                gather::<true, _, _>(now, &code, dd, ii)
            } else {
                gather::<false, _, _>(now, &code, dd, ii)
            };
            ranges = ranges.wrapping_add(valid);
            self.valid = self.valid.wrapping_add(valid as u16);
            self.pushed = self.pushed.wrapping_add(room as u16);
            self.gathered = self.gathered.wrapping_add(room);
            self.in_segment = self.in_segment.wrapping_add(room);
            taken = taken.wrapping_add(room);
            rest = later;
            if self.gathered == BLOCK_POINTS {
                self.put_blocks(out);
            }
            if self.in_segment >= self.segment_len {
                self.end_segment(out);
            }
        }
        (taken, taken.wrapping_sub(ranges))
    }

    #[cold]
    fn begin_segment<S: FrameSink + ?Sized>(&mut self, d: u32, i: u32, out: &mut Out<'_, S>) {
        // Called after the segment's first point was counted: `pushed >= 1`.
        let index = usize::from(self.pushed.wrapping_sub(1)) / SEGMENT_POINTS;
        self.segment_len = segment_points(usize::from(self.point_count), index);
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
        self.in_segment = 1;
        self.gathered = 0;
    }

    fn put_blocks<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        let n = self.gathered;
        let (w, scratch) = (&mut self.w, &mut self.scratch);
        put_block(
            self.d.get(..n).unwrap_or(&[]),
            &mut self.hd,
            scratch,
            w,
            out,
        );
        if self.intensity {
            put_block(
                self.i.get(..n).unwrap_or(&[]),
                &mut self.hi,
                scratch,
                w,
                out,
            );
        }
        self.gathered = 0;
    }

    fn end_segment<S: FrameSink + ?Sized>(&mut self, out: &mut Out<'_, S>) {
        if self.gathered > 0 {
            self.put_blocks(out);
        }
        let crc = self.w.end_segment(out);
        self.crc.bytes(&crc.to_le_bytes());
        self.sent = self.pushed;
        self.valid_sent = self.valid;
        self.in_segment = 0;
        self.segment_len = 0;
    }
}
