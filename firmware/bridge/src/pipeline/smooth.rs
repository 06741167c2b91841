//! Speckle removal and the median over a data line in place, a stage at a time.
//!
//! [`line`] is the window stages of [`super::Pipeline::filter_line`]: the line's readings
//! are classified into cells (no range as [`NONE`]) behind the points the windows still
//! hold from the line before (copied into headroom in front of the line, so that each
//! stage sees one contiguous array), then each stage is one tight loop over the cells,
//! writing each centre's result into its own cell. A loop carries only the ranges just
//! before its centre (which it has overwritten) in registers; the look-ahead is read from
//! the cells, which still hold the stage's input there. The loops are chosen per line,
//! never per point: speckle removal (exact, or a shorter form when no range and no
//! threshold comes near [`NONE`]), median of 3 (branch-free min/max), median of 5 (a
//! selection network when the five are ranges, the general rule otherwise).

use scip::Reading;

use super::window::{median_line, speckle3_line, Regs};
use super::{LineConsts, MedianWidth, Tally};

/// No range, inside a line.
pub(super) const NONE: u32 = u32::MAX;

/// Cells a line needs in front of it for the points the windows hold from the line
/// before (1 for speckle removal, 2 for the median of 5).
pub const LINE_HEADROOM: usize = 3;

/// Ranges and speckle thresholds below this take the short speckle loop: the distance
/// from such a range to [`NONE`] is above any such threshold, so no range is supported
/// by a missing neighbour.
const SMALL: u32 = 1 << 31;

/// Whether `d` is no range or a range below [`SMALL`].
#[inline(always)]
fn small(d: u32) -> bool {
    d.wrapping_add(1) <= SMALL
}

/// The window stages of [`super::Pipeline::filter_line`] (speckle removal and/or the
/// median; the caller has checked that one is on) over the line's readings `input`,
/// with the windows' state `sp` and `md`; `cells` holds at least [`LINE_HEADROOM`]
/// more than `input`. The output points go to the front of `cells`. Returns their
/// number, how many of them have no range (when not decimating: they are then in the
/// encoder's form) and whether the median changed a range.
#[inline(never)]
pub(super) fn line(
    input: &[Reading],
    cells: &mut [Reading],
    k: &LineConsts,
    sp: &mut Regs,
    md: &mut Regs,
    c: &mut Tally,
) -> (usize, usize, bool) {
    let half2 = k.median.map_or(0, MedianWidth::half);
    // The points each window holds, in stream order: the median's, then speckle
    // removal's (the later points), then the line.
    let np1 = if k.jump.is_some() { sp.np.min(1) } else { 0 };
    let np2 = md.np.min(half2);
    let head = np2.wrapping_add(np1);
    let m = input.len();
    let Some(all) = cells.get_mut(..head.wrapping_add(m)) else {
        return (0, 0, false);
    };
    let held = [md.p0, md.p1, sp.p0];
    let slots = [(0, np2 > 0), (1, np2 > 1), (2, np1 > 0)];
    let mut at = 0usize;
    for (i, on) in slots {
        if let (true, Some(cell), Some(p)) = (on, all.get_mut(at), held.get(i)) {
            (cell.distance, cell.aux) = *p;
            at = at.wrapping_add(1);
        }
    }
    let (big, zero_free) = classify(input, all.get_mut(head..).unwrap_or_default(), k, c);

    // Speckle removal over its held point and the line: its outputs stay in place.
    // The last stage gives its outputs in the encoder's form when not decimating
    // (`done`), counting those without a range (`invalid`).
    let (mut invalid, mut done) = (0usize, false);
    let mut o1 = m;
    if let Some(jump) = k.jump {
        let l1 = np1.wrapping_add(m);
        let region = all.get_mut(np2..np2.wrapping_add(l1)).unwrap_or_default();
        o1 = l1.saturating_sub(1);
        if o1 > 0 {
            let short = jump < SMALL && !big && small(sp.b1) && small(sp.p0.0);
            let removed = if !short {
                speckle_exact(region, &mut sp.b1, jump)
            } else if half2 == 0 && !k.decimate && zero_free {
                // The last stage: its outputs in the encoder's form.
                let (removed, none) = speckle_short::<true>(region, &mut sp.b1, jump, k.out_none);
                invalid = none;
                done = true;
                removed
            } else {
                speckle_short::<false>(region, &mut sp.b1, jump, NONE).0
            };
            c.speckle = c.speckle.wrapping_add(removed);
        }
        sp.np = l1.min(1);
        if let Some(cell) = region.get(o1) {
            sp.p0 = (cell.distance, cell.aux);
        }
    }

    // The median over its held points and the previous stage's outputs.
    let mut out = o1;
    let mut diff = 0u32;
    if half2 > 0 {
        let l2 = np2.wrapping_add(o1);
        let region = all.get_mut(..l2).unwrap_or_default();
        out = l2.saturating_sub(half2);
        if out > 0 {
            let mut b = [md.b1, md.b2];
            // Not the last stage: no range stays NONE (one loop per width either way).
            let last = !k.decimate && zero_free;
            let none = if last { k.out_none } else { NONE };
            (diff, invalid) = if half2 == 1 {
                median3(region, &mut b, none)
            } else {
                median5(region, &mut b, none)
            };
            done = last;
            [md.b1, md.b2] = b;
        }
        md.np = l2.wrapping_sub(out);
        if let Some(cell) = region.get(out) {
            md.p0 = (cell.distance, cell.aux);
        }
        if let Some(cell) = region.get(out.wrapping_add(1)) {
            md.p1 = (cell.distance, cell.aux);
        }
    }

    if k.decimate {
        // Counted after decimation.
        invalid = 0;
    } else if !done {
        invalid = finish(all.get_mut(..out).unwrap_or_default(), k.out_none);
    }
    (out, invalid, diff != 0)
}

