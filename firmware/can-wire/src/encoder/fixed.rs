//! The fixed-width encodings' runs (D16, D14, D12 with or without intensity): the
//! dispatch to a loop compiled per frame kind and width, the CAN FD run, coding a block of
//! points, and flushing a data frame. Classic frames are framed in `classic`.

use super::{FrameSink, InProgress, RangeRule, Run, RunStop, ScanEncoder, BLOCK};
use crate::data::{data_frame_len, DataHeader, DATA_HEADER_LEN};
use crate::encoding::Distance;
use crate::frame::Frame;
use crate::header::put;
use crate::Error;

impl ScanEncoder {
    /// [`Self::run_with`] (CAN FD, `CLASSIC` false) or [`Self::run_classic_with`] for
    /// `DB`-bit distances and `IB`-bit intensities compiled in; `DB` = 0 takes the widths
    /// `db` and `ib` as values instead (one loop for the rarer encodings).
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_fixed<const CLASSIC: bool, const DB: u32, const IB: u32, T, F, S>(
        &mut self,
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
        let (db, ib) = if DB == 0 { (db, ib) } else { (DB, IB) };
        if CLASSIC {
            self.run_classic_with(DB != 0, db, ib, points, rule, point, sink)
        } else {
            self.run_with(db, ib, points, rule, point, sink)
        }
    }

    /// [`ScanEncoder::push_run`] for CAN FD frames with `DB`-bit distances and `IB`-bit
    /// intensities: points are coded a block at a time ([`code_block`]), then packed.
    #[inline(always)]
    pub(super) fn run_with<T, F, S>(
        &mut self,
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
        let fd = self.format.is_fd();
        let codes_buf = &mut self.codes;
        let s = self.open.fixed_mut().ok_or(Error::NoScan)?;
        let mut run = Run::default();
        let (count, capacity) = (s.header.point_count, s.capacity);
        // The arithmetic below counts points of one scan (at most 4096, a u16) and the
        // frames they make: `valid + invalid <= block <= BLOCK`, `j <= block`, the
        // counters of the scan below its point count and those of the run below the
        // run's points. Nothing wraps, and the wrapping ops compile to the plain ones.
        let bits = db.wrapping_add(ib);
        let mut rest = points;
        loop {
            let left = rest.len();
            if left == 0 {
                break;
            }
            if s.pushed >= count {
                run.stop = Some(RunStop::TooManyPoints);
                break;
            }
            let block = left
                .min(BLOCK)
                .min(usize::from(count.wrapping_sub(s.pushed)));
            let (now, later) = rest.split_at(block);
            rest = later;
            let (mut valid, mut invalid, mut rejected) =
                code_block_any(ib, now, rule, point, s, codes_buf);
            let mut j = 0;
            while j < block {
                // Points until a frame is due: the frame is full or the scan's last is in.
                let room = capacity
                    .saturating_sub(s.buffered)
                    .min(count.saturating_sub(s.pushed));
                let k = usize::from(room).min(block.wrapping_sub(j));
                let codes = codes_buf.get(j..j.wrapping_add(k)).unwrap_or(&[]);
                let whole = (bits / 8) as usize;
                // 16-bit distances alone (a 16-bit field has no other): the CRC and the
                // bytes in one pass.
                let d16 = whole == 2 && db == 16;
                if !d16 {
                    s.crc.point_codes(codes, ib > 0);
                }
                if bits % 8 == 0 {
                    // Whole bytes per point: straight into their place, no bit position.
                    let Some(bytes) = s.packer.take_bytes(k.saturating_mul(whole)) else {
                        return Err(Error::FrameTooLong);
                    };
                    // A field's length known at compile time: a store or two per
                    // point, not a `memcpy` call of a length known at run time.
                    match whole {
                        2 if d16 => s.crc.codes16_into(codes, bytes),
                        2 => put_fields::<2>(codes, bytes, db),
                        3 => put_fields::<3>(codes, bytes, db),
                        4 => put_fields::<4>(codes, bytes, db),
                        _ => {
                            for (&code, out) in codes.iter().zip(bytes.chunks_exact_mut(whole)) {
                                let word = (code & 0xFFFF) | (code >> 16) << db;
                                if let Some(field) = word.to_le_bytes().get(..whole) {
                                    out.copy_from_slice(field);
                                }
                            }
                        }
                    }
                } else {
                    for &code in codes {
                        s.packer.put_point(code & 0xFFFF, code >> 16, db, ib);
                    }
                }
                // k <= room, a u16.
                let k16 = k as u16;
                s.pushed = s.pushed.wrapping_add(k16);
                s.buffered = s.buffered.wrapping_add(k16);
                j = j.wrapping_add(k);
                if usize::from(room) != k {
                    continue;
                }
                let slot = sink.data_slot();
                let lost = slot.is_none();
                match slot {
                    Some(frame) => flush(s, id, fd, frame)?,
                    None => flush(s, id, fd, &mut Frame::default())?,
                }
                if lost {
                    let rest = codes_buf.get(j..block).unwrap_or(&[]);
                    let (v, i) = untake(s, rest);
                    // The untaken points are among the block's counted ones.
                    valid = valid.wrapping_sub(v);
                    invalid = invalid.wrapping_sub(i);
                    let given_back = now.get(j..).unwrap_or(&[]);
                    rejected = rejected.wrapping_sub(count_rejected(&rule, given_back, point));
                    run.rejected = run.rejected.wrapping_add(rejected);
                    s.valid = s.valid.wrapping_add(valid);
                    run.points = run.points.wrapping_add(j as u32);
                    run.invalid = run.invalid.wrapping_add(invalid);
                    run.stop = Some(RunStop::NoSlot);
                    return Ok(run);
                }
                run.frames = run.frames.wrapping_add(1);
            }
            s.valid = s.valid.wrapping_add(valid);
            run.points = run.points.wrapping_add(block as u32);
            run.invalid = run.invalid.wrapping_add(invalid);
            run.rejected = run.rejected.wrapping_add(rejected);
        }
        Ok(run)
    }
}

