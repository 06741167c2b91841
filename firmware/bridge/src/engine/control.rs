//! Frames received from the bus: control frames (parsed, planned, applied and answered,
//! SPEC 6), the governor's decimation plan they may hand back to, and the time frames
//! of a time master (SPEC 9).

use can_wire::{AbortReason, Frame};

use super::{BridgeStats, Core};
use crate::governor::Governor;
use crate::pipeline::{Decimation, DecimationMode, ScanInfo, TemporalDecimation};

impl<const Q: usize> Core<Q> {
    pub(super) fn control(&mut self, data: &[u8], now: u64) {
        let answer = match can_wire::Control::parse(data) {
            Err(e) => can_wire::Answer::reject(data, &e),
            Ok(control) => {
                match crate::control::plan(&control, &self.config.pipeline, self.config.fd_capable)
                {
                    Err((outcome, detail)) => crate::control::rejection(&control, outcome, detail),
                    Ok(apply) => {
                        self.apply(apply, now);
                        can_wire::Answer::accept(&control)
                    }
                }
            }
        };
        let id = self.config.ids.id(can_wire::Kind::ControlAnswer);
        if let Ok(frame) = Frame::new(id, &answer.emit(), self.encoder.format().is_fd()) {
            self.push_priority(frame);
        }
    }

    pub(super) fn apply(&mut self, apply: crate::control::Apply, now: u64) {
        use crate::control::Apply;
        match apply {
            Apply::Start => self.start_session(now),
            Apply::Stop => {
                self.abort_scan(AbortReason::Stopped);
                self.session.stop(now);
            }
            Apply::SensorInfo => {
                let pages = crate::status::info_pages(self.session.params(), self.model);
                for page in pages.into_iter().rev() {
                    self.push_status(page);
                }
            }
            Apply::ResetCounters => {
                self.stats = BridgeStats::default();
                let boot = self.health.boot_ms;
                let state = self.health.bus_state;
                self.health = crate::status::Health::new();
                self.health.boot_ms = boot;
                self.health.bus_state = state;
            }
            Apply::Pipeline(cfg) => {
                if cfg.decimation != self.config.pipeline.decimation
                    || cfg.temporal != self.config.pipeline.temporal
                {
                    // The user takes the decimation over from the governor.
                    self.auto_decimation = false;
                }
                // Validated by `plan`; takes effect when the next scan begins.
                let _ = self.pipeline.set_config(cfg);
                self.config.pipeline = cfg;
            }
            Apply::Encoding(e) => self.config.encoding = e,
            Apply::Format(f) => {
                self.pending_format = Some(f);
                self.config.budget.format = f;
                self.governor = Governor::new(self.config.budget);
            }
        }
    }

    /// Lets the governor choose decimation for the stream the session runs.
    pub(super) fn apply_plan(&mut self) {
        let scan = self.session.scan_request();
        let Some(rpm) = self.session.params().scan_rpm.filter(|&r| r > 0) else {
            return;
        };
        let info = ScanInfo {
            seq: 0,
            timestamp_ms: 0,
            first_step: scan.start,
            last_step: scan.end,
            cluster: u16::from(scan.cluster),
        };
        let mut cfg = self.config.pipeline;
        cfg.decimation = None;
        cfg.temporal = TemporalDecimation::All;
        let points = u16::try_from(crate::pipeline::output_len(&cfg, &info)).unwrap_or(u16::MAX);
        // Scans per second × 1000: rpm / 60 per second, one in (skip + 1) sent.
        // The rpm comes from the sensor: saturating. `skip + 1` is 1..=256.
        let rate_milli = (rpm.saturating_mul(1000) / 60)
            .checked_div(u32::from(scan.skip).wrapping_add(1))
            .unwrap_or(0);
        let plan = self
            .governor
            .plan(points, &self.wire_encoding(&scan), rate_milli);
        cfg.decimation = (plan.factor > 1).then_some(Decimation {
            factor: u16::from(plan.factor),
            mode: DecimationMode::Min,
        });
        if plan.every_nth > 1 {
            cfg.temporal = TemporalDecimation::EveryNth(u16::from(plan.every_nth));
        }
        if self.pipeline.set_config(cfg).is_ok() {
            self.config.pipeline = cfg;
            self.plan = Some(plan);
        }
    }

    /// A frame on the time identifier (SPEC 9): taken by the time sync, and page 7 sent
    /// after a FOLLOW-UP. Returns whether it was one (malformed ones are counted).
    #[inline(never)]
    pub(super) fn time_frame(&mut self, frame: &Frame, now_us: u64) -> bool {
        if self.time_id != Some(frame.id()) {
            return false;
        }
        match can_wire::TimeFrame::parse(frame.data()) {
            Ok(can_wire::TimeFrame::Sync { seq }) => self.time_sync.on_sync(seq, now_us),
            Ok(can_wire::TimeFrame::FollowUp { seq, master_us }) => {
                self.time_sync.on_follow_up(seq, master_us);
                let master = self.time_sync.to_master(now_us);
                self.push_status(can_wire::Status::TimeSync {
                    synced: master.is_some(),
                    error_us: u16::try_from(self.time_sync.mean_error_us()).unwrap_or(u16::MAX),
                    // Modulo 2^32 (SPEC 5, page 7).
                    master_time: master.map_or(0, |m| m as u32),
                });
            }
            Err(_) => self.time_sync.on_malformed(),
        }
        true
    }
}
