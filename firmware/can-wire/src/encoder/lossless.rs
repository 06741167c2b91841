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
use core::cell::Cell;

/// The most range units a lossless distance code carries.
const MAX_RANGE_UNITS: u32 = crate::lossless::MAX_VALUE - code::RANGE_BASE;

/// A scan in the lossless coding: its header and its segment stream.
#[derive(Debug, Clone)]
pub(super) struct Lossless {
    pub(super) header: ScanHeader,
    pub(super) stream: ScanStream,
    /// What a run needs of the scan's encoding, worked out once per scan.
    units: Units,
}

/// The per-point constants of a run that follow from the scan's encoding alone: the
/// unit's shift `e`, the bias `half + 128·2^e` of a range's code (`(d + bias) >> e`),
/// the first distance too long for that (or whose sum with the bias would wrap), and
/// the intensity code as a shift and a mask (none: mask 0).
#[derive(Debug, Clone, Copy)]
struct Units {
    e: u32,
    bias: u32,
    too_long: u32,
    ishift: u32,
    imask: u32,
}

impl Units {
    fn of(enc: &crate::encoding::Encoding) -> Units {
        let e = u32::from(enc.unit_exp & 0xF);
        let half = (1u32 << e) >> 1;
        let bias = half.wrapping_add(code::RANGE_BASE << e); // at most 2^14 + 2^22
                                                             // In 32 bits (no 64-bit shift on the MCU): `(MAX_RANGE_UNITS + 1) << e` is
                                                             // below 2^32 up to e = 12; from 13 on it is past any distance with a bias.
        let too_long = if e <= 12 {
            ((MAX_RANGE_UNITS + 1) << e).saturating_sub(half)
        } else {
            u32::MAX
        };
        let too_long = too_long.min(u32::MAX.wrapping_sub(bias)); // bias < 2^23
        Units {
            e,
            bias,
            too_long,
            ishift: 16u32.wrapping_sub(enc.intensity.bits().min(16)),
            imask: if enc.intensity.is_present() {
                u32::MAX
            } else {
                0
            },
        }
    }
}

impl Lossless {
    /// A lossless scan with `header`, coded into `stream`.
    pub(super) fn new(header: ScanHeader, stream: ScanStream) -> Lossless {
        Lossless {
            units: Units::of(&header.encoding),
            header,
            stream,
        }
    }
}

/// The lossless distance code of raw distance `d` as `rule` classifies it, ranges in
/// units of `2^e` mm, and whether it is a range the rule's window rejects: the full
/// test, for the distances outside the span a run codes without one (error codes, the
/// band, too long ones, those outside the window).
#[cold]
#[inline(never)]
fn lossless_code(rule: &RangeRule, d: u32, e: u32) -> (u32, bool) {
    if d < rule.min.min(code::ERROR_CODES) {
        // The common case here: below `min` (no range, none the window rejects) and
        // below the first value past the sensors' error codes, an error code coded as
        // itself (what the full test below gives it).
        return (d, false);
    }
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
        let id = self.data_id;
        let l = self.open.lossless_mut().ok_or(Error::NoScan)?;
        let mut out = Out::new(sink, id, self.format.is_fd());
        // The per-point work with every constant worked out once: those of the encoding
        // once per scan, the rule's here.
        let (min, [a, b]) = (rule.min, rule.except);
        let Units {
            e,
            bias,
            too_long,
            ishift,
            imask,
        } = l.units;
        // The common case in one test: the distances from `min` up to (not including)
        // the first of the rule's error codes, its band and the first distance too long
        // for a code are ranges, coded `(d + half + 128·2^e) >> e` (the rounded units
        // plus the range base) without any further check. An error code or band below
        // `min` leaves the span empty: every distance takes the full test.
        let first_other = a.min(b).min(rule.band.unwrap_or(u32::MAX));
        let [lo, hi] = rule.window;
        let low = min.max(lo);
        let span = first_other
            .min(too_long)
            .min(hi.saturating_add(1))
            .saturating_sub(low);
        // Points that are no range, and the window's rejections among them: only the
        // full test makes any (the stream codes exactly the points it takes).
        let misses = Cell::new(0u32);
        let rejected = Cell::new(0u32);
        let code = |p: &T| {
            let (d, i) = point(p);
            let dc = if d.wrapping_sub(low) < span {
                // d < too_long: d + bias stays below 2^32 and the code below MAX_VALUE.
                d.wrapping_add(bias) >> e
            } else {
                let (c, out) = lossless_code(&rule, d, e);
                // At most one each per point of the run: no wrap.
                misses.set(misses.get().wrapping_add(u32::from(!code::is_range(c))));
                rejected.set(rejected.get().wrapping_add(u32::from(out)));
                c
            };
            (dc, ((u32::from(i) >> ishift) & imask) as u16)
        };
        let (taken, invalid) = l.stream.push_run(points, code, &misses, &mut out);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding::{DistanceEncoding, Encoding, IntensityEncoding};

    /// The first distance too long for a code, against the same bound worked out in 64
    /// bits from SPEC 4.2's code range, for every unit.
    #[test]
    fn too_long_in_32_bits_for_every_unit() {
        for unit_exp in 0..16u8 {
            let enc = Encoding {
                distance: DistanceEncoding::Lossless,
                intensity: IntensityEncoding::None,
                unit_exp,
            };
            let u = Units::of(&enc);
            let e = u32::from(unit_exp);
            let half = (1u64 << e) >> 1;
            let bias = half + (128u64 << e);
            let want = (((1u64 << 20) - 128) << e)
                .saturating_sub(half)
                .min(u64::from(u32::MAX) - bias);
            assert_eq!(u64::from(u.too_long), want, "unit_exp {unit_exp}");
            assert_eq!(u64::from(u.bias), bias);
        }
    }
}