/// `codes` (distance code in the low 16 bits, intensity above) as `N`-byte fields into
/// `bytes`, little endian: the distance code, then the intensity code from bit `db`.
#[inline(always)]
fn put_fields<const N: usize>(codes: &[u32], bytes: &mut [u8], db: u32) {
    for (&code, out) in codes.iter().zip(bytes.chunks_exact_mut(N)) {
        // A field has at most 32 bits (`db` plus the intensity's width).
        let word = (code & 0xFFFF) | (code >> 16) << db;
        if let (Some(out), Some(field)) = (
            out.first_chunk_mut::<N>(),
            word.to_le_bytes().first_chunk::<N>(),
        ) {
            *out = *field;
        }
    }
}

/// The points of `points` whose distance `rule`'s window rejects (points given back
/// after a lost frame).
#[cold]
pub(super) fn count_rejected<T, F: Fn(&T) -> (u32, u16)>(
    rule: &RangeRule,
    points: &[T],
    point: &F,
) -> u32 {
    let n = points.iter().filter(|p| rule.rejects(point(p).0)).count();
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// [`code_block`] for an intensity width given as a value: a loop of its own without
/// intensity, one loop for the intensity widths ([`code_block_cut`]).
#[inline(always)]
pub(super) fn code_block_any<T, F: Fn(&T) -> (u32, u16)>(
    ib: u32,
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    match ib {
        0 => {
            // A whole checked run (`push_checked_run`) in 1 mm units: tested here, in
            // the run, so that `code_block`'s general loop keeps its set-up.
            let (len, zeros) = s.checked;
            if let Some(zeros) = zeros.filter(|_| len == points.len()) {
                if let Some(counts) = checked_block(points, point, s, zeros, codes) {
                    return counts;
                }
            }
            code_block::<0, T, F>(points, rule, point, s, codes)
        }
        // Three arms for one call: as a two-way test the CAN FD run's loop around it
        // compiled to more instructions per point (measured, D16 on CAN FD).
        8 => code_block_cut(points, rule, point, s, codes),
        12 => code_block_cut(points, rule, point, s, codes),
        _ => code_block_cut(points, rule, point, s, codes),
    }
}

/// [`code_block`] for the intensity widths 8, 12 and 16: they share the 16-bit loop,
/// each intensity cut to its top `ib` bits before it (`u16 >> (16 - ib)`,
/// [`InProgress`]'s `intensity_shift`: 8, 4 or 0), which is the code a loop for `ib`
/// bits makes (`u32::from(intensity) >> (16 - ib)`). One loop instead of three (about
/// 1.4 KB of M4 code); these rarer encodings pay a call per block.
#[inline(never)]
fn code_block_cut<T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    let shift = s.intensity_shift;
    let cut = |p: &T| {
        let (d, intensity) = point(p);
        // shift = 16 - ib, 0..=8.
        (d, intensity.checked_shr(shift).unwrap_or(0))
    };
    code_block::<16, T, _>(points, rule, &cut, s, codes)
}

