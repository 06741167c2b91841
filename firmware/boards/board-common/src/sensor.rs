//! The main loop: the sensor link (a UART, or a TCP connection to an Ethernet sensor),
//! the session's commands, and the once-per-tick housekeeping (watchdog, bus state and
//! recovery, CPU load, the link's state).
//!
//! ```text
//!            ┌────────── select ──────────┐
//! UART/TCP ─▶│ chunk → Bridge::on_uart    │──▶ Bridge::poll → Send: UART/TCP tx
//! Ticker  ──▶│ tick  → watchdog, bus, load│              → SetBitRate: UART rate
//!            └────────────────────────────┘──▶ notify the CAN transmit task
//! ```
//! Before the session starts, `reset_sensor_bit_rate` brings back a sensor left at the
//! streaming rate by an earlier run. The UART's DMA ring buffer keeps receiving while
//! the loop writes a command or works on a chunk, and reading it is cancel-safe, so
//! nothing the sensor sends is lost to the `select`. The CAN side never blocks this
//! loop: frames wait in the bridge's queue until the transmit task takes them.
//!
//! **Links that go down** (TCP; [`Board::link_state`]): the session starts when the
//! link is first up. An error or end of stream on a read, or a link the board reports
//! down at a tick (cable pulled, connection closed), closes the link and tells the
//! bridge ([`Board::link_changed`]); the loop then keeps ticking (watchdog, status
//! frames, CAN) and opens the link again on the [`Backoff`] schedule (250 ms doubling
//! to 4 s). Commands the session wants sent while the link is down are dropped. Such
//! links have no bit rate: the session's `bit_rate` is `None`, so no `SS` and no rate
//! reset at boot.

use core::future::Future;

use bridge::session::Action;
use can_wire::BusState;
use embassy_futures::select::{select, Either};
use embassy_time::{with_timeout, Duration, Instant, Ticker, Timer};
use embedded_io_async::{ErrorType, Read, Write};

use crate::config::{
    Bridge, BUS_OFF_RETRY_MS, LOAD_WINDOW_MS, SENSOR_BIT_RATE, SENSOR_POWER_UP_BIT_RATE, TICK_MS,
    UART_CHUNK,
};
use crate::link::{Backoff, FIRST_RETRY_MS, MAX_RETRY_MS};
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

/// A command write that takes longer than this (a TCP send buffer that stays full) is
/// given up, ms: well inside the watchdog's timeout.
const WRITE_TIMEOUT_MS: u64 = 100;

/// The state of the sensor link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// Bytes flow (a UART always; a TCP connection established).
    Up,
    /// Being opened ([`Board::open_link`] was called; a TCP handshake runs).
    Opening,
    /// Closed: the last attempt failed, or the link was lost.
    Down,
}

/// What the main loop needs from a board.
pub trait Board {
    /// The sensor link: a UART ([`Uart`] joins its two halves) or a TCP socket.
    type Sensor: Read + Write;

    /// The sensor link.
    fn sensor(&mut self) -> &mut Self::Sensor;

    /// Switches the sensor UART to `bit_rate`; false if the UART cannot (or the link has
    /// no bit rate).
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

    /// Whether the sensor link can go down (a TCP connection). A UART cannot (the
    /// default): the loop's link supervision and write timeout are then compiled out.
    const LINK_CAN_FAIL: bool = false;

    /// The sensor link's state. A UART is always up (the default).
    fn link_state(&mut self) -> LinkState {
        LinkState::Up
    }

    /// Starts opening the link (a TCP connect) without waiting for it;
    /// [`Board::link_state`] tells how it went. A UART has nothing to open.
    fn open_link(&mut self) {}

    /// Closes the link at once (a TCP abort), after it failed.
    fn close_link(&mut self) {}

    /// The link came up (`up`) or went down at `now_ms`: the one place where the bridge
    /// learns it. Never called for a UART (always up); the default does nothing.
    fn link_changed(&mut self, bridge: &mut Bridge, up: bool, now_ms: u64) {
        let _ = (bridge, up, now_ms);
    }
}

