//! The fixed-width run for classic CAN frames: a block of points coded, then framed whole
//! into each frame's 64-bit payload word at shifts known at compile time, with the codes
//! of a frame not yet full kept pending for the next run.

use super::fixed::{code_block_any, count_rejected, untake};
use super::{FrameSink, InProgress, RangeRule, Run, RunStop, ScanEncoder, BLOCK};
use crate::crc::ScanCrc;
use crate::data::{data_frame_len, DATA_HEADER_LEN};
use crate::frame::Frame;
use crate::Error;

impl ScanEncoder {
    /// [`ScanEncoder::push_run`] for classic frames. Points are coded a block at a time
    /// (one data line is one block), then framed: whole frames go into their 64-bit
    /// payload word at shifts known at compile time. The codes of a frame not yet full
    /// at the end of a run wait, uncounted by the CRC, at the front of the code buffer
    /// for the next run (`pending`), so frames that straddle data lines are built whole
    /// too. Only a frame begun by [`ScanEncoder::push_point`] (its points already in the
    /// packer) or the scan's short last frame take their points one by one.
    ///
    /// `known` tells that `db` and `ib` are constants (a loop compiled for them): whole
    /// frames are then written out per point count; otherwise each goes through the
    /// out-of-line [`place_points`], so the general loop is not compiled once per point
    /// count (flash).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_classic_with<T, F, S>(
        &mut self,
        known: bool,
        db: u32,
        ib: u32,
        points: &[T],
        rule: RangeRule,
        point: &F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        let id = self.data_id;
        let codes_buf = &mut self.codes;
        let s = self.open.fixed_mut().ok_or(Error::NoScan)?;
        let mut run = Run::default();
        // As in `run_fd_with`, the arithmetic below counts points of one scan (at most
        // 4096) and frames: `before + k <= cap`, `j <= end = pending + block`, the
        // scan's counters below its point count, the run's below its points, and
        // what is given back was counted before. Nothing wraps.
        let bits = db.wrapping_add(ib);
        // Points in a full classic frame: 48 bits after the data header (a point has
        // at least 12 bits). `begin` made the scan's capacity the same (the classic
        // frame's 6 payload bytes over the point's bits), and a run leaves fewer codes
        // than that pending: neither is checked again per run.
        let cap = 48u32.checked_div(bits).unwrap_or(0) as usize;
        let count = s.header.point_count;
        // The sequence number's bits of every data header, once per run.
        let seq = u32::from(s.header.seq & 0xF) << 12;
        let seq_bits = u64::from(seq);
        let mut crc = s.crc;
        let mut rest = points;
        while !rest.is_empty() {
            if s.pushed >= count {
                run.stop = Some(RunStop::TooManyPoints);
                break;
            }
            let block = rest
                .len()
                .min(BLOCK)
                .min(usize::from(count.wrapping_sub(s.pushed)));
            let (now, later) = rest.split_at(block);
            rest = later;
            // The pending codes, then this block's.
            let p = s.pending;
            let end = p.wrapping_add(block);
            let fresh = codes_buf.get_mut(p..end).unwrap_or(&mut []);
            let (valid, invalid, rejected) = code_block_any(ib, now, rule, point, s, fresh);
            let codes = codes_buf.get(..end).unwrap_or(&[]);
            // The block is taken; a lost frame gives back what follows it.
            let before = usize::from(s.buffered).wrapping_sub(p);
            s.pushed = s.pushed.wrapping_add(block as u16);
            s.buffered = s.buffered.wrapping_add(block as u16);
            s.valid = s.valid.wrapping_add(valid);
            run.points = run.points.wrapping_add(block as u32);
            run.invalid = run.invalid.wrapping_add(invalid);
            run.rejected = run.rejected.wrapping_add(rejected);
            let mut j = 0;
            let mut lost = false;
            if before > 0 {
                let begun = Begun {
                    id,
                    db,
                    ib,
                    cap,
                    before,
                    block,
                    count,
                    seq_bits,
                };
                (j, lost) = begun.go_on(s, codes, &mut crc, sink, &mut run.frames)?;
            }
            // Whole frames, into slots the sink hands out a batch at a time.
            if !lost {
                let whole = codes.get(j..).unwrap_or(&[]);
                // A full frame's length: for widths known at compile time a constant
                // (the header and the points' bytes, at most 8: the scan's `full_len`),
                // so the frame loop keeps no register for it.
                let full_len = if known {
                    DATA_HEADER_LEN.wrapping_add((cap.wrapping_mul(bits as usize)).div_ceil(8))
                } else {
                    s.full_len
                };
                let shape = Frame::classic_shape(full_len);
                // The data header of the next frame: its first index (below the scan's
                // point count, at most 4095: 12 bits) and the sequence number above;
                // each frame's is the one before plus a frame's points.
                let first = u32::from(s.sent & 0x0FFF) | seq;
                let mut header = first;
                let step = cap as u32;
                let mut left = whole;
                while left.len() >= cap {
                    let slots = sink.data_slots(left.len().checked_div(cap).unwrap_or(0));
                    if slots.is_empty() {
                        // No room: the frame is built (its points in the CRC) and lost,
                        // and the scan goes on as if it had been sent.
                        whole_frame(db, ib, left, cap, u64::from(header), &mut crc);
                        header = header.wrapping_add(step);
                        lost = true;
                        break;
                    }
                    // The sink gave at most as many slots as frames are left: each is
                    // written (one loop counter: the zip of two slices). The zip runs
                    // over all of `left`, whose frame count was just asked for (its
                    // length is the smaller of that and `given`: no second division).
                    let given = slots.len();
                    let these = left;
                    left = left.get(given.wrapping_mul(cap)..).unwrap_or(&[]);
                    for (frame, chunk) in slots.iter_mut().zip(these.chunks_exact(cap)) {
                        let h = u64::from(header);
                        let word = if known {
                            whole_frame(db, ib, chunk, cap, h, &mut crc)
                        } else {
                            place_points(db, ib, chunk, h, 16, &mut crc).0
                        };
                        header = header.wrapping_add(step);
                        frame.set_classic_as(id, word.to_le_bytes(), shape);
                    }
                    run.frames = run.frames.wrapping_add(given as u32);
                }
                // Frames sent (or lost) count points of the block: no wrap.
                let framed = header.wrapping_sub(first) as u16;
                j = j.wrapping_add(usize::from(framed));
                s.buffered = s.buffered.wrapping_sub(framed);
                s.sent = s.sent.wrapping_add(framed);
            }
            // The rest: the scan's last frame, or codes pending for the next run.
            let r = end.wrapping_sub(j);
            s.pending = 0;
            // (A frame begun in the packer and not yet due took the whole block: r = 0.)
            if !lost && r > 0 {
                if usize::from(s.sent).wrapping_add(r) == usize::from(count) {
                    let header = u64::from(s.sent & 0x0FFF) | seq_bits;
                    let last = codes.get(j..end).unwrap_or(&[]);
                    let (word, _) = place_points(db, ib, last, header, 16, &mut crc);
                    let len = data_frame_len(&s.header.encoding, r).ok_or(Error::FrameTooLong)?;
                    s.sent = s.sent.wrapping_add(r as u16);
                    s.buffered = 0;
                    j = end;
                    match sink.data_slot() {
                        Some(frame) => {
                            frame.set_classic_as(id, word.to_le_bytes(), Frame::classic_shape(len));
                            run.frames = run.frames.wrapping_add(1);
                        }
                        None => lost = true,
                    }
                } else {
                    // Fewer than a frame's points (`r < cap <= 48 / 12`) to the
                    // front, forwards, in a loop of a constant 4 passes: `copy_within`
                    // would link `memmove`, 1.5 KB of M4 code that nothing else needs.
                    for t in 0..4 {
                        if t < r {
                            let code = codes_buf.get(j.wrapping_add(t)).copied().unwrap_or(0);
                            if let Some(c) = codes_buf.get_mut(t) {
                                *c = code;
                            }
                        }
                    }
                    s.pending = r;
                    j = end;
                }
            }
            if lost {
                // The points after the lost frame are not taken.
                let untaken = codes_buf.get(j..end).unwrap_or(&[]);
                let (v, i) = untake(s, untaken);
                s.valid = s.valid.wrapping_sub(v);
                s.pushed = s.pushed.wrapping_sub(untaken.len() as u16);
                s.buffered = 0;
                run.points = run.points.wrapping_sub(untaken.len() as u32);
                run.invalid = run.invalid.wrapping_sub(i);
                // The block's points given back (codes pending from the last run that
                // are given back were counted by it).
                let given_back = now.get(j.saturating_sub(p)..).unwrap_or(&[]);
                run.rejected = run
                    .rejected
                    .saturating_sub(count_rejected(&rule, given_back, point));
                s.crc = crc;
                run.stop = Some(RunStop::NoSlot);
                return Ok(run);
            }
        }
        s.crc = crc;
        Ok(run)
    }
}

