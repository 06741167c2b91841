//! Status frames (SPEC 5): the periodic heartbeat, sensor and bus pages, and any status
//! page queued ahead of the scan's frames.

use can_wire::Frame;

use super::Core;

impl<const Q: usize> Core<Q> {
    pub(super) fn push_status(&mut self, status: can_wire::Status) {
        let id = self.config.ids.id(can_wire::Kind::Status);
        let fd = self.encoder.format().is_fd();
        if let Ok(bytes) = status.emit() {
            if let Ok(frame) = Frame::new(id, &bytes, fd) {
                self.push_priority(frame);
            }
        }
    }

    pub(super) fn periodic_status(&mut self, now: u64, dec: &scip::DecoderStats) {
        let boot = *self.health.boot_ms.get_or_insert(now);
        let period = u64::from(self.config.status_period_ms);
        if period == 0 {
            return;
        }
        let last = self.health.last_status_ms.unwrap_or(boot);
        if self.health.last_status_ms.is_some() && now.saturating_sub(last) < period {
            return;
        }
        if self.health.last_status_ms.is_some() {
            let budget = self.config.budget;
            self.health
                .close_period(now.saturating_sub(last), budget.rates, budget.extended);
        }
        self.health.last_status_ms = Some(now);
        let sum_errors = dec
            .by_kind
            .get(
                scip::ErrorKind::BadSum {
                    expected: 0,
                    found: 0,
                }
                .index(),
            )
            .copied()
            .unwrap_or(0);
        let g = self.governor.stats();
        let dropped = self
            .stats
            .scans_aborted
            .saturating_add(self.stats.scans_lost)
            .saturating_add(g.dropped_budget)
            .saturating_add(g.dropped_queue);
        let pages = crate::status::periodic_pages(
            &self.health,
            crate::status::bridge_state(self.session.state()),
            now,
            sum_errors,
            dec.resyncs,
            dropped,
            self.session.stats().recoveries,
        );
        // Pushed to the front in reverse, so they leave as heartbeat, sensor, bus.
        for page in pages.into_iter().rev() {
            self.push_status(page);
        }
    }
}