/// A sensor UART's receiver and transmitter as one link.
pub struct Uart<Rx, Tx> {
    /// The receiver (a DMA ring buffer with idle-line detection).
    pub rx: Rx,
    /// The transmitter.
    pub tx: Tx,
}

impl<Rx: ErrorType, Tx: ErrorType<Error = Rx::Error>> ErrorType for Uart<Rx, Tx> {
    type Error = Rx::Error;
}

// The halves' own futures, not wrapped in one more state machine each (smaller code).
impl<Rx: Read, Tx: ErrorType<Error = Rx::Error>> Read for Uart<Rx, Tx> {
    fn read(&mut self, buf: &mut [u8]) -> impl Future<Output = Result<usize, Self::Error>> {
        self.rx.read(buf)
    }
}

impl<Rx: ErrorType, Tx: Write<Error = Rx::Error>> Write for Uart<Rx, Tx> {
    fn write(&mut self, buf: &[u8]) -> impl Future<Output = Result<usize, Self::Error>> {
        self.tx.write(buf)
    }

    fn flush(&mut self) -> impl Future<Output = Result<(), Self::Error>> {
        self.tx.flush()
    }
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
    /// Times the sensor link went down.
    pub link_losses: u32,
    /// Commands dropped because the link was down.
    pub dropped_commands: u32,
}

/// The main loop's view of the sensor link: up or not, and when to open it again.
struct Link {
    up: bool,
    opening: bool,
    backoff: Backoff,
}

impl Link {
    /// Follows the board's link state at `now_ms`: reports changes to the bridge, opens
    /// the link when the back-off says so.
    fn supervise<B: Board>(
        &mut self,
        shared: &Shared,
        board: &mut B,
        now: u64,
        stats: &mut LoopStats,
    ) {
        let state = board.link_state();
        match (self.up, state) {
            (true, LinkState::Up) | (false, LinkState::Opening) => {}
            (true, _) => self.lost(shared, board, now, stats),
            (false, LinkState::Up) => {
                self.up = true;
                self.opening = false;
                self.backoff.up();
                shared.with(|b| board.link_changed(b, true, now));
                info!("sensor link up");
            }
            (false, LinkState::Down) => {
                if self.opening {
                    // The attempt failed: wait longer before the next.
                    self.opening = false;
                    self.backoff.down(now);
                } else if self.backoff.due(now) {
                    self.opening = true;
                    board.open_link();
                    info!(
                        "sensor link: connecting (attempt {})",
                        self.backoff.attempts()
                    );
                }
            }
        }
    }

    /// The link failed (a read error, the end of the stream, or the board said so).
    fn lost<B: Board>(&mut self, shared: &Shared, board: &mut B, now: u64, stats: &mut LoopStats) {
        self.up = false;
        self.opening = false;
        board.close_link();
        self.backoff.down(now);
        shared.with(|b| board.link_changed(b, false, now));
        stats.link_losses = stats.link_losses.wrapping_add(1);
        warn!("sensor link lost (#{})", stats.link_losses);
    }
}

