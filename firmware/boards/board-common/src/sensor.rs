//! The main loop: the sensor's UART, the session's commands, and the once-per-tick
//! housekeeping (watchdog, bus state and recovery, CPU load).
//!
//! ```text
//!            ┌────────── select ──────────┐
//! UART rx ──▶│ chunk → Bridge::on_uart    │──▶ Bridge::poll → Send: UART tx
//! Ticker  ──▶│ tick  → watchdog, bus, load│              → SetBitRate: UART rate
//!            └────────────────────────────┘──▶ notify the CAN transmit task
//! ```
//! Before the session starts, `reset_sensor_bit_rate` brings back a sensor left at the
//! streaming rate by an earlier run. The UART's DMA ring buffer keeps receiving while
//! the loop writes a command or works on a chunk, and reading it is cancel-safe, so
//! nothing the sensor sends is lost to the `select`. The CAN side never blocks this
//! loop: frames wait in the bridge's queue until the transmit task takes them.

use bridge::session::Action;
use can_wire::BusState;
use embassy_futures::select::{select, Either};
use embassy_time::{Duration, Instant, Ticker, Timer};
use embedded_io_async::{Read, Write};

use crate::config::{
    BUS_OFF_RETRY_MS, LOAD_WINDOW_MS, SENSOR_BIT_RATE, SENSOR_POWER_UP_BIT_RATE, TICK_MS,
    UART_CHUNK,
};
use crate::load;
use crate::recovery::BusOff;
use crate::shared::Shared;

/// Session actions carried out per pass of the loop (the session yields one or two).
const MAX_ACTIONS: usize = 4;

/// What [`reset_sensor_bit_rate`] sends at the streaming rate: stop a stream, then reset
/// the sensor, which puts its bit rate back to the power-up rate.
const RATE_RESET: &[u8] = b"QT\nRS\n";

/// Time the sensor gets to answer and reset before the session starts, ms.
const RATE_RESET_WAIT_MS: u64 = 100;

/// What the main loop needs from a board.
pub trait Board {
    /// The sensor UART's receiver (a DMA ring buffer with idle-line detection).
    type Rx: Read;
    /// The sensor UART's transmitter.
    type Tx: Write;

    /// The sensor UART's two halves.
    fn sensor(&mut self) -> (&mut Self::Rx, &mut Self::Tx);

    /// Switches the sensor UART to `bit_rate`; false if the UART cannot.
    fn set_sensor_bit_rate(&mut self, bit_rate: u32) -> bool;

    /// The CAN controller's error state.
    fn bus_state(&mut self) -> BusState;

    /// CAN bus errors seen since the last call (controllers that count them in
    /// hardware); 0 if the board counts them elsewhere.
    fn take_bus_errors(&mut self) -> u32;

    /// Starts the controller's bus-off recovery sequence (128 × 11 recessive bits).
    fn recover_bus(&mut self);

    /// Feeds the independent watchdog.
    fn feed_watchdog(&mut self);
}

/// Milliseconds since boot.
pub fn now_ms() -> u64 {
    Instant::now().as_millis()
}

/// Counters of the main loop (logged, not on the wire).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoopStats {
    /// UART receive errors (overrun, framing, noise, parity): the ring buffer restarts.
    pub uart_errors: u32,
    /// Commands that could not be encoded or written.
    pub command_errors: u32,
    /// Bit rate changes the UART refused.
    pub bit_rate_errors: u32,
}

/// Runs the bridge on `board` forever: starts the sensor session, then serves the UART
/// and the tick.
pub async fn run<B: Board>(shared: &Shared, board: &mut B) -> ! {
    reset_sensor_bit_rate(board).await;

    let mut chunk = [0u8; UART_CHUNK];
    let mut ticker = Ticker::every(Duration::from_millis(TICK_MS));
    let mut bus = BusOff::new(BUS_OFF_RETRY_MS);
    let mut load = load::Window::new(load::sample());
    let mut load_due = now_ms() + LOAD_WINDOW_MS;
    let mut stats = LoopStats::default();

    let now = now_ms();
    shared.with(|b| b.start(now));
    info!("bridge started");

    loop {
        let (rx, _) = board.sensor();
        let event = select(rx.read(&mut chunk), ticker.next()).await;
        let now = now_ms();
        match event {
            Either::First(Ok(n)) => {
                let bytes = chunk.get(..n).unwrap_or(&[]);
                shared.with(|b| b.on_uart(bytes, now));
            }
            Either::First(Err(_)) => {
                // The driver drops what it held and restarts reception; the decoder
                // sees the gap as a damaged line and resynchronises.
                stats.uart_errors = stats.uart_errors.wrapping_add(1);
                warn!("sensor UART error #{}", stats.uart_errors);
            }
            Either::Second(()) => {
                board.feed_watchdog();
                supervise_bus(shared, board, &mut bus, now);
                if now >= load_due {
                    load_due = now + LOAD_WINDOW_MS;
                    let permille = load.close(load::sample());
                    shared.with(|b| b.set_cpu_load(permille));
                }
            }
        }
        drive_session(shared, board, now, &mut stats).await;
        shared.notify_frames();
    }
}

