//! Centred sliding windows and the two filters that use them: speckle removal and median.
//!
//! A centred window of half-width `h` (1 or 2) holds a point until the `h` points after it
//! have arrived (or the scan ended); the point then leaves with its neighbourhood: the
//! ranges of the `h` points before and after it, cut at the ends of the scan (no padding).
//! Only what the filters need is kept: the ranges of the `h` points before the oldest
//! pending one, and the pending points themselves (at most `h`). A push is a few moves
//! of registers, no ring, no slice.

use super::config::MedianWidth;
use super::point::Point;

/// Largest window the pipeline uses (median of 5).
pub(crate) const WINDOW_CAP: usize = 5;

const EMPTY: Point = Point {
    step: 0,
    range_mm: None,
    intensity: None,
};

/// The ranges around a centre point, nearest last before it and nearest first after it:
/// `[second before, before, after, second after]`. `None` where the neighbour is
/// invalid or absent (cut at the scan's ends, or outside a window of half-width 1): both
/// mean the same to the filters, which use valid ranges only.
pub(crate) type Neighbours = [Option<u32>; 4];

/// A centred window of half-width 1 or 2 emitting each point with its [`Neighbours`].
#[derive(Debug, Clone)]
pub(crate) struct CentredWindow {
    /// The pending points, oldest first (`n` of them).
    pending: [Point; 2],
    /// Points pending (at most `half`, between calls).
    n: u8,
    /// Neighbours on each side (1 or 2).
    half: u8,
    /// Ranges of the point just before the oldest pending one, and of the one before
    /// that (`None`: invalid, or no such point).
    before: [Option<u32>; 2],
}

impl CentredWindow {
    /// A window with `half` neighbours on each side (clamped to 1..=2).
    pub fn new(half: usize) -> Self {
        CentredWindow {
            pending: [EMPTY; 2],
            n: 0,
            half: if half >= 2 { 2 } else { 1 },
            before: [None; 2],
        }
    }

    /// Points received but not yet emitted.
    pub fn pending(&self) -> usize {
        usize::from(self.n)
    }

    /// Forgets everything (the start of a new scan).
    pub fn clear(&mut self) {
        self.n = 0;
        self.before = [None; 2];
    }

    /// Adds the next point; returns the point that became complete, if any, with its
    /// neighbours. Constant work. (Never inlined: one copy serves both filters and
    /// the end of a scan, the per-point path being the rare one.)
    #[inline(never)]
    pub fn push(&mut self, p: Point) -> Option<(Point, Neighbours)> {
        if self.n < self.half {
            if let Some(slot) = self.pending.get_mut(usize::from(self.n)) {
                *slot = p;
            }
            self.n = self.n.wrapping_add(1);
            return None;
        }
        let [b1, b2] = self.before;
        let c = self.pending[0];
        let nb = if self.half == 1 {
            self.pending[0] = p;
            [None, b1, p.range_mm, None]
        } else {
            let a1 = self.pending[1];
            self.pending = [a1, p];
            [b2, b1, a1.range_mm, p.range_mm]
        };
        self.before = [c.range_mm, b1];
        Some((c, nb))
    }

    /// Emits the next pending point at the end of the scan, its window cut there.
    pub fn pop_tail(&mut self) -> Option<(Point, Neighbours)> {
        if self.n == 0 {
            return None;
        }
        let [b1, b2] = self.before;
        let c = self.pending[0];
        let a1 = if self.n >= 2 {
            self.pending[1].range_mm
        } else {
            None
        };
        let nb = if self.half == 1 {
            [None, b1, None, None]
        } else {
            [b2, b1, a1, None]
        };
        self.pending[0] = self.pending[1];
        self.n = self.n.wrapping_sub(1);
        self.before = [c.range_mm, b1];
        Some((c, nb))
    }
}

/// The state of a [`CentredWindow`] in the form the line loops
/// ([`super::Pipeline::filter_line`]) take it: distances with a "no range"
/// value instead of options, intensities as plain values.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Regs {
    /// The oldest pending point (distance, intensity).
    pub p0: (u32, u32),
    /// The next pending point (half-width 2 only).
    pub p1: (u32, u32),
    /// Points pending.
    pub np: usize,
    /// Distance of the point just before the oldest pending one.
    pub b1: u32,
    /// Distance of the point before that.
    pub b2: u32,
}

impl CentredWindow {
    /// The window's state as [`Regs`] (`none` for no range). (Never inlined: one copy
    /// for both windows, it runs once a scan or after a point-by-point path.)
    #[inline(never)]
    pub fn load(&self, none: u32) -> Regs {
        let d = |p: &Point| p.range_mm.unwrap_or(none);
        let [p0, p1] = self.pending;
        let [b1, b2] = self.before;
        Regs {
            p0: (d(&p0), p0.intensity.unwrap_or(0)),
            p1: (d(&p1), p1.intensity.unwrap_or(0)),
            np: usize::from(self.n),
            b1: b1.unwrap_or(none),
            b2: b2.unwrap_or(none),
        }
    }

