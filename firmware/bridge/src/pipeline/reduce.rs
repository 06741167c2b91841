//! Angular decimation of a line at a time: the block path of
//! [`super::Pipeline::filter_line`].
//!
//! [`reduce_line`] takes a line's points (already through every earlier stage) in one
//! contiguous array and reduces them in place, group by group, carrying the open group
//! from line to line in the [`Decimator`]'s state, so that it gives exactly what
//! [`Decimator::push`] gives point by point (the groups span lines; the end of the scan
//! flushes the last one with [`Decimator::flush`]). The group's state is kept in locals
//! for the line: `First` is a stride over the line, `Min` a running minimum (the first
//! of equals) and `Mean` a sum and a count with one division per group.

use super::config::DecimationMode;
use super::decimate::Decimator;
use super::stats::add;
use super::{Pipeline, NONE};
use core::cell::Cell;

/// A group's running state, in the line loop's registers.
#[derive(Clone, Copy)]
struct Acc {
    /// `Min`: the smallest range so far ([`NONE`]: none yet) and its intensity.
    best: u32,
    best_aux: u32,
    /// `Mean`: the sum and count of the valid ranges, and of their intensities.
    sum: u64,
    valid: u32,
    aux_sum: u64,
    auxes: u32,
}

impl Acc {
    const EMPTY: Acc = Acc {
        best: NONE,
        best_aux: 0,
        sum: 0,
        valid: 0,
        aux_sum: 0,
        auxes: 0,
    };
}

/// Rounded mean (halves up) of `sum / n` ([`NONE`] when `n` is 0), the division in 32
/// bits when the sum fits (one instruction on the Cortex-M4).
#[inline(always)]
fn mean(sum: u64, n: u32) -> u32 {
    let half = n >> 1;
    match u32::try_from(sum).ok().and_then(|s| s.checked_add(half)) {
        Some(s) => s.checked_div(n).unwrap_or(NONE),
        None => wide_mean(sum, n),
    }
}

/// [`mean`] of a sum past 32 bits (groups of thousands of long ranges).
#[cold]
#[inline(never)]
fn wide_mean(sum: u64, n: u32) -> u32 {
    let n = u64::from(n);
    sum.saturating_add(n >> 1)
        .checked_div(n)
        .and_then(|m| u32::try_from(m).ok())
        .unwrap_or(NONE)
}

/// What [`reduce_in_place`] needs to know of the line.
#[derive(Debug, Clone, Copy)]
pub(super) struct LineArgs {
    /// Whether the points carry intensities.
    pub intensity: bool,
    /// The step of the first point.
    pub step: u32,
    /// The steps between points.
    pub cluster: u32,
    /// The encoder's value for no range.
    pub out_none: u32,
}

/// The output side: the slots the output points go to, in order, and their counts.
struct Out<'a> {
    slots: core::slice::Iter<'a, Cell<scip::Reading>>,
    out_none: u32,
    emitted: usize,
    invalid: usize,
}

impl Out<'_> {
    /// One output point (the encoder's form) in the next slot.
    #[inline(always)]
    fn emit(&mut self, d: u32, aux: u32) {
        let none = d == NONE;
        // Both at most the line's points.
        self.invalid = self.invalid.wrapping_add(usize::from(none));
        self.emitted = self.emitted.wrapping_add(1);
        let distance = if none { self.out_none } else { d.max(1) };
        if let Some(slot) = self.slots.next() {
            slot.set(scip::Reading {
                index: 0,
                echo: 0,
                distance,
                aux,
            });
        }
    }
}

