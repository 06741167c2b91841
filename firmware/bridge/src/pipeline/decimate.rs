//! Angular decimation: groups of `factor` consecutive points become one point.
//!
//! The state is a running accumulator (no buffer), so any factor costs the same memory and
//! constant work per point.

use super::config::{Decimation, DecimationMode};
use super::point::Point;

/// Running state of one group.
#[derive(Debug, Clone)]
pub(crate) struct Decimator {
    pub(super) factor: u16,
    pub(super) mode: DecimationMode,
    /// Points of the current group seen so far.
    pub(super) count: u16,
    /// Step of the group's first point.
    pub(super) first_step: u16,
    /// `Min`: the best valid point so far (range, intensity).
    pub(super) best: Option<(u32, Option<u32>)>,
    /// `Mean`: sum and count of valid ranges.
    pub(super) sum: u64,
    pub(super) valid: u32,
    /// `Mean`: sum and count of the intensities of valid points.
    pub(super) intensity_sum: u64,
    pub(super) intensities: u32,
}

/// Rounded mean (halves up) of `sum / n`, or `None` when `n` is 0: the line loops' out
/// of line mean (its 32-bit division when the sum fits), shared for code size.
fn rounded_mean(sum: u64, n: u32) -> Option<u32> {
    (n != 0).then(|| super::reduce::mean(sum, n))
}

impl Decimator {
    /// A decimator for `setting` (`None` = pass every point through).
    pub fn new(setting: Option<Decimation>) -> Self {
        let (factor, mode) = match setting {
            Some(d) => (d.factor.max(1), d.mode),
            None => (1, DecimationMode::First),
        };
        Decimator {
            factor,
            mode,
            count: 0,
            first_step: 0,
            best: None,
            sum: 0,
            valid: 0,
            intensity_sum: 0,
            intensities: 0,
        }
    }

    /// Whether groups of more than one point are merged (otherwise every point passes
    /// [`Decimator::push`] unchanged).
    #[inline]
    pub fn is_active(&self) -> bool {
        self.factor > 1
    }

    /// Points of the current group received so far.
    pub fn pending(&self) -> usize {
        match self.mode {
            // `First` emits on the group's first point: nothing is ever pending.
            DecimationMode::First => 0,
            DecimationMode::Min | DecimationMode::Mean => usize::from(self.count),
        }
    }

    /// Forgets the current group (the start of a new scan).
    pub fn clear(&mut self) {
        *self = Decimator {
            factor: self.factor,
            mode: self.mode,
            ..Decimator::new(None)
        };
    }

    /// Adds the next point; returns the group's output point when it is determined.
    pub fn push(&mut self, p: Point) -> Option<Point> {
        if self.factor <= 1 {
            return Some(p);
        }
        let first = self.count == 0;
        if first {
            self.first_step = p.step;
        }
        self.count = self.count.saturating_add(1);
        let out = match self.mode {
            DecimationMode::First => first.then_some(p),
            DecimationMode::Min | DecimationMode::Mean => {
                self.accumulate(p);
                None
            }
        };
        if self.count >= self.factor {
            let group = self.finish();
            self.clear();
            return out.or(group);
        }
        out
    }

    /// The end of the scan: the output point of a short last group, if one is open.
    pub fn flush(&mut self) -> Option<Point> {
        let out = if self.count > 0 { self.finish() } else { None };
        self.clear();
        out
    }

    fn accumulate(&mut self, p: Point) {
        let Some(range) = p.range_mm else {
            return;
        };
        match self.mode {
            DecimationMode::First => {}
            DecimationMode::Min => {
                let better = match self.best {
                    Some((best, _)) => range < best,
                    None => true,
                };
                if better {
                    self.best = Some((range, p.intensity));
                }
            }
            DecimationMode::Mean => {
                self.sum = self.sum.saturating_add(u64::from(range));
                self.valid = self.valid.saturating_add(1);
                if let Some(i) = p.intensity {
                    self.intensity_sum = self.intensity_sum.saturating_add(u64::from(i));
                    self.intensities = self.intensities.saturating_add(1);
                }
            }
        }
    }

