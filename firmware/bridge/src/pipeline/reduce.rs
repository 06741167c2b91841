//! Angular decimation of a line at a time, for [`super::Pipeline::filter_line`]: the
//! line's points, already classified (and filtered by speckle removal or a median when
//! those are on), reduced group by group in place.
//!
//! [`reduce_line`] carries the open group from line to line in the [`Decimator`]'s
//! state, so that it gives exactly what [`Decimator::push`] gives point by point (the
//! groups span lines; the end of the scan flushes the last one with
//! [`Decimator::flush`]). A loop per mode, the group's state in registers: `First`
//! copies every `factor`-th point (from the first group that begins in the line) in a
//! loop of its own; `Min` keeps a running minimum (the first of equals), counting each
//! group's points down; pairs, after the open group's rest, take a loop of their own
//! that writes each output through a zip with the cells behind it (no check per
//! output). `Mean` of points without intensities (the common case) takes the whole
//! line in one call ([`mean_plain`]): the rest of the group the line before left open,
//! then the whole groups in a loop of their own that writes its outputs the same way
//! (threes by `(sum + 1) / 3` in 32 bits, a multiply by the reciprocal, when their
//! ranges are below 2^30; pairs by the rounded mean of two without a division, `(a |
//! b) - ((a ^ b) >> 1)`; other factors a sum and a count with one division a group), then the
//! points left into the new open group; with intensities every group counts down. The
//! points are read and written through a slice of [`Cell`]s, each output over a cell
//! already read.

use core::cell::Cell;

use scip::Reading;

use super::config::DecimationMode;
use super::decimate::Decimator;
use super::NONE;

/// Rounded mean (halves up) of `sum / n`, `n` at least 1: the division in 32 bits when
/// the sum fits (one instruction on the Cortex-M4). Once per group: out of line (code
/// size, and the group loop's registers).
#[inline(never)]
pub(super) fn mean(sum: u64, n: u32) -> u32 {
    let half = n >> 1;
    match u32::try_from(sum).ok().and_then(|s| s.checked_add(half)) {
        Some(s) => s.checked_div(n).unwrap_or(NONE),
        None => wide_mean(sum, n),
    }
}

/// [`mean`] of a sum past 32 bits (long ranges).
#[cold]
#[inline(never)]
fn wide_mean(sum: u64, n: u32) -> u32 {
    let n = u64::from(n);
    sum.saturating_add(n >> 1)
        .checked_div(n)
        .and_then(|m| u32::try_from(m).ok())
        .unwrap_or(NONE)
}

/// The rounded mean (halves up) of two values, `(a + b + 1) / 2` without the 33-bit
/// sum: `a + b` is `(a ^ b) + 2 (a & b)`, so the mean is `(a & b) + ceil((a ^ b) / 2)`,
/// which is `(a | b) - floor((a ^ b) / 2)`.
#[inline(always)]
fn mean2(a: u32, b: u32) -> u32 {
    // `a | b` is at least `a ^ b`, which is at least half of it: no wrap.
    (a | b).wrapping_sub((a ^ b) >> 1)
}

/// The output side of [`reduce_line`]: the cells the output points go to, in order
/// (each written after the points of its group were read, so never ahead of the
/// reading), and how many of the outputs have no range.
#[derive(Clone)]
struct Written<'a> {
    slots: core::slice::Iter<'a, Cell<Reading>>,
    out_none: u32,
    invalid: usize,
}

impl Written<'_> {
    /// One output point, in the encoder's form (no range as `out_none`, a range of 0
    /// as 1).
    #[inline(always)]
    fn emit(&mut self, (d, aux): (u32, u32)) {
        let none = d == NONE;
        if let Some(slot) = self.slots.next() {
            let mut r = slot.get();
            r.distance = if none { self.out_none } else { d.max(1) };
            r.aux = aux;
            slot.set(r);
        }
        // At most the line's points.
        self.invalid = self.invalid.wrapping_add(usize::from(none));
    }

    /// The output points of the groups of `k` of `cells`, `point` of each (the groups
    /// behind the slots written so far: each output over a cell already read), in one
    /// loop without a check per output; returns the points left over (fewer than `k`).
    #[inline(always)]
    fn groups<'c>(
        &mut self,
        cells: &'c [Cell<Reading>],
        k: usize,
        point: impl Fn(&[Cell<Reading>]) -> (u32, u32),
    ) -> &'c [Cell<Reading>] {
        let groups = cells.chunks_exact(k);
        let left = groups.remainder();
        let slots = self.slots.as_slice();
        let (mut invalid, out_none) = (self.invalid, self.out_none);
        let mut taken = 0usize;
        for (slot, group) in slots.iter().zip(groups) {
            let (d, aux) = point(group);
            let none = d == NONE;
            let mut r = slot.get();
            r.distance = if none { out_none } else { d.max(1) };
            r.aux = aux;
            slot.set(r);
            // Both at most the line's points.
            invalid = invalid.wrapping_add(usize::from(none));
            taken = taken.wrapping_add(1);
        }
        self.invalid = invalid;
        self.slots = slots.get(taken..).unwrap_or_default().iter();
        left
    }
}

