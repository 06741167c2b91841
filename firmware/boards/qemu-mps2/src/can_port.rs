//! The CAN port: UART1 speaking SLCAN, as a USB-CAN adapter on the bridge's bus would.
//!
//! What the host sends is split into lines and handed to [`slcan::Adapter`]; the frames
//! it asks to transmit come back to the caller (they are the bus traffic the bridge
//! receives: control frames). The bridge's frames are written as SLCAN lines while the
//! channel is open, and dropped (counted) while it is closed: they went on the bus, the
//! adapter just was not listening. Output goes through a small ring so that the main
//! loop never waits for UART1.
//!
//! One extension: a line starting with `?` asks for the board's diagnostics (stack
//! high-water mark, work counters; see `main.rs`), answered as one `?...` line. SLCAN
//! clients never send it.

use core::fmt::Write as _;

use can_wire::Frame;
use embedded_can::Id;
use heapless::Deque;
use slcan::line::Line;
use slcan::{Adapter, FrameKind, LineBuffer, Outcome, StatusFlags, LINE_MAX};

use crate::hw::{Uart, UartError};

/// Capacity of the output ring, bytes: a few lines.
const OUT_CAP: usize = 512;

/// What arrived on the port.
pub enum Input {
    /// A frame the host put on the bus, and when its line began (µs of the SysTick clock).
    Frame(Frame, u64),
    /// The `?` diagnostics request.
    Diagnostics,
}

/// The SLCAN port.
pub struct CanPort {
    lines: LineBuffer,
    adapter: Adapter,
    out: Deque<u8, OUT_CAP>,
    /// Bridge frames dropped while the channel was closed.
    pub closed_drops: u32,
    /// Bytes lost on UART1's receive side.
    pub rx_overruns: u32,
    /// When the first byte of the line being read arrived, µs.
    line_start_us: Option<u64>,
}

impl CanPort {
    /// A closed port.
    pub fn new(version: [u8; 4], serial: [u8; 4]) -> Self {
        Self {
            lines: LineBuffer::new(),
            adapter: Adapter::new(version, serial, true),
            out: Deque::new(),
            closed_drops: 0,
            rx_overruns: 0,
            line_start_us: None,
        }
    }

    /// Latches SLCAN status flags for the next `F`.
    pub fn raise(&mut self, flags: StatusFlags) {
        self.adapter.raise(flags);
    }

    /// Whether there is room for one more line of output.
    pub fn has_room(&self) -> bool {
        OUT_CAP - self.out.len() >= LINE_MAX
    }

    /// Whether there is room for one more frame line while keeping room for the answer
    /// to a command (so frames never starve the host's commands).
    pub fn has_room_for_frame(&self) -> bool {
        OUT_CAP - self.out.len() >= 2 * LINE_MAX
    }

    /// Whether output is waiting for the UART.
    pub fn has_output(&self) -> bool {
        !self.out.is_empty()
    }

    /// Reads what the host sent, up to the end of one line, and answers it. Returns what
    /// the line asked for beyond an answer. Reads nothing while the output ring has no
    /// room for an answer (the host waits; QEMU holds its bytes back).
    pub fn receive(&mut self, uart: &mut Uart) -> Option<Input> {
        while self.has_room() {
            let byte = match uart.try_read() {
                Ok(Some(b)) => b,
                Ok(None) => return None,
                Err(UartError::Overrun) => {
                    self.rx_overruns = self.rx_overruns.wrapping_add(1);
                    self.adapter.raise(StatusFlags::DATA_OVERRUN);
                    continue;
                }
            };
            // A frame was on the bus when the host wrote its line: the line's first byte
            // is the nearest this port sees of it. The characters after it are the serial
            // link's time (a longer frame's line takes longer), not the bus's.
            let start = *self.line_start_us.get_or_insert_with(now_us);
            let (_, line) = self.lines.feed(&[byte]);
            let Some(line) = line else { continue };
            self.line_start_us = None;
            if let Line::Text([b'?', ..]) = line {
                return Some(Input::Diagnostics);
            }
            let outcome = self.adapter.line(line);
            self.reply(&outcome.reply());
            if let Outcome::Transmit(frame, _) = outcome {
                if frame.kind() == FrameKind::Remote {
                    // The protocol has no remote frames; nobody answers them.
                    return None;
                }
                let fd = frame.kind().is_fd();
                return Frame::new(frame.id(), frame.data(), fd)
                    .ok()
                    .map(|f| Input::Frame(f, start));
            }
        }
        None
    }

