//! scip2can firmware for QEMU's `mps2-an386` machine: the bridge.
//!
//! - **UART0** is the sensor: its bytes go to [`bridge::engine::Bridge::on_uart`], the
//!   session's commands are written back to it. `SetBitRate` only sets `BAUDDIV`:
//!   QEMU's UART has no bit rate (and the session sends no `SS` by default).
//! - **UART1** is the CAN port, speaking SLCAN like a USB-CAN adapter (`can_port`):
//!   closed until `O`; the bridge's frames go out as `t`/`d`/`b` lines while it is open;
//!   frames written to it go to [`bridge::engine::Bridge::on_can_frame_at`] (control
//!   frames, and a time master's SYNC / FOLLOW-UP, stamped in µs); `F` answers the
//!   status flags.
//! - Time is SysTick's millisecond count. The session starts at boot. The CMSDK watchdog
//!   is fed every millisecond; a stalled loop raises the NMI, which reports and resets.
//!
//! Everything else is the core's: this file binds peripherals and moves bytes and frames.

#![no_std]
#![no_main]
#![deny(unsafe_code)]

mod can_port;
mod config;
mod hw;
mod meter;

use bridge::engine::Bridge;
use bridge::session::Action;
use can_port::CanPort;
use cortex_m_rt::entry;
use embedded_io::Write;
use slcan::StatusFlags;

/// Milliseconds since boot as the core wants them: SysTick's 32-bit count extended.
struct Clock {
    last: u32,
    high: u64,
}

impl Clock {
    fn now(&mut self) -> u64 {
        let ms = hw::now_ms();
        if ms < self.last {
            self.high += 1 << 32;
        }
        self.last = ms;
        self.high | u64::from(ms)
    }
}

/// Counters whose growth raises SLCAN status flags.
#[derive(Default, PartialEq)]
struct Seen {
    tx_lost: u32,
    rx_lost: u32,
}

#[entry]
fn main() -> ! {
    hw::paint_stack();
    let Some(cp) = cortex_m::Peripherals::take() else {
        hw::exit()
    };
    hw::start_systick(cp.SYST);
    let Some(hw::Board {
        uart0: mut sensor,
        uart1: mut can,
    }) = hw::Board::take(config::BAUD)
    else {
        hw::exit()
    };
    hw::rx0_use_ring();
    let mut watchdog = hw::Watchdog::start(config::WATCHDOG_MS);

    let Some(bridge_config) = config::bridge() else {
        hw::exit()
    };
    let Ok(mut bridge) = Bridge::<{ config::QUEUE }>::new(bridge_config) else {
        hw::exit()
    };
    bridge.set_bus_state(can_wire::BusState::ErrorActive);
    let mut port = CanPort::new(config::SLCAN_VERSION, config::SLCAN_SERIAL);
    let mut meter = meter::Meter::default();
    let mut clock = Clock { last: 0, high: 0 };
    let mut seen = Seen::default();
    let mut last_ms = hw::now_ms();
    let (mut load_start, mut sleep_ticks) = (hw::ticks(), 0u64);
    bridge.start(clock.now());

    let mut chunk = [0u8; 64];
    let mut last_uart_ms = last_ms;
    loop {
        let now = clock.now();
        let ms = hw::now_ms();
        if ms != last_ms {
            last_ms = ms;
            watchdog.feed();
            seen = raise_flags(&bridge, &mut port, seen);
            let elapsed = hw::ticks().saturating_sub(load_start);
            if elapsed >= u64::from(hw::TICKS_PER_MS) * 1000 {
                let busy = elapsed.saturating_sub(sleep_ticks);
                bridge.set_cpu_load(u16::try_from(busy * 1000 / elapsed).unwrap_or(1000));
                (load_start, sleep_ticks) = (hw::ticks(), 0);
            }
        }

        // Sensor bytes into the core, a chunk at a time (like a DMA half-buffer), or
        // whatever arrived by the next millisecond tick, so a scan's end is never held.
        let tick = ms != last_uart_ms;
        let n = if hw::rx0_len() >= chunk.len() || tick {
            last_uart_ms = ms;
            hw::rx0_read(&mut chunk)
        } else {
            0
        };
        if n > 0 {
            let read_at = hw::ticks();
            let sent_before = bridge.stats().scans_sent;
            let data = chunk.get(..n).unwrap_or_default();
            let ((), ticks) = hw::measure(|| bridge.on_uart(data, now));
            meter.uart(n, read_at, ticks, sent_before, bridge.stats());
        }

        // The session's commands to the sensor.
        while let Some(action) = bridge.poll(now) {
            match action {
                Action::Send(request) => {
                    let mut line = [0u8; scip::REQUEST_MAX];
                    if let Ok(len) = request.encode(&mut line) {
                        let _ = sensor.write_all(line.get(..len).unwrap_or_default());
                    }
                }
                Action::SetBitRate(rate) => sensor.set_baud(rate),
            }
        }

        // Control and time frames from the bus (the SLCAN host), the bridge's frames
        // onto it.
        if can_port::serve(&mut port, &mut can, &mut bridge, &mut meter, ms) {
            diagnostics(&mut port, &mut can, &bridge, &meter);
        }

        let output_moves = port.has_output() && !can.tx_full();
        let frames_wait = bridge.queued() > 0 && port.has_room_for_frame();
        let full_chunk = || hw::rx0_len() >= chunk.len();
        let idle = !(full_chunk() || can.rx_pending() || output_moves || frames_wait);
        if idle {
            let before = hw::ticks();
            hw::sleep_until(|| full_chunk() || can.rx_pending() || hw::now_ms() != last_ms);
            sleep_ticks += hw::ticks().saturating_sub(before);
        }
    }
}

/// Raises SLCAN's "transmit FIFO full" when the bridge lost frames or whole scans to a
/// full queue, "data overrun" when sensor bytes were lost.
fn raise_flags(bridge: &Bridge<{ config::QUEUE }>, port: &mut CanPort, seen: Seen) -> Seen {
    let now = Seen {
        tx_lost: bridge
            .health()
            .tx_overflows
            .wrapping_add(bridge.stats().queue_overflows)
            .wrapping_add(bridge.governor().stats().dropped_queue),
        rx_lost: hw::rx0_lost(),
    };
    if now.tx_lost != seen.tx_lost {
        port.raise(StatusFlags::TX_FIFO_FULL);
    }
    if now.rx_lost != seen.rx_lost {
        port.raise(StatusFlags::DATA_OVERRUN);
    }
    now
}

/// The `?` line: firmware, stack high-water mark, and the work counters of `meter`.
fn diagnostics(
    port: &mut CanPort,
    can: &mut hw::Uart,
    bridge: &Bridge<{ config::QUEUE }>,
    meter: &meter::Meter,
) {
    // The line is longer than one frame line: let the ring empty first.
    while port.has_output() {
        port.flush(can);
    }
    let core = meter::CoreFields {
        meter,
        stats: bridge.stats(),
        governor: bridge.governor().stats(),
    };
    let closed_drops = port.closed_drops;
    port.text(format_args!(
        "?fw={} {core} lat_n={} lat_sum={} lat_max={} early={} late={} \
         rx_lost={} closed_drops={} cpu_permille={} ms={}",
        env!("CARGO_PKG_VERSION"),
        meter.latency_n,
        meter.latency_sum,
        meter.latency_max,
        meter.early,
        meter.late,
        hw::rx0_lost(),
        closed_drops,
        bridge.health().cpu_permille,
        hw::now_ms(),
    ));
}