    /// The output point of the current group (`Min` and `Mean` only).
    fn finish(&self) -> Option<Point> {
        let (range_mm, intensity) = match self.mode {
            DecimationMode::First => return None,
            DecimationMode::Min => match self.best {
                Some((r, i)) => (Some(r), i),
                None => (None, None),
            },
            DecimationMode::Mean => match rounded_mean(self.sum, self.valid) {
                Some(r) => (Some(r), rounded_mean(self.intensity_sum, self.intensities)),
                None => (None, None),
            },
        };
        Some(Point {
            step: self.first_step,
            range_mm,
            intensity,
        })
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn pt(step: u16, r: Option<u32>, i: Option<u32>) -> Point {
        Point {
            step,
            range_mm: r,
            intensity: i,
        }
    }

    fn run(factor: u16, mode: DecimationMode, input: &[Point]) -> Vec<Point> {
        let mut d = Decimator::new(Some(Decimation { factor, mode }));
        let mut out: Vec<Point> = input.iter().filter_map(|p| d.push(*p)).collect();
        out.extend(d.flush());
        out
    }

    /// Seven points, steps 10..=16:
    /// ranges 500, -, 300, 300, 900, -, -   intensities 5, 6, 7, 8, 9, 10, 11
    fn seven() -> Vec<Point> {
        let r = [Some(500), None, Some(300), Some(300), Some(900), None, None];
        (0..7u16)
            .map(|i| pt(10 + i, r[usize::from(i)], Some(5 + u32::from(i))))
            .collect()
    }

    #[test]
    fn first_of_three_by_hand() {
        // groups [10 11 12] [13 14 15] [16]: firsts 10, 13, 16 unchanged.
        let s = seven();
        assert_eq!(
            run(3, DecimationMode::First, &s),
            std::vec![s[0], s[3], s[6]]
        );
    }

    #[test]
    fn min_of_three_by_hand() {
        // [500 - 300] -> 300 (step 12's intensity 7), group step 10
        // [300 900 -] -> 300 (intensity 8), group step 13
        // [-]         -> invalid, no intensity, group step 16
        assert_eq!(
            run(3, DecimationMode::Min, &seven()),
            std::vec![
                pt(10, Some(300), Some(7)),
                pt(13, Some(300), Some(8)),
                pt(16, None, None),
            ]
        );
        // Ties keep the first: [300 300] in a group of 2 starting at step 12.
        let s = seven();
        assert_eq!(
            run(2, DecimationMode::Min, &s),
            std::vec![
                pt(10, Some(500), Some(5)),
                pt(12, Some(300), Some(7)),
                pt(14, Some(900), Some(9)),
                pt(16, None, None),
            ]
        );
    }

    #[test]
    fn mean_of_three_by_hand() {
        // [500 - 300] -> (800 + 1) / 2 = 400; intensities (5 + 7 + 1) / 2 = 6
        // [300 900 -] -> 600; intensities (8 + 9 + 1) / 2 = 9 (8.5 rounds up)
        // [-] -> invalid
        assert_eq!(
            run(3, DecimationMode::Mean, &seven()),
            std::vec![
                pt(10, Some(400), Some(6)),
                pt(13, Some(600), Some(9)),
                pt(16, None, None),
            ]
        );
        // Halves round up: 1 and 2 -> 1.5 -> 2; 1, 1, 2 -> 1.33 -> 1.
        let a = [pt(0, Some(1), None), pt(1, Some(2), None)];
        assert_eq!(
            run(2, DecimationMode::Mean, &a),
            std::vec![pt(0, Some(2), None)]
        );
        let b = [
            pt(0, Some(1), None),
            pt(1, Some(1), None),
            pt(2, Some(2), None),
        ];
        assert_eq!(
            run(3, DecimationMode::Mean, &b),
            std::vec![pt(0, Some(1), None)]
        );
        // Intensity mean over the valid points that carry one.
        let c = [
            pt(0, Some(10), Some(4)),
            pt(1, Some(20), None),
            pt(2, None, Some(1000)),
        ];
        assert_eq!(
            run(3, DecimationMode::Mean, &c),
            std::vec![pt(0, Some(15), Some(4))]
        );
        // Large values do not overflow.
        let d = [
            pt(0, Some(u32::MAX), Some(u32::MAX)),
            pt(1, Some(u32::MAX), Some(u32::MAX)),
        ];
        assert_eq!(
            run(2, DecimationMode::Mean, &d),
            std::vec![pt(0, Some(u32::MAX), Some(u32::MAX))]
        );
    }

    #[test]
    fn factor_one_and_none_pass_through() {
        let s = seven();
        assert_eq!(run(1, DecimationMode::Mean, &s), s);
        let mut d = Decimator::new(None);
        let out: Vec<Point> = s.iter().filter_map(|p| d.push(*p)).collect();
        assert_eq!(out, s);
        assert_eq!(d.flush(), None);
    }

    #[test]
    fn pending_and_clear() {
        let mut d = Decimator::new(Some(Decimation {
            factor: 4,
            mode: DecimationMode::Min,
        }));
        assert_eq!(d.push(pt(0, Some(1), None)), None);
        assert_eq!(d.push(pt(1, Some(1), None)), None);
        assert_eq!(d.pending(), 2);
        d.clear();
        assert_eq!(d.pending(), 0);
        assert_eq!(d.flush(), None);
        // After clear, the next group starts fresh.
        for s in 5..8 {
            assert_eq!(d.push(pt(s, Some(u32::from(s)), None)), None);
        }
        assert_eq!(d.push(pt(8, Some(2), None)), Some(pt(5, Some(2), None)));
    }
}