    fn reply(&mut self, reply: &slcan::Reply) {
        let mut buf = [0u8; LINE_MAX];
        if let Ok(n) = reply.emit(&mut buf) {
            self.push(buf.get(..n).unwrap_or_default());
        }
    }

    fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if self.out.push_back(b).is_err() {
                break;
            }
        }
    }

    /// Queues one bridge frame as an SLCAN line (if open; else counts it as dropped).
    /// The caller checks [`CanPort::has_room`] first.
    pub fn send(&mut self, frame: &Frame, now_ms: u32) {
        let kind = if frame.is_fd() {
            FrameKind::FdBrs
        } else {
            FrameKind::Data
        };
        let Ok(line) = slcan::Frame::new(frame.id(), kind, frame.data()) else {
            return;
        };
        let mut buf = [0u8; LINE_MAX];
        match self.adapter.received(&line, now_ms, &mut buf) {
            Some(n) => self.push(buf.get(..n).unwrap_or_default()),
            None => self.closed_drops = self.closed_drops.wrapping_add(1),
        }
    }

    /// Queues a text line (diagnostics), CR added.
    pub fn text(&mut self, args: core::fmt::Arguments<'_>) {
        struct Ring<'a>(&'a mut Deque<u8, OUT_CAP>);
        impl core::fmt::Write for Ring<'_> {
            fn write_str(&mut self, s: &str) -> core::fmt::Result {
                for &b in s.as_bytes() {
                    self.0.push_back(b).map_err(|_| core::fmt::Error)?;
                }
                Ok(())
            }
        }
        let mut ring = Ring(&mut self.out);
        let _ = ring.write_fmt(args);
        let _ = ring.0.push_back(slcan::CR);
    }

    /// Moves queued output into UART1 while it takes bytes; returns the bytes moved.
    pub fn flush(&mut self, uart: &mut Uart) -> usize {
        let mut n = 0;
        while let Some(&b) = self.out.front() {
            if !uart.try_write(b) {
                break;
            }
            self.out.pop_front();
            n += 1;
        }
        n
    }
}

/// The SysTick clock in µs.
fn now_us() -> u64 {
    crate::hw::ticks() / u64::from(crate::hw::TICKS_PER_MS / 1000)
}

/// The identifier's kind in the bridge's window, for the board's bookkeeping.
pub fn kind(ids: &can_wire::NodeIds, id: Id) -> Option<can_wire::Kind> {
    ids.window().classify(id).map(|(_, k)| k)
}

/// The CAN side of one pass of a board's loop: a frame from the SLCAN host goes to the
/// bridge, stamped in µs of the SysTick clock when its line began (so a time master's
/// SYNC, SPEC 9, is taken at that resolution, and a FOLLOW-UP's longer line does not
/// make it later than its SYNC); then the bridge's frames go out as far as the port has room,
/// each metered. True when the host asked for the diagnostics line (`?`), which the
/// board writes.
pub fn serve<const Q: usize>(
    port: &mut CanPort,
    can: &mut Uart,
    bridge: &mut bridge::engine::Bridge<Q>,
    meter: &mut crate::meter::Meter,
    now_ms: u32,
) -> bool {
    let diagnostics = match port.receive(can) {
        Some(Input::Frame(frame, line_start_us)) => {
            bridge.on_can_frame_at(&frame, line_start_us);
            false
        }
        Some(Input::Diagnostics) => true,
        None => false,
    };
    let ids = bridge.config().ids;
    port.flush(can);
    while port.has_room_for_frame() {
        let Some(frame) = bridge.pop_frame() else {
            break;
        };
        let kind = kind(&ids, frame.id());
        let ((), ticks) = crate::hw::measure(|| port.send(&frame, now_ms));
        meter.frame(kind, crate::hw::ticks(), ticks, bridge.stats());
        port.flush(can);
    }
    diagnostics
}