/// A frame begun by `push_point` (its points in the packer) that a classic run goes on
/// with: what the run knows of it.
struct Begun {
    id: embedded_can::Id,
    db: u32,
    ib: u32,
    /// Points in a full frame.
    cap: usize,
    /// The frame's points in the packer (at least 1).
    before: usize,
    /// The run's block of points (nothing is pending before them).
    block: usize,
    /// The scan's point count.
    count: u16,
    /// The sequence number's bits of a data header.
    seq_bits: u64,
}

impl Begun {
    /// The frame's next points (from the front of `codes`) one by one, sent if that makes
    /// it due; returns the points taken and whether the frame was lost (no slot). Out
    /// of line and cold: a run meets such a frame only where point-by-point pushing
    /// and runs take turns within a scan, and the runs' usual path keeps its registers.
    /// With the `compact` feature (one classic run, flash first) it is inlined: its own
    /// copy, with the code it inlines, took about 240 bytes more than it saved there.
    #[cfg_attr(not(feature = "compact"), cold, inline(never))]
    #[cfg_attr(feature = "compact", inline(always))]
    fn go_on<S: FrameSink + ?Sized>(
        self,
        s: &mut InProgress,
        codes: &[u32],
        crc: &mut ScanCrc,
        sink: &mut S,
        frames: &mut u32,
    ) -> Result<(usize, bool), Error> {
        let Begun {
            id,
            db,
            ib,
            cap,
            before,
            block,
            count,
            seq_bits,
        } = self;
        // Counts of one frame's points (at most 4) and bits (at most 48 + 16): no wrap.
        let k = cap.wrapping_sub(before).min(block);
        let at = (before as u32)
            .wrapping_mul(db.wrapping_add(ib))
            .wrapping_add(16);
        let word = s.packer.word64() & !0xFFFF & (u64::MAX >> 64u32.wrapping_sub(at.min(64)));
        let taking = codes.get(..k).unwrap_or(&[]);
        let (mut word, at) = place_points(db, ib, taking, word, at, crc);
        let n = before.wrapping_add(k);
        if n == cap || usize::from(s.sent).wrapping_add(n) == usize::from(count) {
            let len = if n == cap {
                s.full_len
            } else {
                data_frame_len(&s.header.encoding, n).ok_or(Error::FrameTooLong)?
            };
            word |= u64::from(s.sent & 0x0FFF) | seq_bits;
            s.packer.reset(DATA_HEADER_LEN);
            s.sent = s.sent.wrapping_add(n as u16);
            s.buffered = s.buffered.wrapping_sub(n as u16);
            match sink.data_slot() {
                Some(frame) => {
                    frame.set_classic_as(id, word.to_le_bytes(), Frame::classic_shape(len));
                    *frames = frames.wrapping_add(1);
                }
                None => return Ok((k, true)),
            }
        } else {
            s.packer.set_word64(word, at);
        }
        Ok((k, false))
    }
}

