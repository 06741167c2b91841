//! Speckle removal and the median over a data line in place.
//!
//! [`line`] is the window stages of [`super::Pipeline::filter_line`]: the line's readings
//! are classified into cells (no range as [`NONE`]) behind the points the windows still
//! hold from the line before (copied into headroom in front of the line, so that the
//! stages see one contiguous array), then speckle removal and the median of 3 run in
//! one loop over the cells ([`stages`]: the windows' distances in registers, each
//! output written over the cell of its centre; speckle removal alone a loop of its own
//! that classifies the line's readings as it loads them, [`speckle_line`], with no
//! pass of its own for the classification; the median alone a loop of its own taking
//! four centres at a time, [`median3_pairs`]). Each stage first tries a
//! quick test: a centre within the threshold of the point before it stays, a centre
//! between its neighbours is their median. The median of 5 runs a loop of its own,
//! two centres a turn until its first change, then four (one sorted pair of new
//! distances per two outputs when all six are ranges below 2^31, the general rule
//! otherwise: the same network with the missing neighbours filled in), after speckle
//! removal's loop.

use scip::Reading;

use super::window::{speckle3_line, Regs};
use super::{LineConsts, Tally};

/// No range, inside a line.
pub(super) const NONE: u32 = u32::MAX;

/// Cells a line needs in front of it for the points the windows hold from the line
/// before (1 for speckle removal, 2 for the median of 5).
pub const LINE_HEADROOM: usize = 3;

/// Ranges and speckle thresholds below this take the short speckle loop: the distance
/// from such a range to [`NONE`] is above any such threshold, so no range is supported
/// by a missing neighbour.
const SMALL: u32 = 1 << 31;

/// `d` with its top bit clear exactly when `d` is no range or a range below
/// [`SMALL`] (so that one test of an OR covers several: `d & (d + 1)`, the `+ 1`
/// wrapping no range to 0 and a range from 2^31 on staying at or above it).
#[inline(always)]
fn small_bit(d: u32) -> u32 {
    d & d.wrapping_add(1)
}

/// The window stages of [`super::Pipeline::filter_line`] (speckle removal and/or the
/// median; the caller has checked that one is on) over the line's readings `input`,
/// with the windows' state `sp` and `md`; `cells` holds at least [`LINE_HEADROOM`]
/// more than `input`. The output points go to the front of `cells`. Returns their
/// number and how many of them have no range (when not decimating: they are then in the
/// encoder's form); ORs into `changed` every range the median changed with its new
/// value.
#[inline(never)]
pub(super) fn line(
    input: &[Reading],
    cells: &mut [Reading],
    k: &LineConsts,
    sp: &mut Regs,
    md: &mut Regs,
    c: &mut Tally,
    changed: &mut u32,
) -> (usize, usize) {
    let half2 = k.half2;
    // The points each window holds, in stream order: the median's, then speckle
    // removal's (the later points), then the line.
    let np1 = if k.jump.is_some() { sp.np.min(1) } else { 0 };
    let np2 = md.np.min(half2);
    let head = np2.wrapping_add(np1);
    let m = input.len();
    // The held points into the headroom without a test each: the median's two into the
    // first cells, speckle removal's after the median's held ones. A cell written that
    // a window does not hold is the line's (the classification writes it after) or
    // past the line's end (not a cell of the stages, nor of the output).
    if let Some(cell) = cells.get_mut(0) {
        (cell.distance, cell.aux) = md.p0;
    }
    if let Some(cell) = cells.get_mut(1) {
        (cell.distance, cell.aux) = md.p1;
    }
    if let Some(cell) = cells.get_mut(np2) {
        (cell.distance, cell.aux) = sp.p0;
    }
    let Some(all) = cells.get_mut(..head.wrapping_add(m)) else {
        return (0, 0);
    };
    // Without decimation after and with no range of 0 possible, the last stage gives
    // its outputs in the encoder's form; otherwise no range stays NONE.
    let none = if k.last { k.out_none } else { NONE };
    // The loops' quick tests hold when every range is below SMALL (else every point
    // takes the exact rule): `x & (x + 1)` has its top bit clear exactly when `x` is
    // no range or below SMALL (one OR for the two). A range at or above SMALL in the
    // line (found by the classification) makes the median exact too; speckle removal
    // alone does not need it.
    let small_held = |r: &Regs| (small_bit(r.b1) | small_bit(r.p0.0)) < SMALL;
    let held = !small_held(md) || k.jump.is_some_and(|j| j >= SMALL || !small_held(sp));
    let jump = k.jump.unwrap_or(0);
    // The line classified into its cells by a pass of its own (returns whether a range
    // at or above SMALL passed), but where speckle removal runs without the median in
    // its loop: `speckle_line` classifies as it loads.
    let span = k.span;
    let pass = |all: &mut [Reading], c: &mut Tally| {
        classify(input, all.get_mut(head..).unwrap_or_default(), k, c)
    };

    // The common case, every stage in one loop (the median's point held from the line
    // before, when both are on); otherwise a loop per stage.
    let (out, mut invalid);
    if k.jump.is_some() && half2 == 0 {
        // Speckle removal alone.
        (out, invalid) = speckle_line(all, input, k, span, held, sp, none, c);
    } else if half2 < 2 && (k.jump.is_none() || np2 == half2) {
        let exact = pass(all, c) || held;
        (out, invalid) = match (k.jump.is_some(), exact) {
            // Both stages by the exact rules: a loop of their own (the quick loop then
            // holds no `exact`).
            (true, true) => stages_exact(all, jump, sp, md, none, c, changed),
            (true, false) => stages::<true>(all, jump, false, sp, md, none, c, changed),
            _ => median3_pairs(all, exact, md, none, changed),
        };
    } else {
        // Speckle removal over its held point and the line: its outputs stay in place.
        let (mut o1, mut exact) = (m, held);
        if k.jump.is_some() {
            let region = all.get_mut(np2..).unwrap_or_default();
            (o1, _) = speckle_line(region, input, k, span, held, sp, NONE, c);
        } else {
            exact |= pass(all, c);
        }
        // The median over its held points and the previous stage's outputs.
        let l2 = np2.wrapping_add(o1);
        let region = all.get_mut(..l2).unwrap_or_default();
        if half2 < 2 {
            // (After speckle removal, which does not say whether a range at or above
            // SMALL passed, by the exact rules when the window lets one pass: the
            // scan's first line only.)
            exact |= k.jump.is_some() && k.rule.window[1] >= SMALL;
            (out, invalid) = median3_pairs(region, exact, md, none, changed);
        } else {
            out = l2.saturating_sub(half2);
            let diff;
            (diff, invalid) = median5(region, md, none, *changed);
            *changed |= diff;
        }
    }
    if !k.last {
        invalid = if k.decimate {
            // Counted after decimation.
            0
        } else {
            finish(all.get_mut(..out).unwrap_or_default(), k.out_none)
        };
    }
    (out, invalid)
}

/// The median of 3 of a centre `c` that [`stages`]' test did not pass: a missing
/// centre stays missing (its output is `none`, counted in `invalid`), else `c` when a
/// neighbour is no range, else the median. `exact` (`SMALL` when a range may be at or
/// above it, else 0) takes the general rule; without it every range is below
/// [`SMALL`] (no range the only value with the top bit set: one test of the OR of the
/// three finds any no range) and a range `c` not between its neighbours: the median is
/// the neighbour nearest `c`, picked by one sign test. ORs into `diff` the change of a
/// range.
#[inline(always)]
fn median3_off<const NONE_FIRST: bool>(
    (b, c, s): (u32, u32, u32),
    exact: u32,
    diff: &mut u32,
    invalid: &mut usize,
    none: u32,
) -> u32 {
    // `NONE_FIRST`: a missing centre tested first by itself, then the neighbours, and
    // the nearest neighbour by `c >= b`: the form [`median3_pairs`] keeps (its
    // one-centre path meets the missing centres; with the one-test form LLVM laid it
    // out longer: median of 3 on URG-04LX, 3 scans, 246 953 -> 247 420 `on_uart`).
    if NONE_FIRST {
        if c == NONE {
            return no_range(invalid, none);
        }
        let x = if (b | s | exact) >= SMALL {
            median3_exact(b, c, s)
        } else if c >= b {
            // `c - b` at least 0: `c` is at least `b` and above `s`.
            b.max(s)
        } else {
            // Below `b`, at most `s`.
            b.min(s)
        };
        *diff |= x ^ c;
        return x;
    }
    let x = if (b | c | s | exact) >= SMALL {
        // A value is no range (or `exact`): the general rule, a missing centre
        // counted.
        if c == NONE {
            return no_range(invalid, none);
        }
        median3_exact(b, c, s)
    } else if (b.wrapping_sub(s) ^ c.wrapping_sub(b)) < SMALL {
        // `c` above both or below both: the median is the neighbour nearest it, `b`
        // when `b` is between `s` and `c` (`b - s` and `c - b` of the same sign).
        b
    } else {
        s
    };
    *diff |= x ^ c;
    x
}

/// The median of 3 by the general rule (any ranges): `c` when one of the three is no
/// range, else the median. Out of [`stages`]' loops (rare, and one copy for all).
#[inline(never)]
fn median3_exact(b: u32, c: u32, s: u32) -> u32 {
    if b == NONE || c == NONE || s == NONE {
        c
    } else {
        c.max(b.min(s)).min(b.max(s))
    }
}