/// Error codes, the range window and the intensity threshold: `input` into `out` (as
/// long), no range as [`NONE`], counted into `c`. Returns whether a range at or above
/// [`SMALL`] passed, and whether no range of 0 can (in this line or, the rule being
/// the scan's, any line of the scan).
fn classify(input: &[Reading], out: &mut [Reading], k: &LineConsts, c: &mut Tally) -> (bool, bool) {
    let rule = &k.rule;
    let [wmin, wmax] = rule.window;
    // The distances from `low` up to (not including) `low + span` are ranges inside
    // the window, found by one test; the others take the full one. The sensor's error
    // codes at or above its minimum end the span, and so does SMALL.
    let [a, b] = rule.except;
    let first = a
        .min(b)
        .min(rule.band.unwrap_or(NONE))
        .min(wmax.saturating_add(1))
        .min(SMALL);
    let low = rule.min.max(wmin);
    let span = first.saturating_sub(low);
    let mut n = [0usize; 3];
    let mut big = false;
    if k.min_intensity > 0 {
        classify_loop::<true>(input, out, (low, span), k, &mut n, &mut big);
    } else {
        classify_loop::<false>(input, out, (low, span), k, &mut n, &mut big);
    }
    let [error_code, out_of_range, low_intensity] = n;
    c.error_code = c.error_code.wrapping_add(error_code);
    c.out_of_range = c.out_of_range.wrapping_add(out_of_range);
    c.low_intensity = c.low_intensity.wrapping_add(low_intensity);
    (big, !rule.is_sensor_range(0) || !rule.is_range(0))
}

/// The loop of [`classify`], with or without an intensity threshold.
#[inline(always)]
fn classify_loop<const THRESHOLD: bool>(
    input: &[Reading],
    out: &mut [Reading],
    (low, span): (u32, u32),
    k: &LineConsts,
    n: &mut [usize; 3],
    big: &mut bool,
) {
    let mut low_intensity = 0usize;
    for (cell, r) in out.iter_mut().zip(input) {
        let mut d = r.distance;
        cell.aux = r.aux;
        if d.wrapping_sub(low) >= span {
            d = classify_rare(&k.rule, d, n, big);
        }
        if THRESHOLD && d != NONE && r.aux < k.min_intensity {
            // At most the line's points: no wrap.
            low_intensity = low_intensity.wrapping_add(1);
            d = NONE;
        }
        cell.distance = d;
    }
    n[2] = n[2].wrapping_add(low_intensity);
}

/// A distance outside the common span: the distance or [`NONE`], counted in `n`
/// (error codes, ranges outside the window); `big` set for a range at or above
/// [`SMALL`].
#[cold]
#[inline(never)]
fn classify_rare(rule: &can_wire::RangeRule, d: u32, n: &mut [usize; 3], big: &mut bool) -> u32 {
    // Counts of at most the line's points: no wrap.
    if d == NONE || !rule.is_sensor_range(d) {
        n[0] = n[0].wrapping_add(1);
        NONE
    } else if !rule.is_range(d) {
        n[1] = n[1].wrapping_add(1);
        NONE
    } else {
        *big |= d >= SMALL;
        d
    }
}

