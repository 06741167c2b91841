//! The on-chip scan pipeline: filters and decimates a scan point by point, as its lines
//! arrive.
//!
//! A scan goes through [`Pipeline::begin_scan`], any number of [`Pipeline::push`] (or
//! [`Pipeline::push_batch`], e.g. one SCIP data line of about 21 points at a time), and
//! [`Pipeline::end_scan`]. Output points go to a caller-supplied [`PointSink`] the moment
//! they are determined, so RAM holds only the few points the windows need, never a scan.
//!
//! # Example
//! ```
//! use bridge::pipeline::*;
//!
//! let config = PipelineConfig {
//!     median: Some(MedianWidth::Three),
//!     decimation: Some(Decimation { factor: 2, mode: DecimationMode::Min }),
//!     ..PipelineConfig::default()
//! };
//! let mut pipeline = Pipeline::new(config)?;
//! let info = ScanInfo { seq: 0, timestamp_ms: 0, first_step: 44, last_step: 48, cluster: 1 };
//! // The count a CAN header announces, known before any point arrives.
//! assert_eq!(pipeline.begin_scan(info), ScanStart::Publish { points: 3 });
//!
//! let mut out = Vec::new(); // on the MCU: the CAN encoder, or a fixed queue
//! let line = [(44, 1000, true), (45, 9000, true), (46, 1010, true), (47, 3, false), (48, 990, true)]
//!     .map(|(step, distance, valid)| RawPoint { step, distance, intensity: None, valid });
//! pipeline.push_batch(&line, &mut |p: Point| out.push(p));
//! pipeline.end_scan(true, &mut |p: Point| out.push(p));
//!
//! // median 3: 1000, 1010, 1010, (error code), 990; then min of 2.
//! let ranges: Vec<_> = out.iter().map(|p| (p.step, p.range_mm)).collect();
//! assert_eq!(ranges, [(44, Some(1000)), (46, Some(1010)), (48, Some(990))]);
//! # Ok::<(), ConfigError>(())
//! ```
//!
//! # Stages, in order
//! 1. **Temporal decimation** ([`TemporalDecimation`]), decided at `begin_scan` from the
//!    scan's timestamp: a skipped scan's points are only counted.
//! 2. **Sequence check**: point `i` must have step `first_step + i * cluster` and lie
//!    within the announced geometry. The first point that does not is dropped with the
//!    rest of the scan, which then ends [`ScanEnd::Incomplete`].
//! 3. **Region of interest** ([`StepWindow`]): points outside are dropped entirely; all
//!    later stages see only the region (their windows end at its edges).
//! 4. **Error codes** (always): a point marked not valid becomes an invalid point.
//! 5. **Range window** ([`RangeWindow`]): a valid range outside it becomes invalid.
//! 6. **Intensity threshold**: a valid point carrying an intensity below it becomes
//!    invalid; points without intensity are untouched.
//! 7. **Speckle removal** ([`SpeckleFilter`]): a valid point with no valid neighbour
//!    within the jump threshold becomes invalid (1 point of look-ahead).
//! 8. **Median** of 3 or 5 ([`MedianWidth`]) over the valid ranges of the window, only
//!    for valid centres (1 or 2 points of look-ahead). The result is always a measured
//!    range; see the median semantics on [`MedianWidth`]'s stage below.
//! 9. **Angular decimation** ([`Decimation`]): groups of `factor` points become one point
//!    (first, min or mean); up to `factor - 1` points of look-ahead, held as a running
//!    accumulator, not a buffer.
//!
//! Median semantics: for a valid centre, take the valid ranges of its window (cut at the
//! region's ends, never padded), sorted, `n` of them; the output range is the centre's
//! range clamped into `[sorted[(n-1)/2], sorted[n/2]]`: the median when `n` is odd, and
//! for even `n` whichever middle value is nearest the centre (the centre itself when it is
//! one). The centre keeps its intensity.
//!
//! # Invalid points
//! An invalid input point (error code) never yields a range. Per-point stages only ever
//! take ranges away. The median outputs a range only for a valid centre, and takes it from
//! valid points only; `Min` and `Mean` decimation output a range only when their group
//! holds a valid point, and combine valid points only. `First` decimation passes its
//! point unchanged.
//!
//! # Work and memory
//! The pipeline is a fixed-size value (under 768 bytes, asserted by a test; no heap). Each
//! `push` does constant work: a sequence check and a few comparisons, a few moves in
//! each window (its pending points and the ranges before them), an insertion sort of at most 5 ranges (at
//! most 10 comparisons), an accumulator update, and at most one call to the sink.
//! `end_scan` makes at most 4 sink calls. An intact scan gives exactly [`output_len`]
//! points, announced by `begin_scan`; any scan gives at most that many. Measured with
//! callgrind (x86-64, release, a 1081-point scan fed 21 points at a time), before the
//! line paths below: about 84 instructions per point with every stage off and about 450
//! with every stage on; BENCHMARKS.md has the M4 counts of every configuration. With every
//! stage off, `push_batch` and `push_iter` skip the stages altogether (a sequence check
//! and the sink call per point, the counters added once per call), and
//! [`Pipeline::pass_run`] lets the bridge engine publish a data line directly, also with
//! a region of interest (a slice of the line) and a range window (part of the encoder's
//! range rule). With a window stage or decimation on, [`Pipeline::filter_line`] runs the
//! engine's data line through every stage: without speckle or median, the
//! classification and decimation in one pass (`reduce.rs`: the open group carried from
//! line to line); with them, classification, then speckle and median a loop each over
//! the line in place (the points the windows hold from the line before copied in front
//! of it, `smooth.rs`), decimation in a pass after them; and
//! [`Pipeline::filter_run`] does the same for a run of points in one loop without a
//! sink call per point; both give exactly what pushing the points one by one gives.

// No panics on any input: the input paths may not index, unwrap or overflow.
#![cfg_attr(
    not(test),
    deny(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::arithmetic_side_effects
    )
)]

mod config;
mod decimate;
mod point;
mod reduce;
mod smooth;
mod stats;
mod temporal;
mod window;

pub use config::{
    output_len, ConfigError, Decimation, DecimationMode, MedianWidth, PipelineConfig, RangeWindow,
    SpeckleFilter, StepWindow, TemporalDecimation,
};
pub use point::{Point, PointSink, RawPoint, ScanEnd, ScanInfo, ScanStart};
pub use smooth::LINE_HEADROOM;
pub use stats::Stats;

use decimate::Decimator;
use stats::{add, bump};
use temporal::TemporalGate;
use window::{CentredWindow, Verdict};

/// The scan in progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Open {
    /// No scan, or a scan that is not published.
    Idle,
    /// A published scan.
    Active(ActiveScan),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ActiveScan {
    /// Step the next point must have.
    next_step: u32,
    /// Step of the scan's last point.
    last_point_step: u32,
    /// Steps between points.
    cluster: u32,
    /// A point came out of sequence: the rest of the scan is dropped.
    broken: bool,
    /// Points emitted so far.
    emitted: usize,
}

/// The streaming scan pipeline. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Pipeline {
    config: PipelineConfig,
    next_config: Option<PipelineConfig>,
    gate: TemporalGate,
    open: Open,
    speckle: CentredWindow,
    median: CentredWindow,
    decimator: Decimator,
    stats: Stats,
    /// A filter changed or invalidated a point of the current (or last) scan.
    filtered: bool,
    /// The windows' state after the last [`Pipeline::filter_line`], in its loops' form,
    /// while no other path has needed it (then it is moved into `speckle` and `median`).
    held: Held,
    /// The runs [`Pipeline::pass_run`] takes with `config`, worked out when it is set.
    direct: DirectRuns,
    /// What [`Pipeline::filter_line`]'s stages need of `config`, worked out when it is
    /// set (a line fills in the sensor's rule, the intensity threshold when its points
    /// carry intensities, and the encoder's value for no range).
    line: LineConsts,
    /// The intensity threshold of `config` (0: none).
    min_intensity: u32,
}

/// The runs [`Pipeline::pass_run`] takes with a configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DirectRuns {
    /// Every run, and no stage is on ([`PipelineConfig::is_passthrough`]).
    Passthrough,
    /// None: a filter or decimation works on every point.
    Never,
    /// Runs without intensities: an intensity threshold is the only other stage on.
    WithoutIntensity,
    /// Every run (at most a region of interest and a range window are on).
    Always,
}

impl DirectRuns {
    /// The runs `config` lets [`Pipeline::pass_run`] take.
    fn of(config: &PipelineConfig) -> DirectRuns {
        if config.is_passthrough() {
            return DirectRuns::Passthrough;
        }
        if config.speckle.is_some()
            || config.median.is_some()
            || config.decimation.is_some_and(|d| d.factor > 1)
        {
            DirectRuns::Never
        } else if config.min_intensity.is_some() {
            DirectRuns::WithoutIntensity
        } else {
            DirectRuns::Always
        }
    }
}

/// The windows' state between data lines (see [`Pipeline::filter_line`]).
#[derive(Debug, Clone, Copy)]
struct Held {
    /// Whether this is the state (not `speckle` and `median` of the pipeline).
    live: bool,
    speckle: window::Regs,
    median: window::Regs,
    /// The step of the last point the windows took, and the steps between points.
    last_step: u32,
    cluster: u32,
    /// Whether the points carry intensities.
    intensity: bool,
}

