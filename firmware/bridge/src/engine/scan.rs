//! The scan lifecycle: a scan begun at its timestamp (admission, header, geometry and the
//! first point's offsets), finished with its trailer, or ended with an abort frame.

use can_wire::{AbortReason, Encoding, Grouping, ScanHeader, TrailerFlags};
use scip::ScanRequest;

use super::output::push;
use super::{Core, Phase};
use crate::link::LinkKind;
use crate::pipeline::{DecimationMode, Point, ScanInfo, ScanStart};

impl<const Q: usize> Core<Q> {
    /// A scan's timestamp line: the scan begins (or is skipped, dropped or lost). Never
    /// inlined, like [`Core::finish_scan`] and [`Core::abort_scan`]: once a scan, and
    /// inlined into the loop over a UART chunk they made it keep more state across
    /// each chunk.
    #[inline(never)]
    pub(super) fn begin_scan(&mut self, s: ScanRequest, raw_timestamp: u32, now: u64) {
        self.stats.scans_in = self.stats.scans_in.wrapping_add(1);
        self.phase = Phase::Ignored;
        // SPEC 3.1: the sensor's 24-bit clock extended (modulo 2^32), or with a time
        // sync the caller's clock.
        let sensor_ms = self.clock.unwrap(raw_timestamp);
        let estimate = if self.estimating() {
            self.scan_clock.on_scan(sensor_ms, self.event_us())
        } else {
            crate::clock::Estimate {
                time_us: 0,
                valid: false,
            }
        };
        let (mut timestamp, time_synced) = match self.sync_offset {
            Some(offset) => ((sensor_ms as i64).wrapping_add(offset) as u32, true),
            None => (sensor_ms as u32, false),
        };
        let time_estimated = self.estimating() && estimate.valid;
        let mut time_master = false;
        if time_estimated {
            // SPEC 3.1: the first point's time, µs modulo 2^32, in the time master's
            // clock while a time sync holds (SPEC 9), else in the bridge's.
            let first_us = estimate
                .time_us
                .wrapping_add(self.first_point_offset_us(&s));
            let master = self.time_sync.to_master(first_us);
            time_master = master.is_some();
            timestamp = master.unwrap_or(first_us) as u32;
        }
        let time_synced = time_synced || time_estimated;
        if !self.session.geometry().allows_scans() {
            // The last PP answer was damaged or doubted: no angles to publish it with.
            self.lose_scan();
            return;
        }
        let info = ScanInfo {
            seq: u32::from(self.seq),
            timestamp_ms: sensor_ms as u32,
            first_step: s.start,
            last_step: s.end,
            cluster: u16::from(s.cluster),
        };
        let points = match self.pipeline.begin_scan(info) {
            ScanStart::Publish { points } => points,
            ScanStart::Skip => {
                self.stats.scans_skipped = self.stats.scans_skipped.wrapping_add(1);
                return;
            }
            ScanStart::BadGeometry => return,
        };
        let Ok(point_count) = u16::try_from(points) else {
            self.pipeline_discard();
            return;
        };
        let encoding = self.wire_encoding(&s);
        let cost = self.governor.cost(point_count, &encoding);
        // 10 bits per UART byte; a step is `width` chars, lines add 2 bytes per 64 chars.
        // Widths are at most 3 + 4 chars and `value_count` a u16: `bytes` is below 2^23,
        // `bytes × 10^7` below 2^47, no overflow.
        let width = u64::from(s.data.distance_width().wrapping_add(s.data.aux_width()));
        let chars = u64::from(s.value_count()).wrapping_mul(width);
        let bytes = chars
            .wrapping_add(chars.div_ceil(64).wrapping_mul(2))
            .wrapping_add(40);
        let uart_us = match self.config.link {
            // A TCP stream brings a scan at once: no frame leaves while it arrives.
            LinkKind::Tcp => 0,
            LinkKind::Uart => bytes,
        }
        .wrapping_mul(10 * 1_000_000)
        .checked_div(u64::from(self.config.uart_bit_rate.max(1)))
        .unwrap_or(0);
        let free = Q.saturating_sub(self.queue.len());
        if !self.governor.admit(now, &cost, uart_us, free) {
            self.stats.scans_dropped = self.stats.scans_dropped.wrapping_add(1);
            self.pipeline_discard();
            return;
        }
        self.admitted = Some(cost);
        let header = ScanHeader {
            seq: self.seq,
            timestamp_ms: timestamp,
            point_count,
            encoding,
            time_synced,
            time_estimated,
            time_master,
            grouping: self.grouping(&s),
            step_increment: u8::try_from(self.step_increment(&s)).unwrap_or(u8::MAX),
            first_step: self.first_output_step(&s),
            ares: self.geometry().map_or(0, |(ares, _)| ares),
        };
        if let Some(format) = self.pending_format.take() {
            // Between scans: cannot fail for a validated format.
            let _ = self.encoder.set_format(format);
        }
        // Matched in place: the frames are copied once, into their queue slots.
        match &self.encoder.begin(&header) {
            Ok(frames) => {
                for f in frames {
                    push(&mut self.queue, f, &mut self.stats);
                }
                self.seq = self.seq.wrapping_add(1);
                self.overflow = false;
                self.filtered = false;
                self.phase = Phase::Active(s);
            }
            Err(_) => self.pipeline_discard(),
        }
    }