/// Speckle removal over `s`: each cell but the last is a centre (the last is its
/// look-ahead), `b1` the distance before the first (updated to the one before the
/// last). For a threshold and ranges below [`SMALL`] (a missing neighbour is then never
/// within the threshold, and a missing centre stays missing either way). Returns the
/// number of ranges removed and, when `LAST` (the outputs then in the encoder's form,
/// see [`out`]), the number of outputs without a range.
#[inline(never)]
fn speckle_short<const LAST: bool>(
    s: &mut [Reading],
    b1: &mut u32,
    jump: u32,
    out_none: u32,
) -> (usize, usize) {
    let Some((mut cell, rest)) = s.split_first_mut() else {
        return (0, 0);
    };
    let (mut b, mut c) = (*b1, cell.distance);
    let (mut removed, mut invalid) = (0usize, 0usize);
    for next in rest {
        let a = next.distance;
        let keep = b.abs_diff(c) <= jump || a.abs_diff(c) <= jump;
        let x = if keep { c } else { NONE };
        // At most the line's points: no wrap.
        removed = removed.wrapping_add(usize::from(x != c));
        cell.distance = out::<LAST>(x, out_none, &mut invalid);
        (b, c, cell) = (c, a, next);
    }
    *b1 = b;
    (removed, invalid)
}

/// A stage's output `x`: as it is, or when `LAST` in the encoder's form (no range as
/// `out_none`, counted in `invalid`; only for lines without a range of 0, which the
/// encoder's form gives as 1).
#[inline(always)]
fn out<const LAST: bool>(x: u32, out_none: u32, invalid: &mut usize) -> u32 {
    if !LAST {
        return x;
    }
    // At most the line's points: no wrap.
    *invalid = invalid.wrapping_add(usize::from(x == NONE));
    if x == NONE {
        out_none
    } else {
        x
    }
}

/// [`speckle_short`] for any threshold and range.
#[inline(never)]
fn speckle_exact(s: &mut [Reading], b1: &mut u32, jump: u32) -> usize {
    let Some((mut cell, rest)) = s.split_first_mut() else {
        return 0;
    };
    let (mut b, mut c) = (*b1, cell.distance);
    let mut removed = 0usize;
    for next in rest {
        let a = next.distance;
        let (out, gone) = speckle3_line(c, b, a, NONE, jump);
        removed = removed.wrapping_add(usize::from(gone));
        cell.distance = out;
        (b, c, cell) = (c, a, next);
    }
    *b1 = b;
    removed
}

/// The median of 3 over `s` (as [`speckle_short`]: every cell but the last is a centre,
/// `b[0]` the distance before the first, updated likewise). No range is written as
/// `out_none` ([`NONE`] to leave it). Returns the OR of every changed range with its
/// new value (0: none changed) and the number of outputs without a range.
#[inline(never)]
fn median3(s: &mut [Reading], b: &mut [u32; 2], out_none: u32) -> (u32, usize) {
    let Some((mut cell, rest)) = s.split_first_mut() else {
        return (0, 0);
    };
    // Each distance also with no range as 0: a window with a neighbour missing then
    // clamps its centre into [0, NONE], which leaves it (the centre is one of the
    // middle pair); with both, into the neighbours' span, which is the median.
    let zero = |d: u32| if d == NONE { 0 } else { d };
    let (mut x1, mut c) = (b[0], cell.distance);
    let (mut z1, mut zc) = (zero(x1), zero(c));
    let (mut diff, mut invalid) = (0u32, 0usize);
    for next in rest {
        let a = next.distance;
        let za = zero(a);
        let m = c.max(z1.min(za)).min(x1.max(a));
        // A missing centre stays missing.
        let x = if c == NONE { NONE } else { m };
        diff |= x ^ c;
        cell.distance = out::<true>(x, out_none, &mut invalid);
        (x1, z1, c, zc, cell) = (c, zc, a, za, next);
    }
    b[0] = x1;
    (diff, invalid)
}

