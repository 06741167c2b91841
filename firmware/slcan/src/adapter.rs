//! The adapter side as a state machine: what a USB-CAN adapter does with each command
//! line, sans-IO. The board moves bytes; this decides the answers.
//!
//! - The channel starts closed. `O` (or `L`, listen-only) opens it, `C` closes it.
//!   `O`/`L` on an open channel is an error (BEL); `C` on a closed one is OK, as the
//!   CAN FD adapters answer (clients send `C` first to be sure).
//! - `S`, `Y` and `Z` only while closed. Without `S` the board's default bit rate holds.
//! - A frame to transmit needs the channel open in normal mode; classic frames are
//!   answered `z`/`Z`, CAN FD frames CR. CAN FD frames and `Y` need an FD adapter.
//! - `F` (channel open) answers the latched [`StatusFlags`] and clears them.
//! - Received frames go to the host only while the channel is open.

use crate::command::{Command, BIT_RATES, DATA_BIT_RATES};
use crate::frame::Frame;
use crate::line::Line;
use crate::reply::Reply;
use crate::Error;

/// How the channel is open.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// Sending and receiving.
    Normal,
    /// Receiving only.
    ListenOnly,
}

/// The Lawicel status flags (`F`), latched until read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StatusFlags(pub u8);

impl StatusFlags {
    /// Bit 0: a received frame was lost (receive FIFO full).
    pub const RX_FIFO_FULL: StatusFlags = StatusFlags(1 << 0);
    /// Bit 1: a frame to send was lost (transmit FIFO full).
    pub const TX_FIFO_FULL: StatusFlags = StatusFlags(1 << 1);
    /// Bit 2: error warning (an error counter reached 96).
    pub const ERROR_WARNING: StatusFlags = StatusFlags(1 << 2);
    /// Bit 3: data overrun (bytes lost on the serial line or in the controller).
    pub const DATA_OVERRUN: StatusFlags = StatusFlags(1 << 3);
    /// Bit 5: error passive.
    pub const ERROR_PASSIVE: StatusFlags = StatusFlags(1 << 5);
    /// Bit 6: arbitration lost.
    pub const ARBITRATION_LOST: StatusFlags = StatusFlags(1 << 6);
    /// Bit 7: bus error.
    pub const BUS_ERROR: StatusFlags = StatusFlags(1 << 7);

    /// Both sets of flags.
    pub const fn union(self, other: StatusFlags) -> StatusFlags {
        StatusFlags(self.0 | other.0)
    }

    /// Whether every flag of `other` is set here.
    pub const fn contains(self, other: StatusFlags) -> bool {
        self.0 & other.0 == other.0
    }
}

/// What the board does after a command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Send this reply to the host.
    Reply(Reply),
    /// Put this frame on the bus, then send the reply.
    Transmit(Frame, Reply),
}

impl Outcome {
    /// The reply to send.
    pub fn reply(&self) -> Reply {
        match self {
            Outcome::Reply(r) | Outcome::Transmit(_, r) => *r,
        }
    }
}

/// An SLCAN adapter's state.
#[derive(Debug, Clone)]
pub struct Adapter {
    open: Option<Mode>,
    bit_rate: Option<u8>,
    data_bit_rate: Option<u8>,
    timestamps: bool,
    fd: bool,
    version: [u8; 4],
    serial: [u8; 4],
    flags: StatusFlags,
    errors: u32,
}

impl Adapter {
    /// A closed adapter answering `V` with `version` and `N` with `serial` (4 printable
    /// characters each); `fd` when it handles CAN FD frames.
    pub const fn new(version: [u8; 4], serial: [u8; 4], fd: bool) -> Self {
        Self {
            open: None,
            bit_rate: None,
            data_bit_rate: None,
            timestamps: false,
            fd,
            version,
            serial,
            flags: StatusFlags(0),
            errors: 0,
        }
    }

    /// Handles one line from [`crate::LineBuffer`]: parse errors and BEL are answered
    /// BEL and counted.
    pub fn line(&mut self, line: Line<'_>) -> Outcome {
        let result = match line {
            Line::Text(text) => Command::parse(text).and_then(|c| self.command(c)),
            Line::Bell => Err(Error::UnknownCommand(crate::BEL)),
            Line::Error(e) => Err(e),
        };
        result.unwrap_or_else(|_| {
            self.errors = self.errors.wrapping_add(1);
            Outcome::Reply(Reply::Error)
        })
    }