    /// Takes the state back from [`Regs`] after a line: the points left pending get
    /// steps counted back from `last_step` (the step of the last point the window
    /// took), `cluster` apart; intensities only when `intensity`.
    #[inline(never)]
    pub fn store(
        &mut self,
        r: &Regs,
        none: u32,
        intensity: bool,
        (last_step, cluster): (u32, u32),
    ) {
        let point = |(dist, aux): (u32, u32), back: usize| Point {
            step: u16::try_from(
                last_step.saturating_sub(u32::try_from(back).unwrap_or(0).saturating_mul(cluster)),
            )
            .unwrap_or(u16::MAX),
            range_mm: (dist != none).then_some(dist),
            intensity: intensity.then_some(aux),
        };
        // The pending points are the last `np` of the stream.
        let last = r.np.saturating_sub(1);
        self.pending = [point(r.p0, last), point(r.p1, last.saturating_sub(1))];
        self.n = u8::try_from(r.np).unwrap_or(0);
        self.before = [
            (r.b1 != none).then_some(r.b1),
            (r.b2 != none).then_some(r.b2),
        ];
    }
}

/// Speckle removal on distances with a "no range" value `none` (as [`speckle`]) for
/// the centre `c` and the distances before (`b`) and after (`a`) it: the centre's new
/// distance and whether it was removed.
#[inline(always)]
pub(crate) fn speckle3_line(c: u32, b: u32, a: u32, none: u32, max_jump_mm: u32) -> (u32, bool) {
    let supports = |n: u32| n != none && n.abs_diff(c) <= max_jump_mm;
    if c == none || supports(b) || supports(a) {
        (c, false)
    } else {
        (none, true)
    }
}

/// The median on distances with a "no range" value `none` (as [`median`]; the
/// reference the median of 5's tests check the line loop against).
#[cfg(test)]
pub(crate) fn median_line(c: u32, nb: [u32; 4], none: u32) -> u32 {
    if c == none {
        return c;
    }
    if nb[0] == none && nb[3] == none {
        let (b, a) = (nb[1], nb[2]);
        return if b != none && a != none {
            c.min(b).max(c.max(b).min(a))
        } else {
            c
        };
    }
    let opt = |v: u32| (v != none).then_some(v);
    let centre = Point {
        step: 0,
        range_mm: Some(c),
        intensity: None,
    };
    median(centre, &nb.map(opt)).range_mm.unwrap_or(c)
}

/// What a filter did to one point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// The point goes on as it is (or with its new range, for the median).
    Keep(Point),
    /// The point was valid and the filter made it invalid.
    Invalidated(Point),
}

/// Speckle removal for the centre `c` of a window of half-width 1 (see
/// [`super::SpeckleFilter`]): a valid centre with no valid neighbour within `max_jump_mm`
/// becomes invalid.
#[inline]
pub(crate) fn speckle(c: Point, nb: &Neighbours, max_jump_mm: u32) -> Verdict {
    let Some(range) = c.range_mm else {
        return Verdict::Keep(c);
    };
    let supports = |n: Option<u32>| n.is_some_and(|r| r.abs_diff(range) <= max_jump_mm);
    if supports(nb[1]) || supports(nb[2]) {
        Verdict::Keep(c)
    } else {
        Verdict::Invalidated(Point {
            range_mm: None,
            ..c
        })
    }
}

/// Median over the valid ranges of a window.
///
/// An invalid centre stays invalid. For a valid centre, the valid ranges of the window
/// (centre included, so at least one) are sorted; with `n` of them the result is the
/// centre's own range clamped into `[sorted[(n-1)/2], sorted[n/2]]`. For odd `n` both
/// bounds are the median; for even `n` (only possible when a neighbour is invalid or the
/// window is cut at the scan's end) the result is whichever middle value is nearest the
/// centre's own range, which is the centre's range when it is one of them. The result is
/// always one of the measured ranges, never an average. The centre keeps its intensity.
#[inline(never)]
pub(crate) fn median(c: Point, nb: &Neighbours) -> Point {
    let Some(own) = c.range_mm else {
        return c;
    };
    // The common case, a window of 3 valid ranges: their median, no sort. (With one
    // neighbour only, n = 2 and the centre is one of the middle pair: it stays.)
    if let [None, b, a, None] = *nb {
        let r = match (b, a) {
            (Some(b), Some(a)) => own.min(b).max(own.max(b).min(a)),
            _ => own,
        };
        return Point {
            range_mm: Some(r),
            ..c
        };
    }
    let mut vals = [own; WINDOW_CAP];
    let mut n = 1usize;
    for r in nb.iter().flatten() {
        if let Some(slot) = vals.get_mut(n) {
            *slot = *r;
            n = n.saturating_add(1);
        }
    }
    let sorted = match vals.get_mut(..n) {
        Some(s) => s,
        None => return c,
    };
    insertion_sort(sorted);
    let lo = sorted.get(n.saturating_sub(1) / 2).copied().unwrap_or(own);
    let hi = sorted.get(n / 2).copied().unwrap_or(own);
    Point {
        range_mm: Some(own.clamp(lo, hi.max(lo))),
        ..c
    }
}

