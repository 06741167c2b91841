//! Angular decimation of a line at a time: the block path of
//! [`super::Pipeline::filter_line`] when decimation is the only stage after the
//! classification (error codes, range window, intensity threshold).
//!
//! [`classify_reduce`] classifies a line's readings and reduces them group by
//! group in one pass, carrying the open group from line to line in the
//! [`Decimator`]'s state, so that it gives exactly what [`Decimator::push`] gives
//! point by point (the groups span lines; the end of the scan flushes the last one
//! with [`Decimator::flush`]). The group's state is kept in locals for the line:
//! `First` emits a group's first point, `Min` keeps a running minimum (the first of
//! equals) and `Mean` a sum and a count with one division per group. With speckle
//! removal or a median before it, decimation runs on their output with
//! [`Decimator::run_line`].

use super::config::DecimationMode;
use super::decimate::Decimator;
use super::smooth::classify_rare;
use super::{LineConsts, Tally, NONE};

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
/// bits when the sum fits (one instruction on the Cortex-M4). Once per group: out of
/// line (code size).
#[inline(never)]
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

/// What [`classify_reduce`] needs to know of the line.
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

impl Acc {
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
    /// The open group's state as [`classify_reduce`] keeps it.
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

    /// Keeps [`classify_reduce`]'s open group: `count` points (below the factor), the first
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
/// threshold) as [`classify_reduce`] does it on the way into the groups.
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

/// The points the classification took the range of, by reason (error codes, ranges
/// outside the window, low intensities), and whether a range at or above 2^31 passed
/// (unused here).
#[derive(Default)]
struct Rejected {
    n: [usize; 3],
    big: bool,
}

impl Classes {
    /// The distance of `r` after the classification ([`NONE`] for no range); the
    /// rejections are counted in `why` (rare: kept out of the loop's registers).
    #[inline(always)]
    fn of(&self, r: &scip::Reading, why: &mut Rejected) -> u32 {
        let mut d = r.distance;
        if d.wrapping_sub(self.low) >= self.span {
            d = classify_rare(&self.rule, d, &mut why.n, &mut why.big);
        }
        if r.aux < self.min_intensity && d != NONE {
            // At most the line's points.
            why.n[2] = why.n[2].wrapping_add(1);
            d = NONE;
        }
        d
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
/// group; the output points go to `out` from its front, in the encoder's form (as
/// [`super::Pipeline::filter_line`] leaves them). Returns their number and how many have no range.
#[inline(never)]
pub(super) fn classify_reduce(
    dec: &mut Decimator,
    input: &[scip::Reading],
    out: &mut [scip::Reading],
    consts: &LineConsts,
    (step, cluster, intensity): (u32, u32, bool),
    counts: &mut Tally,
) -> (usize, usize) {
    let rule = consts.rule;
    let (low, span) = super::one_test_span(&rule);
    let classes = Classes {
        rule,
        low,
        span,
        min_intensity: consts.min_intensity,
    };
    let line = LineArgs {
        intensity,
        step,
        cluster,
        out_none: consts.out_none,
    };
    let mut why = Rejected::default();
    let why = &mut why;
    let n = input.len();
    // At most one output point per point: `out` (as long as `input`) never runs out.
    let out = out.get_mut(..n).unwrap_or_default();
    let room = out.len();
    let mut o = Written {
        slots: out.iter_mut(),
        out_none: line.out_none,
        invalid: 0,
    };
    let k = usize::from(dec.factor.max(1));
    // Without decimation (a factor of 1) every point is the first of its group.
    let mode = if k > 1 {
        dec.mode
    } else {
        DecimationMode::First
    };
    let first = mode == DecimationMode::First;
    let min = mode == DecimationMode::Min;
    // `u32::MAX` when the points carry intensities, 0 otherwise.
    let aux_mask = if line.intensity { u32::MAX } else { 0 };
    // One loop for every mode (code size): each point goes into both the running
    // minimum and the sums; `First` emits a group's first point as it comes, the
    // others a group's output point when it closes. Points of the open group already
    // seen: `pos` (below `k`; each count below the line's points plus `k`: no wrap).
    let mut acc = dec.load();
    let mut pos = usize::from(dec.count);
    for r in input {
        let d = classes.of(r, why);
        if first && pos == 0 {
            o.emit(d, r.aux);
        }
        // NONE is above every range: an invalid point never wins.
        if d < acc.best {
            acc.best = d;
            acc.best_aux = r.aux;
        }
        let v = d != NONE;
        let m = if v { u32::MAX } else { 0 };
        acc.sum = acc.sum.wrapping_add(u64::from(d & m));
        acc.aux_sum = acc.aux_sum.wrapping_add(u64::from(r.aux & m & aux_mask));
        acc.valid = acc.valid.wrapping_add(u32::from(v));
        acc.auxes = acc.auxes.wrapping_add(u32::from(v) & aux_mask);
        pos = pos.wrapping_add(1);
        if pos >= k {
            if !first {
                let (d, aux) = acc.output(min);
                o.emit(d, aux);
            }
            acc = Acc::EMPTY;
            pos = 0;
        }
    }
    if first {
        acc = Acc::EMPTY;
    }
    dec.store(&acc, pos, dec.first_step, line.intensity);
    // The group open after the line: `pos` points, its first in this line when there
    // are at most the line's points in it (the run fits the scan's u16 steps).
    dec.count = u16::try_from(pos).unwrap_or(0);
    if pos > 0 && pos <= n {
        let at = u32::try_from(n.wrapping_sub(pos)).unwrap_or(0);
        let step = line.step.wrapping_add(at.wrapping_mul(line.cluster));
        dec.first_step = u16::try_from(step).unwrap_or(u16::MAX);
    }
    [counts.error_code, counts.out_of_range, counts.low_intensity] = why.n;
    // The slots written (at most `room`).
    (room.wrapping_sub(o.slots.len()), o.invalid)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::super::*;
    use std::vec::Vec;

    fn reading(distance: u32, aux: u32) -> scip::Reading {
        scip::Reading {
            index: 0,
            echo: 0,
            distance,
            aux,
        }
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
        assert_eq!(k, Some(1));
        assert_eq!((cells[0].distance, cells[0].aux), (300, 2));
        let k = p.filter_line(4, &line2, &mut cells, rule, true, none);
        assert_eq!(k, Some(1));
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
}