/// Brings a sensor that still runs at the streaming rate back to its power-up rate.
///
/// The session starts at the power-up rate and raises it with `SS`. When the MCU alone
/// restarts (the watchdog, a flash, a brown-out the sensor rode through), the sensor is
/// still at the raised rate and would not understand the session. So before the session
/// starts, `QT` and `RS` go out at the streaming rate: a sensor at that rate stops and
/// resets to its power-up rate; a sensor already at the power-up rate sees a few garbled
/// bytes and at worst answers an unknown command, which the decoder skips. Its answers,
/// if any, reach the bridge before the session starts and change nothing.
async fn reset_sensor_bit_rate<B: Board>(board: &mut B) {
    if SENSOR_BIT_RATE == SENSOR_POWER_UP_BIT_RATE || !board.set_sensor_bit_rate(SENSOR_BIT_RATE) {
        return;
    }
    let (_, tx) = board.sensor();
    let sent = tx.write_all(RATE_RESET).await.is_ok() && tx.flush().await.is_ok();
    Timer::after(Duration::from_millis(RATE_RESET_WAIT_MS)).await;
    let restored = board.set_sensor_bit_rate(SENSOR_POWER_UP_BIT_RATE);
    if !sent || !restored {
        warn!("sensor bit rate reset incomplete");
    }
}

/// Reports the controller's state and errors to the bridge, and recovers from bus-off
/// when the policy says so.
fn supervise_bus<B: Board>(shared: &Shared, board: &mut B, bus: &mut BusOff, now: u64) {
    let state = board.bus_state();
    let errors = board.take_bus_errors();
    let verdict = bus.check(state, now);
    shared.with(|b| {
        for _ in 0..errors {
            b.on_bus_error();
        }
        if let Some(state) = verdict.changed {
            b.set_bus_state(state);
        }
    });
    if verdict.changed.is_some() {
        info!("CAN bus state {}", u8::from(state));
    }
    if verdict.recover {
        board.recover_bus();
        info!("CAN bus-off recovery #{}", bus.attempts());
    }
}

/// Carries out what the session asks for: commands to the sensor, bit rate changes.
async fn drive_session<B: Board>(shared: &Shared, board: &mut B, now: u64, stats: &mut LoopStats) {
    for _ in 0..MAX_ACTIONS {
        let Some(action) = shared.with(|b| b.poll(now)) else {
            return;
        };
        match action {
            Action::Send(request) => {
                let mut line = [0u8; scip::REQUEST_MAX];
                let written = match request.encode(&mut line) {
                    Ok(n) => {
                        let (_, tx) = board.sensor();
                        tx.write_all(line.get(..n).unwrap_or(&[])).await.is_ok()
                    }
                    Err(_) => false,
                };
                if !written {
                    stats.command_errors = stats.command_errors.wrapping_add(1);
                    warn!("sensor command not sent (#{})", stats.command_errors);
                }
            }
            Action::SetBitRate(bit_rate) => {
                // The last command's bytes must be out of the shift register first.
                let (_, tx) = board.sensor();
                let flushed = tx.flush().await.is_ok();
                if !flushed || !board.set_sensor_bit_rate(bit_rate) {
                    stats.bit_rate_errors = stats.bit_rate_errors.wrapping_add(1);
                    warn!("sensor UART bit rate {} refused", bit_rate);
                } else {
                    info!("sensor UART at {} bit/s", bit_rate);
                }
            }
        }
    }
}