    /// The configured encoding, without an intensity channel when the scan has none.
    pub(super) fn wire_encoding(&self, s: &ScanRequest) -> Encoding {
        let mut e = self.config.encoding;
        if s.data.aux_width() == 0 {
            e.intensity = can_wire::IntensityEncoding::None;
        }
        e
    }

    pub(super) fn step_increment(&self, s: &ScanRequest) -> u32 {
        let factor = self
            .pipeline
            .config()
            .decimation
            .map_or(1, |d| u32::from(d.factor));
        // u8 × u16: no overflow.
        u32::from(s.cluster.max(1)).wrapping_mul(factor)
    }

    pub(super) fn grouping(&self, s: &ScanRequest) -> Grouping {
        match self.pipeline.config().decimation.map(|d| d.mode) {
            Some(DecimationMode::Mean) => Grouping::Mean,
            Some(DecimationMode::Min) => Grouping::Min,
            _ if s.cluster > 1 => Grouping::Min,
            _ => Grouping::Single,
        }
    }

    /// The sensor's geometry, `(ARES, AFRT)`, when a PP answer (or
    /// [`Bridge::assume_sensor`]) gave both; `None`: unknown (SPEC 3.2, `ares` = 0).
    ///
    /// [`Bridge::assume_sensor`]: super::Bridge::assume_sensor
    pub(super) fn geometry(&self) -> Option<(u16, u32)> {
        let params = self.session.params();
        let ares = params.ares.or(self.assumed.0);
        let afrt = params.afrt.or(self.assumed.1);
        let ares = ares
            .and_then(|a| u16::try_from(a).ok())
            .filter(|&a| a > 0)?;
        Some((ares, afrt?))
    }

    /// How long after the sensor's stamp (step 0 of its revolution) the first output
    /// point was measured, µs: its step × the scan period / ARES (0 without geometry
    /// or scan speed).
    pub(super) fn first_point_offset_us(&self, s: &ScanRequest) -> u64 {
        let Some((ares, afrt)) = self.geometry() else {
            return 0;
        };
        let Some(rpm) = self.session.params().scan_rpm.filter(|&r| r > 0) else {
            return 0;
        };
        // The first point's sensor step: its step relative to AFRT, plus AFRT.
        let step = i64::from(self.first_output_step(s)).saturating_add(i64::from(afrt));
        let step = u64::try_from(step).unwrap_or(0);
        // step < 2^16, 60·10^6 < 2^26: the product fits easily.
        step.saturating_mul(60_000_000)
            .checked_div(u64::from(rpm).saturating_mul(u64::from(ares)))
            .unwrap_or(0)
    }