/// Speckle removal's rule (any ranges and threshold) for the centre `c` between `b` and
/// `a`: its new distance, a removal counted in `removed` (at most the line's points: no
/// wrap; in memory, so that the loops keep their registers for the common paths). Out
/// of [`stages`]' loops (rare, and one copy for all).
#[inline(never)]
fn speckle_exact(c: u32, b: u32, a: u32, jump: u32, removed: &mut usize) -> u32 {
    let (x, gone) = speckle3_line(c, b, a, NONE, jump);
    *removed = removed.wrapping_add(usize::from(gone));
    x
}

/// Counts one output without a range (at most the line's points: no wrap); returns the
/// encoder's value for it.
#[cold]
#[inline(never)]
fn no_range(invalid: &mut usize, out_none: u32) -> u32 {
    *invalid = invalid.wrapping_add(1);
    out_none
}

/// Speckle removal (threshold `jump`), then the median of 3 when `MD`, in one loop
/// over `d`, in place (the median alone is [`median3_pairs`]; `line` takes
/// [`speckle_line`] for speckle removal alone, which classifies as it loads). `line`
/// builds only `MD`; the loop keeps the speckle-alone case of its generic form
/// because the form compiles better: written for `MD` alone, with the same operations,
/// LLVM laid the median's test out one instruction a point longer (typical
/// configuration, URG-04LX, 3 scans: 267 966 -> 270 632 instructions of `on_uart`).
/// The held points and the classified line in stream order (the
/// median's held point first when both are on: the caller has checked that it holds
/// one, and it is speckle removal's output for the point before speckle removal's
/// held centre, `sp.b1` or no range). The windows' state is carried in registers from `sp` and `md` and stored
/// back after; the outputs go to the front of `d`, no range as `none`. Returns the
/// number of outputs and how many of them have no range; ORs into `changed` every
/// range the median changed with its new value and adds the ranges speckle removal
/// took to `t.speckle` (two values returned in registers, the rest once a line).
///
/// Each stage first tries a quick test that holds when every range is below [`SMALL`]
/// (else the caller sets `exact` and every point takes the exact rule; with both
/// stages on, the caller takes [`stages_exact`] instead: `exact` is then ignored).
/// Speckle removal: a centre within `jump` of the
/// point before it stays. The median: a centre between its neighbours is the median,
/// found by one sign test, (c - b) and (s - c) of the same sign in 32-bit two's
/// complement and `c` a range (its top bit clear), exact for ranges below 2^31 (with
/// a neighbour missing the test can only pass when the answer is the centre too), so
/// that no quick output is no range.
// (The counts go out through `t` and `changed`: two outputs in registers, not a
// four-value return through memory.)
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn stages<const MD: bool>(
    d: &mut [Reading],
    jump: u32,
    exact: bool,
    sp: &mut Regs,
    md: &mut Regs,
    none: u32,
    t: &mut Tally,
    changed: &mut u32,
) -> (usize, usize) {
    let dist = |d: &[Reading], i: usize| d.get(i).map_or(NONE, |c| c.distance);
    let aux = |d: &[Reading], i: usize| d.get(i).map_or(0, |c| c.aux);
    let (mut removed, mut invalid, mut diff) = (0usize, 0usize, 0u32);
    // Speckle removal's quick test made to fail when `exact` (with the median on, the
    // caller takes `stages_exact` instead).
    let quick_jump = if exact && !MD { 0 } else { jump };
    let n = d.len();
    // Each stage's centre (as input) and the distance before it. Speckle removal's
    // first centre is the point after the median's held one; the median's, its held
    // point or else the first point. With both stages on, the distance before speckle
    // removal's centre is the median's centre (speckle removal's output for that
    // point, not its input): they differ only where speckle removal took a range, and
    // a range taken had no support from the centre after it (support is symmetric), so
    // it gives that centre none either way.
    let (mut bm, mut cm) = (md.b1, dist(d, 0));
    let (mut bs, mut cs) = (sp.b1, dist(d, usize::from(MD)));
    // Outputs lag the look-ahead by one point per stage.
    let lag = 1usize.wrapping_add(usize::from(MD));
    for j in lag..n {
        // Speckle removal's output replaces its centre `cs`.
        let s = {
            let b = if MD { cm } else { bs };
            // Alone, speckle removal gives the last outputs: its quick test fails for
            // no range (the sign of `cs` as i32 makes the difference above any
            // threshold), so that no quick output needs the no-range test.
            let guard = if MD { 0 } else { ((cs as i32) >> 31) as u32 };
            bs = cs;
            // Alone, its output is written first (the centre), the slow branch
            // writes over it.
            let out = |d: &mut [Reading], x: u32| {
                if let (false, Some(o)) = (MD, d.get_mut(j.wrapping_sub(lag))) {
                    o.distance = x;
                }
            };
            out(d, cs);
            if b.abs_diff(cs) | guard > quick_jump {
                let x = speckle_exact(cs, b, dist(d, j), jump, &mut removed);
                cs = if !MD && x == NONE {
                    no_range(&mut invalid, none)
                } else {
                    x
                };
                out(d, cs);
            }
            cs
        };
        if MD {
            // The centre stays (written first, the other cases write over it) when
            // the test passes: only for a range `c` (its top bit clear) between its
            // neighbours.
            let c = cm;
            if let Some(o) = d.get_mut(j.wrapping_sub(lag)) {
                o.distance = c;
                if ((c.wrapping_sub(bm) ^ s.wrapping_sub(c)) | c) >= SMALL {
                    o.distance = median3_off::<false>((bm, c, s), 0, &mut diff, &mut invalid, none);
                }
            }
            (bm, cm) = (c, s);
        }
        cs = dist(d, j);
    }
    let out = n.saturating_sub(lag);
    sp.np = n.min(1);
    // The last centre's input before it (with the median on, still in place: the
    // outputs end two points before the last).
    if !MD || n > lag {
        sp.b1 = if MD { dist(d, n.wrapping_sub(2)) } else { bs };
    }
    sp.p0 = (cs, aux(d, n.wrapping_sub(1)));
    if MD && n > 0 {
        md.np = 1;
        md.b1 = bm;
        md.p0 = (cm, aux(d, out));
    }
    // At most the line's points: no wrap.
    t.speckle = t.speckle.wrapping_add(removed);
    *changed |= diff;
    (out, invalid)
}

/// Speckle removal alone (threshold from `k`) over `d`, in place: the point it holds
/// from the line before (`sp.p0`, when `d` is one longer than `input`) in front, then
/// the line's readings `input`, classified as they are loaded (error codes, the range
/// window, the intensity threshold: counted into `t`, no range as [`NONE`]; `span` is
/// [`LineConsts`]' `span`) into their cells, so that the line is read and written once (no classification pass
/// before). The window's state in `sp`; outputs to the front of `d`, no range as
/// `none`. Returns the number of outputs and how many of them have no range, and adds
/// the ranges taken to `t.speckle`.
///
/// The quick test of [`stages`] (a centre within the threshold of the point before it
/// stays, a centre without a range or at or above [`SMALL`] never) is exact for a
/// threshold below [`SMALL`], whatever the ranges: the distance from [`NONE`] to a
/// centre below [`SMALL`] is above any such threshold, so no range is supported by a
/// missing point. `exact` (set for a threshold at or above [`SMALL`]) takes the
/// general rule for every point.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn speckle_line(
    d: &mut [Reading],
    input: &[Reading],
    k: &LineConsts,
    span: u32,
    exact: bool,
    sp: &mut Regs,
    none: u32,
    t: &mut Tally,
) -> (usize, usize) {
    // A loop with the intensity threshold and one without.
    if k.min_intensity > 0 {
        speckle_loop::<true>(d, input, k, span, exact, sp, none, t)
    } else {
        speckle_loop::<false>(d, input, k, span, exact, sp, none, t)
    }
}

/// The loop of [`speckle_line`], with or without the intensity threshold's test.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn speckle_loop<const THRESHOLD: bool>(
    d: &mut [Reading],
    input: &[Reading],
    k: &LineConsts,
    span: u32,
    exact: bool,
    sp: &mut Regs,
    none: u32,
    t: &mut Tally,
) -> (usize, usize) {
    let jump = k.jump.unwrap_or(0);
    let (mut removed, mut invalid) = (0usize, 0usize);
    // Its quick test made to fail when `exact`.
    let quick_jump = if exact { 0 } else { jump };
    let n = d.len();
    // The classification as the points are loaded: the common span by one test (and
    // one for the intensity with a threshold), an error code below the sensor's
    // minimum by a second, any other distance through `classify_point`.
    let (low, min_intensity) = (k.low, k.min_intensity);
    let class = |r: &Reading, t: &mut Tally| {
        let x = r.distance;
        if x.wrapping_sub(low) < span && (!THRESHOLD || r.aux >= min_intensity) {
            x
        } else if x < k.rule.min {
            // Counted here, at most the line's points (no wrap).
            t.error_code = t.error_code.wrapping_add(1);
            NONE
        } else {
            classify_point(k, x, r.aux, t)
        }
    };
    // The line's first point is the first centre when no point is held (then
    // classified before the loop); the loop's look-ahead reads the rest.
    let held = n.saturating_sub(input.len());
    let mut src = input.iter();
    if held == 0 {
        if let (Some(cell), Some(r)) = (d.first_mut(), src.next()) {
            (cell.distance, cell.aux) = (classify_point(k, r.distance, r.aux, t), r.aux);
        }
    }
    let (mut bs, mut cs) = (sp.b1, d.first().map_or(NONE, |c| c.distance));
    if let [w0, rest @ ..] = &mut *d {
        // The output's cell, one behind the look-ahead.
        let mut o = w0;
        for (cell, r) in rest.iter_mut().zip(src) {
            // The look-ahead, classified into its cell.
            let a = class(r, t);
            (cell.distance, cell.aux) = (a, r.aux);
            // The quick test fails for no range (the sign of `cs` as i32 makes the
            // difference above any threshold), so that no quick output needs the
            // no-range test. The centre is written first, the slow branch writes over
            // it.
            let guard = ((cs as i32) >> 31) as u32;
            let b = bs;
            bs = cs;
            o.distance = cs;
            if b.abs_diff(cs) | guard > quick_jump {
                let x = speckle_exact(cs, b, a, jump, &mut removed);
                o.distance = if x == NONE {
                    no_range(&mut invalid, none)
                } else {
                    x
                };
            }
            o = cell;
            cs = a;
        }
    }
    sp.np = n.min(1);
    sp.b1 = bs;
    sp.p0 = (cs, d.last().map_or(0, |c| c.aux));
    // At most the line's points: no wrap.
    t.speckle = t.speckle.wrapping_add(removed);
    (n.saturating_sub(1), invalid)
}

