//! CAN ports of the live bridge: a candump log (file or standard output), an SLCAN
//! adapter (serial device or TCP socket), and SocketCAN (Linux, feature `socketcan`).

use std::io::{self, BufWriter, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use can_wire::Frame;

use crate::candump::{write_record, Record};

/// A CAN port: frames out, control frames in.
pub trait CanPort {
    /// Transmits a frame.
    fn send(&mut self, frame: &Frame) -> anyhow::Result<()>;
    /// A received frame, if one is waiting (never blocks long).
    fn recv(&mut self) -> anyhow::Result<Option<Frame>>;
    /// What the port is, for messages.
    fn describe(&self) -> String;
}

/// Opens a port from its spec: `candump:-`, `candump:FILE`, `slcan:DEVICE[@BAUD]`,
/// `slcan:tcp://HOST:PORT`, `socketcan:IFACE`. `nominal` is the bus bit rate (SLCAN `S`
/// command); `fd` opens FD frames with bit-rate switch.
pub fn open(spec: &str, nominal: u32, data: u32, fd: bool) -> anyhow::Result<Box<dyn CanPort>> {
    if let Some(path) = spec.strip_prefix("candump:") {
        return Ok(Box::new(CandumpPort::open(path)?));
    }
    if let Some(rest) = spec.strip_prefix("slcan:") {
        return Ok(Box::new(SlcanPort::open(rest, nominal, data, fd)?));
    }
    if let Some(iface) = spec.strip_prefix("socketcan:") {
        return socketcan_port(iface);
    }
    bail!("unknown CAN port {spec:?}: use candump:FILE|-, slcan:DEVICE[@BAUD], slcan:tcp://HOST:PORT or socketcan:IFACE")
}

/// Frames written as a candump log (`(sec.usec) can0 ID#DATA`); receives nothing.
pub struct CandumpPort {
    out: Box<dyn Write>,
    start: Instant,
    name: String,
}

impl CandumpPort {
    /// `-` is standard output.
    pub fn open(path: &str) -> anyhow::Result<Self> {
        let out: Box<dyn Write> = if path == "-" || path.is_empty() {
            Box::new(io::stdout())
        } else {
            Box::new(BufWriter::new(
                std::fs::File::create(path).with_context(|| format!("creating {path}"))?,
            ))
        };
        Ok(Self {
            out,
            start: Instant::now(),
            name: if path.is_empty() {
                "-".into()
            } else {
                path.into()
            },
        })
    }
}

impl CanPort for CandumpPort {
    fn send(&mut self, frame: &Frame) -> anyhow::Result<()> {
        let t = self.start.elapsed().as_micros() as u64;
        write_record(
            &mut self.out,
            &Record::from_frame(t, "can0", frame, frame.is_fd()),
        )?;
        self.out.flush()?;
        Ok(())
    }

    fn recv(&mut self) -> anyhow::Result<Option<Frame>> {
        Ok(None)
    }

    fn describe(&self) -> String {
        format!("candump log {}", self.name)
    }
}

/// A byte stream to an SLCAN adapter.
trait Stream: Read + Write {}
impl<T: Read + Write> Stream for T {}

/// An SLCAN (Lawicel) adapter: `S`/`Y` bit rates, `O` to open, frames as `t`/`d`/`b`
/// lines; received frames (control frames for the bridge) read back.
pub struct SlcanPort {
    io: Box<dyn Stream>,
    lines: slcan::LineBuffer,
    pending: Vec<u8>,
    name: String,
    fd: bool,
}

impl SlcanPort {
    /// `DEVICE[@BAUD]` (serial, default 115200 bit/s) or `tcp://HOST:PORT`.
    pub fn open(spec: &str, nominal: u32, data: u32, fd: bool) -> anyhow::Result<Self> {
        let io: Box<dyn Stream> = if let Some(addr) = spec.strip_prefix("tcp://") {
            let s = TcpStream::connect(addr)
                .with_context(|| format!("connecting to the SLCAN port at {addr}"))?;
            s.set_read_timeout(Some(Duration::from_millis(1)))?;
            s.set_nodelay(true)?;
            Box::new(s)
        } else {
            let (path, baud) = match spec.rsplit_once('@') {
                Some((p, b)) => (p, b.parse().context("SLCAN serial bit rate")?),
                None => (spec, 115_200),
            };
            Box::new(
                serialport::new(path, baud)
                    .timeout(Duration::from_millis(1))
                    .open()
                    .with_context(|| format!("opening SLCAN adapter {path}"))?,
            )
        };
        let mut port = Self {
            io,
            lines: slcan::LineBuffer::new(),
            pending: Vec::new(),
            name: format!("SLCAN {spec}"),
            fd,
        };
        let Some(s) = slcan::Command::bit_rate_index(nominal) else {
            bail!("SLCAN has no S command for {nominal} bit/s");
        };
        port.command(&slcan::Command::Close)?;
        port.command(&slcan::Command::BitRate(s))?;
        if fd {
            let y = slcan::command::DATA_BIT_RATES
                .iter()
                .position(|&r| r == data)
                .and_then(|i| u8::try_from(i).ok());
            let Some(y) = y else {
                bail!("SLCAN has no Y command for a {data} bit/s data phase");
            };
            port.command(&slcan::Command::DataBitRate(y))?;
        }
        port.command(&slcan::Command::Open)?;
        Ok(port)
    }

    fn command(&mut self, cmd: &slcan::Command) -> anyhow::Result<()> {
        let mut buf = [0u8; slcan::LINE_MAX];
        let n = cmd
            .emit(&mut buf)
            .map_err(|e| anyhow::anyhow!("SLCAN command: {e:?}"))?;
        self.io.write_all(buf.get(..n).unwrap_or(&[]))?;
        self.io.flush()?;
        Ok(())
    }
}

impl CanPort for SlcanPort {
    fn send(&mut self, frame: &Frame) -> anyhow::Result<()> {
        let kind = if !frame.is_fd() {
            slcan::FrameKind::Data
        } else if self.fd {
            slcan::FrameKind::FdBrs
        } else {
            slcan::FrameKind::Fd
        };
        let f = slcan::Frame::new(frame.id(), kind, frame.data())
            .map_err(|e| anyhow::anyhow!("SLCAN frame: {e:?}"))?;
        self.command(&slcan::Command::Transmit(f))
    }

    fn recv(&mut self) -> anyhow::Result<Option<Frame>> {
        let mut buf = [0u8; 512];
        match self.io.read(&mut buf) {
            Ok(0) => bail!("the SLCAN port closed"),
            Ok(n) => self.pending.extend_from_slice(buf.get(..n).unwrap_or(&[])),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(e.into()),
        }
        while !self.pending.is_empty() {
            let (used, line) = self.lines.feed(&self.pending);
            let frame = match line {
                Some(slcan::line::Line::Text(text)) => match slcan::Reply::parse(text) {
                    Ok(slcan::Reply::Frame(f, _)) => {
                        let fd = matches!(f.kind(), slcan::FrameKind::Fd | slcan::FrameKind::FdBrs);
                        Frame::new(f.id(), f.data(), fd).ok()
                    }
                    _ => None,
                },
                _ => None,
            };
            self.pending.drain(..used);
            if frame.is_some() {
                return Ok(frame);
            }
            if used == 0 {
                break;
            }
        }
        Ok(None)
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}

#[cfg(all(target_os = "linux", feature = "socketcan"))]
fn socketcan_port(iface: &str) -> anyhow::Result<Box<dyn CanPort>> {
    Ok(Box::new(socket::SocketCanPort::open(iface)?))
}

#[cfg(not(all(target_os = "linux", feature = "socketcan")))]
fn socketcan_port(iface: &str) -> anyhow::Result<Box<dyn CanPort>> {
    bail!("socketcan:{iface}: this build has no SocketCAN support (Linux, `--features socketcan`)")
}

#[cfg(all(target_os = "linux", feature = "socketcan"))]
mod socket {
    //! SocketCAN through the `socketcan` crate (CAN FD sockets take classic frames too).

    use anyhow::Context;
    use can_wire::Frame;
    use socketcan::{CanAnyFrame, CanFdFrame, CanFdSocket, CanFrame, EmbeddedFrame, Socket};

    use super::CanPort;

    /// A CAN FD raw socket on an interface.
    pub struct SocketCanPort {
        socket: CanFdSocket,
        iface: String,
    }

    impl SocketCanPort {
        /// Opens `iface` (e.g. `can0`) non-blocking.
        pub fn open(iface: &str) -> anyhow::Result<Self> {
            let socket =
                CanFdSocket::open(iface).with_context(|| format!("opening SocketCAN {iface}"))?;
            socket.set_nonblocking(true)?;
            Ok(Self {
                socket,
                iface: iface.to_owned(),
            })
        }
    }

    impl CanPort for SocketCanPort {
        fn send(&mut self, frame: &Frame) -> anyhow::Result<()> {
            if frame.is_fd() {
                let f = CanFdFrame::new(frame.id(), frame.data())
                    .context("frame does not fit a CAN FD frame")?;
                self.socket.write_frame(&f)?;
            } else {
                let f = CanFrame::new(frame.id(), frame.data())
                    .context("frame does not fit a classic frame")?;
                self.socket.write_frame(&f)?;
            }
            Ok(())
        }

        fn recv(&mut self) -> anyhow::Result<Option<Frame>> {
            match self.socket.read_frame() {
                Ok(CanAnyFrame::Normal(f)) => Ok(Frame::new(f.id(), f.data(), false).ok()),
                Ok(CanAnyFrame::Fd(f)) => Ok(Frame::new(f.id(), f.data(), true).ok()),
                Ok(_) => Ok(None),
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(None),
                Err(e) => Err(e.into()),
            }
        }

        fn describe(&self) -> String {
            format!("SocketCAN {}", self.iface)
        }
    }
}
