//! Bus-off recovery policy: explicit and rate-limited.
//!
//! Both CAN controllers could leave bus-off by themselves (FDCAN's driver clears `INIT`
//! in its interrupt, bxCAN has `ABOM`); the boards turn that off, so that a node with a
//! broken transceiver or a wrong bit rate does not re-join the bus the moment it is
//! allowed to and destroy traffic again. Instead the main loop feeds the controller's
//! state to [`BusOff::check`] every tick, and starts a recovery only after the node has
//! stayed off the bus for [`BUS_OFF_RETRY_MS`](crate::config::BUS_OFF_RETRY_MS), and
//! at most once per that period. State changes go to the bridge
//! (`Bridge::set_bus_state`, which counts entries into bus-off for the status frames).

use can_wire::BusState;

/// What the main loop does after a [`BusOff::check`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Verdict {
    /// The state changed since the last check: report it to the bridge.
    pub changed: Option<BusState>,
    /// Start a bus-off recovery now.
    pub recover: bool,
}

/// The recovery policy's state.
#[derive(Debug, Clone)]
pub struct BusOff {
    retry_ms: u64,
    state: BusState,
    /// When the current wait began (entering bus-off, or the last attempt).
    waiting_since: Option<u64>,
    attempts: u32,
}

impl BusOff {
    /// A policy that waits `retry_ms` before each attempt; the bus starts error-active.
    pub const fn new(retry_ms: u64) -> Self {
        Self {
            retry_ms,
            state: BusState::ErrorActive,
            waiting_since: None,
            attempts: 0,
        }
    }

    /// Takes the controller's state at `now_ms`.
    pub fn check(&mut self, state: BusState, now_ms: u64) -> Verdict {
        let changed = (state != self.state).then_some(state);
        self.state = state;
        if state != BusState::BusOff {
            self.waiting_since = None;
            return Verdict {
                changed,
                recover: false,
            };
        }
        let since = *self.waiting_since.get_or_insert(now_ms);
        let recover = now_ms.saturating_sub(since) >= self.retry_ms;
        if recover {
            self.waiting_since = Some(now_ms);
            self.attempts = self.attempts.saturating_add(1);
        }
        Verdict { changed, recover }
    }

    /// Recoveries started so far.
    pub fn attempts(&self) -> u32 {
        self.attempts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OFF: BusState = BusState::BusOff;
    const ACTIVE: BusState = BusState::ErrorActive;
    const PASSIVE: BusState = BusState::ErrorPassive;

    fn v(changed: Option<BusState>, recover: bool) -> Verdict {
        Verdict { changed, recover }
    }

    #[test]
    fn healthy_bus_reports_nothing() {
        let mut p = BusOff::new(100);
        for t in (0..1000).step_by(5) {
            assert_eq!(p.check(ACTIVE, t), v(None, false));
        }
        assert_eq!(p.attempts(), 0);
    }

    #[test]
    fn waits_the_retry_period_then_at_most_once_per_period() {
        let mut p = BusOff::new(100);
        assert_eq!(p.check(PASSIVE, 0), v(Some(PASSIVE), false));
        // Enters bus-off at 10: no recovery before 110.
        assert_eq!(p.check(OFF, 10), v(Some(OFF), false));
        assert_eq!(p.check(OFF, 109), v(None, false));
        assert_eq!(p.check(OFF, 110), v(None, true));
        // Still off (the bus is broken): the next attempt 100 ms after the last one.
        assert_eq!(p.check(OFF, 115), v(None, false));
        assert_eq!(p.check(OFF, 209), v(None, false));
        assert_eq!(p.check(OFF, 210), v(None, true));
        assert_eq!(p.attempts(), 2);
        // Recovered.
        assert_eq!(p.check(ACTIVE, 212), v(Some(ACTIVE), false));
        // Off again at 250: a fresh wait of 100 ms from there, not from the last attempt.
        assert_eq!(p.check(OFF, 250), v(Some(OFF), false));
        assert_eq!(p.check(OFF, 349), v(None, false));
        assert_eq!(p.check(OFF, 350), v(None, true));
        assert_eq!(p.attempts(), 3);
    }

    #[test]
    fn at_most_one_attempt_per_period_whatever_the_tick() {
        // Checked every millisecond for 10 s of a dead bus: attempts at 100, 200, ...
        let mut p = BusOff::new(100);
        let mut attempts = Vec::new();
        for t in 0..10_000 {
            if p.check(OFF, t).recover {
                attempts.push(t);
            }
        }
        assert_eq!(attempts.len(), 99);
        assert_eq!(attempts.first(), Some(&100));
        assert!(attempts.windows(2).all(|w| w[1] - w[0] == 100));
    }

    #[test]
    fn clock_going_backwards_does_not_trigger() {
        let mut p = BusOff::new(100);
        assert_eq!(p.check(OFF, 1000), v(Some(OFF), false));
        assert_eq!(p.check(OFF, 500), v(None, false));
    }
}
