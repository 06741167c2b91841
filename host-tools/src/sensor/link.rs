//! Byte links to a sensor, all with timeouts: TCP, a serial device, an in-process
//! simulator; and a wrapper that records both directions.

use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
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

/// Simulated time that a [`SimLink`] shares with the loop driving it: µs that advance
/// only while the link waits for the sensor, straight to the sensor's next event, so that
/// a run takes as long as its work and comes out the same on any host
/// (`scip2can bridge --virtual-time`).
#[derive(Debug, Clone, Default)]
pub struct VirtualClock(Arc<AtomicU64>);

impl VirtualClock {
    /// A clock at 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// µs since the clock was made.
    pub fn now_us(&self) -> u64 {
        self.0.load(Ordering::SeqCst)
    }

    /// Moves the clock on to `t_us` (never back).
    fn advance_to(&self, t_us: u64) {
        self.0.fetch_max(t_us, Ordering::SeqCst);
    }
}

/// What a [`SimLink`]'s sensor runs on.
#[derive(Debug)]
enum SimTime {
    /// The host's clock, times the speed.
    Real(Clock),
    /// A [`VirtualClock`], times the speed.
    Virtual { clock: VirtualClock, speed: f64 },
}

impl SimTime {
    /// Sensor µs now.
    fn now_us(&self) -> u64 {
        match self {
            SimTime::Real(clock) => clock.now_us(),
            SimTime::Virtual { clock, speed } => (clock.now_us() as f64 * speed) as u64,
        }
    }
}

/// A simulator in this process, driven by the real clock (× its speed) or by a
/// [`VirtualClock`].
#[derive(Debug)]
pub struct SimLink {
    sensor: Sensor,
    time: SimTime,
    pending: Vec<u8>,
}

impl SimLink {
    /// A link to `sensor`, whose time runs `speed` times faster than real time.
    pub fn new(sensor: Sensor, speed: f64) -> Self {
        Self {
            sensor,
            time: SimTime::Real(Clock::new(speed)),
            pending: Vec::new(),
        }
    }

    /// A link to `sensor` on `clock`: its time runs `speed` times faster than the
    /// clock's, and waiting for it moves the clock on instead of sleeping.
    pub fn on_virtual_clock(sensor: Sensor, speed: f64, clock: VirtualClock) -> Self {
        let speed = if speed > 0.0 { speed } else { 1.0 };
        Self {
            sensor,
            time: SimTime::Virtual { clock, speed },
            pending: Vec::new(),
        }
    }

    /// The simulated sensor (e.g. for its fault log).
    pub fn sensor(&self) -> &Sensor {
        &self.sensor
    }

    /// Waits on the virtual clock for the sensor's next bytes, at most `timeout` of it.
    fn wait_virtual(&mut self, clock: &VirtualClock, speed: f64, timeout: Duration) {
        let deadline = clock
            .now_us()
            .saturating_add(u64::try_from(timeout.as_micros()).unwrap_or(u64::MAX));
        loop {
            let now = clock.now_us();
            let out = self.sensor.take_output((now as f64 * speed) as u64);
            if !out.is_empty() {
                self.pending = out;
                return;
            }
            if now >= deadline {
                return;
            }
            // The first clock µs at which the sensor's next event is due; at least
            // 1 µs on, so that an event that keeps nothing for the host cannot stall.
            let wake = self
                .sensor
                .next_wakeup()
                .map_or(deadline, |at| (at as f64 / speed).ceil() as u64);
            clock.advance_to(wake.clamp(now.saturating_add(1), deadline));
        }
    }
}

impl Link for SimLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.sensor.receive(self.time.now_us(), bytes);
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        match &self.time {
            SimTime::Virtual { clock, speed } => {
                if self.pending.is_empty() {
                    let (clock, speed) = (clock.clone(), *speed);
                    self.wait_virtual(&clock, speed, timeout);
                }
            }
            SimTime::Real(clock) => {
                let deadline = Instant::now() + timeout;
                while self.pending.is_empty() {
                    let out = self.sensor.take_output(clock.now_us());
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
                        .map_or(Duration::from_millis(5), |at| clock.until(at));
                    std::thread::sleep(wake.min(deadline - now).min(Duration::from_millis(5)));
                }
            }
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

/// Opens the simulated sensor a spec names on `clock` ([`SimLink::on_virtual_clock`]);
/// an error for any other sensor, whose time is the world's.
pub fn open_virtual(spec: &SensorSpec, clock: VirtualClock) -> anyhow::Result<Box<dyn Link>> {
    match spec {
        SensorSpec::Sim(options) => Ok(Box::new(SimLink::on_virtual_clock(
            options.build()?,
            options.speed,
            clock,
        ))),
        _ => Err(anyhow!(
            "virtual time needs the simulated sensor (sim:...): a real sensor's time is the world's"
        )),
    }
}