/// Runs the bridge on `board` forever: starts the sensor session (once the link is up),
/// then serves the link and the tick.
pub async fn run<B: Board>(shared: &Shared, board: &mut B) -> ! {
    if shared.with(|b| b.config().session.bit_rate.is_some()) {
        reset_sensor_bit_rate(board).await;
    }

    let mut chunk = [0u8; UART_CHUNK];
    let mut ticker = Ticker::every(Duration::from_millis(TICK_MS));
    let mut bus = BusOff::new(BUS_OFF_RETRY_MS);
    let mut load = load::Window::new(load::sample());
    let mut load_due = now_ms() + LOAD_WINDOW_MS;
    let mut stats = LoopStats::default();

    let now = now_ms();
    let mut link = Link {
        up: !B::LINK_CAN_FAIL || board.link_state() == LinkState::Up,
        opening: false,
        backoff: Backoff::new(FIRST_RETRY_MS, MAX_RETRY_MS),
    };
    // On a TCP link the bridge's session waits for `Bridge::link_up` (the board's
    // `link_changed`).
    shared.with(|b| b.start(now));
    info!("bridge started");
    if !link.up {
        // The first attempt at once.
        link.opening = true;
        board.open_link();
    }

    loop {
        let event = if !B::LINK_CAN_FAIL || link.up {
            let sensor = board.sensor();
            select(sensor.read(&mut chunk), ticker.next()).await
        } else {
            ticker.next().await;
            Either::Second(())
        };
        // With the sensor clock model, when a chunk ended arriving (µs of the monotonic
        // clock) places the scans in the board's clock; the rest of the loop runs in ms.
        #[cfg(feature = "time-estimate")]
        let (now_us, now) = {
            let us = Instant::now().as_micros();
            (us, us / 1000)
        };
        #[cfg(not(feature = "time-estimate"))]
        let now = now_ms();
        match event {
            Either::First(Ok(n)) if n > 0 => {
                let bytes = chunk.get(..n).unwrap_or(&[]);
                #[cfg(feature = "time-estimate")]
                shared.with(|b| b.on_uart_at(bytes, now_us));
                #[cfg(not(feature = "time-estimate"))]
                shared.with(|b| b.on_uart(bytes, now));
            }
            Either::First(result) => {
                if B::LINK_CAN_FAIL {
                    // A connection reset or closed by the sensor (a socket reads 0
                    // bytes only at the end of the stream).
                    link.lost(shared, board, now, &mut stats);
                } else if result.is_err() {
                    // The driver drops what it held and restarts reception; the decoder
                    // sees the gap as a damaged line and resynchronises.
                    stats.uart_errors = stats.uart_errors.wrapping_add(1);
                    warn!("sensor UART error #{}", stats.uart_errors);
                }
            }
            Either::Second(()) => {
                board.feed_watchdog();
                if B::LINK_CAN_FAIL {
                    link.supervise(shared, board, now, &mut stats);
                }
                supervise_bus(shared, board, &mut bus, now);
                if now >= load_due {
                    load_due = now + LOAD_WINDOW_MS;
                    let permille = load.close(load::sample());
                    shared.with(|b| b.set_cpu_load(permille));
                }
            }
        }
        drive_session(shared, board, now, !B::LINK_CAN_FAIL || link.up, &mut stats).await;
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
    let sensor = board.sensor();
    let sent = sensor.write_all(RATE_RESET).await.is_ok() && sensor.flush().await.is_ok();
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

/// Carries out what the session asks for: commands to the sensor (dropped while the
/// link is down), bit rate changes.
async fn drive_session<B: Board>(
    shared: &Shared,
    board: &mut B,
    now: u64,
    link_up: bool,
    stats: &mut LoopStats,
) {
    for _ in 0..MAX_ACTIONS {
        // With the sensor clock model, when a `TM` request leaves (µs) bounds the
        // sensor's reading (poll_at times the request's bytes on the UART).
        #[cfg(feature = "time-estimate")]
        let action = {
            let _ = now;
            shared.with(|b| b.poll_at(Instant::now().as_micros()))
        };
        #[cfg(not(feature = "time-estimate"))]
        let action = shared.with(|b| b.poll(now));
        let Some(action) = action else {
            return;
        };
        match action {
            Action::Send(_) if !link_up => {
                stats.dropped_commands = stats.dropped_commands.wrapping_add(1);
            }
            Action::Send(request) => {
                let mut line = [0u8; scip::REQUEST_MAX];
                let written = match request.encode(&mut line) {
                    Ok(n) => {
                        let write = board.sensor().write_all(line.get(..n).unwrap_or(&[]));
                        if B::LINK_CAN_FAIL {
                            let timeout = Duration::from_millis(WRITE_TIMEOUT_MS);
                            matches!(with_timeout(timeout, write).await, Ok(Ok(())))
                        } else {
                            write.await.is_ok()
                        }
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
                let flushed = board.sensor().flush().await.is_ok();
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