/// `First` over the line (see [`reduce_line`]): the points of `cells` from the `i`-th,
/// every `k`-th (`k` at least 1), to the front in the encoder's form (no range as
/// `out_none`, a range of 0 as 1), intensity kept. Returns the outputs written and
/// how many of them have no range.
#[inline(never)]
fn firsts(cells: &[Cell<Reading>], mut i: usize, k: usize, out_none: u32) -> (usize, usize) {
    let (mut taken, mut invalid) = (0usize, 0usize);
    // Each output's slot is at or before its point (`i` is at least `taken`).
    while let (Some(c), Some(slot)) = (cells.get(i), cells.get(taken)) {
        let p = c.get();
        let none = p.distance == NONE;
        let mut r = slot.get();
        r.distance = if none { out_none } else { p.distance.max(1) };
        r.aux = p.aux;
        slot.set(r);
        // At most the line's points (`i` below its length plus 2^16): no wrap.
        invalid = invalid.wrapping_add(usize::from(none));
        taken = taken.wrapping_add(1);
        i = i.wrapping_add(k);
    }
    (taken, invalid)
}

/// A point into the running minimum `best` (range, intensity): NONE is above every
/// range, so an invalid point never wins; of equals the first stays.
#[inline(always)]
fn min1((d, aux): (u32, u32), best: (u32, u32)) -> (u32, u32) {
    if d < best.0 {
        (d, aux)
    } else {
        best
    }
}

/// A cell's distance and intensity.
#[inline(always)]
fn value(cell: &Cell<Reading>) -> (u32, u32) {
    let r = cell.get();
    (r.distance, r.aux)
}

/// No range, no intensity: an empty group's minimum.
const EMPTY: (u32, u32) = (NONE, 0);

/// `Min` over the line (see [`reduce_line`]): the open group's `have` points (below
/// `k`) and their minimum `best` in, the same of the group left open out. Pairs take a
/// loop of their own after the open group's rest.
#[inline(always)]
fn min_line(
    cells: &[Cell<Reading>],
    k: usize,
    open: (usize, (u32, u32)),
    o: &mut Written<'_>,
) -> (usize, (u32, u32)) {
    if k != 2 {
        return min_count(cells, k, open, o);
    }
    // The open group's rest first (its one missing point when `have` is 1).
    // (No points leave the group as it is: no call.)
    let (head, rest) = cells.split_at(open.0.min(cells.len()));
    let open = if head.is_empty() {
        open
    } else {
        min_count(head, k, open, o)
    };
    // The pairs, then the point left over into a new group (when the line ended in the
    // open group, `rest` is empty and the group stays open).
    let left = min_pairs(rest, o);
    if left.is_empty() {
        open
    } else {
        min_count(left, k, open, o)
    }
}

/// The pairs of `cells` (a pair beginning at the first): their `Min` (the first of
/// equals), in one loop writing the output points behind them. Returns the point left
/// over, if any.
#[inline(never)]
fn min_pairs<'c>(cells: &'c [Cell<Reading>], o: &mut Written<'_>) -> &'c [Cell<Reading>] {
    o.groups(cells, 2, |g| match g {
        [a, b] => min1(value(b), min1(value(a), EMPTY)),
        _ => EMPTY,
    })
}

/// `Min` over the line (see [`reduce_line`]), counting each group's points down: the
/// open group's `have` points (below `k`) and their minimum `best` in, the same of the
/// group left open out.
#[inline(never)]
fn min_count(
    cells: &[Cell<Reading>],
    k: usize,
    (have, mut best): (usize, (u32, u32)),
    o: &mut Written<'_>,
) -> (usize, (u32, u32)) {
    // Points until the group is complete (`have` is below `k`).
    let mut left = k.wrapping_sub(have);
    // The writer in registers for the loop.
    let mut w = o.clone();
    for c in cells {
        best = min1(value(c), best);
        left = left.wrapping_sub(1);
        if left == 0 {
            w.emit(best);
            (best, left) = (EMPTY, k);
        }
    }
    *o = w;
    (k.wrapping_sub(left), best)
}

/// A `Mean` group's sums: of the valid ranges, their count, and of their intensities
/// and the count of those.
#[derive(Clone, Copy)]
struct Sums {
    sum: u64,
    valid: u32,
    aux_sum: u64,
    auxes: u32,
}

impl Sums {
    const EMPTY: Sums = Sums {
        sum: 0,
        valid: 0,
        aux_sum: 0,
        auxes: 0,
    };

    /// The sums with a point added (its intensity masked with `aux_mask`, `u32::MAX`
    /// when the points carry intensities, 0 otherwise).
    #[inline(always)]
    fn add(mut self, (d, aux): (u32, u32), aux_mask: u32) -> Sums {
        if d != NONE {
            // Each count at most the scan's points, each sum of u32s: no wrap.
            self.sum = self.sum.wrapping_add(u64::from(d));
            self.valid = self.valid.wrapping_add(1);
            self.aux_sum = self.aux_sum.wrapping_add(u64::from(aux & aux_mask));
            self.auxes = self.auxes.wrapping_add(1 & aux_mask);
        }
        self
    }