/// Decimates the points of `buf` in place: `buf` holds the line's points in order (a
/// `distance` of [`NONE`] is no range, `aux` the intensity when the line carries
/// intensities), the first at the step `line.step`, the next `line.cluster` steps
/// apart; they continue `dec`'s open group. The output points of the groups completed
/// in the line are left at the front of `buf` as readings for the CAN encoder (no
/// range as `line.out_none`, a range of 0 mm as 1, `aux` the intensity or 0), and the
/// points of a group still open go into `dec`. Returns the number of output points
/// and how many of them have no range. `dec` must be active (a factor above 1).
#[inline(never)]
pub(super) fn reduce_in_place(
    dec: &mut Decimator,
    buf: &mut [scip::Reading],
    line: LineArgs,
) -> (usize, usize) {
    let cells = Cell::from_mut(buf).as_slice_of_cells();
    // An output slot is written only once every point before it was read: a group's
    // output goes to a slot at or before its first point.
    let mut out = Out {
        slots: cells.iter(),
        out_none: line.out_none,
        emitted: 0,
        invalid: 0,
    };
    let k = usize::from(dec.factor.max(1));
    let count = usize::from(dec.count);
    let n = cells.len();
    if dec.mode == DecimationMode::First {
        // Every group's first point, unchanged; the open group's first was emitted in
        // an earlier line (`count < k`: no wrap).
        let skip = if count == 0 { 0 } else { k.wrapping_sub(count) };
        for c in cells.iter().skip(skip).step_by(k) {
            let r = c.get();
            out.emit(r.distance, r.aux);
        }
        // The points of the group open after the line.
        dec.count = u16::try_from(count.wrapping_add(n).checked_rem(k).unwrap_or(0)).unwrap_or(0);
        return (out.emitted, out.invalid);
    }
    let min = dec.mode == DecimationMode::Min;
    // `u32::MAX` when the points carry intensities, 0 otherwise.
    let aux_mask = if line.intensity { u32::MAX } else { 0 };
    let mut rest = cells;
    if count > 0 {
        // The open group's other points (`count < k`: no wrap).
        let need = k.wrapping_sub(count);
        let (head, tail) = rest.split_at(need.min(n));
        let acc = dec.load().add(head, min, aux_mask);
        if head.len() == need {
            let (d, aux) = acc.output(min);
            out.emit(d, aux);
            dec.clear();
        } else {
            dec.store(
                &acc,
                count.wrapping_add(head.len()),
                dec.first_step,
                line.intensity,
            );
        }
        rest = tail;
    }
    let mut groups = rest.chunks_exact(k);
    if min {
        for g in &mut groups {
            let (mut best, mut best_aux) = (NONE, 0);
            for c in g {
                let r = c.get();
                // NONE is above every range: an invalid point never wins.
                if r.distance < best {
                    best = r.distance;
                    best_aux = r.aux;
                }
            }
            out.emit(best, best_aux);
        }
    } else {
        for g in &mut groups {
            let (d, aux) = Acc::EMPTY.add(g, false, aux_mask).output(false);
            out.emit(d, aux);
        }
    }
    let tail = groups.remainder();
    if !tail.is_empty() {
        // A group opens at the tail's first point (the run fits the scan's u16 steps).
        let at = u32::try_from(n.wrapping_sub(tail.len())).unwrap_or(0);
        let step = line.step.wrapping_add(at.wrapping_mul(line.cluster));
        let acc = Acc::EMPTY.add(tail, min, aux_mask);
        let first_step = u16::try_from(step).unwrap_or(u16::MAX);
        dec.store(&acc, tail.len(), first_step, line.intensity);
    }
    (out.emitted, out.invalid)
}

impl Acc {
    /// The group's state after the points `part` (`min` for `Min`, else `Mean`; the
    /// intensities count where `aux_mask` is all ones).
    #[inline(always)]
    fn add(self, part: &[Cell<scip::Reading>], min: bool, aux_mask: u32) -> Acc {
        let mut acc = self;
        if min {
            for c in part {
                let r = c.get();
                if r.distance < acc.best {
                    acc.best = r.distance;
                    acc.best_aux = r.aux;
                }
            }
            return acc;
        }
        let (mut sum, mut valid, mut aux_sum) = (acc.sum, 0u32, acc.aux_sum);
        for c in part {
            let r = c.get();
            let v = r.distance != NONE;
            let m = if v { u32::MAX } else { 0 };
            sum = sum.wrapping_add(u64::from(r.distance & m));
            aux_sum = aux_sum.wrapping_add(u64::from(r.aux & m & aux_mask));
            // At most the group's points.
            valid = valid.wrapping_add(u32::from(v));
        }
        acc.valid = acc.valid.wrapping_add(valid);
        acc.auxes = acc.auxes.wrapping_add(valid & aux_mask);
        acc.sum = sum;
        acc.aux_sum = aux_sum;
        acc
    }

