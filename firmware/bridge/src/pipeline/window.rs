//! Centred sliding windows and the two filters that use them: speckle removal and median.
//!
//! A centred window of half-width `h` holds at most `2h + 1` points. A point leaves once
//! the `h` points after it have arrived (or the scan ended); its window is then the points
//! from `h` before to `h` after it, cut at the ends of the scan (no padding).

use super::config::MedianWidth;
use super::point::Point;

/// Largest window the pipeline uses (median of 5).
pub(crate) const WINDOW_CAP: usize = 5;

const EMPTY: Point = Point {
    step: 0,
    range_mm: None,
    intensity: None,
};

/// A centred point and its neighbours, cut at the ends of the scan.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Window<'a> {
    /// The points of the window in step order.
    pub points: &'a [Point],
    /// Position of the centre point in `points`.
    pub centre: usize,
}

impl Window<'_> {
    /// The centre point, or an invalid placeholder if the window is malformed (never
    /// happens; keeps the code free of panics).
    pub fn centre_point(&self) -> Point {
        self.points.get(self.centre).copied().unwrap_or(EMPTY)
    }
}

/// A sliding window of fixed capacity emitting each point with its neighbourhood.
///
/// The points are kept in a mirrored ring: each point is written twice, at `head` and at
/// `head + span`, so the newest `span` points are always one contiguous slice ending at
/// `head + span`. A push costs two writes, never a shift.
#[derive(Debug, Clone)]
pub(crate) struct CentredWindow {
    buf: [Point; 2 * WINDOW_CAP],
    /// Next write position, `0..span`.
    head: usize,
    /// Points held (at most `span`).
    len: usize,
    /// Newest points not yet emitted (at most `half`, between calls).
    pending: usize,
    /// Neighbours on each side.
    half: usize,
    /// `2 * half + 1`.
    span: usize,
}

impl CentredWindow {
    /// A window with `half` neighbours on each side (`2 * half + 1 <= WINDOW_CAP`).
    pub fn new(half: usize) -> Self {
        let half = half.min((WINDOW_CAP - 1) / 2);
        CentredWindow {
            buf: [EMPTY; 2 * WINDOW_CAP],
            head: 0,
            len: 0,
            pending: 0,
            half,
            span: half.saturating_mul(2).saturating_add(1),
        }
    }

    /// Points received but not yet emitted.
    pub fn pending(&self) -> usize {
        self.pending
    }

    /// Forgets everything (the start of a new scan).
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.pending = 0;
    }

    /// Adds the next point; returns the window of the point that became complete, if any.
    /// Constant work: two writes and a few index computations. (Wrapping arithmetic on
    /// the indices: each stays at most `span <= WINDOW_CAP`, so none ever wraps.)
    pub fn push(&mut self, p: Point) -> Option<Window<'_>> {
        let head = self.head;
        if let Some(slot) = self.buf.get_mut(head) {
            *slot = p;
        }
        if let Some(slot) = self.buf.get_mut(head.wrapping_add(self.span)) {
            *slot = p;
        }
        let next = head.wrapping_add(1);
        self.head = if next >= self.span { 0 } else { next };
        if self.len < self.span {
            self.len = self.len.wrapping_add(1);
        }
        self.pending = self.pending.wrapping_add(1);
        if self.pending > self.half {
            self.emit()
        } else {
            None
        }
    }

    /// Emits the next pending point at the end of the scan, its window cut there.
    pub fn pop_tail(&mut self) -> Option<Window<'_>> {
        if self.pending == 0 {
            return None;
        }
        self.emit()
    }

    /// Emits the oldest pending point (there is one); its window runs to the newest
    /// point held, which is `half` points after it, or fewer at the end of the scan.
    fn emit(&mut self) -> Option<Window<'_>> {
        let centre = self.len.checked_sub(self.pending)?;
        self.pending = self.pending.wrapping_sub(1);
        let start = centre.saturating_sub(self.half);
        // The held points, oldest first, end just before `head + span`.
        let end = self.head.wrapping_add(self.span);
        let first = end.checked_sub(self.len)?.wrapping_add(start);
        let points = self.buf.get(first..end)?;
        Some(Window {
            points,
            centre: centre.wrapping_sub(start),
        })
    }
}

/// What a filter did to one point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// The point goes on as it is (or with its new range, for the median).
    Keep(Point),
    /// The point was valid and the filter made it invalid.
    Invalidated(Point),
}