    /// The group's output point: the rounded means, no range (and intensity 0) when no
    /// point was valid, intensity 0 when none carried one.
    #[inline(always)]
    fn point(&self) -> (u32, u32) {
        if self.valid == 0 {
            EMPTY
        } else {
            let aux = if self.auxes == 0 {
                0
            } else {
                mean(self.aux_sum, self.auxes)
            };
            (mean(self.sum, self.valid), aux)
        }
    }
}

/// The valid ranges of `cells` added to `(sum, valid)` (the open group's: at most the
/// factor's points, so no wrap). Out of line (code size: a few points a line).
#[inline(never)]
fn range_sums(cells: &[Cell<Reading>], sums: (u64, u32)) -> (u64, u32) {
    sums_of(cells, sums)
}

/// [`range_sums`] in line (the points left at the end of every line).
#[inline(always)]
fn sums_of(cells: &[Cell<Reading>], (mut sum, mut valid): (u64, u32)) -> (u64, u32) {
    for c in cells {
        let d = c.get().distance;
        if d != NONE {
            sum = sum.wrapping_add(u64::from(d));
            valid = valid.wrapping_add(1);
        }
    }
    (sum, valid)
}

/// A cell's range set to `d` (in the encoder's form) and its intensity to 0.
#[inline(always)]
fn put(slot: &Cell<Reading>, d: u32) {
    let mut r = slot.get();
    r.distance = d;
    r.aux = 0;
    slot.set(r);
}

/// [`reduce_line`] for `Mean` of points without intensities (the common case), the
/// whole line in one call: the open group's rest, then the whole groups in a loop of
/// their own ([`mean_threes`], [`mean_pairs`]; other factors a sum and a count a group),
/// then the points left over into a new
/// open group.
#[inline(never)]
fn mean_plain(
    dec: &mut Decimator,
    cells: &[Cell<Reading>],
    (step, cluster): (u32, u32),
    out_none: u32,
) -> (usize, usize) {
    let n = cells.len();
    let k = usize::from(dec.factor.max(1));
    let have = usize::from(dec.count);
    // The outputs written, and how many of them have no range (at most the line's
    // points: no wrap).
    let (mut w, mut invalid) = (0usize, 0usize);
    let mut body = cells;
    if have > 0 {
        // The open group's rest (`have` is below `k`: no wrap).
        let need = k.wrapping_sub(have);
        let (head, rest) = cells.split_at(need.min(n));
        let (sum, valid) = range_sums(head, (dec.sum, dec.valid));
        if head.len() < need {
            // The line ended in the open group (`have + n` below `k`: no wrap).
            (dec.sum, dec.valid) = (sum, valid);
            dec.count = u16::try_from(have.wrapping_add(n)).unwrap_or(0);
            return (0, 0);
        }
        // Its output over the line's first cell (read).
        if let Some(slot) = cells.first() {
            let d = if valid == 0 {
                invalid = 1;
                out_none
            } else {
                mean(sum, valid).max(1)
            };
            put(slot, d);
            w = 1;
        }
        body = rest;
    }
    let slots = cells.get(w..).unwrap_or_default();
    // The outputs written, how many have no range, and the points left over.
    let (taken, none, left) = if k == 3 {
        mean_threes(body, slots, out_none)
    } else {
        let mut o = Written {
            slots: slots.iter(),
            out_none,
            invalid: 0,
        };
        let left = if k == 2 {
            mean_pairs(body, &mut o)
        } else {
            // Other factors: each group's sum and count, one division.
            o.groups(body, k, |g| match range_sums(g, (0, 0)) {
                (_, 0) => EMPTY,
                (sum, valid) => (mean(sum, valid), 0),
            })
        };
        (slots.len().wrapping_sub(o.slots.len()), o.invalid, left)
    };
    (dec.sum, dec.valid) = sums_of(left, (0, 0));
    let pos = left.len();
    // Fewer than `k` points: fits.
    dec.count = u16::try_from(pos).unwrap_or(0);
    if pos > 0 {
        // The open group's first point is in this line (`pos` is at most `n`).
        let at = u32::try_from(n.wrapping_sub(pos)).unwrap_or(0);
        let first = step.wrapping_add(at.wrapping_mul(cluster));
        dec.first_step = u16::try_from(first).unwrap_or(u16::MAX);
    }
    (w.wrapping_add(taken), invalid.wrapping_add(none))
}