    /// Executes one command.
    pub fn command(&mut self, cmd: Command) -> Result<Outcome, Error> {
        let ok = Ok(Outcome::Reply(Reply::Ok));
        let closed = |s: &Self| {
            if s.open.is_some() {
                Err(Error::AlreadyOpen)
            } else {
                Ok(())
            }
        };
        match cmd {
            Command::Open | Command::ListenOnly => {
                closed(self)?;
                self.open = Some(if cmd == Command::Open {
                    Mode::Normal
                } else {
                    Mode::ListenOnly
                });
                ok
            }
            Command::Close => {
                self.open = None;
                ok
            }
            Command::BitRate(n) => {
                closed(self)?;
                if usize::from(n) >= BIT_RATES.len() {
                    return Err(Error::BadBitRate);
                }
                self.bit_rate = Some(n);
                ok
            }
            Command::DataBitRate(n) => {
                closed(self)?;
                if !self.fd {
                    return Err(Error::FdNotSupported);
                }
                if usize::from(n) >= DATA_BIT_RATES.len() {
                    return Err(Error::BadBitRate);
                }
                self.data_bit_rate = Some(n);
                ok
            }
            Command::Timestamps(on) => {
                closed(self)?;
                self.timestamps = on;
                ok
            }
            Command::Version => Ok(Outcome::Reply(Reply::Version(self.version))),
            Command::SerialNumber => Ok(Outcome::Reply(Reply::SerialNumber(self.serial))),
            Command::StatusFlags => {
                if self.open.is_none() {
                    return Err(Error::NotOpen);
                }
                let flags = core::mem::take(&mut self.flags);
                Ok(Outcome::Reply(Reply::Flags(flags.0)))
            }
            Command::Transmit(frame) => {
                match self.open {
                    None => return Err(Error::NotOpen),
                    Some(Mode::ListenOnly) => return Err(Error::ListenOnly),
                    Some(Mode::Normal) => {}
                }
                if frame.kind().is_fd() {
                    if !self.fd {
                        return Err(Error::FdNotSupported);
                    }
                    return Ok(Outcome::Transmit(frame, Reply::Ok));
                }
                let extended = matches!(frame.id(), embedded_can::Id::Extended(_));
                Ok(Outcome::Transmit(frame, Reply::Transmitted { extended }))
            }
            Command::Empty => ok,
        }
    }

    /// Latches status flags for the next `F`.
    pub fn raise(&mut self, flags: StatusFlags) {
        self.flags = self.flags.union(flags);
    }

    /// The flags latched so far (not cleared).
    pub fn flags(&self) -> StatusFlags {
        self.flags
    }

    /// How the channel is open, if it is.
    pub fn mode(&self) -> Option<Mode> {
        self.open
    }

    /// Whether the channel is open (either mode).
    pub fn is_open(&self) -> bool {
        self.open.is_some()
    }

    /// The nominal bit rate set with `S`, bit/s.
    pub fn bit_rate(&self) -> Option<u32> {
        self.bit_rate
            .and_then(|n| BIT_RATES.get(usize::from(n)).copied())
    }

    /// The CAN FD data bit rate set with `Y`, bit/s.
    pub fn data_bit_rate(&self) -> Option<u32> {
        self.data_bit_rate
            .and_then(|n| DATA_BIT_RATES.get(usize::from(n)).copied())
    }

    /// Whether received frames carry timestamps.
    pub fn timestamps(&self) -> bool {
        self.timestamps
    }

    /// Command lines answered with BEL so far.
    pub fn errors(&self) -> u32 {
        self.errors
    }