/// The median of 3 alone (its state in `md`, the median's held point first
/// in `d` when it holds one), four centres at a time: the centres `k` and `k + 1` share
/// the pair `v(k)`, `v(k + 1)`; with `lo <= hi` that pair, their medians are
/// `max(lo, min(hi, v(k - 1)))` and `max(lo, min(hi, v(k + 2)))` when the four are
/// ranges below [`SMALL`]. Two such pairs per step, one test: `v(k - 1)` is checked
/// before the loop (and is the last pair's high one after), the other ends are the
/// pairs' own values but `v(k + 4)` (one test of the OR of the two highs and
/// `v(k + 4)`). Otherwise (or with `exact`, [`SMALL`] when a range may be at or above
/// it) two centres one at a time by [`stages`]' median rule (its quick test, else
/// [`median3_off`]). Outputs in place, no range as `none`; returns the number of
/// outputs and how many have no range, ORs into `changed` every changed range with its
/// new value.
#[inline(never)]
fn median3_pairs(
    d: &mut [Reading],
    exact: bool,
    md: &mut Regs,
    none: u32,
    changed: &mut u32,
) -> (usize, usize) {
    let exact = if exact { SMALL } else { 0 };
    let n = d.len();
    let (mut invalid, mut diff) = (0usize, 0u32);
    // v(k - 1) and v(k), the raw distances before and at the centre `rest[0]`.
    let mut b = md.b1;
    let mut rest = d;
    let mut c0 = rest.first().map_or(NONE, |r| r.distance);
    loop {
        // `b` is a range below SMALL in the loop (after the first step, the last
        // pair's high one is at least it).
        if (b | exact) < SMALL {
            // Four centres at a time: two pairs, one test (the second pair's `b` is
            // the first's high one, the first's end the second's low or high one).
            while let [o0, o1, o2, o3, r4, ..] = rest {
                let (c1, c2, c3, s) = (o1.distance, o2.distance, o3.distance, r4.distance);
                let (h0, h1) = (c0.max(c1), c2.max(c3));
                if (h0 | h1 | s) >= SMALL {
                    break;
                }
                let (l0, l1) = (c0 ^ c1 ^ h0, c2 ^ c3 ^ h1);
                let (x0, x1) = (h0.min(b).max(l0), h0.min(c2).max(l0));
                let (x2, x3) = (h1.min(c1).max(l1), h1.min(s).max(l1));
                diff |= (x0 ^ c0) | (x1 ^ c1) | (x2 ^ c2) | (x3 ^ c3);
                (o0.distance, o1.distance, o2.distance, o3.distance) = (x0, x1, x2, x3);
                (b, c0) = (c3, s);
                rest = core::mem::take(&mut rest).get_mut(4..).unwrap_or_default();
            }
        }
        // Two centres alone (a window the pair rule does not cover, or the last
        // centres of the line).
        for _ in 0..2 {
            let [o0, r1, ..] = rest else {
                break;
            };
            let (c, s) = (c0, r1.distance);
            if ((c.wrapping_sub(b) ^ s.wrapping_sub(c)) | c | exact) >= SMALL {
                o0.distance = median3_off::<true>((b, c, s), exact, &mut diff, &mut invalid, none);
            }
            (b, c0) = (c, s);
            rest = core::mem::take(&mut rest).get_mut(1..).unwrap_or_default();
        }
        if rest.len() < 2 {
            break;
        }
    }
    if let Some(cell) = rest.first() {
        md.np = 1;
        md.b1 = b;
        md.p0 = (cell.distance, cell.aux);
    }
    *changed |= diff;
    (n.saturating_sub(1), invalid)
}

/// [`stages`] with both stages on, by the exact rules (any ranges and threshold):
/// rare (a range at or above [`SMALL`]), out of the quick loop.
#[inline(never)]
fn stages_exact(
    d: &mut [Reading],
    jump: u32,
    sp: &mut Regs,
    md: &mut Regs,
    none: u32,
    t: &mut Tally,
    changed: &mut u32,
) -> (usize, usize) {
    let dist = |d: &[Reading], i: usize| d.get(i).map_or(NONE, |c| c.distance);
    let aux = |d: &[Reading], i: usize| d.get(i).map_or(0, |c| c.aux);
    let (mut removed, mut invalid, mut diff) = (0usize, 0usize, 0u32);
    let n = d.len();
    let (mut bs, mut cs) = (sp.b1, dist(d, 1));
    let (mut bm, mut cm) = (md.b1, dist(d, 0));
    for j in 2..n {
        let a = dist(d, j);
        let s = speckle_exact(cs, bs, a, jump, &mut removed);
        (bs, cs) = (cs, a);
        let x = median3_exact(bm, cm, s);
        diff |= x ^ cm;
        (bm, cm) = (cm, s);
        if let Some(o) = d.get_mut(j.wrapping_sub(2)) {
            o.distance = if x == NONE {
                no_range(&mut invalid, none)
            } else {
                x
            };
        }
    }
    let out = n.saturating_sub(2);
    sp.np = n.min(1);
    sp.b1 = bs;
    sp.p0 = (cs, aux(d, n.wrapping_sub(1)));
    if n > 0 {
        md.np = 1;
        md.b1 = bm;
        md.p0 = (cm, aux(d, out));
    }
    // At most the line's points: no wrap.
    t.speckle = t.speckle.wrapping_add(removed);
    *changed |= diff;
    (out, invalid)
}

/// What [`classify`] works out of a rule, once per rule ([`LineConsts`] keeps it): the
/// distances from `low` up to (not including) `low + span` are ranges inside the
/// window, found by one test (the others take the full one), and whether no range of
/// 0 can pass. Returns `(low, span, zero_free)`.
pub(super) fn span(rule: &can_wire::RangeRule) -> (u32, u32, bool) {
    let [wmin, wmax] = rule.window;
    // The sensor's error codes at or above its minimum end the span, and so does
    // SMALL.
    let [a, b] = rule.except;
    let first = a
        .min(b)
        .min(rule.band.unwrap_or(NONE))
        .min(wmax.saturating_add(1))
        .min(SMALL);
    let low = rule.min.max(wmin);
    // (A range inside the window is a range to the sensor.)
    let zero_free = !rule.is_range(0);
    (low, first.saturating_sub(low), zero_free)
}

/// Error codes, the range window and the intensity threshold: `input` into `out` (as
/// long), no range as [`NONE`], counted into `c`. Returns whether a range at or above
/// [`SMALL`] passed (whether no range of 0 can pass is part of [`LineConsts`]' `last`).
/// A loop with the threshold and one without (one copy each for the callers).
#[inline(always)]
pub(super) fn classify(
    input: &[Reading],
    out: &mut [Reading],
    k: &LineConsts,
    c: &mut Tally,
) -> bool {
    // (The span passed in: read inside, LLVM versions the loop on it.)
    if k.min_intensity > 0 {
        classify_loop::<true>(input, out, k, k.span, c)
    } else {
        classify_loop::<false>(input, out, k, k.span, c)
    }
}

/// The loop of [`classify`]: a distance in the common span (`k.low`, `span` long) is a
/// range by one test, and with a `THRESHOLD` one more for its intensity; an error code
/// below the sensor's minimum by a second; any other reading takes the full rule.
#[inline(never)]
fn classify_loop<const THRESHOLD: bool>(
    input: &[Reading],
    out: &mut [Reading],
    k: &LineConsts,
    span: u32,
    c: &mut Tally,
) -> bool {
    let (mut big, mut below) = (false, 0usize);
    let (min, low, min_intensity) = (k.rule.min, k.low, k.min_intensity);
    for (cell, r) in out.iter_mut().zip(input) {
        let (mut d, aux) = (r.distance, r.aux);
        if d.wrapping_sub(low) >= span || (THRESHOLD && aux < min_intensity) {
            if d < min {
                // An error code below the sensor's minimum (the common one): counted
                // here, at most the line's points (no wrap).
                below = below.wrapping_add(1);
                d = NONE;
            } else {
                d = classify_point(k, d, aux, c);
                big |= small_bit(d) >= SMALL;
            }
        }
        // Both words at once (adjacent in the cell).
        (cell.distance, cell.aux) = (d, aux);
    }
    // At most the line's points: no wrap.
    c.error_code = c.error_code.wrapping_add(below);
    big
}