/// The median of 5 over `s`: every cell but the last two is a centre, `b` the
/// distances before the first (nearest first; updated likewise). Returns as
/// [`median3`].
#[inline(never)]
fn median5(s: &mut [Reading], b: &mut [u32; 2], out_none: u32) -> (u32, usize) {
    let Some((mut cell, rest)) = s.split_first_mut() else {
        return (0, 0);
    };
    let Some((mut cell1, rest)) = rest.split_first_mut() else {
        return (0, 0);
    };
    let (mut x2, mut x1, mut c, mut a1) = (b[1], b[0], cell.distance, cell1.distance);
    // Bit i set: the i-th newest distance of the window is no range.
    let none = |d: u32| u32::from(d == NONE);
    let mut missing = none(x2) << 3 | none(x1) << 2 | none(c) << 1 | none(a1);
    let (mut diff, mut invalid) = (0u32, 0usize);
    for next in rest {
        let a2 = next.distance;
        missing = missing << 1 | none(a2);
        let x = if missing & 0x1f == 0 {
            // Five ranges: the median of the two pairs' inner values and the centre.
            let lo = x2.min(x1).max(a1.min(a2));
            let hi = x2.max(x1).min(a1.max(a2));
            c.min(lo).max(c.max(lo).min(hi))
        } else {
            median_line(c, [x2, x1, a1, a2], NONE)
        };
        diff |= x ^ c;
        cell.distance = out::<true>(x, out_none, &mut invalid);
        (x2, x1, c, a1) = (x1, c, a1, a2);
        (cell, cell1) = (cell1, next);
    }
    *b = [x1, x2];
    (diff, invalid)
}

/// The output points into the encoder's form: no range as `out_none`, a range of 0 as
/// 1. Returns the number without a range.
#[inline(never)]
fn finish(cells: &mut [Reading], out_none: u32) -> usize {
    let mut invalid = 0usize;
    for cell in cells {
        let d = cell.distance;
        // At most the line's points: no wrap.
        invalid = invalid.wrapping_add(usize::from(d == NONE));
        cell.distance = if d == NONE { out_none } else { d.max(1) };
    }
    invalid
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn cells(d: &[u32]) -> Vec<Reading> {
        d.iter()
            .map(|&distance| Reading {
                distance,
                ..Reading::default()
            })
            .collect()
    }

    fn dist(c: &[Reading]) -> Vec<u32> {
        c.iter().map(|r| r.distance).collect()
    }

    /// The median of 5 by sorting (every one of the five a range).
    fn sorted_median(v: [u32; 5]) -> u32 {
        let mut s = v;
        s.sort_unstable();
        s[2]
    }

    #[test]
    fn median5_network_is_the_sorted_median() {
        // Every 5-tuple over 0..5 (ties included): the network against sorting.
        for t in 0..5u32.pow(5) {
            let v: [u32; 5] = core::array::from_fn(|i| t / 5u32.pow(i as u32) % 5 * 100);
            let mut s = cells(&v[2..]);
            let mut b = [v[1], v[0]];
            median5(&mut s, &mut b, NONE);
            assert_eq!(s[0].distance, sorted_median(v), "{v:?}");
            assert_eq!(b, [v[2], v[1]]);
        }
    }

    #[test]
    fn median3_and_speckle_by_hand() {
        // 1000 9999 1002 1004 (none) 1010: the spike goes (to 1002, the median of
        // 1000 9999 1002), 1002 becomes 1004 (of 9999 1002 1004), a centre beside a
        // missing neighbour stays.
        let mut s = cells(&[9999, 1002, 1004, NONE, 1010]);
        let mut b = [1000, 0];
        let (diff, _) = median3(&mut s, &mut b, NONE);
        assert_eq!(dist(&s), [1002, 1004, 1004, NONE, 1010]);
        assert_ne!(diff, 0);
        assert_eq!(b[0], NONE);
        // The last stage: no range as the encoder's value, counted.
        let mut s = cells(&[9999, NONE, 1004, 1003]);
        let mut b = [1000, 0];
        assert_eq!(median3(&mut s, &mut b, 7).1, 1);
        assert_eq!(dist(&s), [9999, 7, 1004, 1003]);
        // Threshold 5: 1000 (supported by 1004) stays, 2000 and 3000 go, a missing
        // centre is not counted.
        let short =
            |s: &mut [Reading], b1: &mut u32, jump| speckle_short::<false>(s, b1, jump, NONE).0;
        for f in [short, speckle_exact] {
            let mut s = cells(&[1000, 2000, NONE, 3000, 3010]);
            let mut b1 = 1004;
            assert_eq!(f(&mut s, &mut b1, 5), 2);
            assert_eq!(dist(&s), [1000, NONE, NONE, NONE, 3010]);
            assert_eq!(b1, 3000);
        }
    }
}
