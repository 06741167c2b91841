//! The lossless coding's path: a scan's points coded into its segment stream (SPEC 8), and
//! its trailer.

use super::{Emitted, FrameSink, RangeRule, Run, RunStop, ScanEncoder};
use crate::header::ScanHeader;
use crate::id::Kind;
use crate::lossless::bits::Out;
use crate::lossless::code;
use crate::lossless::stream::ScanStream;
use crate::trailer::{Trailer, TrailerFlags};
use crate::Error;

/// The most range units a lossless distance code carries.
const MAX_RANGE_UNITS: u32 = crate::lossless::MAX_VALUE - code::RANGE_BASE;

/// A scan in the lossless coding: its header and its segment stream.
#[derive(Debug, Clone)]
pub(super) struct Lossless {
    pub(super) header: ScanHeader,
    pub(super) stream: ScanStream,
}

/// The lossless distance code of raw distance `d` as `rule` classifies it, ranges in
/// units of `2^e` mm, and whether it is a range the rule's window rejects: the full
/// test, for the distances outside the span a run codes without one (error codes, the
/// band, too long ones, those outside the window).
#[cold]
#[inline(never)]
fn lossless_code(rule: &RangeRule, d: u32, e: u32) -> (u32, bool) {
    let e = e & 0xF;
    if rule.rejects(d) {
        // A range the window takes away has no sensor value.
        return (code::INVALID, true);
    }
    if !rule.is_range(d) {
        return (code::error_code(d), false);
    }
    let q = d.saturating_add((1u32 << e) >> 1) >> e;
    if q <= MAX_RANGE_UNITS {
        (q.wrapping_add(code::RANGE_BASE), false) // q <= MAX_RANGE_UNITS: no wrap
    } else {
        (code::OUT_OF_RANGE, false)
    }
}

impl ScanEncoder {
    /// [`ScanEncoder::push_run`] of a lossless scan: each point's codes into the scan's
    /// segment stream.
    pub(super) fn run_lossless<T, F, S>(
        &mut self,
        points: &[T],
        rule: RangeRule,
        point: &F,
        sink: &mut S,
    ) -> Result<Run, Error>
    where
        F: Fn(&T) -> (u32, u16),
        S: FrameSink + ?Sized,
    {
        let l = self.open.lossless_mut().ok_or(Error::NoScan)?;
        let enc = l.header.encoding;
        let mut out = Out::new(sink, self.ids.id(Kind::Data), self.format.is_fd());
        // The per-point work with every constant worked out once: the rule's band, the
        // unit's rounding, the intensity code as a shift and a mask (none: mask 0).
        let (min, [a, b]) = (rule.min, rule.except);
        let e = u32::from(enc.unit_exp & 0xF);
        let half = (1u32 << e) >> 1;
        let ishift = 16u32.wrapping_sub(enc.intensity.bits().min(16));
        let imask = if enc.intensity.is_present() {
            u32::MAX
        } else {
            0
        };
        // The common case in one test: the distances from `min` up to (not including)
        // the first of the rule's error codes, its band and the first distance too long
        // for a code are ranges, coded `(d + half + 128·2^e) >> e` (the rounded units
        // plus the range base) without any further check. An error code or band below
        // `min` leaves the span empty: every distance takes the full test.
        let bias = half.wrapping_add(code::RANGE_BASE << e); // at most 2^14 + 2^22
        let too_long = (u64::from(MAX_RANGE_UNITS) + 1) << e;
        let too_long = too_long
            .saturating_sub(u64::from(half))
            .min(u64::from(u32::MAX.wrapping_sub(bias))) as u32; // bias < 2^23
        let first_other = a.min(b).min(rule.band.unwrap_or(u32::MAX));
        let [lo, hi] = rule.window;
        let low = min.max(lo);
        let span = first_other
            .min(too_long)
            .min(hi.saturating_add(1))
            .saturating_sub(low);
        // The window's rejections are counted off the common path, where the full test
        // finds them (the stream codes exactly the points it takes).
        let rejected = core::cell::Cell::new(0u32);
        let code = |p: &T| {
            let (d, i) = point(p);
            let dc = if d.wrapping_sub(low) < span {
                // d < too_long: d + bias stays below 2^32 and the code below MAX_VALUE.
                d.wrapping_add(bias) >> e
            } else {
                let (dc, out) = lossless_code(&rule, d, e);
                // At most the run's points.
                rejected.set(rejected.get().wrapping_add(u32::from(out)));
                dc
            };
            (dc, ((u32::from(i) >> ishift) & imask) as u16)
        };
        let (taken, invalid) = l.stream.push_run(points, code, &mut out);
        let stop = if out.lost > 0 {
            Some(RunStop::NoSlot)
        } else if taken < points.len() {
            Some(RunStop::TooManyPoints)
        } else {
            None
        };
        Ok(Run {
            points: taken as u32,
            invalid: invalid as u32,
            frames: out.frames,
            stop,
            rejected: rejected.get(),
        })
    }

    /// The trailer of a lossless scan: the points of its whole segments count as sent.
    pub(super) fn finish_lossless(
        &mut self,
        l: Lossless,
        flags: TrailerFlags,
    ) -> Result<Emitted, Error> {
        let sent = l.stream.sent();
        let mut t = Trailer {
            seq: l.header.seq,
            points_sent: sent,
            points_valid: l.stream.valid_sent(),
            flags: TrailerFlags {
                truncated: sent < l.header.point_count,
                ..flags
            },
            crc: 0,
        };
        t.crc = l.stream.crc(&t.emit_head()?);
        let mut out = Emitted::new();
        let f = self.frame(Kind::Trailer, &t.emit()?)?;
        out.push(f).map_err(|_| Error::FrameTooLong)?;
        Ok(out)
    }
}