/// Speckle removal on a window of half-width 1 (see [`super::SpeckleFilter`]).
pub(crate) fn speckle(w: &Window<'_>, max_jump_mm: u32) -> Verdict {
    let c = w.centre_point();
    let Some(range) = c.range_mm else {
        return Verdict::Keep(c);
    };
    let supports = |n: Option<&Point>| match n.and_then(|n| n.range_mm) {
        Some(r) => r.abs_diff(range) <= max_jump_mm,
        None => false,
    };
    let before = w.centre.checked_sub(1).and_then(|i| w.points.get(i));
    let after = w.points.get(w.centre.saturating_add(1));
    let supported = supports(before) || supports(after);
    if supported {
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
pub(crate) fn median(w: &Window<'_>) -> Point {
    let c = w.centre_point();
    let Some(own) = c.range_mm else {
        return c;
    };
    // The common case, a whole window of 3 valid ranges: their median, no sort.
    if let [Point {
        range_mm: Some(a), ..
    }, _, Point {
        range_mm: Some(b), ..
    }] = w.points
    {
        if w.centre == 1 {
            return Point {
                range_mm: Some(own.min(*a).max(own.max(*a).min(*b))),
                ..c
            };
        }
    }
    let mut vals = [0u32; WINDOW_CAP];
    let mut n = 0usize;
    for r in w.points.iter().filter_map(|p| p.range_mm) {
        if let Some(slot) = vals.get_mut(n) {
            *slot = r;
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

    /// Runs a window over a whole sequence; returns (centre step, window steps) pairs.
    fn windows(half: usize, n: u16) -> Vec<(u16, Vec<u16>)> {
        let mut w = CentredWindow::new(half);
        let mut out = Vec::new();
        let record = |win: Window<'_>, out: &mut Vec<(u16, Vec<u16>)>| {
            out.push((
                win.centre_point().step,
                win.points.iter().map(|p| p.step).collect(),
            ));
        };
        for s in 0..n {
            if let Some(win) = w.push(pt(s, Some(1))) {
                record(win, &mut out);
            }
        }
        while let Some(win) = w.pop_tail() {
            record(win, &mut out);
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
            windows(0, 2),
            std::vec![(0, std::vec![0]), (1, std::vec![1])]
        );
        assert!(windows(2, 0).is_empty());
    }

    #[test]
    fn window_emits_after_half_points_of_look_ahead() {
        let mut w = CentredWindow::new(2);
        assert!(w.push(pt(0, None)).is_none());
        assert!(w.push(pt(1, None)).is_none());
        assert_eq!(w.pending(), 2);
        assert_eq!(w.push(pt(2, None)).map(|x| x.centre_point().step), Some(0));
        assert_eq!(w.pending(), 2);
        w.clear();
        assert_eq!(w.pending(), 0);
        assert!(w.pop_tail().is_none());
    }

    fn win(points: &[Point], centre: usize) -> Window<'_> {
        Window { points, centre }
    }

    #[test]
    fn speckle_by_hand() {
        let keep = |p| Verdict::Keep(p);
        // 1000 between 1040 and 5000, threshold 50: 1040 supports it.
        let p = [pt(0, Some(1040)), pt(1, Some(1000)), pt(2, Some(5000))];
        assert_eq!(speckle(&win(&p, 1), 50), keep(p[1]));
        // Threshold 39: nobody supports it.
        assert_eq!(speckle(&win(&p, 1), 39), Verdict::Invalidated(pt(1, None)));
        // Exactly at the threshold still supports.
        assert_eq!(speckle(&win(&p, 1), 40), keep(p[1]));
        // Both neighbours invalid.
        let q = [pt(0, None), pt(1, Some(1000)), pt(2, None)];
        assert_eq!(
            speckle(&win(&q, 1), 10_000),
            Verdict::Invalidated(pt(1, None))
        );
        // Edge point: only its inner neighbour counts.
        let e = [pt(0, Some(700)), pt(1, Some(705))];
        assert_eq!(speckle(&win(&e, 0), 5), keep(e[0]));
        assert_eq!(speckle(&win(&e, 0), 4), Verdict::Invalidated(pt(0, None)));
        // A lone point has no support.
        let l = [pt(9, Some(700))];
        assert_eq!(
            speckle(&win(&l, 0), u32::MAX),
            Verdict::Invalidated(pt(9, None))
        );
        // An invalid centre passes unchanged.
        assert_eq!(speckle(&win(&q, 0), 0), keep(q[0]));
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
        assert_eq!(r(median(&win(&p, 2))), Some(30));
        // Centre invalid stays invalid.
        let q = [pt(0, Some(10)), pt(1, None), pt(2, Some(20))];
        assert_eq!(r(median(&win(&q, 1))), None);
        // Even count: centre 10 with neighbour 20 -> middle pair (10, 20) holds the centre.
        assert_eq!(r(median(&win(&q, 0))), Some(10));
        // Even count, centre outside the middle pair: 9000 with 100, 200, 300 ->
        // sorted 100 200 300 9000, pair (200, 300), nearest to 9000 is 300.
        let s = [
            pt(0, Some(100)),
            pt(1, Some(200)),
            pt(2, Some(9000)),
            pt(3, Some(300)),
            pt(4, None),
        ];
        assert_eq!(r(median(&win(&s, 2))), Some(300));
        // Centre 5 with 100, 200, 300 -> pair (100, 200), nearest is 100.
        let t = [
            pt(0, Some(100)),
            pt(1, Some(5)),
            pt(2, Some(200)),
            pt(3, Some(300)),
        ];
        assert_eq!(r(median(&win(&t, 1))), Some(100));
        // Single valid (the centre itself).
        let u = [pt(0, None), pt(1, Some(77)), pt(2, None)];
        assert_eq!(r(median(&win(&u, 1))), Some(77));
        // Spike removal with 3: 1000 9999 1002 -> 1002.
        let v = [pt(0, Some(1000)), pt(1, Some(9999)), pt(2, Some(1002))];
        assert_eq!(r(median(&win(&v, 1))), Some(1002));
        // Intensity of the centre is kept.
        let mut w = v;
        w[1].intensity = Some(321);
        assert_eq!(median(&win(&w, 1)).intensity, Some(321));
    }
}