    /// The line for a frame received from the bus at `now_ms`, written into `buf`; `None`
    /// while the channel is closed (the frame is not for the host).
    pub fn received(&self, frame: &Frame, now_ms: u32, buf: &mut [u8]) -> Option<usize> {
        self.open?;
        let ts = self.timestamps.then_some((now_ms % 60_000) as u16);
        frame.emit(ts, buf).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::line::LineBuffer;
    use crate::FrameKind;
    use embedded_can::{Id, StandardId};

    /// Feeds `input` to an adapter; returns every byte it answers and the frames it sends.
    fn run(adapter: &mut Adapter, input: &[u8]) -> (Vec<u8>, Vec<Frame>) {
        let mut lb = LineBuffer::new();
        let mut out = Vec::new();
        let mut sent = Vec::new();
        let mut rest = input;
        while !rest.is_empty() {
            let (used, line) = lb.feed(rest);
            rest = &rest[used..];
            if let Some(line) = line {
                let outcome = adapter.line(line);
                if let Outcome::Transmit(f, _) = outcome {
                    sent.push(f);
                }
                let mut buf = [0u8; crate::LINE_MAX];
                let n = outcome.reply().emit(&mut buf).unwrap();
                out.extend_from_slice(&buf[..n]);
            }
        }
        (out, sent)
    }

    #[test]
    fn session_golden_bytes() {
        let mut a = Adapter::new(*b"0100", *b"QEMU", false);
        // python-can's opening sequence (C, S8, an empty line, O), then a frame, V, N, F.
        let (out, sent) = run(&mut a, b"C\rS8\r\rO\rt10041407040A\rV\rN\rF\r");
        assert_eq!(out, b"\r\r\r\rz\rV0100\rNQEMU\rF00\r");
        assert_eq!(sent.len(), 1);
        assert_eq!(sent[0].data(), &[0x14, 0x07, 0x04, 0x0A]);
        assert_eq!(a.bit_rate(), Some(1_000_000));
        assert!(a.is_open());
    }

    #[test]
    fn state_errors_answer_bel() {
        let mut a = Adapter::new(*b"0100", *b"QEMU", false);
        // Closed: no transmit, no F. Unknown command, bad rate, FD on a classic adapter.
        let (out, sent) = run(&mut a, b"t1000\rF\rX\rS9\rY2\rd1000\r");
        assert_eq!(out, [crate::BEL; 6]);
        assert!(sent.is_empty());
        assert_eq!(a.errors(), 6);
        // Open: no S, no second O.
        let (out, _) = run(&mut a, b"O\rS6\rO\rL\rZ1\r");
        assert_eq!(out, b"\r\x07\x07\x07\x07");
        // Listen-only refuses to transmit.
        let (out, sent) = run(&mut a, b"C\rL\rt1000\r");
        assert_eq!(out, b"\r\r\x07");
        assert!(sent.is_empty());
        assert_eq!(a.mode(), Some(Mode::ListenOnly));
    }

    #[test]
    fn fd_adapter_and_flags() {
        let mut a = Adapter::new(*b"0100", *b"QEMU", true);
        let (out, sent) = run(
            &mut a,
            b"S8\rY5\rZ1\rO\rb1009000102030405060708090A0B\rT000001001AA\r",
        );
        assert_eq!(out, b"\r\r\r\r\rZ\r");
        assert_eq!(sent[0].kind(), FrameKind::FdBrs);
        assert_eq!(sent[0].data().len(), 12);
        assert_eq!(a.data_bit_rate(), Some(5_000_000));
        a.raise(StatusFlags::TX_FIFO_FULL);
        a.raise(StatusFlags::DATA_OVERRUN);
        assert!(a.flags().contains(StatusFlags::TX_FIFO_FULL));
        let (out, _) = run(&mut a, b"F\rF\r");
        assert_eq!(out, b"F0A\rF00\r");
        // Timestamps are on: received frames carry the ms clock modulo 60000.
        let f = Frame::new(
            Id::Standard(StandardId::new(0x120).unwrap()),
            FrameKind::Data,
            &[7],
        )
        .unwrap();
        let mut buf = [0u8; crate::LINE_MAX];
        let n = a.received(&f, 60_255, &mut buf).unwrap();
        assert_eq!(&buf[..n], b"t12010700FF\r");
        let (out, _) = run(&mut a, b"C\r");
        assert_eq!(out, b"\r");
        assert_eq!(a.received(&f, 0, &mut buf), None);
    }
}
