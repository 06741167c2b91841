//! Angular decimation of a line at a time, for [`super::Pipeline::filter_line`]: the
//! line's points, already classified (and filtered by speckle removal or a median when
//! those are on), reduced group by group in place.
//!
//! [`reduce_line`] carries the open group from line to line in the [`Decimator`]'s
//! state, so that it gives exactly what [`Decimator::push`] gives point by point (the
//! groups span lines; the end of the scan flushes the last one with
//! [`Decimator::flush`]). The group's state is kept in locals for the line, with a loop
//! per mode: `First` emits a group's first point, `Min` keeps a running minimum (the
//! first of equals) and `Mean` a sum and a count with one division per group.

use super::config::DecimationMode;
use super::decimate::Decimator;
use super::NONE;

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

impl Acc {
    /// The group's output point in `Mean`: distance ([`NONE`] for no range) and
    /// intensity.
    #[inline(always)]
    fn mean(&self) -> (u32, u32) {
        if self.valid == 0 {
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

/// The output side of [`reduce_line`]: the points written so far (at the front of the
/// line's cells, never past the point being read) and how many of them have no range.
struct Written {
    /// Points written.
    at: usize,
    out_none: u32,
    invalid: usize,
}

impl Written {
    /// One output point (the encoder's form) into `cells`.
    #[inline(always)]
    fn emit(&mut self, cells: &mut [scip::Reading], d: u32, aux: u32) {
        let none = d == NONE;
        if let Some(slot) = cells.get_mut(self.at) {
            slot.distance = if none { self.out_none } else { d.max(1) };
            slot.aux = aux;
        }
        // Each at most the line's points.
        self.at = self.at.wrapping_add(1);
        self.invalid = self.invalid.wrapping_add(usize::from(none));
    }
}

/// The decimation modes of [`reduce_loop`].
const FIRST: u8 = 0;
const MIN: u8 = 1;
const MEAN: u8 = 2;

/// [`reduce_line`]'s loop for one mode: the group's state `acc` with `pos` of its points
/// seen (below `k`), `aux_mask` `u32::MAX` when the points carry intensities.
#[inline(always)]
fn reduce_loop<const MODE: u8>(
    cells: &mut [scip::Reading],
    k: usize,
    (acc, pos): (&mut Acc, &mut usize),
    aux_mask: u32,
    o: &mut Written,
) {
    for i in 0..cells.len() {
        let Some(&r) = cells.get(i) else {
            break;
        };
        let (d, aux) = (r.distance, r.aux);
        if MODE == FIRST {
            if *pos == 0 {
                o.emit(cells, d, aux);
            }
        } else if MODE == MIN {
            // NONE is above every range: an invalid point never wins.
            if d < acc.best {
                (acc.best, acc.best_aux) = (d, aux);
            }
        } else if d != NONE {
            // Each count at most the scan's points: no wrap.
            acc.sum = acc.sum.wrapping_add(u64::from(d));
            acc.valid = acc.valid.wrapping_add(1);
            acc.aux_sum = acc.aux_sum.wrapping_add(u64::from(aux & aux_mask));
            acc.auxes = acc.auxes.wrapping_add(1 & aux_mask);
        }
        // Below `k` before the add.
        *pos = pos.wrapping_add(1);
        if *pos >= k {
            // The next group: only the mode's own fields (the others stay as empty as
            // they came: no other mode's loop runs on this decimator).
            if MODE == MIN {
                o.emit(cells, acc.best, acc.best_aux);
                (acc.best, acc.best_aux) = (Acc::EMPTY.best, Acc::EMPTY.best_aux);
            } else if MODE == MEAN {
                let (d, aux) = acc.mean();
                o.emit(cells, d, aux);
                (acc.sum, acc.valid) = (Acc::EMPTY.sum, Acc::EMPTY.valid);
                (acc.aux_sum, acc.auxes) = (Acc::EMPTY.aux_sum, Acc::EMPTY.auxes);
            }
            *pos = 0;
        }
    }
}

/// Decimation of a line's classified points `cells` (no range as [`NONE`]) in place,
/// continuing `dec`'s open group: the output points go to the front of `cells` in the
/// encoder's form (no range as `out_none`, a range of 0 as 1), exactly what
/// [`Decimator::push`] gives point by point. `step` is the step of the first point,
/// the next ones `cluster` apart, `intensity` whether they carry intensities. Returns
/// the number of output points and how many of them have no range.
#[inline(never)]
pub(super) fn reduce_line(
    dec: &mut Decimator,
    cells: &mut [scip::Reading],
    (step, cluster, intensity): (u32, u32, bool),
    out_none: u32,
) -> (usize, usize) {
    let n = cells.len();
    let k = usize::from(dec.factor.max(1));
    let mut o = Written {
        at: 0,
        out_none,
        invalid: 0,
    };
    // `u32::MAX` when the points carry intensities, 0 otherwise.
    let aux_mask = if intensity { u32::MAX } else { 0 };
    // One loop per mode, the group's bookkeeping the same.
    let mut acc = dec.load();
    let mut pos = usize::from(dec.count);
    let state = (&mut acc, &mut pos);
    match dec.mode {
        DecimationMode::First => reduce_loop::<FIRST>(cells, k, state, aux_mask, &mut o),
        DecimationMode::Min => reduce_loop::<MIN>(cells, k, state, aux_mask, &mut o),
        DecimationMode::Mean => reduce_loop::<MEAN>(cells, k, state, aux_mask, &mut o),
    }
    if dec.mode == DecimationMode::First {
        acc = Acc::EMPTY;
    }
    dec.store(&acc, pos, dec.first_step, intensity);
    // The group open after the line: `pos` points, its first in this line when there
    // are at most the line's points in it (the run fits the scan's u16 steps).
    if pos > 0 && pos <= n {
        let at = u32::try_from(n.wrapping_sub(pos)).unwrap_or(0);
        let first = step.wrapping_add(at.wrapping_mul(cluster));
        dec.first_step = u16::try_from(first).unwrap_or(u16::MAX);
    }
    (o.at, o.invalid)
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