impl Pipeline {
    /// A pipeline running `config`, which must validate.
    pub fn new(config: PipelineConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Pipeline {
            config,
            next_config: None,
            gate: TemporalGate::default(),
            open: Open::Idle,
            speckle: CentredWindow::new(1),
            median: CentredWindow::new(window::median_half(config.median)),
            decimator: Decimator::new(config.decimation),
            stats: Stats::default(),
            filtered: false,
            direct: DirectRuns::of(&config),
            line: LineConsts::of(&config),
            min_intensity: config.min_intensity.unwrap_or(0),
            held: Held {
                live: false,
                speckle: window::Regs::default(),
                median: window::Regs::default(),
                last_step: 0,
                cluster: 1,
                intensity: false,
            },
        })
    }

    /// Validates `config` and makes it the settings of the next scan that begins (a scan
    /// in progress keeps the settings its point count was announced with). The temporal
    /// decimation starts over with it.
    pub fn set_config(&mut self, config: PipelineConfig) -> Result<(), ConfigError> {
        config.validate()?;
        self.next_config = Some(config);
        Ok(())
    }

    /// The settings in force for the current (or last) scan.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The counters.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// Whether a filter (range window, intensity threshold, speckle removal or median)
    /// made a valid point of the current scan, or of the last one once it ended, invalid
    /// or changed its range: the trailer's `filtered` flag (SPEC 3.4). Error codes,
    /// the region of interest and decimation do not count (the header describes them).
    pub fn filtered(&self) -> bool {
        self.filtered
    }

    /// Whether a published scan is open (its points are being processed).
    pub fn is_publishing(&self) -> bool {
        matches!(self.open, Open::Active(_))
    }

    /// Starts a scan: applies new settings if any, decides whether the scan is published,
    /// and for a published scan returns the number of points an intact scan will give.
    ///
    /// A published scan still open is first ended as incomplete (its pending points are
    /// discarded, nothing is emitted).
    pub fn begin_scan(&mut self, info: ScanInfo) -> ScanStart {
        bump(&mut self.stats.scans_begun);
        self.abandon();
        self.filtered = false;
        if let Some(config) = self.next_config.take() {
            self.config = config;
            self.direct = DirectRuns::of(&config);
            self.line = LineConsts::of(&config);
            self.min_intensity = config.min_intensity.unwrap_or(0);
            self.median = CentredWindow::new(window::median_half(config.median));
            self.decimator = Decimator::new(config.decimation);
            self.gate.reset();
        }
        let (Some(_), Some(last_point_step)) = (info.point_count(), info.last_point_step()) else {
            bump(&mut self.stats.scans_bad_geometry);
            return ScanStart::BadGeometry;
        };
        if !self
            .gate
            .should_publish(self.config.temporal, info.timestamp_ms)
        {
            bump(&mut self.stats.scans_skipped);
            return ScanStart::Skip;
        }
        bump(&mut self.stats.scans_published);
        self.open = Open::Active(ActiveScan {
            next_step: u32::from(info.first_step),
            last_point_step: u32::from(last_point_step),
            cluster: u32::from(info.cluster_size()),
            broken: false,
            emitted: 0,
        });
        ScanStart::Publish {
            points: output_len(&self.config, &info),
        }
    }

    /// Feeds the scan's next point; output points that became determined go to `sink`
    /// (at most one per call).
    pub fn push<S: PointSink + ?Sized>(&mut self, point: RawPoint, sink: &mut S) {
        bump(&mut self.stats.points_in);
        let Open::Active(scan) = &mut self.open else {
            bump(&mut self.stats.points_ignored);
            return;
        };
        let step = u32::from(point.step);
        if scan.broken || step != scan.next_step || step > scan.last_point_step {
            scan.broken = true;
            bump(&mut self.stats.sequence_errors);
            return;
        }
        scan.next_step = scan.next_step.saturating_add(scan.cluster);
        if let Some(roi) = self.config.roi {
            if !roi.contains(point.step) {
                bump(&mut self.stats.points_outside_roi);
                return;
            }
        }
        self.release();
        self.run_stages(core::iter::once(point), |p| sink.point(p));
    }

    /// Feeds several consecutive points (e.g. one data line's worth); the same as pushing
    /// them one by one.
    pub fn push_batch<S: PointSink + ?Sized>(&mut self, points: &[RawPoint], sink: &mut S) {
        self.push_iter(points.iter().copied(), sink);
    }

    /// Feeds consecutive points from an iterator (e.g. built from a data line's readings
    /// without a copy); the same as pushing them one by one. With every stage off (no
    /// region, filter or decimation) the points take a direct path: a sequence check and
    /// the sink call, the counters added once per call.
    pub fn push_iter<I, S>(&mut self, points: I, sink: &mut S)
    where
        I: IntoIterator<Item = RawPoint>,
        S: PointSink + ?Sized,
    {
        if !self.config.is_passthrough() {
            for p in points {
                self.push(p, sink);
            }
            return;
        }
        let Open::Active(scan) = &mut self.open else {
            for _ in points {
                bump(&mut self.stats.points_in);
                bump(&mut self.stats.points_ignored);
            }
            return;
        };
        // Counted here, added to the saturating counters once. Each count is at most
        // the number of points this call takes, so a plain add cannot wrap (and costs
        // one instruction on a 32-bit MCU where a saturating one costs three).
        let (mut pushed, mut out_of_sequence, mut emitted, mut invalid) =
            (0usize, 0usize, 0usize, 0usize);
        for point in points {
            pushed = pushed.wrapping_add(1);
            let step = u32::from(point.step);
            if scan.broken || step != scan.next_step || step > scan.last_point_step {
                scan.broken = true;
                out_of_sequence = out_of_sequence.wrapping_add(1);
                continue;
            }
            scan.next_step = scan.next_step.saturating_add(scan.cluster);
            emitted = emitted.wrapping_add(1);
            invalid = invalid.wrapping_add(usize::from(!point.valid));
            sink.point(Point {
                step: point.step,
                range_mm: point.valid.then_some(point.distance),
                intensity: point.intensity,
            });
        }
        scan.emitted = scan.emitted.saturating_add(emitted);
        let st = &mut self.stats;
        add(&mut st.points_in, pushed);
        add(&mut st.sequence_errors, out_of_sequence);
        add(&mut st.invalid_error_code, invalid);
        add(&mut st.points_out, emitted);
        add(&mut st.points_out_invalid, invalid);
    }

    /// The direct path for a run of `n` consecutive points from `first_step` (each one
    /// cluster after the last, like one data line's readings), for a caller that can
    /// publish points faster than a [`PointSink`] call each. It takes the settings
    /// without a window or decimation: a region of interest, a range window, and an
    /// intensity threshold when the points carry no intensity (`intensity` false; it
    /// then changes nothing). When the settings are such and the run continues the
    /// open scan in sequence, the points are counted as pushing them counts them and
    /// the part to publish is returned ([`DirectRun`]): the caller publishes those
    /// points unchanged except that a range outside the window is no range (a point is
    /// valid when its reading is a range inside it), and reports the invalid ones with
    /// [`Pipeline::count_direct`]. Otherwise nothing changes and `None` is returned:
    /// use [`Pipeline::filter_line`] or push the points instead.
    #[inline]
    pub fn pass_run(&mut self, first_step: u16, n: usize, intensity: bool) -> Option<DirectRun> {
        let direct = match self.direct {
            DirectRuns::Always | DirectRuns::Passthrough => true,
            DirectRuns::WithoutIntensity => !intensity,
            DirectRuns::Never => false,
        };
        if !direct {
            return None;
        }
        let window = self
            .config
            .range_window
            .map_or([0, u32::MAX], |w| [w.min_mm, w.max_mm]);
        let cluster = self.take_run(first_step, n)?.cluster;
        let (lo, hi) = self.roi_slice(first_step, n, cluster);
        // The slice is at most the run.
        let m = hi.wrapping_sub(lo);
        if let Open::Active(scan) = &mut self.open {
            scan.emitted = scan.emitted.saturating_add(m);
        }
        add(&mut self.stats.points_in, n);
        if m != n {
            add(&mut self.stats.points_outside_roi, n.wrapping_sub(m));
        }
        add(&mut self.stats.points_out, m);
        Some(DirectRun { lo, hi, window })
    }

    /// Counts the points of a [`Pipeline::pass_run`] run that had no range: `invalid`
    /// in all, `rejected` of them ranges outside the range window.
    #[inline]
    pub fn count_direct(&mut self, invalid: usize, rejected: usize) {
        let st = &mut self.stats;
        add(&mut st.invalid_error_code, invalid.saturating_sub(rejected));
        add(&mut st.points_out_invalid, invalid);
        if rejected > 0 {
            // Only with a range window.
            add(&mut st.invalid_out_of_range, rejected);
            self.filtered = true;
        }
    }

    /// The block path for every stage but the direct one: `n` consecutive points from
    /// `first_step` (as for [`Pipeline::pass_run`], e.g. one data line's readings),
    /// turned into raw points by `raw`, go through every stage in one loop, without a
    /// sink call per point; the output points go to `out` (at most one per point) and
    /// their number is returned, with every counter and the `filtered` flag as pushing
    /// them one by one would leave them. The region of interest is a slice of the run.
    /// `None`, nothing changed, when every stage is off (use [`Pipeline::pass_run`]) or
    /// the run does not continue the open scan in sequence: push the points instead.
    pub fn filter_run<T>(
        &mut self,
        first_step: u16,
        points: &[T],
        raw: impl Fn(&T) -> RawPoint,
        out: impl FnMut(Point),
    ) -> Option<usize> {
        if self.config.is_passthrough() {
            return None;
        }
        let n = points.len();
        let cluster = self.take_run(first_step, n)?.cluster;
        let (lo, hi) = self.roi_slice(first_step, n, cluster);
        let inner = points.get(lo..hi).unwrap_or(&[]);
        // The slice is at most the run.
        let outside = n.wrapping_sub(inner.len());
        add(&mut self.stats.points_in, n);
        add(&mut self.stats.points_outside_roi, outside);
        self.release();
        Some(self.run_stages(inner.iter().map(raw), out))
    }

    /// The block path of a data line, for the bridge engine: `input` holds `n`
    /// consecutive points from `first_step` (as for [`Pipeline::pass_run`]) as the
    /// sensor's readings: a `distance` is a range when the `sensor` rule says so (its
    /// window is not used; `u32::MAX` is never a range), an error code otherwise; `aux`
    /// is the intensity when `intensity` (the `index` and `echo` fields are not used).
    /// The stages write into `cells` (at least `n` + [`LINE_HEADROOM`] long): the
    /// region of interest as a slice; without speckle or median, error codes, range
    /// window, intensity threshold and decimation in one pass; otherwise those three as
    /// one classification of the line into `cells`, behind the points the windows
    /// hold from the line before; speckle removal and median as one loop each over
    /// those cells, chosen per line and width; decimation as a block reduction after
    /// them. The output points are left at the front
    /// of `cells` as readings for the CAN encoder: `out_none` for no range, a range of
    /// 0 mm as 1 (the encodings code it so), `aux` the intensity (0 for none); their
    /// number is returned, and how many of them are no range (`out_none`). Counters, the `filtered` flag and what
    /// [`Pipeline::end_scan`] emits are those of pushing the points one by one. `None`,
    /// nothing changed, when every stage is off (use [`Pipeline::pass_run`]), `cells`
    /// is too short, or the run does not continue the open scan in sequence.
    pub fn filter_line(
        &mut self,
        first_step: u16,
        input: &[scip::Reading],
        cells: &mut [scip::Reading],
        sensor: can_wire::RangeRule,
        intensity: bool,
        out_none: u32,
    ) -> Option<(usize, usize)> {
        let n = input.len();
        // (The settings' direct runs say whether every stage is off: one test.)
        if self.direct == DirectRuns::Passthrough || cells.len() < n.saturating_add(LINE_HEADROOM) {
            return None;
        }
        let cluster = self.take_run(first_step, n)?.cluster;
        let (lo, input) = if self.config.roi.is_some() {
            let (lo, hi) = self.roi_slice(first_step, n, cluster);
            let input = input.get(lo..hi).unwrap_or_default();
            // The slice is at most the run.
            add(
                &mut self.stats.points_outside_roi,
                n.wrapping_sub(input.len()),
            );
            (lo, input)
        } else {
            (0, input)
        };
        let buf = cells;
        add(&mut self.stats.points_in, n);
        let Some(last) = input.len().checked_sub(1) else {
            return Some((0, 0));
        };
        // Step of the slice's last point: the run fits the scan's u16 steps, so `lo +
        // last` is below 2^16 and times the cluster (below 2^16) below 2^32.
        let last_step = u32::from(first_step).wrapping_add(
            u32::try_from(lo.wrapping_add(last))
                .unwrap_or(0)
                .wrapping_mul(cluster),
        );
        // Four words (a `Counts::default()` here was a call to clear 25 bytes a line).
        let mut t = Tally::default();
        // The settings' part is kept from when they were set: the line's part only.
        let line = &mut self.line;
        if !line.is_sensor(&sensor) {
            line.set_sensor(sensor);
        }
        line.min_intensity = if intensity { self.min_intensity } else { 0 };
        line.out_none = out_none;
        let line = &self.line;
        let windows = line.jump.is_some() || line.half2 > 0;
        if !windows {
            // The classification, then decimation (pipeline/reduce.rs) or the
            // encoder's form.
            let n = input.len();
            let cells = buf.get_mut(..n).unwrap_or_default();
            smooth::classify(input, cells, line, &mut t);
            let (m, invalid) = if line.decimate {
                let back = u32::try_from(last).unwrap_or(0).saturating_mul(cluster);
                let first = last_step.saturating_sub(back);
                let at = (first, cluster, intensity);
                reduce::reduce_line(&mut self.decimator, cells, at, out_none)
            } else {
                (n, smooth::finish(cells, out_none))
            };
            return Some((self.commit(&t.counts(m, invalid, false)), invalid));
        }
        // The windows' state for the line: as the last line left it, or loaded.
        let h = &mut self.held;
        if !h.live {
            h.speckle = self.speckle.load(NONE);
            h.median = self.median.load(NONE);
        }
        let (sp, md) = (&mut h.speckle, &mut h.median);
        // The output is converted after decimation, or in the loops.
        // The OR of every range the median changed with its new value (0: none), not 0
        // from the start when the scan is already filtered (the median then need not
        // track its changes).
        let mut changed = u32::from(self.filtered);
        let (w, mut invalid) = smooth::line(input, buf, line, sp, md, &mut t, &mut changed);
        (h.live, h.last_step, h.cluster, h.intensity) = (true, last_step, cluster, intensity);
        let mut m = w;
        if line.decimate {
            // Points held back by the windows (steps count back from `last_step`).
            let held = |on: bool, r: &window::Regs| if on { r.np } else { 0 };
            // A few points each, and the line's points: no wrap.
            let lag = held(line.jump.is_some(), sp).wrapping_add(held(line.half2 > 0, md));
            let part = buf.get_mut(..m).unwrap_or_default();
            // Step of the first point the decimator gets (a step of the scan, so no
            // wrap; not used when `m` is 0: no group opens in an empty line).
            let back = u32::try_from(lag.wrapping_add(m).wrapping_sub(1)).unwrap_or(0);
            let step = last_step.wrapping_sub(back.wrapping_mul(cluster));
            (m, invalid) = reduce::reduce_line(
                &mut self.decimator,
                part,
                (step, cluster, intensity),
                out_none,
            );
        }
        Some((self.commit(&t.counts(m, invalid, changed != 0)), invalid))
    }

    /// The slice of a run of `n` points from `first_step`, `cluster` steps apart, that
    /// lies in the region of interest (all of it when there is none).
    fn roi_slice(&self, first_step: u16, n: usize, cluster: u32) -> (usize, usize) {
        let Some(roi) = self.config.roi else {
            return (0, n);
        };
        // Points of the run with a step below `step` (`cluster` is at least 1).
        let below = |step: u32| {
            let d = step.saturating_sub(u32::from(first_step));
            usize::try_from(d.div_ceil(cluster)).map_or(n, |k| k.min(n))
        };
        let lo = below(u32::from(roi.first));
        let hi = below(u32::from(roi.last).saturating_add(1));
        (lo, hi.max(lo))
    }

    /// Every stage from the error codes on, for points in sequence inside the region
    /// of interest (counted in `points_in` by the caller); returns the number of output
    /// points. One loop: the counters are kept in locals and added once.
    #[inline(always)]
    fn run_stages(
        &mut self,
        points: impl Iterator<Item = RawPoint>,
        mut out: impl FnMut(Point),
    ) -> usize {
        let cfg = self.config;
        let mut c = Counts::default();
        // The range window and intensity threshold as bounds (every range passes a
        // window that is off, every intensity a threshold that is off).
        let (lo, hi) = cfg
            .range_window
            .map_or((0, u32::MAX), |w| (w.min_mm, w.max_mm));
        let min_intensity = cfg.min_intensity.unwrap_or(0);
        let decimate = self.decimator.is_active();
        for r in points {
            // Error codes, range window and intensity threshold.
            let mut p = Point {
                step: r.step,
                range_mm: None,
                intensity: r.intensity,
            };
            if !r.valid {
                c.error_code = c.error_code.wrapping_add(1);
            } else if r.distance < lo || r.distance > hi {
                c.out_of_range = c.out_of_range.wrapping_add(1);
            } else if r.intensity.is_some_and(|i| i < min_intensity) {
                c.low_intensity = c.low_intensity.wrapping_add(1);
            } else {
                p.range_mm = Some(r.distance);
            }
            if let Some(f) = cfg.speckle {
                match self.speckle.push(p) {
                    Some((centre, nb)) => p = c.speckle(centre, &nb, f),
                    None => continue,
                }
            }
            if cfg.median.is_some() {
                match self.median.push(p) {
                    Some((centre, nb)) => p = c.median(centre, &nb),
                    None => continue,
                }
            }
            if !decimate {
                c.emit(p, &mut out);
            } else if let Some(d) = self.decimator.push(p) {
                c.emit(d, &mut out);
            }
        }
        self.commit(&c)
    }

    /// Adds a loop's counts to the counters; returns its number of output points.
    fn commit(&mut self, c: &Counts) -> usize {
        let st = &mut self.stats;
        // The four rejection counts are 0 on most lines: one test for them.
        if (c.error_code | c.out_of_range | c.low_intensity | c.speckle) != 0 {
            add(&mut st.invalid_error_code, c.error_code);
            add(&mut st.invalid_out_of_range, c.out_of_range);
            add(&mut st.invalid_low_intensity, c.low_intensity);
            add(&mut st.invalid_speckle, c.speckle);
            self.filtered |= c.out_of_range > 0 || c.low_intensity > 0 || c.speckle > 0;
        }
        add(&mut st.points_out, c.emitted);
        add(&mut st.points_out_invalid, c.invalid_out);
        self.filtered |= c.filtered;
        if let Open::Active(scan) = &mut self.open {
            scan.emitted = scan.emitted.saturating_add(c.emitted);
        }
        c.emitted
    }

    /// The open scan, moved past a run of `n` (at least 1) consecutive points from
    /// `first_step`, when they continue it in sequence and fit it; `None`, nothing
    /// changed, otherwise (the points must then be pushed, which counts the error).
    fn take_run(&mut self, first_step: u16, n: usize) -> Option<&mut ActiveScan> {
        let Open::Active(scan) = &mut self.open else {
            return None;
        };
        let n32 = u32::try_from(n).ok().filter(|&n| n > 0)?;
        let span = n32.saturating_sub(1).saturating_mul(scan.cluster);
        let first = u32::from(first_step);
        if scan.broken
            || first != scan.next_step
            || first.saturating_add(span) > scan.last_point_step
        {
            return None;
        }
        scan.next_step = first.saturating_add(span).saturating_add(scan.cluster);
        Some(scan)
    }

    /// Counts `n` points of a [`Pipeline::pass_run`] run that had no range, none of
    /// them a range outside the window.
    #[inline]
    pub fn count_invalid(&mut self, n: usize) {
        self.count_direct(n, 0);
    }

    /// Ends the scan. When `intact` and every announced point arrived in sequence, the
    /// points still in the windows are emitted (their windows cut at the scan's end) and
    /// the scan is complete. Otherwise they are dropped and the scan is incomplete.
    pub fn end_scan<S: PointSink + ?Sized>(&mut self, intact: bool, sink: &mut S) -> ScanEnd {
        let Open::Active(scan) = self.open else {
            return ScanEnd::NotPublished;
        };
        let all_arrived = scan.next_step > scan.last_point_step;
        if !(intact && all_arrived && !scan.broken) {
            return self.abandon();
        }
        self.release();
        let cfg = self.config;
        let mut c = Counts::default();
        let mut out = |p: Point| sink.point(p);
        if let Some(f) = cfg.speckle {
            while let Some((centre, nb)) = self.speckle.pop_tail() {
                let mut p = c.speckle(centre, &nb, f);
                if cfg.median.is_some() {
                    match self.median.push(p) {
                        Some((centre, nb)) => p = c.median(centre, &nb),
                        None => continue,
                    }
                }
                if let Some(d) = self.decimator.push(p) {
                    c.emit(d, &mut out);
                }
            }
        }
        if cfg.median.is_some() {
            while let Some((centre, nb)) = self.median.pop_tail() {
                let p = c.median(centre, &nb);
                if let Some(d) = self.decimator.push(p) {
                    c.emit(d, &mut out);
                }
            }
        }
        if let Some(d) = self.decimator.flush() {
            c.emit(d, &mut out);
        }
        self.commit(&c);
        let points = match self.open {
            Open::Active(s) => s.emitted,
            Open::Idle => 0,
        };
        self.reset_scan();
        bump(&mut self.stats.scans_complete);
        ScanEnd::Complete { points }
    }

    /// Ends an open published scan as incomplete, dropping its pending points.
    fn abandon(&mut self) -> ScanEnd {
        self.release();
        let Open::Active(scan) = self.open else {
            self.open = Open::Idle;
            return ScanEnd::NotPublished;
        };
        let discarded = self
            .speckle
            .pending()
            .saturating_add(self.median.pending())
            .saturating_add(self.decimator.pending());
        add(&mut self.stats.points_discarded, discarded);
        bump(&mut self.stats.scans_incomplete);
        self.reset_scan();
        ScanEnd::Incomplete {
            points: scan.emitted,
            discarded,
        }
    }

    /// Moves the state [`Pipeline::filter_line`] holds into the windows, for the paths
    /// that take them point by point.
    fn release(&mut self) {
        if !self.held.live {
            return;
        }
        self.held.live = false;
        let h = self.held;
        let (last_step, cluster) = (h.last_step, h.cluster);
        let mut lag = 0u32;
        if self.config.speckle.is_some() {
            let sp = &h.speckle;
            self.speckle
                .store(sp, NONE, h.intensity, (last_step, cluster));
            lag = u32::try_from(sp.np).unwrap_or(0);
        }
        if self.config.median.is_some() {
            let at = last_step.saturating_sub(lag.saturating_mul(cluster));
            self.median
                .store(&h.median, NONE, h.intensity, (at, cluster));
        }
    }

    fn reset_scan(&mut self) {
        self.held.live = false;
        self.open = Open::Idle;
        self.speckle.clear();
        self.median.clear();
        self.decimator.clear();
    }
}

