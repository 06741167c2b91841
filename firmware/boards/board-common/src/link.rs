//! Reconnect policy of a sensor link that can go down (a TCP connection to an Ethernet
//! sensor): when to try to connect again.
//!
//! The first attempt after the link went down waits [`Backoff::first_ms`]; each failed
//! attempt doubles the wait, up to [`Backoff::max_ms`]; a connection that came up resets
//! it. A sensor that reboots (its TCP server is gone for a few seconds) is then found
//! again within the longest wait, and a missing sensor costs one SYN per `max_ms`.
//! Sans-IO: the main loop asks [`Backoff::due`] every tick (tested on the host).

/// Wait before the first attempt after the link went down, ms.
pub const FIRST_RETRY_MS: u64 = 250;

/// Longest wait between two attempts, ms.
pub const MAX_RETRY_MS: u64 = 4000;

/// The reconnect policy's state.
#[derive(Debug, Clone)]
pub struct Backoff {
    first_ms: u64,
    max_ms: u64,
    /// The wait before the next attempt, after the current one.
    delay_ms: u64,
    /// When the next attempt is due; `None` while the link is up (or an attempt runs).
    next_ms: Option<u64>,
    attempts: u32,
}

impl Backoff {
    /// A policy waiting `first_ms` before the first attempt, doubling up to `max_ms`.
    pub const fn new(first_ms: u64, max_ms: u64) -> Self {
        Self {
            first_ms,
            max_ms,
            delay_ms: first_ms,
            next_ms: None,
            attempts: 0,
        }
    }

    /// The wait before the first attempt, ms.
    pub const fn first_ms(&self) -> u64 {
        self.first_ms
    }

    /// The longest wait, ms.
    pub const fn max_ms(&self) -> u64 {
        self.max_ms
    }

    /// Connection attempts so far.
    pub const fn attempts(&self) -> u32 {
        self.attempts
    }

    /// The link went down (or never came up) at `now_ms`: the next attempt waits the
    /// current delay.
    pub fn down(&mut self, now_ms: u64) {
        self.next_ms = Some(now_ms.saturating_add(self.delay_ms));
    }

    /// The link is up: the next outage starts again at the first wait.
    pub fn up(&mut self) {
        self.delay_ms = self.first_ms;
        self.next_ms = None;
    }

    /// Whether an attempt is due at `now_ms`. True once per scheduled attempt: the
    /// caller then connects, and calls [`Backoff::down`] if that attempt failed (the
    /// delay has doubled by then) or [`Backoff::up`] if it succeeded.
    pub fn due(&mut self, now_ms: u64) -> bool {
        match self.next_ms {
            Some(at) if now_ms >= at => {
                self.next_ms = None;
                self.attempts = self.attempts.saturating_add(1);
                self.delay_ms = self.delay_ms.saturating_mul(2).min(self.max_ms);
                true
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The times of the attempts when every attempt fails at once, link down at 1000.
    fn schedule(mut b: Backoff, until_ms: u64) -> Vec<u64> {
        let mut out = Vec::new();
        b.down(1000);
        for now in 1000..until_ms {
            if b.due(now) {
                out.push(now);
                b.down(now);
            }
        }
        out
    }

    #[test]
    fn waits_double_from_250_ms_up_to_4_s() {
        // 250, 500, 1000, 2000, 4000, 4000 ms apart (written out by hand).
        let times = schedule(Backoff::new(FIRST_RETRY_MS, MAX_RETRY_MS), 16_000);
        assert_eq!(times, [1250, 1750, 2750, 4750, 8750, 12_750]);
    }

    #[test]
    fn a_connection_resets_the_wait() {
        let mut b = Backoff::new(100, 1000);
        b.down(0);
        assert!(!b.due(99));
        assert!(b.due(100));
        b.down(100);
        assert!(b.due(300));
        assert!(!b.due(300), "once per scheduled attempt");
        b.up();
        assert!(!b.due(10_000), "nothing due while up");
        b.down(10_000);
        assert!(!b.due(10_099));
        assert!(b.due(10_100));
        assert_eq!(b.attempts(), 3);
    }
}