/// Codes `points` (at most [`BLOCK`]) into `codes`: per point its distance code in the
/// low 16 bits and its intensity code (`IB` bits) above. Returns the valid distance codes,
/// the points that are no range (as `rule` says) and those of them that were ranges
/// outside the rule's window. Kept out of line: in a function of
/// its own the loop keeps its counters and constants in registers; the usual cases (no
/// error code above DMIN, 1 mm units) get loops of their own.
#[inline(never)]
pub(super) fn code_block<const IB: u32, T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    if s.coder.is_mm() && rule.min > 0 && rule.min <= s.coder.max_code() {
        return code_mm::<IB, T, F>(points, rule, point, s, codes);
    }
    code_points::<IB, T, F>(points, rule, point, s, codes)
}

/// The whole of a checked run (`push_checked_run`, `zeros` its points without a range)
/// without intensities: in 1 mm units each distance is its own code, when their OR
/// says that none is at or past the out-of-range code; then the block's counts, else
/// `None` (the caller codes the block by the general rule, over what this wrote). In
/// each run's loop, apart from `code_block` (whose general loop keeps its set-up): out
/// of line, its call cost the filtered lines about 30 instructions each (measured).
#[inline(always)]
fn checked_block<T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    point: &F,
    s: &InProgress,
    zeros: u32,
    codes: &mut [u32],
) -> Option<(u16, u32, u32)> {
    if !s.coder.is_mm() {
        return None;
    }
    let any = copy_checked(points, point, codes);
    // `points` is at most a block's points, the caller's zeros among them (if it is
    // right: else the counts are wrong, nothing else).
    (any < s.coder.max_code()).then(|| ((points.len() as u32).wrapping_sub(zeros) as u16, zeros, 0))
}

/// The distances of a whole checked run ([`ScanEncoder::push_checked_run`]: the rule
/// [`RangeRule::at_least`]`(1)`) without intensities into `codes` in 1 mm units, each as
/// its own code, no test per point; returns their OR. When that is below the
/// out-of-range code, so is every distance: each point's code is then right (a range
/// as itself, 0 as no range); otherwise (a range may be at or past the out-of-range
/// code, to be coded so) the caller codes the block by the general rule, over what
/// this wrote. Two points a turn.
///
/// [`ScanEncoder::push_checked_run`]: super::ScanEncoder::push_checked_run
#[inline(always)]
fn copy_checked<T, F: Fn(&T) -> (u32, u16)>(points: &[T], point: &F, codes: &mut [u32]) -> u32 {
    // The codes of the points (the FD run gives the whole buffer), pairs of both; too
    // few codes (never: a block fits the buffer) go the general way.
    let Some(codes) = codes.get_mut(..points.len()) else {
        return u32::MAX;
    };
    let mut any = 0u32;
    let mut pairs = codes.chunks_exact_mut(2);
    let mut from = points.chunks_exact(2);
    (&mut pairs).zip(&mut from).for_each(|(c, p)| {
        if let ([c0, c1], [p0, p1]) = (c, p) {
            let (d0, d1) = (point(p0).0, point(p1).0);
            any |= d0 | d1;
            *c0 = d0;
            *c1 = d1;
        }
    });
    if let ([out], [p]) = (pairs.into_remainder(), from.remainder()) {
        let d = point(p).0;
        any |= d;
        *out = d;
    }
    any
}

/// The loop of [`code_block`] for the usual cases: the unit is 1 mm and `rule.min` is
/// not 0 and below the out-of-range code. The distances from DMIN (and the window's
/// start) below the rule's first error code, band, the window's end and the
/// out-of-range code are ranges coded as they are, found by one test; those below
/// DMIN (the sensor's error codes for no echo: several per cent of a real scan's
/// points) are no range, found by a second; the others take the full test
/// ([`slow_code`], out of line: one copy for every loop). An empty span sends every
/// distance from DMIN on that way.
#[inline(always)]
fn code_mm<const IB: u32, T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    let max = s.coder.max_code();
    let [a, b] = rule.except;
    let [lo, hi] = rule.window;
    let first = a
        .min(b)
        .min(rule.band.unwrap_or(u32::MAX))
        .min(max)
        .min(hi.saturating_add(1));
    let low = rule.min.max(lo);
    let plain = first.saturating_sub(low);
    let (mut flags, mut n) = ([0u32; 3], 0u32);
    for (code, p) in codes.iter_mut().zip(points) {
        let (d, intensity) = point(p);
        let dc = if d.wrapping_sub(low) < plain {
            d
        } else if d < rule.min {
            // A sensor's error code (no echo, too near ...): no range, found without
            // the full test. Counts of at most a block's points: no wrap.
            flags[0] = flags[0].wrapping_add(1);
            0
        } else {
            let (dc, k) = slow_code(&rule, d, max);
            // Counts of at most a block's points: no wrap.
            for (f, bit) in flags.iter_mut().zip(0u32..) {
                *f = f.wrapping_add((k >> bit) & 1);
            }
            dc
        };
        n = n.wrapping_add(1);
        *code = if IB > 0 {
            // IB is an intensity code width, 8..=16 here.
            dc | (u32::from(intensity) >> 16u32.wrapping_sub(IB)) << 16
        } else {
            dc
        };
    }
    let [invalid, over, rejected] = flags;
    // n <= BLOCK; the points at or past the out-of-range code counted are ranges.
    let valid = n.wrapping_sub(invalid).wrapping_sub(over) as u16;
    (valid, invalid, rejected)
}