/// One reading's distance classified by the full rule (error codes, the range
/// window, the intensity threshold): the distance or [`NONE`], counted in `c`. Out of
/// line, for the distances outside the common span (and in [`speckle_line`] every
/// distance when there is a threshold, and the line's first point).
#[cold]
#[inline(never)]
fn classify_point(k: &LineConsts, d: u32, aux: u32, c: &mut Tally) -> u32 {
    let rule = &k.rule;
    // Counts of at most the line's points: no wrap.
    if d == NONE || !rule.is_sensor_range(d) {
        c.error_code = c.error_code.wrapping_add(1);
        NONE
    } else if !rule.is_range(d) {
        c.out_of_range = c.out_of_range.wrapping_add(1);
        NONE
    } else if aux < k.min_intensity {
        c.low_intensity = c.low_intensity.wrapping_add(1);
        NONE
    } else {
        d
    }
}

/// The median of 5 over `s` (the points `md` held, then the line): every cell but the
/// last two is a centre, `md.b1` and `md.b2` the distances before the first (nearest
/// first). No range is written as `out_none` ([`NONE`] to leave it). Leaves in `md`
/// the cells after the centres (held for the next line) and the two distances before
/// them. Returns, for `diff0` 0, the OR of every changed range with its new value (0:
/// none changed), and otherwise a value not 0 (the caller has a change already, e.g.
/// the scan is filtered: the quick loop then does not track the changes); and the
/// number of outputs without a range.
///
/// Two centres at a time: the centres `k` and `k + 1` share the four distances
/// `v(k - 1) ..= v(k + 2)`. With `P` and `Q` those as two sorted pairs, the middle two
/// of the four are `u = max(P.lo, Q.lo)` and `w = min(P.hi, Q.hi)` (the smallest is
/// the smaller low, the largest the larger high); with `s2 <= s3` those two, the
/// median of the four and a fifth value `e` is `max(s2, min(s3, e))`: for centre `k`
/// with `e = v(k - 2)`, for `k + 1` with `v(k + 3)`. The next two centres' `P` is this
/// `Q`, its `e` the centre `k`: the loop takes two such steps a turn when the line
/// holds them. The quick rule holds when the six distances are ranges below [`SMALL`]
/// (no range, [`NONE`], is then the only value with the top bit set): `e` and `P` are
/// tested once on entering the loop, and each step tests only what it adds (the OR of
/// `Q`'s high and `v(k + 3)`), since it leaves `e` and `P` among the distances tested.
/// Until the first change the loop takes one such step a turn (tracking the changes),
/// then [`median5_quads`] two a turn (and an odd last centre by the same network).
/// Otherwise one centre at a time by [`median5_exact`]. The quick rule's outputs are
/// ranges: only [`median5_exact`] counts no range.
#[inline(never)]
fn median5(s: &mut [Reading], md: &mut Regs, out_none: u32, diff0: u32) -> (u32, usize) {
    // Written by the single centres' rule only (out of the loop's registers).
    let mut slow = (0usize, out_none);
    // v(k - 2) and P = v(k - 1) and v(k) sorted (v(k) and v(k + 1) still in their
    // cells, from centre k on: `rest`).
    let mut rest = s;
    let c = rest.first().map_or(NONE, |r| r.distance);
    let mut e = md.b2;
    let (mut pl, mut ph) = (md.b1.min(c), md.b1.max(c));
    let mut diff = diff0;
    loop {
        // `e` and `P` ranges below SMALL: the loops test only the distances they add
        // (each step leaves `e` and `P` among the distances it tested).
        if (e | ph) < SMALL {
            // Until the first change (when the caller has none yet): two centres a
            // turn, the changes tracked.
            if diff == 0 {
                while let [o0, o1, o2, o3, ..] = rest {
                    let (c0, c1, c2, c3) = (o0.distance, o1.distance, o2.distance, o3.distance);
                    let (ql, qh) = (c1.min(c2), c1.max(c2));
                    if (qh | c3) >= SMALL {
                        break;
                    }
                    let (x0, x1) = quick_pair(e, (pl, ph), (ql, qh), c3);
                    diff = (x0 ^ c0) | (x1 ^ c1);
                    (o0.distance, o1.distance) = (x0, x1);
                    (e, pl, ph) = (c0, ql, qh);
                    rest = core::mem::take(&mut rest).get_mut(2..).unwrap_or_default();
                    if diff != 0 {
                        break;
                    }
                }
            }
            // Then (or with a change already made) four centres a turn, the changes
            // no longer tracked.
            if diff != 0 {
                (rest, e, pl, ph) = median5_quads(core::mem::take(&mut rest), e, pl, ph);
            }
        }
        // One centre alone by the general rule: a window the quick rule does not
        // cover (or an odd last centre before the first change).
        let [o0, o1, _, ..] = rest else {
            break;
        };
        let (c, v1, x1) = (o0.distance, o1.distance, pl ^ ph ^ o0.distance);
        // `n` centres: more than one only for a run of missing centres.
        let (d, n) = median5_exact(rest, e, x1, &mut slow);
        diff |= d;
        (e, pl, ph) = (x1, c.min(v1), c.max(v1));
        if n > 1 {
            // After the run: no range before the centre, v(k - 1) the run's last.
            let v;
            (rest, v) = after_run(core::mem::take(&mut rest), n);
            (e, pl, ph) = (NONE, v, NONE);
            continue;
        }
        rest = core::mem::take(&mut rest).get_mut(1..).unwrap_or_default();
    }
    // The cells after the centres held for the next line, and v(k - 1) and v(k - 2).
    md.np = rest.len();
    let mut c = NONE;
    if let Some(cell) = rest.first() {
        c = cell.distance;
        md.p0 = (c, cell.aux);
    }
    if let Some(cell) = rest.get(1) {
        md.p1 = (cell.distance, cell.aux);
    }
    (md.b1, md.b2) = (pl ^ ph ^ c, e);
    (diff, slow.0)
}

/// The quick rule's step of [`median5`]: the medians of the centres `c0` and `c1`
/// (the distances around them ranges below [`SMALL`]: `e` before `P = (pl, ph)`, the
/// sorted pair before `c0`; `(ql, qh)` the sorted pair `c1`, `c2`; `c3` after), each
/// the middle two of the four shared distances (`P` and `Q` merged) clamped to its own
/// outer one (`e` for `c0`, `c3` for `c1`).
#[inline(always)]
fn quick_pair(e: u32, (pl, ph): (u32, u32), (ql, qh): (u32, u32), c3: u32) -> (u32, u32) {
    let (u, w) = (pl.max(ql), ph.min(qh));
    let (s2, s3) = (u.min(w), u.max(w));
    (s3.min(e).max(s2), s3.min(c3).max(s2))
}

/// The quick rule of [`median5`] without tracking changes, four centres a turn (two,
/// then one, at the end of the line), from the first centre of `rest` with `e` and
/// `P = (pl, ph)` ranges below [`SMALL`] as [`median5`] holds them: up to the first
/// window with a distance not below [`SMALL`], or to the last centre. Returns the
/// cells from the next centre on and its `e` and `P`. Inlined into [`median5`]: a call
/// and the state returned through memory cost about 35 instructions a line.
#[inline(always)]
fn median5_quads(
    mut rest: &mut [Reading],
    mut e: u32,
    mut pl: u32,
    mut ph: u32,
) -> (&mut [Reading], u32, u32, u32) {
    while let [o0, o1, o2, o3, tail @ ..] = rest {
        let (c0, c1, c2, c3) = (o0.distance, o1.distance, o2.distance, o3.distance);
        let (ql, qh) = (c1.min(c2), c1.max(c2));
        if (qh | c3) >= SMALL {
            break;
        }
        (o0.distance, o1.distance) = quick_pair(e, (pl, ph), (ql, qh), c3);
        (e, pl, ph) = (c0, ql, qh);
        let pass = match tail {
            [r4, r5, ..] => Some((r4.distance, r5.distance)),
            _ => None,
        };
        let Some((v4, v5)) = pass else {
            rest = core::mem::take(&mut rest).get_mut(2..).unwrap_or_default();
            break;
        };
        let (rl, rh) = (c3.min(v4), c3.max(v4));
        if (rh | v5) >= SMALL {
            rest = core::mem::take(&mut rest).get_mut(2..).unwrap_or_default();
            break;
        }
        (o2.distance, o3.distance) = quick_pair(c0, (ql, qh), (rl, rh), v5);
        (e, pl, ph) = (c2, rl, rh);
        rest = core::mem::take(&mut rest).get_mut(4..).unwrap_or_default();
    }
    // An odd last centre: the same network for one centre, `Q` the two distances
    // after it.
    if let [o0, o1, o2] = rest {
        let (c, v1, v2) = (o0.distance, o1.distance, o2.distance);
        let (ql, qh) = (v1.min(v2), v1.max(v2));
        if qh < SMALL {
            let (u, w) = (pl.max(ql), ph.min(qh));
            let (s2, s3) = (u.min(w), u.max(w));
            o0.distance = s3.min(e).max(s2);
            (e, pl, ph) = (pl ^ ph ^ c, c.min(v1), c.max(v1));
            rest = core::mem::take(&mut rest).get_mut(1..).unwrap_or_default();
        }
    }
    (rest, e, pl, ph)
}

