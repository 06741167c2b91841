//! Work and latency counters of the bridge binary, reported by the `?` diagnostics
//! line. Times are SysTick ticks of the 25 MHz core clock: under
//! `qemu-system-arm -icount shift=0` one instruction takes 1 ns of virtual time, so one
//! tick is 40 instructions.

use bridge::engine::BridgeStats;
use can_wire::Kind;

/// The counters.
#[derive(Default)]
pub struct Meter {
    /// UART0 bytes given to the core.
    pub bytes: u64,
    /// Ticks spent in `Bridge::on_uart` (decode + session + pipeline + framing).
    pub core_ticks: u64,
    /// Calls of `Bridge::on_uart`.
    pub calls: u32,
    /// Longest single `on_uart` call, ticks.
    pub max_call_ticks: u32,
    /// Ticks spent writing frames as SLCAN lines.
    pub slcan_ticks: u64,
    /// Frames written (or dropped while the channel was closed).
    pub frames: u32,
    /// Read time of the chunk that ended the last scan whose trailer is still queued.
    pending_end: Option<u64>,
    /// Scan-end latencies measured: count, sum, maximum (ticks from reading the scan's
    /// last UART byte to writing its trailer frame).
    pub latency_n: u32,
    /// Sum of the latencies.
    pub latency_sum: u64,
    /// Largest latency.
    pub latency_max: u64,
    /// Scans ended (sent or aborted) when the current scan's header A left.
    ended_at_header: Option<u32>,
    /// The current scan's first data frame has left.
    first_data_seen: bool,
    /// Scans whose first data frame left before their last UART byte was read.
    pub early: u32,
    /// Scans whose first data frame left only after.
    pub late: u32,
}

fn ended(stats: &BridgeStats) -> u32 {
    stats.scans_sent.wrapping_add(stats.scans_aborted)
}

impl Meter {
    /// One `on_uart` call of `n` bytes read at tick `read_at`, which took `ticks`;
    /// `sent_before` is the bridge's `scans_sent` before the call.
    pub fn uart(
        &mut self,
        n: usize,
        read_at: u64,
        ticks: u32,
        sent_before: u32,
        stats: &BridgeStats,
    ) {
        self.bytes += n as u64;
        self.core_ticks += u64::from(ticks);
        self.calls = self.calls.wrapping_add(1);
        self.max_call_ticks = self.max_call_ticks.max(ticks);
        if stats.scans_sent != sent_before {
            self.pending_end = Some(read_at);
        }
    }

    /// A frame of `kind` left at tick `now` (after `ticks` of SLCAN work).
    pub fn frame(&mut self, kind: Option<Kind>, now: u64, ticks: u32, stats: &BridgeStats) {
        self.frames = self.frames.wrapping_add(1);
        self.slcan_ticks += u64::from(ticks);
        match kind {
            Some(Kind::HeaderA) => {
                self.ended_at_header = Some(ended(stats));
                self.first_data_seen = false;
            }
            Some(Kind::Data) if !self.first_data_seen => {
                self.first_data_seen = true;
                if let Some(at_header) = self.ended_at_header {
                    if ended(stats) == at_header {
                        self.early = self.early.wrapping_add(1);
                    } else {
                        self.late = self.late.wrapping_add(1);
                    }
                }
            }
            Some(Kind::Trailer) => {
                if let Some(at) = self.pending_end.take() {
                    let lat = now.saturating_sub(at);
                    self.latency_n = self.latency_n.wrapping_add(1);
                    self.latency_sum += lat;
                    self.latency_max = self.latency_max.max(lat);
                }
            }
            _ => {}
        }
    }
}

/// The fields every bridge binary's `?` line starts with after its version: stack,
/// work counters, scans and the governor's drops (`key=value`, space-separated).
pub struct CoreFields<'a> {
    /// The work counters.
    pub meter: &'a Meter,
    /// The core's scan counters.
    pub stats: &'a BridgeStats,
    /// The governor's counters.
    pub governor: &'a bridge::governor::GovernorStats,
}

impl core::fmt::Display for CoreFields<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (m, s, g) = (self.meter, self.stats, self.governor);
        write!(
            f,
            "stack={} stack_size={} bytes={} core_ticks={} calls={} max_call_ticks={} \
             slcan_ticks={} frames={} scans_in={} scans_sent={} scans_aborted={} \
             dropped_budget={} dropped_queue={}",
            crate::hw::stack_used(),
            crate::hw::stack_size(),
            m.bytes,
            m.core_ticks,
            m.calls,
            m.max_call_ticks,
            m.slcan_ticks,
            m.frames,
            s.scans_in,
            s.scans_sent,
            s.scans_aborted,
            g.dropped_budget,
            g.dropped_queue,
        )
    }
}