    /// The group's output point: distance ([`NONE`] for no range) and intensity.
    #[inline(always)]
    fn output(&self, min: bool) -> (u32, u32) {
        if min {
            (self.best, self.best_aux)
        } else if self.valid == 0 {
            (NONE, 0)
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

impl Decimator {
    /// The open group's state as [`reduce_line`] keeps it.
    fn load(&self) -> Acc {
        let (best, best_aux) = match self.best {
            Some((r, i)) => (r, i.unwrap_or(0)),
            None => (NONE, 0),
        };
        Acc {
            best,
            best_aux,
            sum: self.sum,
            valid: self.valid,
            aux_sum: self.intensity_sum,
            auxes: self.intensities,
        }
    }

    /// Keeps [`reduce_line`]'s open group: `count` points (below the factor), the first
    /// at `first_step`.
    fn store(&mut self, acc: &Acc, count: usize, first_step: u16, intensity: bool) {
        self.count = u16::try_from(count).unwrap_or(0);
        self.first_step = first_step;
        self.best = (acc.best != NONE).then_some((acc.best, intensity.then_some(acc.best_aux)));
        self.sum = acc.sum;
        self.valid = acc.valid;
        self.intensity_sum = acc.aux_sum;
        self.intensities = acc.auxes;
    }
}

/// The classification of a line's readings (error codes, range window, intensity
/// threshold) as [`Pipeline::decimate_line`] does it on the way into the groups.
struct Classes {
    /// The sensor's range test with the range window.
    rule: can_wire::RangeRule,
    /// The distances from `low` up to (not including) `low + span` are ranges inside
    /// the window (one test); the others take the full one.
    low: u32,
    span: u32,
    /// The intensity threshold (0: none, or no intensities).
    min_intensity: u32,
}

/// The points the classification took the range of, by reason.
#[derive(Default)]
struct Rejected {
    error_code: usize,
    out_of_range: usize,
    low_intensity: usize,
}

impl Classes {
    /// The distance of `r` after the classification ([`NONE`] for no range); the
    /// rejections are counted in `why` (rare: kept out of the loop's registers).
    #[inline(always)]
    fn of(&self, r: &scip::Reading, why: &mut Rejected) -> u32 {
        let mut d = r.distance;
        if d.wrapping_sub(self.low) >= self.span {
            if d < self.rule.min {
                // An error code below the sensor's minimum (the common one), at most
                // the line's points.
                why.error_code = why.error_code.wrapping_add(1);
                d = NONE;
            } else {
                d = self.slow(d, why);
            }
        }
        if r.aux < self.min_intensity && d != NONE {
            // At most the line's points.
            why.low_intensity = why.low_intensity.wrapping_add(1);
            d = NONE;
        }
        d
    }

    /// [`Classes::of`] for a distance outside the one-test span.
    #[cold]
    #[inline(never)]
    fn slow(&self, d: u32, why: &mut Rejected) -> u32 {
        // Counts of at most the line's points: no wrap.
        if d != NONE && self.rule.is_range(d) {
            d
        } else if d != NONE && self.rule.is_sensor_range(d) {
            why.out_of_range = why.out_of_range.wrapping_add(1);
            NONE
        } else {
            why.error_code = why.error_code.wrapping_add(1);
            NONE
        }
    }
}

impl Pipeline {
    /// [`Pipeline::filter_line`] when decimation is the only stage after the
    /// classification (no speckle removal, no median): the line's readings classified
    /// and decimated in one pass, the output points written to `cells` in the
    /// encoder's form. The same arguments, result and effects as `filter_line`.
    #[inline(never)]
    pub(super) fn decimate_line(
        &mut self,
        first_step: u16,
        input: &[scip::Reading],
        cells: &mut [scip::Reading],
        sensor: can_wire::RangeRule,
        intensity: bool,
        out_none: u32,
    ) -> Option<usize> {
        let n = input.len();
        let cluster = self.take_run(first_step, n)?.cluster;
        let (lo, hi) = self.roi_slice(first_step, n, cluster);
        let input = input.get(lo..hi).unwrap_or_default();
        // The slice is at most the run.
        add(&mut self.stats.points_in, n);
        add(
            &mut self.stats.points_outside_roi,
            n.wrapping_sub(input.len()),
        );
        let cfg = &self.config;
        let window = cfg
            .range_window
            .map_or([0, u32::MAX], |w| [w.min_mm, w.max_mm]);
        let rule = can_wire::RangeRule { window, ..sensor };
        let (low, span) = super::one_test_span(&rule);
        let classes = Classes {
            rule,
            low,
            span,
            min_intensity: cfg.min_intensity.filter(|_| intensity).unwrap_or(0),
        };
        // The run fits the scan's u16 steps.
        let back = u32::try_from(lo).unwrap_or(0).wrapping_mul(cluster);
        let line = LineArgs {
            intensity,
            step: u32::from(first_step).wrapping_add(back),
            cluster,
            out_none,
        };
        let mut why = Rejected::default();
        let (m, invalid) =
            classify_reduce(&mut self.decimator, input, cells, &classes, line, &mut why);
        let c = super::Counts {
            error_code: why.error_code,
            out_of_range: why.out_of_range,
            low_intensity: why.low_intensity,
            emitted: m,
            invalid_out: invalid,
            ..super::Counts::default()
        };
        Some(self.commit(&c))
    }
}

/// The output side of [`classify_reduce`]: the points written so far and how many of
/// them have no range.
struct Written<'a> {
    /// The slots not written yet.
    slots: core::slice::IterMut<'a, scip::Reading>,
    out_none: u32,
    invalid: usize,
}

impl Written<'_> {
    /// One output point (the encoder's form).
    #[inline(always)]
    fn emit(&mut self, d: u32, aux: u32) {
        let none = d == NONE;
        if let Some(slot) = self.slots.next() {
            slot.distance = if none { self.out_none } else { d.max(1) };
            slot.aux = aux;
        }
        // At most the line's points.
        self.invalid = self.invalid.wrapping_add(usize::from(none));
    }
}

/// The readings `input` classified by `classes` and decimated, continuing `dec`'s open
/// group; the output points go to `out` from its front (as [`reduce_in_place`] leaves
/// them). Returns their number and how many have no range.
#[inline(never)]
fn classify_reduce(
    dec: &mut Decimator,
    input: &[scip::Reading],
    out: &mut [scip::Reading],
    classes: &Classes,
    line: LineArgs,
    why: &mut Rejected,
) -> (usize, usize) {
    let k = usize::from(dec.factor.max(1));
    // Points of the open group already seen (below `k`).
    let pos = usize::from(dec.count);
    let n = input.len();
    // At most one output point per point: `out` (as long as `input`) never runs out.
    let out = out.get_mut(..n).unwrap_or_default();
    let room = out.len();
    let mut o = Written {
        slots: out.iter_mut(),
        out_none: line.out_none,
        invalid: 0,
    };
    let mut class = |r: &scip::Reading| classes.of(r, why);
    let pos = match dec.mode {
        DecimationMode::First => {
            // The open group's other points, then every group's first point emitted
            // (`pos < k`: no wrap).
            let skip = if pos == 0 { 0 } else { k.wrapping_sub(pos) };
            let (head, rest) = input.split_at(skip.min(n));
            for r in head {
                class(r);
            }
            for g in rest.chunks(k) {
                if let Some((first, others)) = g.split_first() {
                    o.emit(class(first), first.aux);
                    for r in others {
                        class(r);
                    }
                }
            }
            pos.wrapping_add(n).checked_rem(k).unwrap_or(0)
        }
        DecimationMode::Min => {
            let acc = dec.load();
            let add = |(mut best, mut best_aux): (u32, u32), part: &[scip::Reading]| {
                for r in part {
                    // NONE is above every range: an invalid point never wins.
                    let d = class(r);
                    if d < best {
                        best = d;
                        best_aux = r.aux;
                    }
                }
                (best, best_aux)
            };
            let close = |(best, best_aux): (u32, u32)| o.emit(best, best_aux);
            let ((best, best_aux), pos) = by_groups(
                input,
                k,
                pos,
                (acc.best, acc.best_aux),
                (NONE, 0),
                add,
                close,
            );
            let acc = Acc {
                best,
                best_aux,
                ..Acc::EMPTY
            };
            dec.store(&acc, pos, dec.first_step, line.intensity);
            pos
        }
        DecimationMode::Mean => {
            let aux_mask = if line.intensity { u32::MAX } else { 0 };
            let add = |mut acc: Acc, part: &[scip::Reading]| {
                let (mut sum, mut aux_sum, mut valid) = (acc.sum, acc.aux_sum, 0u32);
                for r in part {
                    let d = class(r);
                    let v = d != NONE;
                    let m = if v { u32::MAX } else { 0 };
                    sum = sum.wrapping_add(u64::from(d & m));
                    aux_sum = aux_sum.wrapping_add(u64::from(r.aux & m & aux_mask));
                    // At most the group's points.
                    valid = valid.wrapping_add(u32::from(v));
                }
                acc.sum = sum;
                acc.aux_sum = aux_sum;
                acc.valid = acc.valid.wrapping_add(valid);
                acc.auxes = acc.auxes.wrapping_add(valid & aux_mask);
                acc
            };
            let close = |acc: Acc| {
                let (d, aux) = acc.output(false);
                o.emit(d, aux);
            };
            let (acc, pos) = by_groups(input, k, pos, dec.load(), Acc::EMPTY, add, close);
            dec.store(&acc, pos, dec.first_step, line.intensity);
            pos
        }
    };
    // The group open after the line: `pos` points, its first in this line when there
    // are at most the line's points in it (the run fits the scan's u16 steps).
    dec.count = u16::try_from(pos).unwrap_or(0);
    if pos > 0 && pos <= n {
        let at = u32::try_from(n.wrapping_sub(pos)).unwrap_or(0);
        let step = line.step.wrapping_add(at.wrapping_mul(line.cluster));
        dec.first_step = u16::try_from(step).unwrap_or(u16::MAX);
    }
    // The slots written (at most `room`).
    (room.wrapping_sub(o.slots.len()), o.invalid)
}

/// The groups of `input` (decimation by `k`) that continue an open group of `pos`
/// points (below `k`) with the state `acc`: `add` takes a group's points into its
/// state (from `empty` for a new group), `close` takes a completed group's state.
/// Returns the state of the group open after `input` and its number of points.
#[inline(always)]
fn by_groups<A: Copy>(
    input: &[scip::Reading],
    k: usize,
    pos: usize,
    acc: A,
    empty: A,
    mut add: impl FnMut(A, &[scip::Reading]) -> A,
    mut close: impl FnMut(A),
) -> (A, usize) {
    let mut rest = input;
    if pos > 0 {
        // `pos < k`: no wrap.
        let need = k.wrapping_sub(pos);
        let (head, tail) = rest.split_at(need.min(rest.len()));
        let acc = add(acc, head);
        if head.len() < need {
            return (acc, pos.wrapping_add(head.len()));
        }
        close(acc);
        rest = tail;
    }
    let mut groups = rest.chunks_exact(k);
    for g in &mut groups {
        close(add(empty, g));
    }
    let tail = groups.remainder();
    (add(empty, tail), tail.len())
}
