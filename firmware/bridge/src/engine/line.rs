//! Data lines: a line's readings through the pipeline into the encoder, in one run where
//! it can (every stage off, or every stage in one loop), point by point otherwise.

use scip::{DataLine, ScanRequest};

use super::Core;
use crate::pipeline::{Point, RawPoint};

impl<const Q: usize> Core<Q> {
    /// One data line of the scan being published. With every pipeline stage off, the
    /// line's readings go straight to the encoder in one run (the pipeline only counts
    /// them); otherwise they go through every stage in one loop
    /// ([`Pipeline::filter_run`]) and the line's output points into the encoder in one
    /// run. Only multi-echo lines and lines out of sequence go point by point.
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
                let readings = line.readings.get(run.lo..run.hi).unwrap_or_default();
                let rule = can_wire::RangeRule {
                    window: run.window,
                    ..sensor
                };
                self.publish_run(readings, rule);
                return;
            }
            // Any other stages: the line's readings, a range or none each, through the
            // stages in place, then the output points into the encoder in one run, as
            // readings so that the encoder runs the same code as for a line's readings.
            // A point without a range: 0 for the fixed-width encodings (invalid to the
            // rule "at least 1"), a value no sensor sends for the lossless coding (coded
            // invalid, not as the sensor's error code 0).
            let lossless = self.encoder.lossless_progress().is_some();
            let (none, rule) = if lossless {
                let no_value = can_wire::lossless::code::NO_SENSOR_VALUE;
                let rule = can_wire::RangeRule {
                    band: Some(no_value),
                    ..can_wire::RangeRule::at_least(1)
                };
                (no_value, rule)
            } else {
                (0, can_wire::RangeRule::at_least(1))
            };
            let (pipeline, cells, mut out) = self.split();
            let k = pipeline.filter_line(first, line.readings, cells, sensor, has_aux, none);
            if let Some((k, no_range)) = k {
                if !*out.overflow {
                    let points = cells.get(..k).unwrap_or_default();
                    // As checked points (0 no range, any other value a range, as the
                    // fixed-width encodings' rule says: no coding test per point; the
                    // lossless coding takes them by its rule). At most the line's
                    // points: no truncation.
                    out.encode_run(points, rule, Some(no_range as u32));
                }
                return;
            }
        }
        let points = line.indexed().filter(|r| r.echo == 0).map(raw);
        let (pipeline, _, mut out) = self.split();
        pipeline.push_iter(points, &mut |p: Point| out.emit(p));
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