/// Sorts at most [`WINDOW_CAP`] values in place (cheaper than the general sort at this
/// size; at most 10 comparisons).
fn insertion_sort(v: &mut [u32]) {
    for i in 1..v.len() {
        let mut j = i;
        while let Some(prev) = j.checked_sub(1) {
            match (v.get(prev), v.get(j)) {
                (Some(a), Some(b)) if a > b => v.swap(prev, j),
                _ => break,
            }
            j = prev;
        }
    }
}

/// The half-width of a median setting.
pub(crate) fn median_half(width: Option<MedianWidth>) -> usize {
    width.map_or(0, MedianWidth::half)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn pt(step: u16, r: Option<u32>) -> Point {
        Point {
            step,
            range_mm: r,
            intensity: None,
        }
    }

    /// Runs a window over a whole sequence of steps (range = step); returns, per centre,
    /// its step and the steps of its neighbours (range = step) in window order.
    fn windows(half: usize, n: u16) -> Vec<(u16, Vec<u16>)> {
        let mut w = CentredWindow::new(half);
        let mut out = Vec::new();
        let record = |(c, nb): (Point, Neighbours), out: &mut Vec<(u16, Vec<u16>)>| {
            let mut steps: Vec<u16> = nb[..2].iter().flatten().map(|&r| r as u16).collect();
            steps.push(c.step);
            steps.extend(nb[2..].iter().flatten().map(|&r| r as u16));
            out.push((c.step, steps));
        };
        for s in 0..n {
            if let Some(x) = w.push(pt(s, Some(u32::from(s)))) {
                record(x, &mut out);
            }
        }
        while let Some(x) = w.pop_tail() {
            record(x, &mut out);
        }
        out
    }

    #[test]
    fn windows_of_half_two_are_cut_at_both_ends() {
        let got = windows(2, 6);
        let want: Vec<(u16, Vec<u16>)> = std::vec![
            (0, std::vec![0, 1, 2]),
            (1, std::vec![0, 1, 2, 3]),
            (2, std::vec![0, 1, 2, 3, 4]),
            (3, std::vec![1, 2, 3, 4, 5]),
            (4, std::vec![2, 3, 4, 5]),
            (5, std::vec![3, 4, 5]),
        ];
        assert_eq!(got, want);
    }

    #[test]
    fn windows_of_half_one_and_short_scans() {
        assert_eq!(
            windows(1, 3),
            std::vec![
                (0, std::vec![0, 1]),
                (1, std::vec![0, 1, 2]),
                (2, std::vec![1, 2]),
            ]
        );
        assert_eq!(windows(2, 1), std::vec![(0, std::vec![0])]);
        assert_eq!(windows(1, 1), std::vec![(0, std::vec![0])]);
        assert_eq!(
            windows(2, 2),
            std::vec![(0, std::vec![0, 1]), (1, std::vec![0, 1])]
        );
        assert!(windows(2, 0).is_empty());
    }

    #[test]
    fn window_emits_after_half_points_of_look_ahead() {
        let mut w = CentredWindow::new(2);
        assert!(w.push(pt(0, None)).is_none());
        assert!(w.push(pt(1, None)).is_none());
        assert_eq!(w.pending(), 2);
        assert_eq!(w.push(pt(2, None)).map(|x| x.0.step), Some(0));
        assert_eq!(w.pending(), 2);
        w.clear();
        assert_eq!(w.pending(), 0);
        assert!(w.pop_tail().is_none());
    }

    /// A window over `points` centred on `points[centre]`: the centre and its neighbours.
    fn win(points: &[Point], centre: usize) -> (Point, Neighbours) {
        let at = |i: Option<usize>| i.and_then(|i| points.get(i)).and_then(|p| p.range_mm);
        let nb = [
            at(centre.checked_sub(2)),
            at(centre.checked_sub(1)),
            at(Some(centre + 1)),
            at(Some(centre + 2)),
        ];
        (points[centre], nb)
    }

    fn speckle_of(w: (Point, Neighbours), jump: u32) -> Verdict {
        speckle(w.0, &w.1, jump)
    }

    fn median_of(w: (Point, Neighbours)) -> Point {
        median(w.0, &w.1)
    }

    #[test]
    fn speckle_by_hand() {
        let keep = |p| Verdict::Keep(p);
        // 1000 between 1040 and 5000, threshold 50: 1040 supports it.
        let p = [pt(0, Some(1040)), pt(1, Some(1000)), pt(2, Some(5000))];
        assert_eq!(speckle_of(win(&p, 1), 50), keep(p[1]));
        // Threshold 39: nobody supports it.
        assert_eq!(
            speckle_of(win(&p, 1), 39),
            Verdict::Invalidated(pt(1, None))
        );
        // Exactly at the threshold still supports.
        assert_eq!(speckle_of(win(&p, 1), 40), keep(p[1]));
        // Both neighbours invalid.
        let q = [pt(0, None), pt(1, Some(1000)), pt(2, None)];
        assert_eq!(
            speckle_of(win(&q, 1), 10_000),
            Verdict::Invalidated(pt(1, None))
        );
        // Edge point: only its inner neighbour counts.
        let e = [pt(0, Some(700)), pt(1, Some(705))];
        assert_eq!(speckle_of(win(&e, 0), 5), keep(e[0]));
        assert_eq!(speckle_of(win(&e, 0), 4), Verdict::Invalidated(pt(0, None)));
        // A lone point has no support.
        let l = [pt(9, Some(700))];
        assert_eq!(
            speckle_of(win(&l, 0), u32::MAX),
            Verdict::Invalidated(pt(9, None))
        );
        // An invalid centre passes unchanged.
        assert_eq!(speckle_of(win(&q, 0), 0), keep(q[0]));
    }

    #[test]
    fn insertion_sort_sorts_every_order_of_five() {
        // All 120 orders of 1..=5, and repeated values.
        let mut v = [1u32, 2, 3, 4, 5];
        let mut orders = 0;
        permute(&mut v, 0, &mut |p| {
            let mut s = *p;
            insertion_sort(&mut s);
            assert_eq!(s, [1, 2, 3, 4, 5]);
            orders += 1;
        });
        assert_eq!(orders, 120);
        let mut r = [7u32, 3, 7, 0, 3];
        insertion_sort(&mut r);
        assert_eq!(r, [0, 3, 3, 7, 7]);
        let mut e: [u32; 0] = [];
        insertion_sort(&mut e);
    }

    fn permute(v: &mut [u32; 5], k: usize, f: &mut dyn FnMut(&[u32; 5])) {
        if k == v.len() {
            return f(v);
        }
        for i in k..v.len() {
            v.swap(k, i);
            permute(v, k + 1, f);
            v.swap(k, i);
        }
    }

    #[test]
    fn median_by_hand() {
        let r = |p: Point| p.range_mm;
        // 5 valid: 10 50 20 40 30 -> sorted 10 20 30 40 50, median 30.
        let p = [
            pt(0, Some(10)),
            pt(1, Some(50)),
            pt(2, Some(20)),
            pt(3, Some(40)),
            pt(4, Some(30)),
        ];
        assert_eq!(r(median_of(win(&p, 2))), Some(30));
        // Centre invalid stays invalid.
        let q = [pt(0, Some(10)), pt(1, None), pt(2, Some(20))];
        assert_eq!(r(median_of(win(&q, 1))), None);
        // Even count: centre 10 with neighbour 20 -> middle pair (10, 20) holds the centre.
        assert_eq!(r(median_of(win(&q, 0))), Some(10));
        // Even count, centre outside the middle pair: 9000 with 100, 200, 300 ->
        // sorted 100 200 300 9000, pair (200, 300), nearest to 9000 is 300.
        let s = [
            pt(0, Some(100)),
            pt(1, Some(200)),
            pt(2, Some(9000)),
            pt(3, Some(300)),
            pt(4, None),
        ];
        assert_eq!(r(median_of(win(&s, 2))), Some(300));
        // Centre 5 with 100, 200, 300 -> pair (100, 200), nearest is 100.
        let t = [
            pt(0, Some(100)),
            pt(1, Some(5)),
            pt(2, Some(200)),
            pt(3, Some(300)),
        ];
        assert_eq!(r(median_of(win(&t, 1))), Some(100));
        // Single valid (the centre itself).
        let u = [pt(0, None), pt(1, Some(77)), pt(2, None)];
        assert_eq!(r(median_of(win(&u, 1))), Some(77));
        // Spike removal with 3: 1000 9999 1002 -> 1002.
        let v = [pt(0, Some(1000)), pt(1, Some(9999)), pt(2, Some(1002))];
        assert_eq!(r(median_of(win(&v, 1))), Some(1002));
        // Intensity of the centre is kept.
        let mut w = v;
        w[1].intensity = Some(321);
        assert_eq!(median_of(win(&w, 1)).intensity, Some(321));
    }
}