/// The median of 5 for one centre of [`median5`], out of its loop (a window with no
/// range in it or a range at or above [`SMALL`], or an odd last centre): the centre
/// `w[0]` (its distance before), between `x2` and `x1` (the distances before it,
/// nearest last) and `w[1]` and `w[2]`, becomes its output, no range as `slow.1`,
/// counted in `slow.0` (fewer than three cells: nothing). Returns the OR of the centre
/// with its new value, and the number of centres taken: 1, or for a missing centre the
/// run of missing centres from it ([`none_run`]).
///
/// A missing centre stays missing. Otherwise the general rule (the centre clamped
/// into the middle one or two of the ranges in the window) is the median of five
/// ranges when the missing neighbours are filled in: a pair of them as 0 and
/// `u32::MAX - 1` (at or below and at or above every range: the middle stays), an odd
/// one as the centre (with `n` ranges, `n` even, the centre once more makes the
/// middle of `n + 1` the centre clamped into the middle two).
#[inline(never)]
fn median5_exact(w: &mut [Reading], x2: u32, x1: u32, slow: &mut (usize, u32)) -> (u32, usize) {
    let centres = w.len().saturating_sub(2);
    let [o, a1, a2, ..] = w else {
        return (0, 1);
    };
    let c = o.distance;
    let mut nb = [x2, x1, a1.distance, a2.distance];
    if (nb[0] | nb[1] | c | nb[2] | nb[3]) >= SMALL {
        if c == NONE {
            return (0, none_run(w, centres, slow));
        }
        let missing = nb.iter().filter(|&&v| v == NONE).count();
        let mut fill = if missing % 2 == 1 { c } else { 0 };
        for v in &mut nb {
            if *v == NONE {
                *v = fill;
                fill = if fill == 0 { NONE - 1 } else { 0 };
            }
        }
    }
    // The median of the middle two of `x1`, `c`, `a1`, `a2` and `x2`.
    let [x2, x1, a1, a2] = nb;
    let (u, w) = (x1.min(c).max(a1.min(a2)), x1.max(c).min(a1.max(a2)));
    let x = u.max(w).min(x2).max(u.min(w));
    o.distance = x;
    (x ^ c, 1)
}

/// The cells of [`median5`] after a run of `n` missing centres, and the distance of
/// the first.
#[cold]
#[inline(never)]
fn after_run(rest: &mut [Reading], n: usize) -> (&mut [Reading], u32) {
    let rest = rest.get_mut(n..).unwrap_or_default();
    let v = rest.first().map_or(NONE, |r| r.distance);
    (rest, v)
}

/// A run of missing centres for [`median5_exact`]: the first `centres` cells of `w`
/// (at least one, the first missing) up to the first range each stay missing, written
/// as `slow.1` and counted in `slow.0`. Returns their number.
#[cold]
#[inline(never)]
fn none_run(w: &mut [Reading], centres: usize, slow: &mut (usize, u32)) -> usize {
    let mut n = 0usize;
    for o in w.iter_mut().take(centres) {
        if o.distance != NONE {
            break;
        }
        o.distance = slow.1;
        // At most the line's points: no wrap.
        n = n.wrapping_add(1);
    }
    slow.0 = slow.0.wrapping_add(n);
    n
}