/// The distance code (1 mm units) of a raw distance `d` outside [`code_mm`]'s span, and
/// what it is: bit 0 no range, bit 1 a range at or past the out-of-range code `max`,
/// bit 2 a range the window rejects.
#[inline(never)]
fn slow_code(rule: &RangeRule, d: u32, max: u32) -> (u32, u32) {
    let [lo, hi] = rule.window;
    let sensor = rule.is_sensor_range(d);
    let outside = d < lo || d > hi;
    let is_range = sensor && !outside;
    // Ranges (at least `min`, so never 0 mm) at or past the out-of-range code are
    // coded so.
    let dc = if is_range { d.min(max) } else { 0 };
    let k = u32::from(!is_range)
        | u32::from(is_range && d >= max) << 1
        | u32::from(sensor && outside) << 2;
    (dc, k)
}

/// The loop of [`code_block`] for any rule and unit.
#[inline(always)]
fn code_points<const IB: u32, T, F: Fn(&T) -> (u32, u16)>(
    points: &[T],
    rule: RangeRule,
    point: &F,
    s: &InProgress,
    codes: &mut [u32],
) -> (u16, u32, u32) {
    let coder = s.coder;
    let (mut valid, mut invalid, mut rejected) = (0u16, 0u32, 0u32);
    for (code, p) in codes.iter_mut().zip(points) {
        let (raw, intensity) = point(p);
        let distance = rule.distance(raw);
        let (dc, is_valid) = coder.code_valid(distance);
        // Counts of at most a block's points: no wrap.
        invalid = invalid.wrapping_add(u32::from(distance == Distance::Invalid));
        rejected = rejected.wrapping_add(u32::from(
            distance == Distance::Invalid && rule.rejects(raw),
        ));
        valid = valid.wrapping_add(u16::from(is_valid));
        *code = if IB > 0 {
            // IB is an intensity code width, 8..=16 here.
            u32::from(dc) | (u32::from(intensity) >> 16u32.wrapping_sub(IB)) << 16
        } else {
            u32::from(dc)
        };
    }
    (valid, invalid, rejected)
}

/// The valid distance codes and the points that were no range among `codes` (of points
/// a lost frame left untaken, to be given back).
#[cold]
pub(super) fn untake(s: &InProgress, codes: &[u32]) -> (u16, u32) {
    let (mut valid, mut invalid) = (0u16, 0u32);
    for &code in codes {
        let dc = code as u16;
        // Counts of at most a block's points: no wrap.
        valid = valid.wrapping_add(u16::from(s.coder.is_valid(dc)));
        invalid = invalid.wrapping_add(u32::from(dc == 0));
    }
    (valid, invalid)
}

/// The buffered points of `s` as a data frame with identifier `id`, written into `out`.
/// Never inlined: the runs and the point path ([`ScanEncoder::flush_into`]) share it.
#[inline(never)]
pub(super) fn flush(
    s: &mut InProgress,
    id: embedded_can::Id,
    fd: bool,
    out: &mut Frame,
) -> Result<(), Error> {
    let len = if s.buffered == s.capacity {
        s.full_len
    } else {
        data_frame_len(&s.header.encoding, usize::from(s.buffered)).ok_or(Error::FrameTooLong)?
    };
    let dh = DataHeader {
        first_index: s.sent,
        seq_low: (s.header.seq & 0xF) as u8,
    };
    put(s.packer.bytes_mut(), 0..DATA_HEADER_LEN, &dh.emit());
    // Both count points of the scan (at most 4096 together): no wrap.
    s.sent = s.sent.wrapping_add(s.buffered);
    s.buffered = 0;
    let done = out.set(
        id,
        s.packer.frame_bytes(len).ok_or(Error::FrameTooLong)?,
        fd,
    );
    s.packer.reset(DATA_HEADER_LEN);
    done
}
