//! CPU load: the share of wall time the executor spends polling tasks.
//!
//! The executor's `trace` hooks (enabled by the boards) mark when a round of polling
//! starts (`_embassy_trace_poll_start`) and when the executor goes idle
//! (`_embassy_trace_executor_idle`, right before it sleeps in `WFE`); the time between
//! them is summed in microseconds of the embassy time driver. The main loop samples the
//! sum once per [`LOAD_WINDOW_MS`](crate::config::LOAD_WINDOW_MS) and hands
//! [`Window::close`]'s permille to `Bridge::set_cpu_load`, which reports it in the
//! heartbeat. Interrupt handlers that run while the executor sleeps are not counted;
//! those that run while it polls are.

/// Busy microseconds since boot (wrapping), and the current time in microseconds
/// (wrapping), as sampled by [`sample`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sample {
    /// Time, µs (low 32 bits).
    pub now_us: u32,
    /// Busy time so far, µs (wrapping).
    pub busy_us: u32,
}

/// A load measurement window.
#[derive(Debug, Clone, Copy)]
pub struct Window {
    start: Sample,
}

impl Window {
    /// A window that starts at `start`.
    pub const fn new(start: Sample) -> Self {
        Self { start }
    }

    /// Closes the window at `end`: the busy share in permille (0..=1000); the next
    /// window starts at `end`. Both counters wrap; a window must be shorter than 71
    /// minutes (2^32 µs).
    pub fn close(&mut self, end: Sample) -> u16 {
        let total = end.now_us.wrapping_sub(self.start.now_us);
        let busy = end.busy_us.wrapping_sub(self.start.busy_us);
        self.start = end;
        permille(busy, total)
    }
}

/// `busy / total` in permille, at most 1000; 0 for an empty window.
pub fn permille(busy: u32, total: u32) -> u16 {
    if total == 0 {
        return 0;
    }
    let p = u64::from(busy) * 1000 / u64::from(total);
    p.min(1000) as u16
}

/// The current time and busy time (both 0 off the MCU, where no executor traces).
pub fn sample() -> Sample {
    #[cfg(all(target_arch = "arm", target_os = "none"))]
    {
        hooks::sample()
    }
    #[cfg(not(all(target_arch = "arm", target_os = "none")))]
    {
        Sample::default()
    }
}

#[cfg(all(target_arch = "arm", target_os = "none"))]
#[allow(unsafe_code)]
mod hooks {
    //! The executor's trace callbacks. With its `trace` feature, embassy-executor
    //! declares these seven functions in an `extern "Rust"` block and calls them; they
    //! must be defined exactly once in the program, with these names and signatures.
    //! Only the two that bracket a round of polling do any work.

    use core::sync::atomic::{AtomicU32, Ordering::Relaxed};

    use super::Sample;

    /// When the current round of polling started, µs.
    static POLL_START_US: AtomicU32 = AtomicU32::new(0);
    /// Busy time since boot, µs (wrapping).
    static BUSY_US: AtomicU32 = AtomicU32::new(0);

    fn now_us() -> u32 {
        // Low 32 bits: every use is a wrapping difference.
        embassy_time::Instant::now().as_micros() as u32
    }

    pub(super) fn sample() -> Sample {
        Sample {
            now_us: now_us(),
            busy_us: BUSY_US.load(Relaxed),
        }
    }

    // SAFETY (all seven): `no_mangle` exports the symbol the executor's `extern "Rust"`
    // declaration names; the signatures match that declaration (embassy-executor 0.10,
    // `src/raw/trace.rs`), and no other definition exists in the program. The bodies
    // only touch atomics.

    #[unsafe(no_mangle)]
    fn _embassy_trace_poll_start(_executor_id: u32) {
        POLL_START_US.store(now_us(), Relaxed);
    }

    #[unsafe(no_mangle)]
    fn _embassy_trace_executor_idle(_executor_id: u32) {
        let busy = now_us().wrapping_sub(POLL_START_US.load(Relaxed));
        BUSY_US.store(BUSY_US.load(Relaxed).wrapping_add(busy), Relaxed);
    }

    #[unsafe(no_mangle)]
    fn _embassy_trace_task_new(_executor_id: u32, _task_id: u32) {}

    #[unsafe(no_mangle)]
    fn _embassy_trace_task_end(_executor_id: u32, _task_id: u32) {}

    #[unsafe(no_mangle)]
    fn _embassy_trace_task_exec_begin(_executor_id: u32, _task_id: u32) {}

    #[unsafe(no_mangle)]
    fn _embassy_trace_task_exec_end(_executor_id: u32, _task_id: u32) {}

    #[unsafe(no_mangle)]
    fn _embassy_trace_task_ready_begin(_executor_id: u32, _task_id: u32) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(now_us: u32, busy_us: u32) -> Sample {
        Sample { now_us, busy_us }
    }

    #[test]
    fn permille_by_hand() {
        assert_eq!(permille(0, 1_000_000), 0);
        assert_eq!(permille(250_000, 1_000_000), 250);
        assert_eq!(permille(1, 3), 333);
        assert_eq!(permille(1_000_000, 1_000_000), 1000);
        // Rounding of the hooks' samples can make busy exceed total by a tick.
        assert_eq!(permille(1_000_001, 1_000_000), 1000);
        assert_eq!(permille(5, 0), 0);
        assert_eq!(permille(u32::MAX, u32::MAX), 1000);
    }

    #[test]
    fn windows_follow_each_other_and_wrap() {
        let mut w = Window::new(s(u32::MAX - 499_999, u32::MAX - 99));
        // 1 s later (the clock wrapped), 100 µs + 99_900 µs busy: 10 %.
        assert_eq!(w.close(s(500_000, 99_900)), 100);
        // Next second: 300 ms busy.
        assert_eq!(w.close(s(1_500_000, 399_900)), 300);
        // Idle second.
        assert_eq!(w.close(s(2_500_000, 399_900)), 0);
    }
}