/// The output points into the encoder's form: no range as `out_none`, a range of 0 as
/// 1. Returns the number without a range.
#[inline(never)]
pub(super) fn finish(cells: &mut [Reading], out_none: u32) -> usize {
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
    use super::super::window::median_line;
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

    /// A fixed sequence of pseudo-random words (xorshift32) from `seed` (not 0).
    fn xorshift(mut seed: u32) -> impl FnMut() -> u32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        }
    }

    fn dist(c: &[Reading]) -> Vec<u32> {
        c.iter().map(|r| r.distance).collect()
    }

    /// `stages` with its counts returned: outputs, outputs without a range, the
    /// median's OR of changes, speckle removal's count.
    fn st<const SP: bool, const MD: bool>(
        d: &mut [Reading],
        jump: u32,
        exact: bool,
        sp: &mut Regs,
        md: &mut Regs,
        none: u32,
    ) -> (usize, usize, u32, usize) {
        let (mut t, mut changed) = (Tally::default(), 0);
        // As `line` takes them: both stages by the exact rules in `stages_exact`.
        let (out, invalid) = match (SP, MD) {
            (true, true) if exact => stages_exact(d, jump, sp, md, none, &mut t, &mut changed),
            (true, true) => stages::<MD>(d, jump, exact, sp, md, none, &mut t, &mut changed),
            (true, false) => {
                // Speckle removal alone classifies the line as it loads it: every cell
                // after the held point is the line's reading, by a rule that takes
                // every distance but NONE (an error code) for a range. Run too with the
                // held point as the line's first (classified before the loop): the
                // same outputs, state and counts.
                let mut k = LineConsts::of(&crate::pipeline::PipelineConfig::default());
                k.set_sensor(can_wire::RangeRule::at_least(0));
                k.jump = Some(jump);
                let d0 = d.to_vec();
                let (mut d2, mut sp2, mut t2) = (d0.clone(), *sp, Tally::default());
                sp2.np = 0;
                let r2 = speckle_line(&mut d2, &d0, &k, k.span, exact, &mut sp2, none, &mut t2);
                // The held point is `sp`'s.
                sp.np = 1;
                if let Some(c) = d0.first() {
                    sp.p0 = (c.distance, c.aux);
                }
                let r = speckle_line(
                    d,
                    d0.get(1..).unwrap_or_default(),
                    &k,
                    k.span,
                    exact,
                    sp,
                    none,
                    &mut t,
                );
                assert_eq!((r, t.speckle), (r2, t2.speckle));
                assert_eq!(dist(&d[..r.0]), dist(&d2[..r2.0]));
                assert_eq!((sp.b1, sp.p0.0, sp.np), (sp2.b1, sp2.p0.0, sp2.np));
                // The error codes: the line's NONE readings (the held point's too in
                // the second run).
                let errors = |v: &[Reading]| v.iter().filter(|r| r.distance == NONE).count();
                assert_eq!(t.error_code, errors(&d0[1..]));
                assert_eq!(t2.error_code, errors(&d0));
                r
            }
            _ => median3_pairs(d, exact, md, none, &mut changed),
        };
        (out, invalid, changed, t.speckle)
    }

    /// `median5` with the two distances before the first centre `b` (nearest first;
    /// updated likewise) as its only state.
    fn median5_b(s: &mut [Reading], b: &mut [u32; 2], none: u32) -> (u32, usize) {
        median5_made(s, b, none, 0)
    }

    /// [`median5_b`] with `made` as the change already made (not 0: the changes not
    /// tracked).
    fn median5_made(s: &mut [Reading], b: &mut [u32; 2], none: u32, made: u32) -> (u32, usize) {
        let mut md = Regs {
            b1: b[0],
            b2: b[1],
            ..Regs::default()
        };
        let r = median5(s, &mut md, none, made);
        *b = [md.b1, md.b2];
        r
    }

    /// The median of 5 by sorting (every one of the five a range).
    fn sorted_median(v: [u32; 5]) -> u32 {
        let mut s = v;
        s.sort_unstable();
        s[2]
    }

    #[test]
    fn small_bit_is_the_rule_written_plainly() {
        for d in [
            0,
            1,
            1000,
            SMALL - 2,
            SMALL - 1,
            SMALL,
            SMALL + 1,
            0xC000_0000,
            NONE - 2,
            NONE - 1,
            NONE,
        ] {
            let small = d == NONE || d < 1 << 31;
            assert_eq!(small_bit(d) >> 31 == 0, small, "{d:#x}");
        }
    }

    #[test]
    fn median5_single_centre_follows_the_rule_written_plainly() {
        // Every window of five over values that meet the fill-ins (0 and u32::MAX - 1,
        // ties with them), ranges beside 2^31 and no range, one to four neighbours
        // missing: the single centre's rule against the rule written plainly, its
        // output as the encoder's value, the count and the returned change.
        const OUT_NONE: u32 = 0xdead_beef;
        let vals = [0, 1, 500, (1 << 31) - 1, 1 << 31, u32::MAX - 1, NONE];
        let n = vals.len();
        for t in 0..n.pow(5) {
            let w: [u32; 5] = core::array::from_fn(|i| vals[t / n.pow(i as u32) % n]);
            let want = median_reference(&w, 2);
            let mut s = cells(&w[2..]);
            let mut slow = (3usize, OUT_NONE);
            let (changed, n) = median5_exact(&mut s, w[0], w[1], &mut slow);
            assert_eq!(n, 1, "{w:?}");
            let shown = if want == NONE { OUT_NONE } else { want };
            // The centre's cell only.
            assert_eq!(dist(&s), [shown, w[3], w[4]], "{w:?}");
            assert_eq!(slow, (3 + usize::from(want == NONE), OUT_NONE), "{w:?}");
            assert_eq!(changed != 0, want != w[2], "{w:?}");
        }
        // By hand: one neighbour missing, the centre clamped into the middle two of
        // the four ranges (10 20 | 30 40); two missing, the median of three.
        let one = |c: u32, nb: [u32; 4]| {
            let mut s = cells(&[c, nb[2], nb[3]]);
            median5_exact(&mut s, nb[0], nb[1], &mut (0, 9));
            s[0].distance
        };
        assert_eq!(one(10, [NONE, 20, 30, 40]), 20);
        assert_eq!(one(25, [NONE, 10, 30, 40]), 25);
        assert_eq!(one(45, [10, NONE, 30, 40]), 40);
        assert_eq!(one(45, [NONE, 10, NONE, 40]), 40);
        assert_eq!(one(5, [10, NONE, NONE, 40]), 10);
        assert_eq!(one(5, [NONE, NONE, NONE, 40]), 5);
        assert_eq!(one(NONE, [1, 2, 3, 4]), 9);
    }

    #[test]
    fn median5_network_is_the_sorted_median() {
        // Every 5-tuple over 0..5 (ties included): the network against sorting.
        for t in 0..5u32.pow(5) {
            let v: [u32; 5] = core::array::from_fn(|i| t / 5u32.pow(i as u32) % 5 * 100);
            let mut s = cells(&v[2..]);
            let mut b = [v[1], v[0]];
            median5_b(&mut s, &mut b, NONE);
            assert_eq!(s[0].distance, sorted_median(v), "{v:?}");
            assert_eq!(b, [v[2], v[1]]);
        }
    }

    #[test]
    fn exact_rules_for_ranges_near_no_range() {
        // Ranges at or above 2^31, where the quick tests do not hold. Speckle removal,
        // threshold 20: a range 10 below NONE after a missing point, with a missing
        // point after it, has no support (no range is not a neighbour).
        let mut s = cells(&[u32::MAX - 10, NONE]);
        let mut sp = Regs {
            b1: NONE,
            ..Regs::default()
        };
        let r = st::<true, false>(&mut s, 20, true, &mut sp, &mut Regs::default(), NONE);
        assert_eq!((r.0, r.3, s[0].distance), (1, 1, NONE));
        // The median of 1, 2^32 - 6 and 2^31 + 1 (three ranges) is 2^31 + 1 (the
        // differences wrap as 32-bit signed values: both negative).
        let mut s = cells(&[u32::MAX - 5, (1 << 31) + 1]);
        let mut md = Regs {
            b1: 1,
            ..Regs::default()
        };
        let r = st::<false, true>(&mut s, 0, true, &mut Regs::default(), &mut md, NONE);
        assert_eq!((r.0, s[0].distance), (1, (1 << 31) + 1));
        assert_ne!(r.2, 0);
    }

    #[test]
    fn median3_and_speckle_by_hand() {
        // Both forms of each loop: the quick tests, and the exact rule alone.
        for exact in [false, true] {
            // 1000 9999 1002 1004 (none) 1010: the spike goes (to 1002, the median of
            // 1000 9999 1002), 1002 becomes 1004 (of 9999 1002 1004), a centre beside
            // a missing neighbour stays.
            let median3 = |s: &mut [Reading], b1: u32, none| {
                let mut md = Regs {
                    b1,
                    ..Regs::default()
                };
                let (out, invalid, diff, _) =
                    st::<false, true>(s, 0, exact, &mut Regs::default(), &mut md, none);
                (out, invalid, diff, md.b1)
            };
            let mut s = cells(&[9999, 1002, 1004, NONE, 1010]);
            let (out, _, diff, b1) = median3(&mut s, 1000, NONE);
            assert_eq!(dist(&s), [1002, 1004, 1004, NONE, 1010]);
            assert_ne!(diff, 0);
            assert_eq!((out, b1), (4, NONE));
            // The last stage: no range as the encoder's value, counted.
            let mut s = cells(&[9999, NONE, 1004, 1003]);
            assert_eq!(median3(&mut s, 1000, 7).1, 1);
            assert_eq!(dist(&s), [9999, 7, 1004, 1003]);
            // Threshold 5: 1000 (supported by 1004) stays, 2000 and 3000 go, a missing
            // centre is not counted.
            let mut s = cells(&[1000, 2000, NONE, 3000, 3010]);
            let mut sp = Regs {
                b1: 1004,
                ..Regs::default()
            };
            let (out, _, _, removed) =
                st::<true, false>(&mut s, 5, exact, &mut sp, &mut Regs::default(), NONE);
            assert_eq!((out, removed), (4, 2));
            assert_eq!(dist(&s), [1000, NONE, NONE, NONE, 3010]);
            assert_eq!((sp.b1, sp.p0.0, sp.np), (3000, 3010, 1));
        }
    }

    /// The median of a window as the pipeline's rule says: a missing centre stays
    /// missing; else the valid ranges sorted, `n` of them, the centre clamped into
    /// `[sorted[(n - 1) / 2], sorted[n / 2]]`.
    fn median_reference(window: &[u32], centre: usize) -> u32 {
        let c = window[centre];
        if c == NONE {
            return c;
        }
        let mut v: Vec<u32> = window.iter().copied().filter(|&x| x != NONE).collect();
        v.sort_unstable();
        let n = v.len();
        c.clamp(v[(n - 1) / 2], v[n / 2])
    }

    #[test]
    fn median5_follows_the_rule_written_plainly() {
        // Lines over edge values (no range, 0, ranges near 2^31 and NONE, ties), with
        // the two distances before them: every output against the rule.
        let vals = [0, 1, 7, 7, 1000, (1 << 31) - 1, 1 << 31, u32::MAX - 1, NONE];
        let mut next = xorshift(0x9e37_79b9_u32);
        for round in 0..40000 {
            // Lines up to 9 points and now and then up to 19 (more than one turn of
            // four centres, and the last one to three centres after them); in half
            // the rounds a change already made (the changes untracked).
            let len = next() as usize % if round % 8 == 0 { 20 } else { 10 };
            let made = u32::from(round % 2 == 1);
            let mut pick = || vals[next() as usize % vals.len()];
            let stream: Vec<u32> = (0..len + 2).map(|_| pick()).collect();
            median5_line_follows_the_plain_rule(&stream, made);
        }
    }

    /// `median5` over the line `stream[2..]`, the two distances before it `stream[0]`
    /// (the older) and `stream[1]` held, `made` a change already made: every output
    /// against the rule written plainly (no range shown as 9), the count of outputs
    /// without a range, the change flag; the cells after the outputs stay, and the two
    /// before the next centre move on.
    fn median5_line_follows_the_plain_rule(stream: &[u32], made: u32) {
        let mut s = cells(&stream[2..]);
        let mut b = [stream[1], stream[0]];
        let (diff, invalid) = median5_made(&mut s, &mut b, 9, made);
        let outs = stream.len().saturating_sub(4);
        let want: Vec<u32> = (0..outs)
            .map(|i| median_reference(&stream[i..i + 5], 2))
            .collect();
        let shown: Vec<u32> = want
            .iter()
            .map(|&x| if x == NONE { 9 } else { x })
            .collect();
        assert_eq!(dist(&s[..outs]), shown, "{stream:?} {made}");
        assert_eq!(invalid, want.iter().filter(|&&x| x == NONE).count());
        let any = want.iter().zip(&stream[2..]).any(|(x, c)| x != c);
        assert_eq!(diff != 0, made != 0 || any, "{stream:?} {made}");
        assert_eq!(dist(&s[outs..]), stream[2 + outs..]);
        assert_eq!(b, [stream[outs + 1], stream[outs]], "{stream:?}");
    }

    #[test]
    fn median5_turns_and_odd_last_centre_follow_the_rule_written_plainly() {
        // Lines of 3 to 18 cells (1 to 16 centres: whole turns of four centres, then
        // none, one, two or three more), ranges below 2^31 with ties, and in turn each
        // distance (the two before the line included) replaced by no range, 0,
        // 2^31 - 1 or 2^31 (the quick loop left at every place of a turn and at the
        // odd last centre); with a change already made (the changes untracked) and
        // without: every output against the rule written plainly.
        let mut next = xorshift(0x2545_f491_u32);
        for n in 3..=18usize {
            for spot in 0..=n + 2 {
                for odd in [NONE, 0, (1 << 31) - 1, 1 << 31] {
                    for made in [0u32, 1] {
                        let mut stream: Vec<u32> = (0..n + 2).map(|_| 1000 + next() % 8).collect();
                        if let Some(v) = stream.get_mut(spot) {
                            *v = odd;
                        }
                        median5_line_follows_the_plain_rule(&stream, made);
                    }
                }
            }
        }
    }

    #[test]
    fn median5_in_lines_follows_the_general_rule() {
        // A stream cut into lines of 0 to 6 points (now and then up to 12 or 39), the median's
        // state held across them as `line` holds it (the distances before the next
        // centre in `b`, the last two cells of a line kept for the next): every output
        // against the general rule (`median_line`, and the rule written plainly), with
        // no range anywhere, ranges near and above 2^31, ties; in half the rounds only
        // ranges below 2^31 (the quick rule's domain) with a few no ranges.
        const OUT_NONE: u32 = 0xdead_beef;
        let edges = [
            0,
            1,
            7,
            (1 << 31) - 2,
            (1 << 31) - 1,
            1 << 31,
            (1 << 31) + 1,
            u32::MAX - 1,
            NONE,
        ];
        let mut next = xorshift(0x1234_5679_u32);
        for round in 0..3000 {
            let quick = round % 2 == 0;
            let pick = |next: &mut dyn FnMut() -> u32| {
                let r = next();
                match (quick, r % 16) {
                    (true, 0) => NONE,
                    // Runs of missing points in a quarter of the rounds.
                    (true, 2..=6) if round % 4 == 0 => NONE,
                    (true, 1) => (1 << 31) - 1 - next() % 3,
                    (true, _) => 1000 + next() % 50,
                    (false, 0..=5) => edges[next() as usize % edges.len()],
                    (false, _) => 1000 + next() % 50,
                }
            };
            let before = [pick(&mut next), pick(&mut next)];
            let lines: Vec<Vec<u32>> = (0..next() % 8)
                .map(|_| {
                    let len = match next() % 8 {
                        0 => next() % 40,
                        1 | 2 => next() % 13,
                        _ => next() % 7,
                    };
                    (0..len).map(|_| pick(&mut next)).collect()
                })
                .collect();
            // v(-2), v(-1), then the stream.
            let v: Vec<u32> = before
                .iter()
                .chain(lines.iter().flatten())
                .copied()
                .collect();
            // `b` nearest first, as `line` keeps it.
            let mut md = Regs {
                b1: before[1],
                b2: before[0],
                ..Regs::default()
            };
            let mut held: Vec<u32> = Vec::new();
            let mut outs: Vec<u32> = Vec::new();
            for line in &lines {
                let region: Vec<u32> = held.iter().chain(line).copied().collect();
                let mut s = cells(&region);
                let out = region.len().saturating_sub(2);
                // A change already made (every third round): the changes untracked.
                let made = u32::from(round % 3 == 1) << 4;
                let (diff, invalid) = median5(&mut s, &mut md, OUT_NONE, made);
                // This line's outputs against the rule: centres outs.len()..
                let first = outs.len();
                let want: Vec<u32> = (first..first + out)
                    .map(|k| {
                        let w = &v[k..k + 5];
                        let x = median_line(w[2], [w[0], w[1], w[3], w[4]], NONE);
                        assert_eq!(x, median_reference(w, 2), "{w:?}");
                        x
                    })
                    .collect();
                let shown: Vec<u32> = want
                    .iter()
                    .map(|&x| if x == NONE { OUT_NONE } else { x })
                    .collect();
                assert_eq!(dist(&s[..out]), shown, "{before:?} {lines:?}");
                assert_eq!(invalid, want.iter().filter(|&&x| x == NONE).count());
                let centres = &v[first + 2..first + 2 + out];
                let any = want.iter().zip(centres).any(|(x, c)| x != c);
                assert_eq!(diff != 0, made != 0 || any);
                // The cells after the outputs stay as they came.
                assert_eq!(dist(&s[out..]), region[out..]);
                outs.extend(&shown);
                held = region[out..].to_vec();
                // The cells held (as `line` copies them in front of the next line) and
                // the two distances before the next centre.
                assert_eq!(md.np, held.len());
                if let Some(&d) = held.first() {
                    assert_eq!(md.p0.0, d);
                }
                if let Some(&d) = held.get(1) {
                    assert_eq!(md.p1.0, d);
                }
                let k = outs.len();
                assert_eq!([md.b1, md.b2], [v[k + 1], v[k]], "{before:?} {lines:?}");
            }
        }
    }

    #[test]
    fn classify_follows_the_rule_written_plainly() {
        // Distances around every edge of a few rules (the sensor's minimum, its error
        // codes at or above it, the range window, 2^31, NONE), with and without an
        // intensity threshold: each reading and the counts against the rule.
        let rules = [
            can_wire::RangeRule {
                min: 20,
                except: [65533, 65535],
                band: Some(40),
                window: [100, 30000],
            },
            can_wire::RangeRule::at_least(1),
            can_wire::RangeRule {
                window: [0, (1 << 31) + 5],
                ..can_wire::RangeRule::at_least(20)
            },
        ];
        let ds = [
            0,
            1,
            19,
            20,
            21,
            39,
            40,
            42,
            43,
            99,
            100,
            30000,
            30001,
            65533,
            65534,
            65535,
            (1 << 31) - 1,
            1 << 31,
            (1 << 31) + 6,
            u32::MAX - 1,
            NONE,
        ];
        for rule in rules {
            for min_intensity in [0, 50] {
                let input: Vec<Reading> = ds
                    .iter()
                    .enumerate()
                    .map(|(i, &distance)| Reading {
                        distance,
                        aux: (i as u32 * 37) % 100,
                    })
                    .collect();
                let mut k = LineConsts::of(&crate::pipeline::PipelineConfig::default());
                k.rule.window = rule.window;
                k.set_sensor(rule);
                k.min_intensity = min_intensity;
                let mut out = cells(&std::vec![7; ds.len()]);
                let mut t = Tally::default();
                classify(&input, &mut out, &k, &mut t);
                let (mut e, mut w, mut l) = (0, 0, 0);
                for (r, o) in input.iter().zip(&out) {
                    let d = r.distance;
                    let want = if d == NONE || !rule.is_sensor_range(d) {
                        e += 1;
                        NONE
                    } else if !rule.is_range(d) {
                        w += 1;
                        NONE
                    } else if r.aux < min_intensity {
                        l += 1;
                        NONE
                    } else {
                        d
                    };
                    assert_eq!((o.distance, o.aux), (want, r.aux), "{rule:?} {d}");
                }
                assert_eq!((t.error_code, t.out_of_range, t.low_intensity), (e, w, l));
            }
        }
    }

    /// The median of 3 of `b`, `c`, `s` as the pipeline's rule says: a missing centre
    /// stays missing, a missing neighbour leaves the centre, else the middle value.
    fn median3_reference(b: u32, c: u32, s: u32) -> u32 {
        if [b, c, s].contains(&NONE) {
            c
        } else {
            let mut v = [b, c, s];
            v.sort_unstable();
            v[1]
        }
    }

    /// Speckle removal as the pipeline's rule says: a range with no range within
    /// `jump` beside it goes.
    fn speckle_reference(b: u32, c: u32, a: u32, jump: u32) -> u32 {
        let near = |x: u32| x != NONE && x.abs_diff(c) <= jump;
        if c == NONE || near(b) || near(a) {
            c
        } else {
            NONE
        }
    }

    /// Runs `stages` over `d` (distances) with the distances before the stages' first
    /// centres `bs` and `bm`: the outputs, how many have no range, whether the median
    /// changed a range, speckle removal's count and the registers left.
    fn run<const SP: bool, const MD: bool>(
        d: &[u32],
        (bs, bm): (u32, u32),
        jump: u32,
        exact: bool,
        none: u32,
    ) -> (Vec<u32>, usize, bool, usize, [u32; 4]) {
        let mut c = cells(d);
        let mut sp = Regs {
            b1: bs,
            ..Regs::default()
        };
        let mut md = Regs {
            b1: bm,
            ..Regs::default()
        };
        let (out, invalid, diff, removed) =
            st::<SP, MD>(&mut c, jump, exact, &mut sp, &mut md, none);
        let regs = [sp.b1, sp.p0.0, md.b1, md.p0.0];
        (dist(&c[..out]), invalid, diff != 0, removed, regs)
    }

    #[test]
    fn both_loops_follow_the_rules_written_plainly() {
        // Lines over edge values (no range, small ranges, ranges near 2^31 and NONE),
        // every speckle threshold among them; the quick loop where it holds (every
        // range below 2^31) and the exact loop everywhere.
        let vals = [
            1,
            2,
            40,
            41,
            1000,
            (1 << 31) - 2,
            (1 << 31) - 1,
            1 << 31,
            (1 << 31) + 1,
            u32::MAX - 2,
            u32::MAX - 1,
            NONE,
        ];
        let mut next = xorshift(0x2545_f491_u32);
        for round in 0..6000 {
            // Small values only half the time (the quick loop's domain).
            let k = if round % 2 == 0 { 6 } else { vals.len() };
            let len = next() as usize % 9;
            let jump = [0, 1, 39, 40, (1 << 31) - 1, 1 << 31, NONE][next() as usize % 7];
            let mut pick = || vals[next() as usize % k];
            let line: Vec<u32> = (0..len).map(|_| pick()).collect();
            let (b0, c0, b1, c1) = (pick(), pick(), pick(), pick());
            let big = |v: &u32| *v != NONE && *v >= 1 << 31;
            let quick_holds = !line.iter().chain(&[b0, c0, b1, c1]).any(big) && jump < 1 << 31;
            for exact in [false, true] {
                // Speckle removal alone: its quick test is exact for any ranges with a
                // threshold below 2^31.
                let alone_holds = jump < 1 << 31;
                if !exact && !alone_holds {
                    continue;
                }
                // Speckle removal alone: its centre c0 (b0 before it), then the line.
                let s: Vec<u32> = std::iter::once(c0).chain(line.iter().copied()).collect();
                let want: Vec<u32> = (0..len)
                    .map(|i| {
                        speckle_reference(if i == 0 { b0 } else { s[i - 1] }, s[i], s[i + 1], jump)
                    })
                    .collect();
                // As the last stage: no range as the encoder's value 9, counted.
                let as_out = |w: &[u32]| -> Vec<u32> {
                    w.iter().map(|&x| if x == NONE { 9 } else { x }).collect()
                };
                let (got, invalid, _, removed, r) =
                    run::<true, false>(&s, (b0, NONE), jump, exact, 9);
                assert_eq!(got, as_out(&want), "speckle {b0} {s:?} {jump} {exact}");
                assert_eq!(invalid, want.iter().filter(|&&x| x == NONE).count());
                let gone = want
                    .iter()
                    .zip(&s)
                    .filter(|(x, c)| **x == NONE && **c != NONE)
                    .count();
                assert_eq!(removed, gone);
                if len > 0 {
                    assert_eq!((r[0], r[1]), (s[len - 1], s[len]));
                }
                if !exact && !quick_holds {
                    continue;
                }
                // The median alone: its centre c1 (b1 before it), then the line.
                let m: Vec<u32> = std::iter::once(c1).chain(line.iter().copied()).collect();
                let want_m: Vec<u32> = (0..len)
                    .map(|i| median3_reference(if i == 0 { b1 } else { m[i - 1] }, m[i], m[i + 1]))
                    .collect();
                let (got, invalid, changed, _, r) = run::<false, true>(&m, (NONE, b1), 0, exact, 9);
                let shown: Vec<u32> = want_m
                    .iter()
                    .map(|&x| if x == NONE { 9 } else { x })
                    .collect();
                assert_eq!(got, shown, "median {b1} {m:?} {exact}");
                assert_eq!(invalid, want_m.iter().filter(|&&x| x == NONE).count());
                assert_eq!(changed, want_m.iter().zip(&m).any(|(x, c)| x != c));
                if len > 0 {
                    assert_eq!((r[2], r[3]), (m[len - 1], m[len]));
                }
                // Both: the median's centre held, then speckle removal's c0 and the
                // line; the median takes speckle removal's outputs. The median's centre
                // is speckle removal's output for b0: b0, or no range when b0 could
                // have gone (no support from c0).
                let unsupported = b0 == NONE || c0 == NONE || c0.abs_diff(b0) > jump;
                let c1 = if unsupported && c1 % 2 == 0 { NONE } else { b0 };
                let m2: Vec<u32> = std::iter::once(c1).chain(want.iter().copied()).collect();
                let want2: Vec<u32> = (0..len)
                    .map(|i| {
                        median3_reference(if i == 0 { b1 } else { m2[i - 1] }, m2[i], m2[i + 1])
                    })
                    .collect();
                let both: Vec<u32> = std::iter::once(c1).chain(s.iter().copied()).collect();
                let (got, invalid, _, removed, r) =
                    run::<true, true>(&both, (b0, b1), jump, exact, 9);
                assert_eq!(
                    got,
                    as_out(&want2),
                    "both {b0} {c0} {b1} {c1} {line:?} {jump} {exact}"
                );
                assert_eq!(invalid, want2.iter().filter(|&&x| x == NONE).count());
                assert_eq!(removed, gone);
                // Speckle removal's registers: the inputs it last saw (b0 and c0
                // with an empty line).
                assert_eq!(
                    (r[0], r[1]),
                    (s.get(len.wrapping_sub(1)).copied().unwrap_or(b0), s[len])
                );
                if len > 0 {
                    assert_eq!((r[2], r[3]), (m2[len - 1], m2[len]));
                }
            }
        }
    }

    #[test]
    fn median3_alone_in_lines_follows_the_rule_written_plainly() {
        // A stream cut into lines of 0 to 6 points, the median's state held across
        // them as `line` holds it (its held point first in the next line's cells),
        // against the median of 3 of the whole stream by the plain rule: no range,
        // ranges near and above 2^31, ties. The four-centre quick rule only where
        // every range is below 2^31, the exact rule everywhere.
        let small = [1, 2, 40, (1 << 31) - 2, (1 << 31) - 1, NONE];
        let vals = [
            1,
            2,
            40,
            (1 << 31) - 2,
            (1 << 31) - 1,
            1 << 31,
            (1 << 31) + 1,
            u32::MAX - 1,
            NONE,
        ];
        let mut next = xorshift(0x1357_9bdf_u32);
        for round in 0..4000 {
            let set: &[u32] = if round % 2 == 0 { &small } else { &vals };
            // Mostly two values, for ties and long quick runs.
            let narrow = round % 3 == 0;
            let mut pick = || {
                let k = if narrow { 2 } else { set.len() };
                set[next() as usize % k]
            };
            let b1 = pick();
            let lines: Vec<Vec<u32>> = (0..1 + round % 5)
                .map(|_| {
                    let len = pick() as usize % 7;
                    (0..len).map(|_| pick()).collect()
                })
                .collect();
            let stream: Vec<u32> = lines.iter().flatten().copied().collect();
            let big = |v: &u32| *v != NONE && *v >= 1 << 31;
            let quick_holds = !stream.iter().chain(&[b1]).any(big);
            // The plain rule: every point but the last is a centre.
            let centres = stream.len().saturating_sub(1);
            let want: Vec<u32> = (0..centres)
                .map(|i| {
                    let b = if i == 0 { b1 } else { stream[i - 1] };
                    median3_reference(b, stream[i], stream[i + 1])
                })
                .collect();
            let want_diff = want
                .iter()
                .zip(&stream)
                .filter(|(x, c)| x != c && **c != NONE)
                .fold(0, |acc, (x, c)| acc | (x ^ c));
            let want_invalid = want.iter().filter(|&&x| x == NONE).count();
            for exact in [false, true] {
                if !exact && !quick_holds {
                    continue;
                }
                let mut md = Regs {
                    b1,
                    ..Regs::default()
                };
                let (mut got, mut invalid, mut diff) = (Vec::new(), 0, 0);
                for line in &lines {
                    let held: Vec<u32> = if md.np > 0 { vec![md.p0.0] } else { vec![] };
                    let mut c = cells(&[held, line.clone()].concat());
                    let mut sp = Regs::default();
                    let (out, inv, d, _) = st::<false, true>(&mut c, 0, exact, &mut sp, &mut md, 9);
                    got.extend(dist(&c[..out]));
                    invalid += inv;
                    diff |= d;
                }
                let shown: Vec<u32> = want
                    .iter()
                    .map(|&x| if x == NONE { 9 } else { x })
                    .collect();
                assert_eq!(got, shown, "{b1} {lines:?} {exact}");
                assert_eq!(invalid, want_invalid, "{b1} {lines:?} {exact}");
                assert_eq!(diff, want_diff, "{b1} {lines:?} {exact}");
                // The state held: the last point and the one before it.
                if let Some(&last) = stream.last() {
                    let before = if stream.len() > 1 {
                        stream[stream.len() - 2]
                    } else {
                        b1
                    };
                    assert_eq!((md.np, md.p0.0, md.b1), (1, last, before));
                }
            }
        }
    }

    #[test]
    fn median3_off_follows_the_rule_written_plainly() {
        // Every triple over edge values (0, 1, ties, ranges near 2^31, no range, and
        // with `exact` ranges at and above 2^31) whose centre the quick test does not
        // pass, against the plain rule: the output, the change ORed, the count.
        let small = [0, 1, 2, 40, SMALL - 2, SMALL - 1, NONE];
        let all = [
            0,
            1,
            2,
            40,
            SMALL - 2,
            SMALL - 1,
            SMALL,
            SMALL + 1,
            NONE - 1,
            NONE,
        ];
        for (vals, exact) in [(&small[..], 0), (&all[..], SMALL)] {
            for &b in vals {
                for &c in vals {
                    for &s in vals {
                        let quick = ((c.wrapping_sub(b) ^ s.wrapping_sub(c)) | c | exact) < SMALL;
                        if quick {
                            // The quick test passes only for the centre as the median.
                            assert_eq!(median3_reference(b, c, s), c, "{b} {c} {s}");
                            continue;
                        }
                        let (mut diff, mut invalid) = (0, 0);
                        let x = median3_off::<false>((b, c, s), exact, &mut diff, &mut invalid, 9);
                        let (mut diff2, mut invalid2) = (0, 0);
                        let x2 =
                            median3_off::<true>((b, c, s), exact, &mut diff2, &mut invalid2, 9);
                        assert_eq!((x2, diff2, invalid2), (x, diff, invalid));
                        let want = median3_reference(b, c, s);
                        let shown = if want == NONE { 9 } else { want };
                        assert_eq!(x, shown, "{b} {c} {s} {exact}");
                        assert_eq!(invalid, usize::from(want == NONE));
                        let change = if c == NONE { 0 } else { want ^ c };
                        assert_eq!(diff, change, "{b} {c} {s} {exact}");
                    }
                }
            }
        }
    }

    #[test]
    fn stages_follow_the_rules_over_every_short_line() {
        // Speckle removal then the median of 3 over every line of three points (the
        // speckle centre held, two more) with every held state, over values around
        // each threshold, 0, ranges just below 2^31 and no range (a range below the
        // threshold after no range among them: a difference test on 32-bit wrapping
        // differences would pass it), against the plain rules.
        for jump in [0, 1, 40, SMALL - 1] {
            let vals = [
                0,
                1,
                jump.saturating_sub(1),
                jump,
                (jump + 1).min(SMALL - 1),
                SMALL - 2,
                NONE,
            ];
            for &b0 in &vals {
                for &b1 in &vals {
                    for &c0 in &vals {
                        for &l0 in &vals {
                            for &l1 in &vals {
                                let s = [c0, l0, l1];
                                let want: Vec<u32> = (0..2)
                                    .map(|i| {
                                        let b = if i == 0 { b0 } else { s[i - 1] };
                                        speckle_reference(b, s[i], s[i + 1], jump)
                                    })
                                    .collect();
                                let gone = (0..2).filter(|&i| want[i] == NONE && s[i] != NONE);
                                let gone = gone.count();
                                // The median's held centre: speckle removal's output for
                                // b0 (b0, or no range when b0 had no support from c0).
                                let unsupported =
                                    b0 == NONE || c0 == NONE || c0.abs_diff(b0) > jump;
                                let held = if unsupported {
                                    vec![b0, NONE]
                                } else {
                                    vec![b0]
                                };
                                for c1 in held {
                                    let m = [c1, want[0], want[1]];
                                    let want2: Vec<u32> = (0..2)
                                        .map(|i| {
                                            let b = if i == 0 { b1 } else { m[i - 1] };
                                            median3_reference(b, m[i], m[i + 1])
                                        })
                                        .collect();
                                    let both = [c1, c0, l0, l1];
                                    let (got, invalid, _, removed, r) =
                                        run::<true, true>(&both, (b0, b1), jump, false, 9);
                                    let shown: Vec<u32> = want2
                                        .iter()
                                        .map(|&x| if x == NONE { 9 } else { x })
                                        .collect();
                                    let case = (jump, b0, b1, c1, s);
                                    assert_eq!(got, shown, "{case:?}");
                                    assert_eq!(
                                        invalid,
                                        want2.iter().filter(|&&x| x == NONE).count()
                                    );
                                    assert_eq!(removed, gone, "{case:?}");
                                    assert_eq!(r, [l0, l1, m[1], m[2]], "{case:?}");
                                }
                            }
                        }
                    }
                }
            }
        }
    }
}
