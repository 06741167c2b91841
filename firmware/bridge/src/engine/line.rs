//! Data lines: a line's readings through the pipeline into the encoder, in one run where
//! it can (every stage off, or every stage in one loop: the filtered lines that end in
//! one UART chunk go into the encoder as one run), point by point otherwise.

use scip::{DataLine, ScanRequest};

use super::{Core, BATCH_CELLS};
use crate::pipeline::{Point, RawPoint};

impl<const Q: usize> Core<Q> {
    /// One data event of the scan being published: a data line, or a run of them
    /// ([`scip::Decoder::feed_runs`]). With every pipeline stage off, the
    /// line's readings go straight to the encoder in one run (the pipeline only counts
    /// them); otherwise they go through every stage in one loop
    /// ([`Pipeline::filter_run`]) and the line's output points onto the batch of the
    /// chunk's filtered lines, which goes into the encoder as one run
    /// ([`Core::flush_batch`]: the encoder's set-up once per chunk, not per line). Only
    /// multi-echo lines and lines out of sequence go point by point.
    ///
    /// [`Pipeline::filter_run`]: crate::pipeline::Pipeline::filter_run
    pub(super) fn data_line(&mut self, line: &DataLine<'_>, s: &ScanRequest) {
        let cluster = u32::from(s.cluster.max(1));
        let start = u32::from(s.start);
        let has_aux = line.data.aux_width() > 0;
        let width = line.data.distance_width();
        let step = move |index: u16| {
            // u16 + u16 × u8: below 2^25, no overflow.
            let step = start.wrapping_add(u32::from(index).wrapping_mul(cluster));
            u16::try_from(step).unwrap_or(u16::MAX)
        };
        // Without multi-echo every reading is a first echo, the next step of the scan.
        let first = (!line.readings.is_empty()).then(|| step(line.first));
        let test = line.limits.range_test(width);
        // The sensor's rule for its ranges: the same for each of the line's paths.
        let sensor = can_wire::RangeRule {
            min: test.min(),
            except: [test.exception(), u32::MAX],
            band: test.band(),
            window: [0, u32::MAX],
        };
        let raw = move |r: scip::IndexedReading| RawPoint {
            step: step(r.index),
            distance: r.distance,
            intensity: has_aux.then_some(r.aux),
            valid: test.is_range(r.distance),
        };
        if let Some(first) = first.filter(|_| !s.multi_echo) {
            if let Some(run) = self.pipeline.pass_run(first, line.readings.len(), has_aux) {
                self.flush_batch();
                let readings = line.readings.get(run.lo..run.hi).unwrap_or_default();
                let rule = can_wire::RangeRule {
                    window: run.window,
                    ..sensor
                };
                self.publish_run(readings, rule);
                return;
            }
            // Any other stages: the line's readings, a range or none each, through the
            // stages in place, and the output points, as readings so that the encoder
            // runs the same code as for a line's readings, onto the batch that goes into
            // the encoder as one run ([`Core::flush_batch`]).
            let (none, _) = self.checked_coding();
            // The line's cells after the batch's points (the batch goes first when they
            // would not hold the line and the windows' headroom).
            let room = line
                .readings
                .len()
                .wrapping_add(crate::pipeline::LINE_HEADROOM);
            if self.batch.0.saturating_add(room) > BATCH_CELLS {
                self.flush_batch();
            }
            let at = self.batch.0;
            let (pipeline, cells, _) = self.split();
            let cells = cells.get_mut(at..).unwrap_or_default();
            let k = pipeline.filter_line(first, line.readings, cells, sensor, has_aux, none);
            if let Some((k, no_range)) = k {
                // At most the cells: no wrap.
                self.batch = (at.wrapping_add(k), self.batch.1.wrapping_add(no_range));
                return;
            }
        }
        // Point by point, after the batch.
        self.flush_batch();
        let points = line.indexed().filter(|r| r.echo == 0).map(raw);
        let (pipeline, _, mut out) = self.split();
        pipeline.push_iter(points, &mut |p: Point| out.emit(p));
    }