/// No range, inside a line.
const NONE: u32 = u32::MAX;

/// What [`smooth::line`] needs of the settings, worked out when they are set, with the
/// line's own parts filled in for each line.
#[derive(Debug, Clone, Copy)]
struct LineConsts {
    /// The sensor's range test with the range window.
    rule: can_wire::RangeRule,
    /// The first distance of the classification's common span of `rule` (see
    /// [`smooth::span`]).
    low: u32,
    /// The length of that span.
    span: u32,
    /// Whether the window stages' last gives its outputs in the encoder's form: no
    /// decimation after, and no range of 0 can pass `rule`.
    last: bool,
    /// The points the median holds on each side of its centre (0: the median is off).
    half2: usize,
    /// The intensity threshold (0: none, or no intensities).
    min_intensity: u32,
    /// Speckle removal's threshold, when on.
    jump: Option<u32>,
    /// Whether decimation follows (the output then stays in the loop's form).
    decimate: bool,
    /// The encoder's value for no range.
    out_none: u32,
}

impl LineConsts {
    /// The constants of `config`'s lines, the line's own parts (the sensor's rule but
    /// the window, the intensity threshold, the value for no range) left to fill in
    /// ([`LineConsts::set_sensor`] for the rule).
    fn of(config: &PipelineConfig) -> LineConsts {
        let window = config
            .range_window
            .map_or([0, u32::MAX], |w| [w.min_mm, w.max_mm]);
        LineConsts {
            // No sensor's rule (none has no range at all): the first line sets its own.
            // Until then an empty span and `last` false, right for any rule (every
            // distance takes the full test, every output the encoder's form after).
            rule: can_wire::RangeRule {
                window,
                ..can_wire::RangeRule::at_least(u32::MAX)
            },
            low: 0,
            span: 0,
            last: false,
            half2: config.median.map_or(0, MedianWidth::half),
            min_intensity: 0,
            jump: config.speckle.map(|f| f.max_jump_mm),
            decimate: config.decimation_factor() > 1,
            out_none: 0,
        }
    }

