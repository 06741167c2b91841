//! The on-chip scan pipeline: filters and decimates a scan point by point, as its lines
//! arrive.
//!
//! A scan goes through [`Pipeline::begin_scan`], any number of [`Pipeline::push`] (or
//! [`Pipeline::push_batch`], e.g. one SCIP data line of about 21 points at a time), and
//! [`Pipeline::end_scan`]. Output points go to a caller-supplied [`PointSink`] the moment
//! they are determined, so RAM holds only the few points the windows need, never a scan.
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
//! The pipeline is a fixed-size value (a few hundred bytes; no heap). Each `push` does
//! constant work: a few comparisons, a shift of at most 4 points in each window, a sort of
//! at most 5 ranges, and at most one call to the sink. `end_scan` makes at most 4 sink
//! calls. An intact scan gives exactly [`output_len`] points, announced by `begin_scan`;
//! any scan gives at most that many.

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
mod stats;
mod temporal;
mod window;

pub use config::{
    output_len, ConfigError, Decimation, DecimationMode, MedianWidth, PipelineConfig, RangeWindow,
    SpeckleFilter, StepWindow, TemporalDecimation,
};
pub use point::{Point, PointSink, RawPoint, ScanEnd, ScanInfo, ScanStart};
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
        if let Some(config) = self.next_config.take() {
            self.config = config;
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
        let p = self.classify(point);
        self.feed_speckle(p, sink);
    }

    /// Feeds several consecutive points (e.g. one data line's worth); the same as pushing
    /// them one by one.
    pub fn push_batch<S: PointSink + ?Sized>(&mut self, points: &[RawPoint], sink: &mut S) {
        for p in points {
            self.push(*p, sink);
        }
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
        if let Some(f) = self.config.speckle {
            while let Some(v) = self
                .speckle
                .pop_tail()
                .map(|w| window::speckle(&w, f.max_jump_mm))
            {
                let p = self.count_verdict(v);
                self.feed_median(p, sink);
            }
        }
        while let Some(p) = self.median.pop_tail().map(|w| window::median(&w)) {
            self.feed_decimator(p, sink);
        }
        if let Some(p) = self.decimator.flush() {
            self.emit(p, sink);
        }
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

    fn reset_scan(&mut self) {
        self.open = Open::Idle;
        self.speckle.clear();
        self.median.clear();
        self.decimator.clear();
    }

    /// Error codes, range window and intensity threshold.
    fn classify(&mut self, raw: RawPoint) -> Point {
        let invalid = Point {
            step: raw.step,
            range_mm: None,
            intensity: raw.intensity,
        };
        if !raw.valid {
            bump(&mut self.stats.invalid_error_code);
            return invalid;
        }
        if let Some(w) = self.config.range_window {
            if !w.contains(raw.distance) {
                bump(&mut self.stats.invalid_out_of_range);
                return invalid;
            }
        }
        if let (Some(min), Some(i)) = (self.config.min_intensity, raw.intensity) {
            if i < min {
                bump(&mut self.stats.invalid_low_intensity);
                return invalid;
            }
        }
        Point {
            range_mm: Some(raw.distance),
            ..invalid
        }
    }

    fn count_verdict(&mut self, v: Verdict) -> Point {
        match v {
            Verdict::Keep(p) => p,
            Verdict::Invalidated(p) => {
                bump(&mut self.stats.invalid_speckle);
                p
            }
        }
    }

    fn feed_speckle<S: PointSink + ?Sized>(&mut self, p: Point, sink: &mut S) {
        let Some(f) = self.config.speckle else {
            return self.feed_median(p, sink);
        };
        if let Some(v) = self
            .speckle
            .push(p)
            .map(|w| window::speckle(&w, f.max_jump_mm))
        {
            let p = self.count_verdict(v);
            self.feed_median(p, sink);
        }
    }

    fn feed_median<S: PointSink + ?Sized>(&mut self, p: Point, sink: &mut S) {
        if self.config.median.is_none() {
            return self.feed_decimator(p, sink);
        }
        if let Some(m) = self.median.push(p).map(|w| window::median(&w)) {
            self.feed_decimator(m, sink);
        }
    }

    fn feed_decimator<S: PointSink + ?Sized>(&mut self, p: Point, sink: &mut S) {
        if let Some(d) = self.decimator.push(p) {
            self.emit(d, sink);
        }
    }

    fn emit<S: PointSink + ?Sized>(&mut self, p: Point, sink: &mut S) {
        bump(&mut self.stats.points_out);
        if !p.is_valid() {
            bump(&mut self.stats.points_out_invalid);
        }
        if let Open::Active(scan) = &mut self.open {
            scan.emitted = scan.emitted.saturating_add(1);
        }
        sink.point(p);
    }
}
