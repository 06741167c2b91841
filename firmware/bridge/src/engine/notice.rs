//! The session's start and its notices: the sensor clock's TM readings (time sync and
//! the clock model), recoveries (the scan in progress aborted), and when an event's last
//! byte arrived.

use can_wire::AbortReason;

use super::Core;
use crate::session::{Notice, RecoverReason};

impl<const Q: usize> Core<Q> {
    pub(super) fn start_session(&mut self, now: u64) {
        self.model = None;
        self.clock.reset();
        self.sync_offset = None;
        self.sync_asked = false;
        self.scan_clock.reset();
        if self.link_up {
            self.session.start(now);
            if self.estimating() {
                self.session.request_time_sync(now);
            }
        } else {
            // Nothing to send to yet: held until the link is up.
            self.session.start_link_down();
        }
    }

    pub(super) fn notice(&mut self, notice: Notice) {
        if notice == Notice::Streaming && self.auto_decimation {
            self.apply_plan();
        }
        if let Notice::TimeSync { sensor_ms, now_ms } = notice {
            // The TM reading is one more reading of the sensor's clock, in order with the
            // scans' timestamps: extended the same way.
            let sensor = self.clock.unwrap(sensor_ms);
            // The sensor read its clock before sending the answer: echo `TM1`, status
            // and the timestamp line are 14 bytes ahead of the time this line ended.
            let byte_ns = 10_000_000_000u64
                .checked_div(u64::from(self.config.uart_bit_rate))
                .unwrap_or(0);
            let read_by = self
                .event_us()
                .saturating_sub(byte_ns.saturating_mul(14) / 1000);
            self.scan_clock
                .on_tm(sensor, self.sent_us.min(read_by), read_by);
            if self.sync_asked {
                self.sync_offset = i64::try_from(now_ms)
                    .ok()
                    .zip(i64::try_from(sensor).ok())
                    .map(|(now, sensor)| now.wrapping_sub(sensor));
            }
        }
        if matches!(notice, Notice::Recovering(_)) {
            // The sensor rebooted, or the recovery's `RS` resets its clock to 0: the
            // extension and the sync are void.
            self.clock.reset();
            self.sync_offset = None;
            self.scan_clock.sensor_restarted();
        }
        if let Notice::Recovering(reason) = notice {
            self.abort_scan(match reason {
                RecoverReason::Reboot => AbortReason::SensorRestart,
                RecoverReason::Silence | RecoverReason::Timeout => AbortReason::Timeout,
                _ => AbortReason::SensorError,
            });
        }
        self.notice = Some(notice);
    }

    /// When the byte that ended the current event arrived, caller's µs: the chunk's
    /// end less the bytes after it at the UART's bit rate.
    pub(super) fn event_us(&self) -> u64 {
        let byte_ns = 10_000_000_000u64
            .checked_div(u64::from(self.config.uart_bit_rate))
            .unwrap_or(0);
        let after = u64::try_from(self.bytes_after).unwrap_or(u64::MAX);
        self.chunk_end_us
            .saturating_sub(after.saturating_mul(byte_ns) / 1000)
    }

    /// Whether the sensor clock model runs: asked for, and built in (a constant false
    /// without the `time-estimate` feature, so that none of its code is linked).
    pub(super) fn estimating(&self) -> bool {
        cfg!(feature = "time-estimate") && self.estimate_time
    }
}