    /// Step of the first output point, relative to the sensor's front step (AFRT); with
    /// the geometry unknown, the sensor step itself (SPEC 3.2).
    pub(super) fn first_output_step(&self, s: &ScanRequest) -> i16 {
        let cluster = u32::from(s.cluster.max(1));
        let mut first = u32::from(s.start);
        if let Some(roi) = self.pipeline.config().roi {
            let lo = u32::from(roi.first);
            if lo > first {
                // `lo > first`, both u16, cluster a u8: no overflow.
                first = first.wrapping_add(
                    lo.wrapping_sub(first)
                        .div_ceil(cluster)
                        .wrapping_mul(cluster),
                );
            }
        }
        let afrt = self.geometry().map_or(0, |(_, afrt)| afrt);
        // Two u32 values: the difference fits an i64.
        let rel = i64::from(first).wrapping_sub(i64::from(afrt));
        i16::try_from(rel).unwrap_or(i16::MIN)
    }

    #[inline(never)]
    pub(super) fn finish_scan(&mut self) {
        let (pipeline, _, mut out) = self.split();
        let _ = pipeline.end_scan(true, &mut |p: Point| out.emit(p));
        self.phase = Phase::None;
        if self.overflow {
            self.abort_scan_now(AbortReason::QueueOverflow);
            return;
        }
        let flags = TrailerFlags {
            truncated: false,
            sensor_error: false,
            filtered: self.filtered || self.pipeline.filtered(),
        };
        self.settle_lossless();
        match &self.encoder.finish(flags) {
            Ok(frames) => {
                for f in frames {
                    push(&mut self.queue, f, &mut self.stats);
                }
                self.stats.scans_sent = self.stats.scans_sent.wrapping_add(1);
            }
            Err(_) => self.abort_scan_now(AbortReason::BadData),
        }
    }

    /// A lossless scan about to be finished: the governor learns what it really cost,
    /// is charged what it took beyond its admission, and re-plans when its estimate
    /// moved.
    pub(super) fn settle_lossless(&mut self) {
        let (Some((points, bytes)), Some(admitted)) =
            (self.encoder.lossless_progress(), self.admitted.take())
        else {
            return;
        };
        let budget = *self.governor.budget();
        let encoding = self.config.encoding;
        // A u32 × 128 fits 64 bits.
        let bits_x16 = u32::try_from(
            u64::from(bytes)
                .wrapping_mul(128)
                .checked_div(u64::from(points.max(1)))
                .unwrap_or(0),
        )
        .unwrap_or(u32::MAX);
        let actual = can_wire::bandwidth::lossless_cost(
            points,
            &encoding,
            Some(bits_x16),
            budget.format,
            budget.extended,
            budget.rates,
        );
        self.governor.observe(points, bytes);
        self.governor.settle(&admitted, &actual);
        if self.auto_decimation && self.governor.replan_due(&encoding) {
            self.apply_plan();
        }
    }

    /// Ends the scan in progress, if any, with an abort frame.
    #[inline(never)]
    pub(super) fn abort_scan(&mut self, reason: AbortReason) {
        if matches!(self.phase, Phase::Active(_)) {
            self.pipeline_discard();
            self.abort_scan_now(reason);
        }
        self.phase = Phase::None;
    }

    pub(super) fn abort_scan_now(&mut self, reason: AbortReason) {
        if let Ok(f) = self.encoder.abort(reason, 0) {
            push(&mut self.queue, &f, &mut self.stats);
            self.stats.scans_aborted = self.stats.scans_aborted.wrapping_add(1);
        }
        self.phase = Phase::None;
    }

    /// Ends the pipeline's scan without publishing what its windows still hold.
    pub(super) fn pipeline_discard(&mut self) {
        let _ = self.pipeline.end_scan(false, &mut |_p: Point| {});
    }
}