    /// Whether `rule` holds the sensor's `sensor` (its window aside): one compare a line.
    #[inline(always)]
    fn is_sensor(&self, sensor: &can_wire::RangeRule) -> bool {
        let r = &self.rule;
        r.min == sensor.min && r.except == sensor.except && r.band == sensor.band
    }

    /// The sensor's rule `sensor` (its window aside: the settings' stays), and what the
    /// classification works out of it (when the sensor's rule changes, rare).
    #[inline(never)]
    fn set_sensor(&mut self, sensor: can_wire::RangeRule) {
        self.rule = can_wire::RangeRule {
            window: self.rule.window,
            ..sensor
        };
        let zero_free;
        (self.low, self.span, zero_free) = smooth::span(&self.rule);
        self.last = !self.decimate && zero_free;
    }
}

/// What [`Pipeline::filter_line`]'s classification and speckle removal rejected in a
/// line (each at most the line's points). Four words: cleared by four stores (a fifth
/// made it a call to clear memory).
#[derive(Default)]
struct Tally {
    error_code: usize,
    out_of_range: usize,
    low_intensity: usize,
    speckle: usize,
}

impl Tally {
    /// The line's [`Counts`]: these, `emitted` output points, `invalid_out` of them
    /// without a range, `filtered` when the median changed a range.
    #[inline(always)]
    fn counts(&self, emitted: usize, invalid_out: usize, filtered: bool) -> Counts {
        Counts {
            error_code: self.error_code,
            out_of_range: self.out_of_range,
            low_intensity: self.low_intensity,
            speckle: self.speckle,
            emitted,
            invalid_out,
            filtered,
        }
    }
}

/// The part of a run that [`Pipeline::pass_run`] leaves to publish directly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DirectRun {
    /// The first point of the run to publish (the region of interest's first).
    pub lo: usize,
    /// One past the last point to publish.
    pub hi: usize,
    /// The ranges kept, both ends included (`[0, u32::MAX]` with no range window):
    /// a range outside is published as no range.
    pub window: [u32; 2],
}

/// What one loop of the stages did, counted in locals (each at most the points the
/// loop took, so a plain add cannot wrap).
#[derive(Debug, Default)]
struct Counts {
    error_code: usize,
    out_of_range: usize,
    low_intensity: usize,
    speckle: usize,
    emitted: usize,
    invalid_out: usize,
    /// The median changed a range.
    filtered: bool,
}

impl Counts {
    /// Speckle removal's verdict on `centre`.
    #[inline]
    fn speckle(&mut self, centre: Point, nb: &window::Neighbours, f: SpeckleFilter) -> Point {
        match window::speckle(centre, nb, f.max_jump_mm) {
            Verdict::Keep(p) => p,
            Verdict::Invalidated(p) => {
                self.speckle = self.speckle.wrapping_add(1);
                p
            }
        }
    }

    /// The median of `centre`'s window.
    #[inline]
    fn median(&mut self, centre: Point, nb: &window::Neighbours) -> Point {
        let m = window::median(centre, nb);
        self.filtered |= m.range_mm != centre.range_mm;
        m
    }