/// The whole pairs of `cells` (a pair beginning at the first), the points without
/// intensities: their `Mean`, by the rounded mean of two without a division, in a loop
/// writing the output points behind them. Returns the point left over, if any.
#[inline(always)]
fn mean_pairs<'c>(cells: &'c [Cell<Reading>], o: &mut Written<'_>) -> &'c [Cell<Reading>] {
    o.groups(cells, 2, |g| match g {
        [a, b] => {
            let (a, b) = (a.get().distance, b.get().distance);
            // A point without a range takes the other's: the mean of the valid ones,
            // no range when neither is (the mean of two ranges is a range).
            let a = if a == NONE { b } else { a };
            let b = if b == NONE { a } else { b };
            (mean2(a, b), 0)
        }
        _ => EMPTY,
    })
}

/// The whole threes of `cells` (a group beginning at the first), the points without
/// intensities: their `Mean` into `slots` in the encoder's form (no range as
/// `out_none`, a range of 0 as 1), in one loop without a check per output (each slot
/// behind its group: `slots` begin at most one cell before `cells`). Three ranges
/// below 2^30 (the usual group; no range is not) take the rounded mean `(sum + 1) / 3`
/// in 32 bits, a multiply by the reciprocal; other groups [`group_mean`]. Returns the
/// outputs written, how many of them have no range, and the points left over.
#[inline(always)]
fn mean_threes<'c>(
    cells: &'c [Cell<Reading>],
    slots: &[Cell<Reading>],
    out_none: u32,
) -> (usize, usize, &'c [Cell<Reading>]) {
    let groups = cells.chunks_exact(3);
    let left = groups.remainder();
    let (mut taken, mut invalid) = (0usize, 0usize);
    for (slot, g) in slots.iter().zip(groups) {
        let [a, b, c] = g else { break };
        let (a, b, c) = (a.get().distance, b.get().distance, c.get().distance);
        let d = if (a | b | c) < 1 << 30 {
            // Below 3 × 2^30 + 1: no wrap; a range of 0 as 1.
            (a.wrapping_add(b).wrapping_add(c).wrapping_add(1) / 3).max(1)
        } else {
            match group_mean(g) {
                NONE => {
                    // At most the line's points.
                    invalid = invalid.wrapping_add(1);
                    out_none
                }
                d => d.max(1),
            }
        };
        put(slot, d);
        // At most the line's points.
        taken = taken.wrapping_add(1);
    }
    (taken, invalid, left)
}

/// The rounded mean of the valid ranges of `group` (no range as [`NONE`]), [`NONE`]
/// when there is none: the rare groups of [`mean_threes`].
#[cold]
#[inline(never)]
fn group_mean(group: &[Cell<Reading>]) -> u32 {
    match range_sums(group, (0, 0)) {
        (_, 0) => NONE,
        (sum, valid) => mean(sum, valid),
    }
}

/// `Mean` over the line (see [`reduce_line`]) for any factor, counting each group's
/// points down: the open group's `have` points (below `k`) and their sums in, the same
/// of the group left open out. `aux_mask` is `u32::MAX` when the points carry
/// intensities, 0 otherwise.
#[inline(never)]
fn mean_count(
    cells: &[Cell<Reading>],
    k: usize,
    (have, mut s): (usize, Sums),
    aux_mask: u32,
    o: &mut Written<'_>,
) -> (usize, Sums) {
    // Points until the group is complete (`have` is below `k`).
    let mut left = k.wrapping_sub(have);
    // The writer in registers for the loop.
    let mut w = o.clone();
    for c in cells {
        s = s.add(value(c), aux_mask);
        left = left.wrapping_sub(1);
        if left == 0 {
            w.emit(s.point());
            (s, left) = (Sums::EMPTY, k);
        }
    }
    *o = w;
    (k.wrapping_sub(left), s)
}