    /// How the encoder takes filtered points: the value of a point without a range, and
    /// the rule of their run. 0 and "at least 1" for the fixed-width encodings (0
    /// invalid, any other value a range); for the lossless coding a value no sensor
    /// sends (coded invalid, not as the sensor's error code 0), excluded by the rule.
    fn checked_coding(&self) -> (u32, can_wire::RangeRule) {
        let rule = can_wire::RangeRule::at_least(1);
        if self.encoder.lossless_progress().is_some() {
            let none = can_wire::lossless::code::NO_SENSOR_VALUE;
            let rule = can_wire::RangeRule {
                band: Some(none),
                ..rule
            };
            (none, rule)
        } else {
            (0, rule)
        }
    }

    /// The filtered lines' output points waiting at the front of the output buffer into
    /// the encoder, as one run of checked points (0 or the lossless coding's no-value
    /// for no range, any other value a range: no coding test per point for the
    /// fixed-width encodings, the lossless coding takes them by its rule). Called before
    /// anything else reaches the encoder and at the end of each `on_uart` chunk, so
    /// that the frames and their order are those of a run per line.
    #[inline(always)]
    pub(super) fn flush_batch(&mut self) {
        if self.batch.0 != 0 {
            self.encode_batch();
        }
    }

    /// [`Core::flush_batch`] of a batch of points.
    #[inline(never)]
    fn encode_batch(&mut self) {
        let (n, no_range) = core::mem::take(&mut self.batch);
        let (_, rule) = self.checked_coding();
        let (_, cells, mut out) = self.split();
        if !*out.overflow {
            let points = cells.get(..n).unwrap_or_default();
            // At most the buffer's cells: no truncation.
            out.encode_run(points, rule, Some(no_range as u32));
        }
    }

    /// The `readings` of a line that [`Pipeline::pass_run`] accepted (the region of
    /// interest's slice) straight into the encoder: what [`Output::emit`] does for each
    /// of them, in one loop; the range window is part of the encoder's range `rule` (no
    /// work per point).
    ///
    /// [`Pipeline::pass_run`]: crate::pipeline::Pipeline::pass_run
    /// [`Output::emit`]: super::output::Output::emit
    pub(super) fn publish_run(&mut self, readings: &[scip::Reading], rule: can_wire::RangeRule) {
        if self.overflow {
            let (invalid, rejected) = count_no_range(&rule, readings);
            self.pipeline.count_direct(invalid, rejected);
            return;
        }
        let (taken, mut invalid, mut rejected) = self.split().2.encode_run(readings, rule, None);
        // Points the encoder did not take (it stopped early) are counted too, as the
        // pipeline emitted them.
        let rest = readings.get(taken..).unwrap_or(&[]);
        if !rest.is_empty() {
            let (i, r) = count_no_range(&rule, rest);
            // All at most the line's reading count.
            invalid = invalid.wrapping_add(i);
            rejected = rejected.wrapping_add(r);
        }
        self.pipeline.count_direct(invalid, rejected);
    }
}

/// The readings that `rule` finds no range, and those of them that are ranges its
/// window rejects (the points a run did not code).
#[cold]
#[inline(never)]
fn count_no_range(rule: &can_wire::RangeRule, readings: &[scip::Reading]) -> (usize, usize) {
    let (mut invalid, mut rejected) = (0usize, 0usize);
    let [lo, hi] = rule.window;
    for r in readings {
        let d = r.distance;
        // A range is a sensor's range inside the window.
        let sensor = rule.is_sensor_range(d);
        let outside = d < lo || d > hi;
        // At most the readings' count.
        invalid = invalid.wrapping_add(usize::from(!sensor || outside));
        rejected = rejected.wrapping_add(usize::from(sensor && outside));
    }
    (invalid, rejected)
}
