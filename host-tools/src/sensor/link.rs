//! Byte links to a sensor, all with timeouts: TCP, a serial device, an in-process
//! simulator; and a wrapper that records both directions.

use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context};

use super::record_file::{Direction, RecordWriter};
use super::spec::SensorSpec;
use crate::sim::transport::Clock;
use crate::sim::Sensor;

/// A two-way byte link.
pub trait Link: Send {
    /// Writes all of `bytes`.
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what arrives within `timeout`: `Ok(0)` when nothing did; an
    /// `UnexpectedEof` error when the other side closed the link.
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
    /// Changes the host side's bit rate (serial links; others ignore it).
    fn set_bit_rate(&mut self, _rate: u32) -> io::Result<()> {
        Ok(())
    }
    /// The host side's bit rate, for serial links.
    fn bit_rate(&self) -> Option<u32> {
        None
    }
    /// What the link is, for messages.
    fn describe(&self) -> String;
}

fn eof() -> io::Error {
    io::Error::new(
        io::ErrorKind::UnexpectedEof,
        "the sensor closed the connection",
    )
}

/// A TCP connection (Ethernet sensors, `scip2can sim`).
#[derive(Debug)]
pub struct TcpLink {
    stream: TcpStream,
    addr: String,
}

impl TcpLink {
    /// Connects within `timeout`, with clear errors for refused and unreachable hosts.
    pub fn connect(addr: &str, timeout: Duration) -> anyhow::Result<Self> {
        let addrs: Vec<_> = addr
            .to_socket_addrs()
            .with_context(|| format!("cannot resolve {addr}"))?
            .collect();
        let mut last = None;
        for a in addrs {
            match TcpStream::connect_timeout(&a, timeout) {
                Ok(stream) => {
                    stream.set_nodelay(true)?;
                    return Ok(Self {
                        stream,
                        addr: addr.to_owned(),
                    });
                }
                Err(e) => last = Some(e),
            }
        }
        let e = last.ok_or_else(|| anyhow!("{addr} resolves to no address"))?;
        Err(match e.kind() {
            io::ErrorKind::ConnectionRefused => {
                anyhow!("connection refused by {addr}: no sensor listens there")
            }
            io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock => {
                anyhow!("no answer from {addr} within {timeout:?}: wrong address or sensor off")
            }
            _ => anyhow!("cannot connect to {addr}: {e}"),
        })
    }
}

impl Link for TcpLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.stream.write_all(bytes)
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.stream
            .set_read_timeout(Some(timeout.max(Duration::from_millis(1))))?;
        match self.stream.read(buf) {
            Ok(0) => Err(eof()),
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(0)
            }
            Err(e) if e.kind() == io::ErrorKind::ConnectionReset => Err(eof()),
            Err(e) => Err(e),
        }
    }

    fn describe(&self) -> String {
        format!("tcp://{}", self.addr)
    }
}

/// A serial device (RS-232, USB CDC, a pseudo-terminal).
pub struct SerialLink {
    port: Box<dyn serialport::SerialPort>,
    path: String,
    rate: u32,
}

impl core::fmt::Debug for SerialLink {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "SerialLink({}, {} bit/s)", self.path, self.rate)
    }
}

impl SerialLink {
    /// Opens `path` at `rate` bit/s, 8N1.
    pub fn open(path: &str, rate: u32) -> anyhow::Result<Self> {
        let port = serialport::new(path, rate)
            .timeout(Duration::from_millis(100))
            .open()
            .with_context(|| format!("cannot open serial device {path}"))?;
        Ok(Self {
            port,
            path: path.to_owned(),
            rate,
        })
    }
}

impl Link for SerialLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.port
            .set_timeout(timeout.max(Duration::from_millis(1)))
            .map_err(io::Error::other)?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }

    fn set_bit_rate(&mut self, rate: u32) -> io::Result<()> {
        self.port.set_baud_rate(rate).map_err(io::Error::other)?;
        self.rate = rate;
        Ok(())
    }

    fn bit_rate(&self) -> Option<u32> {
        Some(self.rate)
    }

    fn describe(&self) -> String {
        format!("{} at {} bit/s", self.path, self.rate)
    }
}

/// A simulator in this process, driven by the real clock (× its speed).
#[derive(Debug)]
pub struct SimLink {
    sensor: Sensor,
    clock: Clock,
    pending: Vec<u8>,
}

impl SimLink {
    /// A link to `sensor`, whose time runs `speed` times faster than real time.
    pub fn new(sensor: Sensor, speed: f64) -> Self {
        Self {
            sensor,
            clock: Clock::new(speed),
            pending: Vec::new(),
        }
    }

    /// The simulated sensor (e.g. for its fault log).
    pub fn sensor(&self) -> &Sensor {
        &self.sensor
    }
}

impl Link for SimLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.sensor.receive(self.clock.now_us(), bytes);
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let deadline = Instant::now() + timeout;
        while self.pending.is_empty() {
            let out = self.sensor.take_output(self.clock.now_us());
            if !out.is_empty() {
                self.pending = out;
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(0);
            }
            let wake = self
                .sensor
                .next_wakeup()
                .map_or(Duration::from_millis(5), |at| self.clock.until(at));
            std::thread::sleep(wake.min(deadline - now).min(Duration::from_millis(5)));
        }
        let n = self.pending.len().min(buf.len());
        buf.get_mut(..n)
            .unwrap_or(&mut [])
            .copy_from_slice(self.pending.get(..n).unwrap_or(&[]));
        self.pending.drain(..n);
        Ok(n)
    }

    fn describe(&self) -> String {
        format!("simulated {}", self.sensor.model().kind.name())
    }
}

/// A link that writes both directions to a record file.
pub struct RecordingLink<W: Write + Send> {
    inner: Box<dyn Link>,
    record: RecordWriter<W>,
    start: Instant,
}

impl<W: Write + Send> RecordingLink<W> {
    /// Records `inner` into `record`; times count from now.
    pub fn new(inner: Box<dyn Link>, record: RecordWriter<W>) -> Self {
        Self {
            inner,
            record,
            start: Instant::now(),
        }
    }

    fn t_us(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_micros()).unwrap_or(u64::MAX)
    }
}

impl<W: Write + Send> Link for RecordingLink<W> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let t = self.t_us();
        self.record.chunk(Direction::ToSensor, t, bytes)?;
        self.inner.send(bytes)
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let n = self.inner.recv(buf, timeout)?;
        let t = self.t_us();
        self.record
            .chunk(Direction::FromSensor, t, buf.get(..n).unwrap_or(&[]))?;
        if n > 0 {
            self.record.flush()?;
        }
        Ok(n)
    }

    fn set_bit_rate(&mut self, rate: u32) -> io::Result<()> {
        self.inner.set_bit_rate(rate)
    }

    fn bit_rate(&self) -> Option<u32> {
        self.inner.bit_rate()
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }
}

/// Opens the link a spec names.
pub fn open(spec: &SensorSpec, timeout: Duration) -> anyhow::Result<Box<dyn Link>> {
    Ok(match spec {
        SensorSpec::Tcp(addr) => Box::new(TcpLink::connect(addr, timeout)?),
        SensorSpec::Serial { path, baud } => Box::new(SerialLink::open(path, *baud)?),
        SensorSpec::Sim(options) => Box::new(SimLink::new(options.build()?, options.speed)),
    })
}