    /// An output point.
    #[inline]
    fn emit(&mut self, p: Point, out: &mut impl FnMut(Point)) {
        self.emitted = self.emitted.wrapping_add(1);
        self.invalid_out = self.invalid_out.wrapping_add(usize::from(!p.is_valid()));
        out(p);
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    /// Error code the URG-04LX gives for "too far / no echo".
    const E: Option<u32> = None;

    fn scan(first: u16, last: u16) -> ScanInfo {
        ScanInfo {
            seq: 1,
            timestamp_ms: 0,
            first_step: first,
            last_step: last,
            cluster: 1,
        }
    }

    /// Raw points from step `first` on; `None` is an error code (distance 0).
    fn raw(first: u16, ranges: &[Option<u32>]) -> Vec<RawPoint> {
        (first..)
            .zip(ranges)
            .map(|(step, r)| RawPoint {
                step,
                distance: r.unwrap_or(0),
                intensity: None,
                valid: r.is_some(),
            })
            .collect()
    }

    fn pt(step: u16, r: Option<u32>, i: Option<u32>) -> Point {
        Point {
            step,
            range_mm: r,
            intensity: i,
        }
    }

    /// Runs one intact scan; returns (announced count, output, end).
    fn run(config: PipelineConfig, info: ScanInfo, points: &[RawPoint]) -> (usize, Vec<Point>) {
        let mut p = Pipeline::new(config).unwrap();
        let ScanStart::Publish { points: announced } = p.begin_scan(info) else {
            panic!("scan not published");
        };
        let mut out = Vec::new();
        let mut sink = |x: Point| out.push(x);
        p.push_batch(points, &mut sink);
        let end = p.end_scan(true, &mut sink);
        assert_eq!(end, ScanEnd::Complete { points: out.len() });
        assert_eq!(announced, out.len());
        (announced, out)
    }

    fn ranges(points: &[Point]) -> Vec<Option<u32>> {
        points.iter().map(|p| p.range_mm).collect()
    }

    #[test]
    fn no_stage_passes_points_through_and_error_codes_become_invalid() {
        let input = raw(10, &[Some(1000), E, Some(20), Some(5600)]);
        let (_, out) = run(PipelineConfig::default(), scan(10, 13), &input);
        assert_eq!(
            out,
            std::vec![
                pt(10, Some(1000), None),
                pt(11, None, None),
                pt(12, Some(20), None),
                pt(13, Some(5600), None),
            ]
        );
    }

    #[test]
    fn range_window_invalidates_outside() {
        let config = PipelineConfig {
            range_window: Some(RangeWindow {
                min_mm: 100,
                max_mm: 4000,
            }),
            ..PipelineConfig::default()
        };
        let input = raw(0, &[Some(99), Some(100), Some(4000), Some(4001), E]);
        let mut p = Pipeline::new(config).unwrap();
        p.begin_scan(scan(0, 4));
        let mut out = Vec::new();
        p.push_batch(&input, &mut |x| out.push(x));
        p.end_scan(true, &mut |x| out.push(x));
        assert_eq!(ranges(&out), [E, Some(100), Some(4000), E, E]);
        assert_eq!(p.stats().invalid_out_of_range, 2);
        assert_eq!(p.stats().invalid_error_code, 1);
        assert_eq!(p.stats().points_out_invalid, 3);
    }

    #[test]
    fn intensity_threshold_only_where_there_is_intensity() {
        let config = PipelineConfig {
            min_intensity: Some(50),
            ..PipelineConfig::default()
        };
        let mut input = raw(0, &[Some(1000), Some(1001), Some(1002), Some(1003)]);
        input[0].intensity = Some(49);
        input[1].intensity = Some(50);
        input[2].intensity = None;
        input[3].intensity = Some(0);
        let (_, out) = run(config, scan(0, 3), &input);
        assert_eq!(
            out,
            std::vec![
                pt(0, None, Some(49)),
                pt(1, Some(1001), Some(50)),
                pt(2, Some(1002), None),
                pt(3, None, Some(0)),
            ]
        );
    }

    #[test]
    fn roi_drops_points_outside() {
        let config = PipelineConfig {
            roi: Some(StepWindow {
                first: 12,
                last: 14,
            }),
            ..PipelineConfig::default()
        };
        let input = raw(10, &[Some(1), Some(2), Some(3), E, Some(5), Some(6)]);
        let (n, out) = run(config, scan(10, 15), &input);
        assert_eq!(n, 3);
        assert_eq!(
            out,
            std::vec![
                pt(12, Some(3), None),
                pt(13, E, None),
                pt(14, Some(5), None)
            ]
        );
    }

    #[test]
    fn speckle_through_the_pipeline() {
        let config = PipelineConfig {
            speckle: Some(SpeckleFilter { max_jump_mm: 100 }),
            ..PipelineConfig::default()
        };
        // 0: 1000 edge, supported by 1 (50)     -> keep
        // 1: 1050 supported by 0                -> keep
        // 2: 3000 neighbours 1050, E            -> speckle
        // 3: E                                  -> invalid
        // 4: 2000 neighbours E, 2100 (diff 100) -> keep
        // 5: 2100 supported by 4                -> keep
        // 6: 2500 neighbours 2100 (400), edge   -> speckle
        let input = raw(
            0,
            &[
                Some(1000),
                Some(1050),
                Some(3000),
                E,
                Some(2000),
                Some(2100),
                Some(2500),
            ],
        );
        let mut p = Pipeline::new(config).unwrap();
        p.begin_scan(scan(0, 6));
        let mut out = Vec::new();
        p.push_batch(&input, &mut |x| out.push(x));
        p.end_scan(true, &mut |x| out.push(x));
        assert_eq!(
            ranges(&out),
            [Some(1000), Some(1050), E, E, Some(2000), Some(2100), E]
        );
        assert_eq!(p.stats().invalid_speckle, 2);
    }

    #[test]
    fn median3_through_the_pipeline() {
        let config = PipelineConfig {
            median: Some(MedianWidth::Three),
            ..PipelineConfig::default()
        };
        // 0: {100, 900} even -> pair (100, 900) holds 100 -> 100
        // 1: {100, 900, 120} -> 120
        // 2: {900, 120} (3 is E) -> 120
        // 3: E -> E
        // 4: {130} (3 is E, 4 is the end) -> 130
        let input = raw(0, &[Some(100), Some(900), Some(120), E, Some(130)]);
        let (_, out) = run(config, scan(0, 4), &input);
        assert_eq!(
            ranges(&out),
            [Some(100), Some(120), Some(120), E, Some(130)]
        );
    }

    #[test]
    fn first_of_k_decimation_through_the_pipeline() {
        let config = PipelineConfig {
            decimation: Some(Decimation {
                factor: 2,
                mode: DecimationMode::First,
            }),
            ..PipelineConfig::default()
        };
        let input = raw(0, &[E, Some(5), Some(6), Some(7), Some(8)]);
        let (_, out) = run(config, scan(0, 4), &input);
        assert_eq!(
            out,
            std::vec![pt(0, E, None), pt(2, Some(6), None), pt(4, Some(8), None)]
        );
    }

    /// ROI + median of 5 + min of 3 on a 20-point scan, worked out by hand.
    ///
    /// ```text
    /// step  100  101 102  103  104  105  106  107 108 109  110  111 112  113  114 115  116  117  118  119
    /// in   1000 1010   E 1020 5000 1030 1040 1050   E   E 2000 2010  30 2020 2030   E 2040 2050 2060 9999
    /// ROI 102..=116 keeps j0..j14 = steps 102..116 (15 points); windows end at the ROI.
    /// median 5 (valid centres only, valid values of the window, clamp into middle pair):
    ///  j0 102 E                                       -> E
    ///  j1 103 {1020 5000 1030}         sorted 1020 1030 5000        -> 1030
    ///  j2 104 {1020 5000 1030 1040}    pair (1030,1040), 5000       -> 1040
    ///  j3 105 {1020 5000 1030 1040 1050}                            -> 1040
    ///  j4 106 {5000 1030 1040 1050}    pair (1040,1050), 1040       -> 1040
    ///  j5 107 {1030 1040 1050}                                      -> 1040
    ///  j6 108 E, j7 109 E                                           -> E, E
    ///  j8 110 {2000 2010 30}           sorted 30 2000 2010          -> 2000
    ///  j9 111 {2000 2010 30 2020}      pair (2000,2010), 2010       -> 2010
    /// j10 112 {2000 2010 30 2020 2030}                              -> 2010
    /// j11 113 {2010 30 2020 2030}      pair (2010,2020), 2020       -> 2020
    /// j12 114 {30 2020 2030 2040}      pair (2020,2030), 2030       -> 2030
    /// j13 115 E                                                     -> E
    /// j14 116 {2030 2040} (cut)        pair (2030,2040), 2040       -> 2040
    /// min of 3: [E 1030 1040]@102 -> 1030, [1040 1040 1040]@105 -> 1040,
    ///           [E E 2000]@108 -> 2000, [2010 2010 2020]@111 -> 2010, [2030 E 2040]@114 -> 2030
    /// ```
    #[test]
    fn roi_median5_min3_by_hand() {
        let input = raw(
            100,
            &[
                Some(1000),
                Some(1010),
                E,
                Some(1020),
                Some(5000),
                Some(1030),
                Some(1040),
                Some(1050),
                E,
                E,
                Some(2000),
                Some(2010),
                Some(30),
                Some(2020),
                Some(2030),
                E,
                Some(2040),
                Some(2050),
                Some(2060),
                Some(9999),
            ],
        );
        let config = PipelineConfig {
            roi: Some(StepWindow {
                first: 102,
                last: 116,
            }),
            median: Some(MedianWidth::Five),
            decimation: Some(Decimation {
                factor: 3,
                mode: DecimationMode::Min,
            }),
            ..PipelineConfig::default()
        };
        let (n, out) = run(config, scan(100, 119), &input);
        assert_eq!(n, 5);
        assert_eq!(
            out,
            std::vec![
                pt(102, Some(1030), None),
                pt(105, Some(1040), None),
                pt(108, Some(2000), None),
                pt(111, Some(2010), None),
                pt(114, Some(2030), None),
            ]
        );
        // Without decimation: the median stage alone.
        let (_, out) = run(
            PipelineConfig {
                decimation: None,
                ..config
            },
            scan(100, 119),
            &input,
        );
        assert_eq!(
            ranges(&out),
            [
                E,
                Some(1030),
                Some(1040),
                Some(1040),
                Some(1040),
                Some(1040),
                E,
                E,
                Some(2000),
                Some(2010),
                Some(2010),
                Some(2020),
                Some(2030),
                E,
                Some(2040)
            ]
        );
    }

    /// Range window + intensity + speckle + median 3 + mean of 4, by hand.
    ///
    /// ```text
    /// step        0    1    2    3    4    5    6   7    8    9
    /// range    1000 1020 4500 1500 1040 1060 1050   E 3000 3040
    /// intens     80   90  100   60   70   40   75  10   90   95
    /// window/int  .    .  out    .    .  low    .   E    .    .
    /// speckle(50) on the survivors: 3 (1500: E | 460), 4 (1040: 460 | low) and
    ///   6 (1050: low | E) lose their support -> invalid; 0/1 and 8/9 keep each other.
    /// median 3: 0 {1000 1020} -> 1000, 1 {1000 1020} -> 1020, 8 {3000 3040} -> 3000,
    ///   9 {3000 3040} -> 3040.
    /// mean of 4: [0..3]@0 -> (1000+1020)/2 = 1010, intensity (80+90)/2 = 85
    ///            [4..7]@4 -> invalid, no intensity
    ///            [8..9]@8 -> 3020, intensity (90+95)/2 = 92.5 -> 93
    /// ```
    #[test]
    fn window_intensity_speckle_median3_mean4_by_hand() {
        let r = [
            Some(1000),
            Some(1020),
            Some(4500),
            Some(1500),
            Some(1040),
            Some(1060),
            Some(1050),
            E,
            Some(3000),
            Some(3040),
        ];
        let intensity = [80, 90, 100, 60, 70, 40, 75, 10, 90, 95];
        let mut input = raw(0, &r);
        for (p, i) in input.iter_mut().zip(intensity) {
            p.intensity = Some(i);
        }
        input[7].distance = 7; // URG-04LX "neighbour error"
        let config = PipelineConfig {
            range_window: Some(RangeWindow {
                min_mm: 100,
                max_mm: 4000,
            }),
            min_intensity: Some(50),
            speckle: Some(SpeckleFilter { max_jump_mm: 50 }),
            median: Some(MedianWidth::Three),
            decimation: Some(Decimation {
                factor: 4,
                mode: DecimationMode::Mean,
            }),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        assert_eq!(p.begin_scan(scan(0, 9)), ScanStart::Publish { points: 3 });
        let mut out = Vec::new();
        p.push_batch(&input, &mut |x| out.push(x));
        assert_eq!(
            p.end_scan(true, &mut |x| out.push(x)),
            ScanEnd::Complete { points: 3 }
        );
        assert_eq!(
            out,
            std::vec![
                pt(0, Some(1010), Some(85)),
                pt(4, None, None),
                pt(8, Some(3020), Some(93)),
            ]
        );
        let s = p.stats();
        assert_eq!(
            (
                s.invalid_error_code,
                s.invalid_out_of_range,
                s.invalid_low_intensity,
                s.invalid_speckle
            ),
            (1, 1, 1, 3)
        );
        assert_eq!(
            (s.points_in, s.points_out, s.points_out_invalid),
            (10, 3, 1)
        );
        assert_eq!((s.scans_published, s.scans_complete), (1, 1));
    }

    #[test]
    fn outputs_leave_as_soon_as_determined() {
        // Median 5 needs 2 points of look-ahead; min of 2 then needs its pair.
        let config = PipelineConfig {
            median: Some(MedianWidth::Five),
            speckle: Some(SpeckleFilter { max_jump_mm: 1000 }),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        p.begin_scan(scan(0, 9));
        let mut counts = Vec::new();
        let mut n = 0usize;
        for x in raw(0, &[Some(500); 10]) {
            p.push(x, &mut |_| n += 1);
            counts.push(n);
        }
        // speckle (1 ahead) + median (2 ahead): point k leaves when k + 3 arrived.
        assert_eq!(counts, [0, 0, 0, 1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(
            p.end_scan(true, &mut |_| n += 1),
            ScanEnd::Complete { points: 10 }
        );
        assert_eq!(n, 10);
    }

    #[test]
    fn single_point_scans() {
        let one = raw(44, &[Some(1234)]);
        let all = PipelineConfig {
            range_window: Some(RangeWindow {
                min_mm: 20,
                max_mm: 5600,
            }),
            median: Some(MedianWidth::Five),
            decimation: Some(Decimation {
                factor: 3,
                mode: DecimationMode::Mean,
            }),
            ..PipelineConfig::default()
        };
        let (n, out) = run(all, scan(44, 44), &one);
        assert_eq!((n, out), (1, std::vec![pt(44, Some(1234), None)]));
        // A lone point is a speckle.
        let speckle = PipelineConfig {
            speckle: Some(SpeckleFilter { max_jump_mm: 100 }),
            ..all
        };
        let (_, out) = run(speckle, scan(44, 44), &one);
        assert_eq!(out, std::vec![pt(44, None, None)]);
    }

    #[test]
    fn all_invalid_scan_gives_invalid_points_only() {
        let input = raw(0, &[E; 7]);
        for mode in [
            DecimationMode::First,
            DecimationMode::Min,
            DecimationMode::Mean,
        ] {
            let config = PipelineConfig {
                speckle: Some(SpeckleFilter { max_jump_mm: 0 }),
                median: Some(MedianWidth::Three),
                decimation: Some(Decimation { factor: 2, mode }),
                ..PipelineConfig::default()
            };
            let (n, out) = run(config, scan(0, 6), &input);
            assert_eq!(n, 4);
            assert_eq!(ranges(&out), [E; 4]);
        }
    }

    #[test]
    fn empty_roi_gives_no_points() {
        let config = PipelineConfig {
            roi: Some(StepWindow {
                first: 500,
                last: 600,
            }),
            median: Some(MedianWidth::Five),
            ..PipelineConfig::default()
        };
        let (n, out) = run(config, scan(0, 9), &raw(0, &[Some(1); 10]));
        assert_eq!((n, out.len()), (0, 0));
    }

    #[test]
    fn cluster_steps_are_checked() {
        let info = ScanInfo {
            cluster: 3,
            ..scan(10, 20)
        };
        // Points at 10, 13, 16, 19.
        let good: Vec<RawPoint> = [10u16, 13, 16, 19]
            .iter()
            .map(|&step| RawPoint {
                step,
                distance: u32::from(step),
                intensity: None,
                valid: true,
            })
            .collect();
        let (n, out) = run(PipelineConfig::default(), info, &good);
        assert_eq!(n, 4);
        assert_eq!(
            out.iter().map(|p| p.step).collect::<Vec<_>>(),
            [10, 13, 16, 19]
        );
        // A point at 14 instead of 13 breaks the scan.
        let mut bad = good.clone();
        bad[1].step = 14;
        let mut p = Pipeline::new(PipelineConfig::default()).unwrap();
        p.begin_scan(info);
        let mut out = Vec::new();
        p.push_batch(&bad, &mut |x| out.push(x));
        assert_eq!(
            p.end_scan(true, &mut |x| out.push(x)),
            ScanEnd::Incomplete {
                points: 1,
                discarded: 0
            }
        );
        assert_eq!(out.len(), 1);
        assert_eq!(p.stats().sequence_errors, 3);
        assert_eq!(p.stats().scans_incomplete, 1);
    }

    #[test]
    fn extra_points_past_the_end_are_sequence_errors() {
        let mut p = Pipeline::new(PipelineConfig::default()).unwrap();
        p.begin_scan(scan(0, 1));
        let mut n = 0;
        p.push_batch(&raw(0, &[Some(1), Some(2), Some(3)]), &mut |_| n += 1);
        assert_eq!(n, 2);
        assert_eq!(p.stats().sequence_errors, 1);
        assert!(matches!(
            p.end_scan(true, &mut |_| n += 1),
            ScanEnd::Incomplete { points: 2, .. }
        ));
    }

    #[test]
    fn incomplete_scans_drop_pending_points() {
        let config = PipelineConfig {
            median: Some(MedianWidth::Five),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        p.begin_scan(scan(0, 9));
        let mut out = Vec::new();
        p.push_batch(&raw(0, &[Some(7); 6]), &mut |x| out.push(x));
        // 6 of 10 arrived: points 0..=3 are determined, 4 and 5 wait for 6 and 7.
        assert_eq!(out.len(), 4);
        assert_eq!(
            p.end_scan(true, &mut |x| out.push(x)),
            ScanEnd::Incomplete {
                points: 4,
                discarded: 2
            }
        );
        // Declared not intact although every point arrived.
        p.begin_scan(scan(0, 2));
        p.push_batch(&raw(0, &[Some(7); 3]), &mut |x| out.push(x));
        assert_eq!(
            p.end_scan(false, &mut |x| out.push(x)),
            ScanEnd::Incomplete {
                points: 1,
                discarded: 2
            }
        );
        // A new begin_scan abandons an open scan.
        p.begin_scan(scan(0, 2));
        p.push(raw(0, &[Some(7)])[0], &mut |x| out.push(x));
        p.begin_scan(scan(0, 0));
        p.push(raw(0, &[Some(7)])[0], &mut |x| out.push(x));
        assert_eq!(
            p.end_scan(true, &mut |x| out.push(x)),
            ScanEnd::Complete { points: 1 }
        );
        let s = p.stats();
        assert_eq!((s.scans_complete, s.scans_incomplete), (1, 3));
        assert_eq!(s.points_discarded, 2 + 2 + 1);
    }

    #[test]
    fn skipped_scans_cost_nothing_downstream() {
        let config = PipelineConfig {
            temporal: TemporalDecimation::EveryNth(2),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        let mut n = 0;
        let mut starts = Vec::new();
        for _ in 0..4 {
            starts.push(p.begin_scan(scan(0, 2)));
            p.push_batch(&raw(0, &[Some(1); 3]), &mut |_| n += 1);
            p.end_scan(true, &mut |_| n += 1);
        }
        assert_eq!(
            starts,
            [
                ScanStart::Publish { points: 3 },
                ScanStart::Skip,
                ScanStart::Publish { points: 3 },
                ScanStart::Skip
            ]
        );
        assert_eq!(n, 6);
        let s = p.stats();
        assert_eq!((s.scans_skipped, s.points_ignored, s.points_in), (2, 6, 12));
    }

    #[test]
    fn bad_geometry_and_points_outside_a_scan_are_ignored() {
        let mut p = Pipeline::new(PipelineConfig::default()).unwrap();
        let mut n = 0;
        p.push(raw(0, &[Some(1)])[0], &mut |_| n += 1);
        assert_eq!(p.begin_scan(scan(5, 4)), ScanStart::BadGeometry);
        p.push(raw(5, &[Some(1)])[0], &mut |_| n += 1);
        assert_eq!(p.end_scan(true, &mut |_| n += 1), ScanEnd::NotPublished);
        assert_eq!(n, 0);
        assert_eq!(p.stats().points_ignored, 2);
        assert_eq!(p.stats().scans_bad_geometry, 1);
        assert!(!p.is_publishing());
    }

    #[test]
    fn new_settings_wait_for_the_next_scan() {
        let mut p = Pipeline::new(PipelineConfig::default()).unwrap();
        assert_eq!(p.begin_scan(scan(0, 3)), ScanStart::Publish { points: 4 });
        let halve = PipelineConfig {
            decimation: Some(Decimation {
                factor: 2,
                mode: DecimationMode::Min,
            }),
            ..PipelineConfig::default()
        };
        assert_eq!(
            p.set_config(PipelineConfig {
                roi: Some(StepWindow { first: 2, last: 1 }),
                ..halve
            }),
            Err(ConfigError::RoiReversed)
        );
        assert_eq!(p.set_config(halve), Ok(()));
        let mut out = Vec::new();
        p.push_batch(&raw(0, &[Some(4), Some(3), Some(2), Some(1)]), &mut |x| {
            out.push(x)
        });
        p.end_scan(true, &mut |x| out.push(x));
        assert_eq!(out.len(), 4);
        assert_eq!(p.config().decimation, None);
        assert_eq!(p.begin_scan(scan(0, 3)), ScanStart::Publish { points: 2 });
        assert_eq!(p.config(), &halve);
    }

    #[test]
    fn invalid_settings_are_refused_at_construction() {
        let bad = PipelineConfig {
            decimation: Some(Decimation {
                factor: 0,
                mode: DecimationMode::Mean,
            }),
            ..PipelineConfig::default()
        };
        assert_eq!(
            Pipeline::new(bad).map(|_| ()),
            Err(ConfigError::DecimationFactorZero)
        );
    }

    #[test]
    fn the_pipeline_is_small() {
        std::println!(
            "size_of::<Pipeline>() = {}",
            core::mem::size_of::<Pipeline>()
        );
        assert!(core::mem::size_of::<Pipeline>() <= 768);
    }

    proptest::proptest! {
        /// The direct paths when every stage is off (`push_batch`, and `pass_run` for runs
        /// of consecutive points) give the same points, the same end and the same
        /// counters as pushing the points one by one
        /// through every stage, also for points out of sequence, past the end, or with no
        /// scan open.
        #[test]
        fn passthrough_batches_match_single_pushes(
            inputs in proptest::collection::vec(
                (0u16..4, 0u32..3000, proptest::option::of(0u32..70_000), proptest::bool::ANY),
                0..60,
            ),
            cluster in 1u16..4,
            count in 1u16..40,
            decimate_by_one in proptest::bool::ANY,
            open in proptest::bool::ANY,
            sizes in proptest::collection::vec(1usize..25, 1..5),
        ) {
            let config = PipelineConfig {
                decimation: decimate_by_one.then_some(Decimation {
                    factor: 1,
                    mode: DecimationMode::Min,
                }),
                ..PipelineConfig::default()
            };
            proptest::prop_assert!(config.is_passthrough());
            let info = ScanInfo {
                seq: 0,
                timestamp_ms: 0,
                first_step: 10,
                last_step: 10 + (count - 1) * cluster,
                cluster,
            };
            // Mostly in sequence; a skip of 1..3 values now and then.
            let mut step = 10u16;
            let points: Vec<RawPoint> = inputs
                .iter()
                .map(|&(skip, distance, intensity, valid)| {
                    if skip == 3 {
                        step += cluster;
                    }
                    let p = RawPoint { step, distance, intensity, valid };
                    step += cluster;
                    p
                })
                .collect();
            // 0: one by one; 1: in batches; 2: batches of consecutive points through
            // `pass_run` (published here as the caller would), the rest pushed.
            let run = |mode: u8| {
                let mut p = Pipeline::new(config).unwrap();
                if open {
                    p.begin_scan(info);
                }
                let mut out = Vec::new();
                if mode == 0 {
                    for x in &points {
                        p.push(*x, &mut |x| out.push(x));
                    }
                } else {
                    let mut rest = &points[..];
                    let mut i = 0;
                    while !rest.is_empty() {
                        let (a, b) = rest.split_at(sizes[i % sizes.len()].min(rest.len()));
                        let consecutive = a.windows(2).all(|w| w[1].step == w[0].step + cluster);
                        if mode == 2 && consecutive && p.pass_run(a[0].step, a.len(), true).is_some() {
                            out.extend(a.iter().map(|x| Point {
                                step: x.step,
                                range_mm: x.valid.then_some(x.distance),
                                intensity: x.intensity,
                            }));
                            p.count_invalid(a.iter().filter(|x| !x.valid).count());
                        } else {
                            p.push_batch(a, &mut |x| out.push(x));
                        }
                        rest = b;
                        i += 1;
                    }
                }
                let end = p.end_scan(true, &mut |x| out.push(x));
                (out, end, *p.stats())
            };
            let one_by_one = run(0);
            proptest::prop_assert_eq!(&run(1), &one_by_one);
            proptest::prop_assert_eq!(&run(2), &one_by_one);
        }
    }
    proptest::proptest! {
        /// `decimate_run` on runs of consecutive points, with decimation the only stage,
        /// gives the points, end and counters of pushing them one by one.
        #[test]
        fn decimated_runs_match_single_pushes(
            inputs in proptest::collection::vec(
                (0u16..6, 0u32..3000, proptest::option::of(0u32..70_000), proptest::bool::ANY),
                0..80,
            ),
            cluster in 1u16..3,
            count in 1u16..60,
            factor in 1u16..6,
            mode in 0usize..3,
            sizes in proptest::collection::vec(1usize..25, 1..5),
        ) {
            let mode = [DecimationMode::First, DecimationMode::Min, DecimationMode::Mean][mode];
            let config = PipelineConfig {
                decimation: Some(Decimation { factor, mode }),
                ..PipelineConfig::default()
            };
            let info = ScanInfo {
                seq: 0,
                timestamp_ms: 0,
                first_step: 10,
                last_step: 10 + (count - 1) * cluster,
                cluster,
            };
            let mut step = 10u16;
            let points: Vec<RawPoint> = inputs
                .iter()
                .map(|&(skip, distance, intensity, valid)| {
                    if skip == 5 {
                        step += cluster;
                    }
                    let p = RawPoint { step, distance, intensity, valid };
                    step += cluster;
                    p
                })
                .collect();
            let run = |fast: bool| {
                let mut p = Pipeline::new(config).unwrap();
                p.begin_scan(info);
                let mut out = Vec::new();
                let mut rest = &points[..];
                let mut i = 0;
                while !rest.is_empty() {
                    let (a, b) = rest.split_at(sizes[i % sizes.len()].min(rest.len()));
                    let consecutive = a.windows(2).all(|w| w[1].step == w[0].step + cluster);
                    let mut buf = Vec::new();
                    let done = if fast && consecutive {
                        p.filter_run(a[0].step, a, |r| *r, |x| buf.push(x))
                    } else {
                        None
                    };
                    match done {
                        Some(k) => {
                            assert_eq!(k, buf.len());
                            out.extend_from_slice(&buf);
                        }
                        None => p.push_batch(a, &mut |x| out.push(x)),
                    }
                    rest = b;
                    i += 1;
                }
                let end = p.end_scan(true, &mut |x| out.push(x));
                (out, end, *p.stats())
            };
            proptest::prop_assert_eq!(run(true), run(false));
        }
    }

    /// What a scan should give, computed for the whole scan at once from the stage
    /// definitions (module docs, [`SpeckleFilter`], [`MedianWidth`], [`DecimationMode`]),
    /// independently of the pipeline's windows: the output points, the counters
    /// `(outside_roi, error_code, out_of_range, low_intensity, speckle, out, out_invalid)`
    /// and the `filtered` flag.
    fn reference(cfg: &PipelineConfig, points: &[RawPoint]) -> (Vec<Point>, [usize; 7], bool) {
        let mut k = [0usize; 7];
        let mut filtered = false;
        let inside: Vec<&RawPoint> = points
            .iter()
            .filter(|p| {
                cfg.roi
                    .is_none_or(|r| r.first <= p.step && p.step <= r.last)
            })
            .collect();
        k[0] = points.len() - inside.len();
        let mut v: Vec<Point> = inside
            .iter()
            .map(|p| {
                let mut range = None;
                if !p.valid {
                    k[1] += 1;
                } else if cfg
                    .range_window
                    .is_some_and(|w| p.distance < w.min_mm || p.distance > w.max_mm)
                {
                    k[2] += 1;
                    filtered = true;
                } else if let (Some(min), Some(i)) = (cfg.min_intensity, p.intensity) {
                    if i < min {
                        k[3] += 1;
                        filtered = true;
                    } else {
                        range = Some(p.distance);
                    }
                } else {
                    range = Some(p.distance);
                }
                Point {
                    step: p.step,
                    range_mm: range,
                    intensity: p.intensity,
                }
            })
            .collect();
        if let Some(f) = cfg.speckle {
            let before = v.clone();
            for (i, p) in v.iter_mut().enumerate() {
                let Some(r) = p.range_mm else { continue };
                let near = |j: Option<usize>| {
                    j.and_then(|j| before.get(j))
                        .and_then(|q| q.range_mm)
                        .is_some_and(|q| q.abs_diff(r) <= f.max_jump_mm)
                };
                if !near(i.checked_sub(1)) && !near(Some(i + 1)) {
                    p.range_mm = None;
                    k[4] += 1;
                    filtered = true;
                }
            }
        }
        if let Some(m) = cfg.median {
            let h = match m {
                MedianWidth::Three => 1,
                MedianWidth::Five => 2,
            };
            let before = v.clone();
            for (i, p) in v.iter_mut().enumerate() {
                let Some(own) = p.range_mm else { continue };
                let lo_i = i.saturating_sub(h);
                let hi_i = (i + h).min(before.len() - 1);
                let mut vals: Vec<u32> = before[lo_i..=hi_i]
                    .iter()
                    .filter_map(|q| q.range_mm)
                    .collect();
                vals.sort();
                let n = vals.len();
                let (lo, hi) = (vals[(n - 1) / 2], vals[n / 2]);
                let new = own.clamp(lo, hi);
                if new != own {
                    filtered = true;
                }
                p.range_mm = Some(new);
            }
        }
        if let Some(d) = cfg.decimation.filter(|d| d.factor > 1) {
            v = v
                .chunks(usize::from(d.factor))
                .map(|g| match d.mode {
                    DecimationMode::First => g[0],
                    DecimationMode::Min => {
                        let mut best: Option<&Point> = None;
                        for q in g.iter().filter(|q| q.range_mm.is_some()) {
                            if best.is_none_or(|b| q.range_mm < b.range_mm) {
                                best = Some(q);
                            }
                        }
                        Point {
                            step: g[0].step,
                            range_mm: best.and_then(|b| b.range_mm),
                            intensity: best.and_then(|b| b.intensity),
                        }
                    }
                    DecimationMode::Mean => {
                        let valid: Vec<&Point> =
                            g.iter().filter(|q| q.range_mm.is_some()).collect();
                        let mean = |xs: Vec<u64>| {
                            let n = xs.len() as u64;
                            (n > 0).then(|| ((xs.iter().sum::<u64>() + n / 2) / n) as u32)
                        };
                        let range = mean(
                            valid
                                .iter()
                                .map(|q| u64::from(q.range_mm.unwrap()))
                                .collect(),
                        );
                        let intensity = mean(
                            valid
                                .iter()
                                .filter_map(|q| q.intensity.map(u64::from))
                                .collect(),
                        );
                        Point {
                            step: g[0].step,
                            range_mm: range,
                            intensity: range.and(intensity),
                        }
                    }
                })
                .collect();
        }
        k[5] = v.len();
        k[6] = v.iter().filter(|p| p.range_mm.is_none()).count();
        (v, k, filtered)
    }

    /// The sensor's rule may change from one line to the next (what the classification
    /// works out of a rule is kept until it does): each line's readings classified by
    /// its own rule, written plainly here, with a range window, the windows,
    /// decimation, an intensity threshold or none of them after. Distances at every
    /// rule's edges, ranges of 0 allowed by one rule and not the next, ranges near 2^31
    /// and no range; points, counters and `filtered` as the whole-scan reference.
    #[test]
    fn filter_line_takes_each_lines_sensor_rule() {
        let rules = [
            can_wire::RangeRule {
                min: 20,
                except: [65533, u32::MAX],
                band: Some(40),
                window: [0, u32::MAX],
            },
            can_wire::RangeRule::at_least(1),
            can_wire::RangeRule::at_least(0),
            can_wire::RangeRule {
                min: 100,
                except: [500, 30001],
                band: None,
                window: [0, u32::MAX],
            },
        ];
        // The sensor's rule as filter_line's docs say (u32::MAX never a range).
        let plain = |r: &can_wire::RangeRule, d: u32| {
            d != u32::MAX
                && d >= r.min
                && d != r.except[0]
                && d != r.except[1]
                && r.band.is_none_or(|b| d < b || d > b + 2)
        };
        let edges = [
            0,
            1,
            19,
            20,
            21,
            39,
            40,
            41,
            42,
            43,
            99,
            100,
            101,
            499,
            500,
            501,
            29999,
            30000,
            30001,
            65533,
            65534,
            (1 << 31) - 1,
            1 << 31,
            u32::MAX - 1,
            u32::MAX,
        ];
        // Edges among smooth ranges, a jump now and then.
        let distances: Vec<u32> = (0..150u32)
            .map(|i| match i % 3 {
                0 => edges[(i as usize / 3) % edges.len()],
                1 => 1000 + i * 7,
                _ => 1000 + i * 7 + (i % 5) * 400,
            })
            .collect();
        let lengths = [7usize, 1, 13, 21, 5, 2, 21, 9, 30, 4, 17, 20];
        let which = [0usize, 0, 1, 2, 2, 3, 1, 0, 3, 2, 1, 0];
        let window = Some(RangeWindow {
            min_mm: 100,
            max_mm: 30000,
        });
        let configs = [
            PipelineConfig {
                range_window: window,
                speckle: Some(SpeckleFilter { max_jump_mm: 50 }),
                median: Some(MedianWidth::Three),
                ..PipelineConfig::default()
            },
            PipelineConfig {
                median: Some(MedianWidth::Five),
                min_intensity: Some(30),
                ..PipelineConfig::default()
            },
            PipelineConfig {
                speckle: Some(SpeckleFilter { max_jump_mm: 300 }),
                ..PipelineConfig::default()
            },
            PipelineConfig {
                decimation: Some(Decimation {
                    factor: 2,
                    mode: DecimationMode::Mean,
                }),
                ..PipelineConfig::default()
            },
            PipelineConfig {
                range_window: window,
                min_intensity: Some(30),
                ..PipelineConfig::default()
            },
        ];
        for config in configs {
            // Each point valid by its line's rule.
            let mut points = Vec::new();
            let mut line_of = Vec::new();
            let (mut at, mut l) = (0usize, 0usize);
            while at < distances.len() {
                let len = lengths[l % lengths.len()].min(distances.len() - at);
                let rule = &rules[which[l % which.len()]];
                for (j, &d) in distances[at..at + len].iter().enumerate() {
                    let step = (at + j) as u16;
                    points.push(RawPoint {
                        step,
                        distance: d,
                        intensity: Some(u32::from(step) * 13 % 60),
                        valid: plain(rule, d),
                    });
                }
                line_of.push((at, len, *rule));
                at += len;
                l += 1;
            }
            let (mut want, want_k, want_filtered) = reference(&config, &points);
            let mut p = Pipeline::new(config).unwrap();
            let info = scan(0, distances.len() as u16 - 1);
            assert!(matches!(p.begin_scan(info), ScanStart::Publish { .. }));
            let none = 7_777_777;
            let mut out = Vec::new();
            for (at, len, rule) in line_of {
                let input: Vec<scip::Reading> = points[at..at + len]
                    .iter()
                    .map(|r| scip::Reading {
                        distance: r.distance,
                        aux: r.intensity.unwrap_or(0),
                    })
                    .collect();
                let mut cells = std::vec![scip::Reading::default(); len + LINE_HEADROOM];
                let (k, no_range) = p
                    .filter_line(at as u16, &input, &mut cells, rule, true, none)
                    .unwrap();
                // The count of no range is that of the cells so given.
                assert_eq!(
                    no_range,
                    cells[..k].iter().filter(|c| c.distance == none).count()
                );
                out.extend(
                    cells[..k]
                        .iter()
                        .map(|c| (c.distance != none).then_some(c.distance)),
                );
            }
            let mut tail = Vec::new();
            let end = p.end_scan(true, &mut |x: Point| tail.push(x.range_mm));
            out.extend(tail);
            assert_eq!(end, ScanEnd::Complete { points: want.len() });
            let norm = |p: &mut Point| p.range_mm = p.range_mm.map(|r| r.max(1));
            want.iter_mut().for_each(norm);
            let want: Vec<Option<u32>> = want.iter().map(|p| p.range_mm).collect();
            let out: Vec<Option<u32>> = out.into_iter().map(|r| r.map(|r| r.max(1))).collect();
            assert_eq!(out, want, "{config:?}");
            assert_eq!(counters(p.stats()), want_k, "{config:?}");
            assert_eq!(p.filtered(), want_filtered, "{config:?}");
        }
    }

    /// Ranges within the speckle threshold of no range (`u32::MAX`) beside error codes
    /// and beside small ranges, where quick rules would go wrong (no range looks like
    /// support, a median's neighbour near 2^32 looks small), at a line's start, middle
    /// and end, in the scan's first line too: speckle removal alone (its loop classifies
    /// the line as it loads it), with the median of 3 (exact after a range at or above
    /// 2^31) or 5 after; with an intensity threshold (every point then through the
    /// out-of-line classification) and without. Points, counters and `filtered` as the
    /// whole-scan reference.
    #[test]
    fn ranges_near_no_range_take_the_exact_rules() {
        let big = u32::MAX - 5;
        // (Two such ranges side by side stay, and a median's centre beside them is no
        // median of its neighbours by the quick rule: the scan's first line, too.)
        let distances = [
            big,
            big - 4,
            100,
            105,
            110,
            big,
            0,
            1000,
            1010,
            0,
            big,
            0,
            990,
            1000,
            big,
            big - 2,
            2000,
            2005,
            0,
            0,
            big - 3,
            0,
            1500,
            1490,
            1480,
            0,
            big,
        ];
        let lengths = [5usize, 3, 4, 1, 6, 2];
        for median in [None, Some(MedianWidth::Three), Some(MedianWidth::Five)] {
            for min_intensity in [None, Some(4)] {
                let config = PipelineConfig {
                    speckle: Some(SpeckleFilter { max_jump_mm: 10 }),
                    median,
                    min_intensity,
                    ..PipelineConfig::default()
                };
                let points: Vec<RawPoint> = distances
                    .iter()
                    .enumerate()
                    .map(|(i, &d)| RawPoint {
                        step: i as u16,
                        distance: d,
                        intensity: Some(i as u32 % 5 + 1),
                        valid: d != 0,
                    })
                    .collect();
                let (mut want, want_k, want_filtered) = reference(&config, &points);
                let mut p = Pipeline::new(config).unwrap();
                let info = scan(0, distances.len() as u16 - 1);
                assert!(matches!(p.begin_scan(info), ScanStart::Publish { .. }));
                let none = 7_777_777;
                let (mut out, mut at, mut l) = (Vec::new(), 0usize, 0usize);
                while at < points.len() {
                    let len = lengths[l % lengths.len()].min(points.len() - at);
                    let input: Vec<scip::Reading> = points[at..at + len]
                        .iter()
                        .map(|r| scip::Reading {
                            distance: r.distance,
                            aux: r.intensity.unwrap_or(0),
                        })
                        .collect();
                    let mut cells = std::vec![scip::Reading::default(); len + LINE_HEADROOM];
                    let rule = can_wire::RangeRule::at_least(1);
                    let (k, no_range) = p
                        .filter_line(at as u16, &input, &mut cells, rule, true, none)
                        .unwrap();
                    assert_eq!(
                        no_range,
                        cells[..k].iter().filter(|c| c.distance == none).count()
                    );
                    out.extend(
                        cells[..k]
                            .iter()
                            .map(|c| (c.distance != none).then_some(c.distance)),
                    );
                    at += len;
                    l += 1;
                }
                let mut tail = Vec::new();
                p.end_scan(true, &mut |x: Point| tail.push(x.range_mm));
                out.extend(tail);
                let norm = |p: &mut Point| p.range_mm = p.range_mm.map(|r| r.max(1));
                want.iter_mut().for_each(norm);
                let want: Vec<Option<u32>> = want.iter().map(|p| p.range_mm).collect();
                assert_eq!(out, want, "{config:?}");
                assert_eq!(counters(p.stats()), want_k, "{config:?}");
                assert_eq!(p.filtered(), want_filtered, "{config:?}");
            }
        }
    }

    fn counters(s: &Stats) -> [usize; 7] {
        [
            s.points_outside_roi,
            s.invalid_error_code,
            s.invalid_out_of_range,
            s.invalid_low_intensity,
            s.invalid_speckle,
            s.points_out,
            s.points_out_invalid,
        ]
        .map(|x| x as usize)
    }

    proptest::proptest! {
        /// Any configuration: pushing points one by one, `filter_run`, `filter_line` and
        /// the direct path `pass_run` (published as the engine does, with `filter_run`
        /// where it declines) (in runs of any size, each continuing the scan) give the
        /// points, counters and `filtered` flag of the whole-scan reference above.
        /// `filter_line` gives readings: no range as the caller's value, a range of 0
        /// as 1.
        #[test]
        fn every_path_matches_the_reference(
            inputs in proptest::collection::vec(
                (0u32..2500, 0u32..100, 0u8..8),
                1..70,
            ),
            with_intensity in proptest::bool::ANY,
            cluster in 1u16..3,
            roi in proptest::option::of((0u16..80, 0u16..80)),
            window in proptest::option::of((0u32..1500, 0u32..2500)),
            min_intensity in proptest::option::of(0u32..100),
            speckle in proptest::option::of(0u32..400),
            median in 0u8..3,
            decimation in proptest::option::of((1u16..5, 0usize..3)),
            sizes in proptest::collection::vec(1usize..25, 1..5),
        ) {
            let config = PipelineConfig {
                roi: roi.map(|(a, b)| StepWindow { first: a.min(b), last: a.max(b) }),
                range_window: window.map(|(a, b)| RangeWindow { min_mm: a.min(b), max_mm: a.max(b) }),
                min_intensity,
                speckle: speckle.map(|max_jump_mm| SpeckleFilter { max_jump_mm }),
                median: [None, Some(MedianWidth::Three), Some(MedianWidth::Five)][usize::from(median)],
                decimation: decimation.map(|(factor, m)| Decimation {
                    factor,
                    mode: [DecimationMode::First, DecimationMode::Min, DecimationMode::Mean][m],
                }),
                temporal: TemporalDecimation::All,
            };
            let n = inputs.len() as u16;
            let info = ScanInfo { seq: 0, timestamp_ms: 0, first_step: 10, last_step: 10 + (n - 1) * cluster, cluster };
            // An error code one time in eight (distance 0, as the sensors send).
            let points: Vec<RawPoint> = inputs
                .iter()
                .enumerate()
                .map(|(i, &(d, i_val, e))| RawPoint {
                    step: 10 + i as u16 * cluster,
                    distance: if e == 0 { 0 } else { d + 1 },
                    intensity: with_intensity.then_some(i_val),
                    valid: e != 0,
                })
                .collect();
            let (want, want_k, want_filtered) = reference(&config, &points);
            // 0: one by one; 1: filter_run; 2: filter_line; 3: pass_run.
            for mode in 0..4 {
                let mut p = Pipeline::new(config).unwrap();
                let ScanStart::Publish { points: announced } = p.begin_scan(info) else {
                    panic!("not published");
                };
                let mut out = Vec::new();
                let mut rest = &points[..];
                let mut i = 0;
                while !rest.is_empty() {
                    let (a, b) = rest.split_at(sizes[i % sizes.len()].min(rest.len()));
                    let direct = if mode == 3 {
                        p.pass_run(a[0].step, a.len(), with_intensity)
                    } else {
                        None
                    };
                    if let Some(run) = direct {
                        // The engine's publishing: the slice, a point a range when it
                        // is one inside the window.
                        let [lo, hi] = run.window;
                        let part = &a[run.lo..run.hi];
                        let inside = |r: &RawPoint| r.valid && lo <= r.distance && r.distance <= hi;
                        out.extend(part.iter().map(|r| Point {
                            step: r.step,
                            range_mm: inside(r).then_some(r.distance),
                            intensity: r.intensity,
                        }));
                        let invalid = part.iter().filter(|r| !inside(r)).count();
                        let rejected = part.iter().filter(|r| r.valid && !inside(r)).count();
                        p.count_direct(invalid, rejected);
                        rest = b;
                        i += 1;
                        continue;
                    }
                    match mode {
                        0 => p.push_batch(a, &mut |x| out.push(x)),
                        1 | 3 => {
                            let mut buf = Vec::new();
                            let k = p.filter_run(a[0].step, a, |r| *r, |x| buf.push(x));
                            match k {
                                Some(k) => {
                                    proptest::prop_assert_eq!(k, buf.len());
                                    out.extend(buf);
                                }
                                None => {
                                    proptest::prop_assert!(config.is_passthrough());
                                    p.push_batch(a, &mut |x| out.push(x));
                                }
                            }
                        }
                        _ => {
                            let input: Vec<scip::Reading> = a
                                .iter()
                                .map(|r| scip::Reading { distance: r.distance, aux: r.intensity.unwrap_or(0) })
                                .collect();
                            let mut cells = input.clone();
                            cells.extend([scip::Reading::default(); LINE_HEADROOM]);
                            let k = p.filter_line(a[0].step, &input, &mut cells, can_wire::RangeRule::at_least(1), with_intensity, 7_777_777);
                            match k {
                                Some((k, no_range)) => {
                                    let none = 7_777_777;
                                    proptest::prop_assert_eq!(no_range, cells[..k].iter().filter(|c| c.distance == none).count());
                                    let base = out.len();
                                    out.extend(cells[..k].iter().enumerate().map(|(j, c)| Point {
                                    // The line path gives no steps: the reference's are used.
                                    step: want.get(base + j).map_or(0, |w| w.step),
                                    range_mm: (c.distance != 7_777_777).then_some(c.distance),
                                    intensity: with_intensity.then_some(c.aux),
                                }));
                                }
                                None => {
                                    proptest::prop_assert!(config.is_passthrough());
                                    p.push_batch(a, &mut |x| out.push(x));
                                }
                            }
                        }
                    }
                    rest = b;
                    i += 1;
                }
                let end = p.end_scan(true, &mut |x| out.push(x));
                proptest::prop_assert_eq!(end, ScanEnd::Complete { points: want.len() });
                proptest::prop_assert_eq!(announced, want.len());
                let mut want = want.clone();
                if mode == 2 {
                    // Readings: a range of 0 mm is given as 1, and an invalid point has
                    // no intensity to compare.
                    let norm = |p: &mut Point| {
                        p.range_mm = p.range_mm.map(|r| r.max(1));
                        p.intensity = p.range_mm.and(p.intensity);
                    };
                    want.iter_mut().for_each(norm);
                    out.iter_mut().for_each(norm);
                }
                proptest::prop_assert_eq!(&out, &want, "mode {}", mode);
                proptest::prop_assert_eq!(counters(p.stats()), want_k, "mode {}", mode);
                proptest::prop_assert_eq!(p.filtered(), want_filtered, "mode {}", mode);
            }
        }

        /// The line path mixed with the point path in one scan (a line out of order, or
        /// with several echoes, goes point by point in the engine): the windows' and
        /// the decimator's state pass between them. Ranges up to near `u32::MAX` and
        /// speckle thresholds up to it take the exact speckle loop (and means of such
        /// ranges the 64-bit sum). Points, counters and `filtered` as the whole-scan
        /// reference.
        #[test]
        fn line_and_point_paths_mixed_match_the_reference(
            inputs in proptest::collection::vec(
                (
                    proptest::prop_oneof![
                        0u32..3000,
                        ((1u32 << 31) - 3000)..((1u32 << 31) + 3000),
                        (u32::MAX - 3000)..(u32::MAX - 1),
                    ],
                    0u8..6,
                ),
                1..60,
            ),
            speckle in proptest::option::of(proptest::prop_oneof![0u32..500, (u32::MAX - 5000)..u32::MAX]),
            median in 0u8..3,
            decimation in proptest::option::of((1u16..6, 0usize..3)),
            chunks in proptest::collection::vec((1usize..25, proptest::bool::ANY), 1..6),
        ) {
            let config = PipelineConfig {
                speckle: speckle.map(|max_jump_mm| SpeckleFilter { max_jump_mm }),
                median: [None, Some(MedianWidth::Three), Some(MedianWidth::Five)][usize::from(median)],
                decimation: decimation.map(|(factor, m)| Decimation {
                    factor,
                    mode: [DecimationMode::First, DecimationMode::Min, DecimationMode::Mean][m],
                }),
                ..PipelineConfig::default()
            };
            let n = inputs.len() as u16;
            let info = ScanInfo { seq: 0, timestamp_ms: 0, first_step: 0, last_step: n - 1, cluster: 1 };
            let points: Vec<RawPoint> = inputs
                .iter()
                .enumerate()
                .map(|(i, &(d, e))| RawPoint {
                    step: i as u16,
                    distance: if e == 0 { 0 } else { d.max(1) },
                    intensity: None,
                    valid: e != 0,
                })
                .collect();
            let (mut want, want_k, want_filtered) = reference(&config, &points);
            let mut p = Pipeline::new(config).unwrap();
            let published = matches!(p.begin_scan(info), ScanStart::Publish { .. });
            proptest::prop_assert!(published);
            let mut out = Vec::new();
            let (mut rest, mut i) = (&points[..], 0);
            while !rest.is_empty() {
                let (size, by_line) = chunks[i % chunks.len()];
                let (a, b) = rest.split_at(size.min(rest.len()));
                if by_line {
                    let input: Vec<scip::Reading> = a
                        .iter()
                        .map(|r| scip::Reading { distance: r.distance, ..scip::Reading::default() })
                        .collect();
                    let mut cells = std::vec![scip::Reading::default(); a.len() + LINE_HEADROOM];
                    let none = 7_777_777;
                    let k = p.filter_line(a[0].step, &input, &mut cells, can_wire::RangeRule::at_least(1), false, none);
                    let Some((k, no_range)) = k else {
                        // Every stage off: no line path.
                        p.push_batch(a, &mut |x| out.push(x));
                        rest = b;
                        i += 1;
                        continue;
                    };
                    proptest::prop_assert_eq!(no_range, cells[..k].iter().filter(|c| c.distance == none).count());
                    let base = out.len();
                    out.extend(cells[..k].iter().enumerate().map(|(j, c)| Point {
                        step: want.get(base + j).map_or(0, |w| w.step),
                        range_mm: (c.distance != none).then_some(c.distance),
                        intensity: None,
                    }));
                } else {
                    p.push_batch(a, &mut |x| out.push(x));
                }
                rest = b;
                i += 1;
            }
            let end = p.end_scan(true, &mut |x| out.push(x));
            proptest::prop_assert_eq!(end, ScanEnd::Complete { points: want.len() });
            let norm = |p: &mut Point| p.range_mm = p.range_mm.map(|r| r.max(1));
            want.iter_mut().for_each(norm);
            out.iter_mut().for_each(norm);
            proptest::prop_assert_eq!(&out, &want);
            proptest::prop_assert_eq!(counters(p.stats()), want_k);
            proptest::prop_assert_eq!(p.filtered(), want_filtered);
        }
    }
}
