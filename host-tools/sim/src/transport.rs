//! Real-time drivers of the sans-IO [`Sensor`]: TCP, a pseudo-terminal, stdio.
//!
//! Each connection is served by one loop: a reader thread hands the host's bytes over a
//! channel, the loop feeds them to the sensor with the current time, writes what the
//! sensor has due, and sleeps until the sensor's next wakeup or the next input.

use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::model::LinkKind;
use super::session::Sensor;

/// Longest sleep of a serving loop, so that a stop request is seen soon.
const TICK: Duration = Duration::from_millis(20);

/// Sensor time from the real clock, running `speed` times faster.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: Instant,
    speed: f64,
}

impl Clock {
    /// A clock at 0 now.
    pub fn new(speed: f64) -> Self {
        Self {
            start: Instant::now(),
            speed: if speed > 0.0 { speed } else { 1.0 },
        }
    }

    /// Sensor µs now.
    pub fn now_us(&self) -> u64 {
        (self.start.elapsed().as_secs_f64() * 1e6 * self.speed) as u64
    }

    /// The real time until sensor time `at_us`, zero when past.
    pub fn until(&self, at_us: u64) -> Duration {
        let now = self.now_us();
        Duration::from_secs_f64(at_us.saturating_sub(now) as f64 / 1e6 / self.speed)
    }

    /// The real time `bytes` take on a serial line at `rate` bit/s (10 bits a byte).
    pub fn wire_time(&self, bytes: usize, rate: u32) -> Duration {
        Duration::from_secs_f64(bytes as f64 * 10.0 / f64::from(rate.max(1)) / self.speed)
    }
}

/// Reads `input` on a thread and sends what it reads; the channel closes at EOF or on
/// an error other than a timeout. The thread also ends once `stop` is set (at its
/// next read timeout, for inputs that have one).
pub fn reader_thread<R: Read + Send + 'static>(
    mut input: R,
    stop: Arc<AtomicBool>,
) -> Receiver<Vec<u8>> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            match input.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    if tx.send(buf.get(..n).unwrap_or(&[]).to_vec()).is_err() {
                        break;
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::TimedOut
                            | io::ErrorKind::WouldBlock
                            | io::ErrorKind::Interrupted
                    ) => {}
                Err(_) => break,
            }
        }
    });
    rx
}

/// Why [`serve_connection`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// `stop` was set.
    Stopped,
    /// The input ended (the host closed the connection).
    InputClosed,
    /// An Ethernet model rebooted on request (`RB` twice): it drops the connection.
    Rebooted,
}

/// Serves one connection until its input ends or `stop` is set. With `pace`, the
/// sensor sends no faster than its bit rate through its bounded transmit buffer (a
/// serial line, see [`Sensor::set_paced`]); the loop hands its bytes on as they leave
/// and reads the host's input in between, so that a `QT` is seen while a stream is
/// being written.
pub fn serve_connection(
    sensor: &mut Sensor,
    clock: &Clock,
    input: &Receiver<Vec<u8>>,
    out: &mut dyn Write,
    pace: bool,
    stop: &AtomicBool,
    log: &mut dyn FnMut(&str),
) -> io::Result<Ended> {
    sensor.set_paced(pace);
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(Ended::Stopped);
        }
        let bytes = sensor.take_output(clock.now_us());
        for f in sensor.new_faults() {
            log(&format!("fault: {f:?}"));
        }
        if !bytes.is_empty() {
            out.write_all(&bytes)?;
            out.flush()?;
        }
        if sensor.model().link == LinkKind::Ethernet
            && sensor.tx_backlog() == 0
            && sensor.take_rebooted()
        {
            // An Ethernet sensor that reboots (RB twice) drops its connection once the
            // answer has left.
            log("rebooting: connection closed");
            return Ok(Ended::Rebooted);
        }
        let wait = sensor
            .next_wakeup()
            .map_or(TICK, |at| clock.until(at).min(TICK));
        match input.recv_timeout(wait) {
            Ok(bytes) => sensor.receive(clock.now_us(), &bytes),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => {
                sensor.disconnect();
                return Ok(Ended::InputClosed);
            }
        }
    }
}