/// `codes` (distance code in the low 16 bits, intensity above) put one by one into the
/// classic payload `word` from bit `at` on, their codes into `crc`; returns the word and
/// the bit after them.
fn place_points(
    db: u32,
    ib: u32,
    codes: &[u32],
    mut word: u64,
    mut at: u32,
    crc: &mut ScanCrc,
) -> (u64, u32) {
    for &code in codes {
        crc.point_code(code, ib > 0);
        word |= (u64::from(code & 0xFFFF) | u64::from(code >> 16) << db) << (at & 63);
        // At most 4 points of at most 32 bits after 16: no wrap.
        at = at.wrapping_add(db).wrapping_add(ib);
    }
    (word, at)
}

/// The payload word of a whole classic frame of `n` points (1 to 4; `header` in its
/// low 16 bits) from the first `n` of `codes` (distance code in the low 16 bits,
/// intensity above), their codes into `crc`; the header alone when fewer than `n` codes
/// are there or `n` is out of range (the callers give `n` codes, `n` the capacity of
/// 1 to 4). Written out per `n`, so every point goes in at a shift known at compile
/// time.
#[inline(always)]
fn whole_frame(db: u32, ib: u32, codes: &[u32], n: usize, header: u64, crc: &mut ScanCrc) -> u64 {
    whole_points(db, ib, codes, n, crc).map_or(header, |word| header | word)
}

/// The points of [`whole_frame`], `None` for what it takes as the header alone.
#[inline(always)]
fn whole_points(db: u32, ib: u32, codes: &[u32], n: usize, crc: &mut ScanCrc) -> Option<u64> {
    let mut add = |code: u32| crc.point_code(code, ib > 0);
    // Point `i` of the frame, in place.
    let place = |code: u32, i: u32| {
        // At most 4 points of at most 32 bits: no wrap.
        let at = i.wrapping_mul(db.wrapping_add(ib)).wrapping_add(16);
        // Without the channel a point is its distance code alone (a loop compiled for
        // the widths then puts it with one shift, not a second for the intensity).
        let field = if ib == 0 {
            u64::from(code & 0xFFFF)
        } else {
            u64::from(code & 0xFFFF) | u64::from(code >> 16) << db
        };
        field << at
    };
    let word = match n {
        1 => {
            let &[a] = codes.first_chunk::<1>()?;
            add(a);
            place(a, 0)
        }
        2 => {
            let &[a, b] = codes.first_chunk::<2>()?;
            add(a);
            add(b);
            place(a, 0) | place(b, 1)
        }
        3 => {
            let &[a, b, c] = codes.first_chunk::<3>()?;
            add(a);
            add(b);
            add(c);
            place(a, 0) | place(b, 1) | place(c, 2)
        }
        4 => {
            let &[a, b, c, d] = codes.first_chunk::<4>()?;
            add(a);
            add(b);
            add(c);
            add(d);
            place(a, 0) | place(b, 1) | place(c, 2) | place(d, 3)
        }
        _ => return None,
    };
    Some(word)
}