/// Decimation of a line's classified points `cells` (no range as [`NONE`]) in place,
/// continuing `dec`'s open group: the output points go to the front of `cells` in the
/// encoder's form (no range as `out_none`, a range of 0 as 1), exactly what
/// [`Decimator::push`] gives point by point. `step` is the step of the first point,
/// the next ones `cluster` apart, `intensity` whether they carry intensities. Returns
/// the number of output points and how many of them have no range. `Mean` of points
/// without intensities takes [`mean_plain`] (before this function's own set-up).
#[inline(never)]
pub(super) fn reduce_line(
    dec: &mut Decimator,
    cells: &mut [Reading],
    (step, cluster, intensity): (u32, u32, bool),
    out_none: u32,
) -> (usize, usize) {
    let cells = Cell::from_mut(cells).as_slice_of_cells();
    if dec.mode == DecimationMode::Mean && !intensity && dec.intensities == 0 {
        return mean_plain(dec, cells, (step, cluster), out_none);
    }
    let n = cells.len();
    let k = usize::from(dec.factor.max(1));
    let mut o = Written {
        slots: cells.iter(),
        out_none,
        invalid: 0,
    };
    let have = usize::from(dec.count);
    // `u32::MAX` when the points carry intensities, 0 otherwise.
    let aux_mask = if intensity { u32::MAX } else { 0 };
    // The points of the group left open.
    let pos = match dec.mode {
        DecimationMode::First => {
            // Each group's first point: from the first group that begins in the line
            // (`have` is below `k`: no wrap), every `k`-th.
            let i = if have == 0 { 0 } else { k.wrapping_sub(have) };
            let taken;
            (taken, o.invalid) = firsts(cells, i, k, out_none);
            o.slots = cells.get(taken..).unwrap_or_default().iter();
            // (`have` + n) mod `k`.
            have.wrapping_add(n).checked_rem(k).unwrap_or(0)
        }
        DecimationMode::Min => {
            let open = match dec.best {
                Some((r, i)) => (r, i.unwrap_or(0)),
                None => EMPTY,
            };
            let (have, best) = min_line(cells, k, (have, open), &mut o);
            dec.best = (best.0 != NONE).then_some((best.0, intensity.then_some(best.1)));
            have
        }
        DecimationMode::Mean => {
            let open = Sums {
                sum: dec.sum,
                valid: dec.valid,
                aux_sum: dec.intensity_sum,
                auxes: dec.intensities,
            };
            let (have, s) = mean_count(cells, k, (have, open), aux_mask, &mut o);
            (dec.sum, dec.valid) = (s.sum, s.valid);
            (dec.intensity_sum, dec.intensities) = (s.aux_sum, s.auxes);
            have
        }
    };
    dec.count = u16::try_from(pos).unwrap_or(0);
    // The group open after the line: `pos` points, its first in this line when there
    // are at most the line's points in it (the run fits the scan's u16 steps).
    if pos > 0 && pos <= n {
        let at = u32::try_from(n.wrapping_sub(pos)).unwrap_or(0);
        let first = step.wrapping_add(at.wrapping_mul(cluster));
        dec.first_step = u16::try_from(first).unwrap_or(u16::MAX);
    }
    // The outputs written: the cells the writer took.
    (n.wrapping_sub(o.slots.len()), o.invalid)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::super::*;
    use std::vec::Vec;

    fn reading(distance: u32, aux: u32) -> scip::Reading {
        scip::Reading { distance, aux }
    }

    /// The scan of `lines` (distances; each reading's aux is its position in the scan
    /// plus 1) through `filter_line` line by line, decimated by `factor` in `mode`, then
    /// `end_scan`: each output point's range (`None` for none) and intensity (0 for
    /// none), and the count of outputs without a range.
    fn decimate_lines(
        factor: u16,
        mode: DecimationMode,
        intensity: bool,
        lines: &[&[u32]],
    ) -> (Vec<(Option<u32>, u32)>, u32) {
        let config = PipelineConfig {
            decimation: Some(Decimation { factor, mode }),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        let n: usize = lines.iter().map(|l| l.len()).sum();
        let info = ScanInfo {
            seq: 0,
            timestamp_ms: 0,
            first_step: 0,
            last_step: n as u16 - 1,
            cluster: 1,
        };
        assert!(matches!(p.begin_scan(info), ScanStart::Publish { .. }));
        let rule = can_wire::RangeRule::at_least(1);
        let none = 7_777_777;
        let mut out = Vec::new();
        let mut step = 0u16;
        for line in lines {
            let input: Vec<_> = line
                .iter()
                .enumerate()
                .map(|(i, &d)| reading(d, u32::from(step) + i as u32 + 1))
                .collect();
            let mut cells = std::vec![reading(0, 0); line.len() + LINE_HEADROOM];
            let (k, no_range) = p
                .filter_line(step, &input, &mut cells, rule, intensity, none)
                .unwrap();
            // The count of no range is that of the cells so given.
            assert_eq!(
                no_range,
                cells[..k].iter().filter(|c| c.distance == none).count()
            );
            out.extend(
                cells[..k]
                    .iter()
                    .map(|c| ((c.distance != none).then_some(c.distance), c.aux)),
            );
            step += line.len() as u16;
        }
        p.end_scan(true, &mut |x: Point| {
            out.push((x.range_mm, x.intensity.unwrap_or(0)))
        });
        (out, p.stats().points_out_invalid)
    }

    /// The ranges of [`decimate_lines`]' outputs, and its count.
    fn ranges((out, invalid): (Vec<(Option<u32>, u32)>, u32)) -> (Vec<Option<u32>>, u32) {
        (out.iter().map(|&(d, _)| d).collect(), invalid)
    }

    /// Min of 3 by hand, with intensities, a group across two lines and a short last
    /// group: ties keep the first point and its own intensity (DecimationMode::Min).
    #[test]
    fn min_of_three_across_lines_by_hand() {
        let config = PipelineConfig {
            decimation: Some(Decimation {
                factor: 3,
                mode: DecimationMode::Min,
            }),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        let info = ScanInfo {
            seq: 0,
            timestamp_ms: 0,
            first_step: 0,
            last_step: 6,
            cluster: 1,
        };
        assert_eq!(p.begin_scan(info), ScanStart::Publish { points: 3 });
        // Steps 0..=6: 500 300 300 | 900 (error 0) 900 | 100, intensities 1..=7; the
        // lines are steps 0..=3 and 4..=6.
        let line1 = [(500, 1), (300, 2), (300, 3), (900, 4)].map(|(d, a)| reading(d, a));
        let line2 = [(0, 5), (900, 6), (100, 7)].map(|(d, a)| reading(d, a));
        let rule = can_wire::RangeRule::at_least(1);
        let mut cells = [reading(0, 0); 8];
        let none = 7_777_777;
        let k = p.filter_line(0, &line1, &mut cells, rule, true, none);
        assert_eq!(k, Some((1, 0)));
        assert_eq!((cells[0].distance, cells[0].aux), (300, 2));
        let k = p.filter_line(4, &line2, &mut cells, rule, true, none);
        assert_eq!(k, Some((1, 0)));
        assert_eq!((cells[0].distance, cells[0].aux), (900, 4));
        let mut last = Vec::new();
        assert_eq!(
            p.end_scan(true, &mut |x: Point| last.push(x)),
            ScanEnd::Complete { points: 3 }
        );
        assert_eq!(
            last,
            [Point {
                step: 6,
                range_mm: Some(100),
                intensity: Some(7),
            }]
        );
        let s = p.stats();
        assert_eq!(
            (s.invalid_error_code, s.points_out, s.points_out_invalid),
            (1, 3, 0)
        );
        assert!(!p.filtered());
    }

    /// The mean of two without a division is `(a + b + 1) / 2` in 64 bits: every pair
    /// below 2^10 (and their neighbourhoods at 2^31 and at the top of the range), and
    /// random pairs over the whole range.
    #[test]
    fn mean_of_two_is_the_rounded_mean() {
        let want = |a: u32, b: u32| (u64::from(a) + u64::from(b)).div_ceil(2) as u32;
        let bases = [0u32, (1 << 31) - 512, u32::MAX - 1023];
        for &x in &bases {
            for &y in &bases {
                for i in 0..1024u32 {
                    for j in (0..1024u32).step_by(7) {
                        let (a, b) = (x + i, y + j);
                        assert_eq!(super::mean2(a, b), want(a, b), "{a} {b}");
                    }
                }
            }
        }
        // A fixed-seed xorshift over all u32 pairs.
        let mut r = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..1_000_000 {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            let (a, b) = (r as u32, (r >> 32) as u32);
            assert_eq!(super::mean2(a, b), want(a, b), "{a} {b}");
        }
    }

    /// Mean of 2 and of 3 by hand through lines of odd lengths (groups across lines),
    /// with error codes, a group without a range, and ranges whose sums pass 2^32.
    #[test]
    fn means_across_lines_by_hand() {
        const BIG: u32 = u32::MAX - 10;
        const HALF: u32 = 1 << 31;
        let run = |factor: u16, lines: &[&[u32]]| {
            ranges(decimate_lines(factor, DecimationMode::Mean, false, lines))
        };
        // Pairs: [1000 1001] [0 0] [BIG BIG] [HALF HALF+1] [5 0] [0 7] [3]
        // -> 1001 (1000.5 up), none, BIG, HALF+1, 5, 7, 3 (the short last group).
        let lines: [&[u32]; 3] = [
            &[1000, 1001, 0],
            &[0, BIG, BIG, HALF],
            &[HALF + 1, 5, 0, 0, 7, 3],
        ];
        assert_eq!(
            run(2, &lines),
            (
                std::vec![
                    Some(1001),
                    None,
                    Some(BIG),
                    Some(HALF + 1),
                    Some(5),
                    Some(7),
                    Some(3)
                ],
                1
            )
        );
        // Threes: [1000 1001 0] [0 BIG BIG] [HALF HALF+1 5] [0 0 7] [3]
        // -> 1001 (2001 / 2 = 1000.5 up), BIG, (2^32 + 6) / 3 = 1431655767 (the sum
        // past 32 bits; (2^32 + 6 + 1) / 3 rounds down to it), 7, 3.
        assert_eq!(
            run(3, &lines),
            (
                std::vec![Some(1001), Some(BIG), Some(1_431_655_767), Some(7), Some(3)],
                0
            )
        );
        // The scan as one line: the same.
        let all: Vec<u32> = lines.concat();
        assert_eq!(run(3, &[&all]).0, run(3, &lines).0);
    }
    /// Min of 2 by hand through lines of odd lengths (pairs across lines), with and
    /// without intensities: error codes, a pair without a range, ranges near 2^31 and
    /// the top, ties (the first point and its intensity stay) and a short last group.
    #[test]
    fn min_of_two_across_lines_by_hand() {
        const BIG: u32 = u32::MAX - 10;
        const HALF: u32 = 1 << 31;
        let run = |intensity: bool, lines: &[&[u32]]| {
            decimate_lines(2, DecimationMode::Min, intensity, lines)
        };
        // Points 0..=16 (intensity = position + 1), pairs:
        // [500 300] [0 0] [BIG HALF] [HALF HALF+1] [7 0] [0 2] [2 2] [9 4] [11]
        // -> 300 (2), none, HALF (6), HALF (7), 7 (9), 2 (12), 2 (13, the first of the
        // equals), 4 (16), 11 (17, the short last group).
        let lines: [&[u32]; 3] = [
            &[500, 300, 0],
            &[0, BIG, HALF, HALF],
            &[HALF + 1, 7, 0, 0, 2, 2, 2, 9, 4, 11],
        ];
        let want = [
            (Some(300), 2),
            (None, 0),
            (Some(HALF), 6),
            (Some(HALF), 7),
            (Some(7), 9),
            (Some(2), 12),
            (Some(2), 13),
            (Some(4), 16),
            (Some(11), 17),
        ];
        assert_eq!(run(true, &lines), (want.to_vec(), 1));
        // Without intensities the cells' `aux` is not looked at (the encoder has no
        // intensity to write): the ranges only.
        let want_ranges = ranges((want.to_vec(), 1));
        assert_eq!(ranges(run(false, &lines)), want_ranges);
        // The scan as one line, and lines of one point: the same.
        let all: Vec<u32> = lines.concat();
        assert_eq!(run(true, &[&all]), (want.to_vec(), 1));
        let ones: Vec<&[u32]> = all.chunks(1).collect();
        assert_eq!(ranges(run(false, &ones)), want_ranges);
    }
    /// Mean of 3 (the unrolled threes) against the 64-bit rounded mean computed here:
    /// groups by hand (none valid, one, two, three; ranges near 2^31 and the top, sums
    /// past 2^32), then random triples through lines of every length 1 to 7.
    #[test]
    fn mean_of_three_against_the_64_bit_mean() {
        const NO: u32 = 0; // an error code (the rule's minimum is 1)
        let run =
            |lines: &[&[u32]]| ranges(decimate_lines(3, DecimationMode::Mean, false, lines)).0;
        // The reference: the valid ranges' sum in 64 bits, (sum + n / 2) / n.
        let want = |all: &[u32]| -> Vec<Option<u32>> {
            all.chunks(3)
                .map(|g| {
                    let v: Vec<u64> = g.iter().filter(|&&d| d != NO).map(|&d| d.into()).collect();
                    let n = v.len() as u64;
                    (n > 0).then(|| ((v.iter().sum::<u64>() + n / 2) / n) as u32)
                })
                .collect()
        };
        const HALF: u32 = 1 << 31;
        const TOP: u32 = u32::MAX - 1;
        const Q: u32 = 1 << 30;
        let all = [
            NO,
            NO,
            NO, // none valid
            NO,
            5,
            NO, // one
            4,
            NO,
            7, // two: 5.5 up
            HALF,
            HALF + 1,
            HALF + 1, // near 2^31, sum past 2^32
            TOP,
            TOP,
            TOP - 1, // the top: (3 * 2^32 - 7 + 1) / 3
            1,
            1,
            2, // 4 / 3 down
            1,
            2,
            2, // 5 / 3 up
            Q - 1,
            Q - 1,
            Q - 2, // the largest three ranges in 32 bits: (3 * 2^30 - 4 + 1) / 3
            Q,
            1,
            1, // one range from 2^30: (2^30 + 2 + 1) / 3 = 357 913 942.33 down
            Q - 1,
            NO,
            Q - 1, // two
            9,     // the short last group
        ];
        let by_hand = [
            None,
            Some(5),
            Some(6),
            Some(HALF + 1),
            Some(TOP),
            Some(1),
            Some(2),
            Some(Q - 1),
            Some(357_913_942),
            Some(Q - 1),
            Some(9),
        ];
        assert_eq!(want(&all), by_hand);
        for len in 1..=7 {
            let lines: Vec<&[u32]> = all.chunks(len).collect();
            assert_eq!(run(&lines), by_hand, "lines of {len}");
        }
        // A fixed-seed xorshift: ranges over the whole u32 range (about one in eight an
        // error code), lines of 1 to 7 points.
        let mut r = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            r
        };
        for _ in 0..200 {
            let all: Vec<u32> = (0..60)
                .map(|_| {
                    let x = next();
                    if x % 8 == 0 {
                        NO
                    } else {
                        ((x >> 8) as u32).max(1)
                    }
                })
                .collect();
            let len = (next() % 7 + 1) as usize;
            let lines: Vec<&[u32]> = all.chunks(len).collect();
            assert_eq!(run(&lines), want(&all));
        }
        // The same with ranges of every magnitude, most of them real ones (below 2^17)
        // and some near 2^30, where the 32-bit sum ends.
        for _ in 0..200 {
            let all: Vec<u32> = (0..60)
                .map(|_| {
                    let x = next();
                    match x % 8 {
                        0 => NO,
                        1 => Q - 2 + (x >> 8) as u32 % 4,
                        _ => ((x >> 8) as u32 >> ((x >> 40) % 32)).max(1),
                    }
                })
                .collect();
            let len = (next() % 7 + 1) as usize;
            let lines: Vec<&[u32]> = all.chunks(len).collect();
            assert_eq!(run(&lines), want(&all));
        }
    }

    /// Mean of 2 to 5, with and without intensities, against the 64-bit rounded means
    /// computed here (of the valid ranges, and of their intensities), through lines of
    /// 1 to 8 points (groups across lines, open groups carried): every triple of edge
    /// values (no range in each position, 1, ranges near 2^30, 2^31 and u32::MAX - 1),
    /// then random groups of them and of real ranges.
    #[test]
    fn means_against_the_64_bit_reference() {
        const NO: u32 = 0; // an error code (the rule's minimum is 1)
        const Q: u32 = 1 << 30;
        const HALF: u32 = 1 << 31;
        const TOP: u32 = u32::MAX - 1;
        let edges = [
            NO,
            1,
            2,
            Q - 2,
            Q - 1,
            Q,
            Q + 1,
            HALF - 1,
            HALF,
            TOP - 1,
            TOP,
        ];
        // Each reading's intensity is its position in the scan plus 1 (decimate_lines).
        let want = |k: usize, intensity: bool, all: &[u32]| -> Vec<(Option<u32>, u32)> {
            let mean = |v: &[u64]| {
                let n = v.len() as u64;
                ((v.iter().sum::<u64>() + n / 2) / n) as u32
            };
            all.chunks(k)
                .enumerate()
                .map(|(g, group)| {
                    let at = |j: usize| (g * k + j + 1) as u64;
                    let valid: Vec<usize> = (0..group.len()).filter(|&j| group[j] != NO).collect();
                    if valid.is_empty() {
                        return (None, 0);
                    }
                    let r: Vec<u64> = valid.iter().map(|&j| group[j].into()).collect();
                    let i: Vec<u64> = valid.iter().map(|&j| at(j)).collect();
                    (Some(mean(&r)), if intensity { mean(&i) } else { 0 })
                })
                .collect()
        };
        let check = |k: usize, all: &[u32], len: usize| {
            let lines: Vec<&[u32]> = all.chunks(len).collect();
            for intensity in [false, true] {
                let (out, invalid) =
                    decimate_lines(k as u16, DecimationMode::Mean, intensity, &lines);
                let w = want(k, intensity, all);
                assert_eq!(out, w, "k {k}, lines of {len}, intensity {intensity}");
                let none = w.iter().filter(|p| p.0.is_none()).count() as u32;
                assert_eq!(invalid, none);
            }
        };
        // Every triple of edge values, one scan, as groups of three (aligned) and of
        // two, four and five (across the triples).
        let mut all = Vec::new();
        for a in edges {
            for b in edges {
                for c in edges {
                    all.extend([a, b, c]);
                }
            }
        }
        for k in 2..=5 {
            for len in [1, 2, 3, 5, 7, 8, 64] {
                check(k, &all, len);
            }
        }
        // A fixed-seed xorshift: edge values and real ranges, lines of 1 to 8 points,
        // scans of 1 to 40 points (short last groups).
        let mut r = 0x5DEE_CE66_D1B5_4A32u64;
        let mut next = || {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            r
        };
        for _ in 0..500 {
            let n = (next() % 40 + 1) as usize;
            let all: Vec<u32> = (0..n)
                .map(|_| {
                    let x = next();
                    if x % 2 == 0 {
                        edges[(x >> 8) as usize % edges.len()]
                    } else {
                        ((x >> 8) as u32 % 60_000).max(1)
                    }
                })
                .collect();
            let k = (next() % 4 + 2) as usize;
            let len = (next() % 8 + 1) as usize;
            check(k, &all, len);
        }
    }

    /// First of 2 to 4 (with intensities) against the points picked here (every
    /// `k`-th of the scan from its first): edge ranges and no range, through lines of
    /// 1 to 8 points (groups across lines).
    #[test]
    fn firsts_against_the_picked_points() {
        const NO: u32 = 0; // an error code (the rule's minimum is 1)
        let values = [NO, 1, 2, (1 << 30) - 1, 1 << 31, u32::MAX - 1, 5_000];
        let all: Vec<u32> = (0..61).map(|i| values[(i * 5 + i / 7) % 7]).collect();
        for k in 2..=4usize {
            // Each reading's intensity is its position in the scan plus 1.
            let want: Vec<(Option<u32>, Option<u32>)> = (0..all.len())
                .step_by(k)
                .map(|i| match all[i] {
                    NO => (None, None),
                    d => (Some(d), Some(i as u32 + 1)),
                })
                .collect();
            for len in 1..=8 {
                let lines: Vec<&[u32]> = all.chunks(len).collect();
                let (out, invalid) = decimate_lines(k as u16, DecimationMode::First, true, &lines);
                // The intensities of the points with a range.
                let got: Vec<(Option<u32>, Option<u32>)> =
                    out.iter().map(|&(d, a)| (d, d.map(|_| a))).collect();
                assert_eq!(got, want, "k {k}, lines of {len}");
                let none = want.iter().filter(|p| p.0.is_none()).count() as u32;
                assert_eq!(invalid, none);
            }
        }
    }
}