/// Serves TCP clients one after another on `listener` until `stop` is set. The
/// sensor keeps its state from one client to the next (a stream stops when its client
/// leaves). A client that connects while another is served is closed at once, as a
/// busy Ethernet sensor does. `log` gets one line per event.
pub fn serve_tcp(
    listener: TcpListener,
    sensor: &mut Sensor,
    clock: &Clock,
    stop: &Arc<AtomicBool>,
    log: &mut dyn FnMut(&str),
) -> io::Result<()> {
    listener.set_nonblocking(true)?;
    let busy = Arc::new(AtomicBool::new(false));
    let (tx, rx) = mpsc::channel::<TcpStream>();
    {
        let (stop, busy) = (Arc::clone(stop), Arc::clone(&busy));
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((s, _)) => {
                        if busy.swap(true, Ordering::SeqCst) {
                            drop(s);
                        } else if tx.send(s).is_err() {
                            break;
                        }
                    }
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(5))
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(50)),
                }
            }
        });
    }
    while !stop.load(Ordering::Relaxed) {
        let stream = match rx.recv_timeout(TICK) {
            Ok(s) => s,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        let peer = stream
            .peer_addr()
            .map_or_else(|_| "?".into(), |a| a.to_string());
        log(&format!("client {peer} connected"));
        stream.set_nonblocking(false)?;
        stream.set_nodelay(true)?;
        let reader = stream.try_clone()?;
        reader.set_read_timeout(Some(Duration::from_millis(100)))?;
        let conn_stop = Arc::new(AtomicBool::new(false));
        let input = reader_thread(reader, Arc::clone(&conn_stop));
        let mut out = stream;
        let result = serve_connection(sensor, clock, &input, &mut out, false, stop, log);
        conn_stop.store(true, Ordering::Relaxed);
        sensor.disconnect();
        let _ = out.shutdown(std::net::Shutdown::Both);
        busy.store(false, Ordering::SeqCst);
        match result {
            Ok(Ended::Rebooted) => log(&format!("client {peer} dropped: the sensor rebooted")),
            Ok(_) => log(&format!("client {peer} left")),
            Err(e) => log(&format!("client {peer} dropped: {e}")),
        }
    }
    Ok(())
}

/// Serves a pseudo-terminal until `stop` is set; `ready` gets the path a client opens.
/// Output is paced at the sensor's bit rate (which SS changes) unless `pace` is false.
pub fn serve_pty(
    sensor: &mut Sensor,
    clock: &Clock,
    stop: &Arc<AtomicBool>,
    pace: bool,
    ready: &mut dyn FnMut(&str),
    log: &mut dyn FnMut(&str),
) -> anyhow::Result<()> {
    use serialport::SerialPort;
    let (mut master, slave) = serialport::TTYPort::pair()?;
    let path = slave
        .name()
        .ok_or_else(|| anyhow::anyhow!("the pseudo-terminal has no path"))?;
    master.set_timeout(Duration::from_millis(100))?;
    let reader = master.try_clone_native()?;
    let input = reader_thread(reader, Arc::clone(stop));
    ready(&path);
    // The slave end stays open here, so that clients may come and go.
    let _keep = slave;
    // A serial line stays up while the sensor reboots.
    while serve_connection(sensor, clock, &input, &mut master, pace, stop, log)? == Ended::Rebooted
    {
    }
    Ok(())
}

/// Serves standard input and output until input ends.
pub fn serve_stdio(
    sensor: &mut Sensor,
    clock: &Clock,
    log: &mut dyn FnMut(&str),
) -> io::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    let input = reader_thread(io::stdin(), Arc::clone(&stop));
    let mut out = io::stdout().lock();
    let r = loop {
        match serve_connection(sensor, clock, &input, &mut out, false, &stop, log) {
            Ok(Ended::Rebooted) => {}
            other => break other,
        }
    };
    // Whatever is still due (e.g. a G* answer) goes out before we leave.
    let deadline = sensor.next_wakeup();
    if let Some(at) = deadline {
        std::thread::sleep(clock.until(at).min(Duration::from_secs(2)));
        let bytes = sensor.take_output(clock.now_us());
        out.write_all(&bytes)?;
        out.flush()?;
    }
    r.map(|_| ())
}
