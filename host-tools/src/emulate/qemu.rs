//! Running an emulation: the simulator on its TCP listener (recording what it sends),
//! QEMU started with the board's UARTs (or Ethernet) wired to this process, and the
//! SLCAN link to UART1.

use std::io::{self, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command as Process, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context};

use super::{SensorLink, SlcanLink, SENSOR_IP};
use crate::sim::faults::FaultRecord;
use crate::sim::transport::{reader_thread, serve_connection, Clock};
use crate::sim::SimOptions;

/// Whether `qemu` can be run.
pub fn qemu_available(qemu: &str) -> bool {
    Process::new(qemu)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// How UART1 (the SLCAN port) is reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Uart1 {
    /// QEMU connects to a listener of this process: [`Emulation::can`] is the link.
    Connect,
    /// QEMU listens on this port of 127.0.0.1 for an outside client (it does not wait).
    Server(u16),
}

/// What to emulate.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The simulated sensor (model, scene, faults, speed).
    pub sim: SimOptions,
    /// The firmware ELF.
    pub firmware: PathBuf,
    /// The QEMU binary.
    pub qemu: String,
    /// Run QEMU with `-icount shift=0` (one instruction = 1 ns of virtual time).
    pub icount: bool,
    /// How UART1 is reached.
    pub uart1: Uart1,
    /// How the sensor is reached (the firmware must match).
    pub link: SensorLink,
}

/// Bytes the simulator sent, with their time in ms since the emulation started.
pub type Recorded = Vec<(u64, Vec<u8>)>;

/// A running emulation. Dropping it kills QEMU and stops the simulator.
pub struct Emulation {
    qemu: Child,
    stop: Arc<AtomicBool>,
    sim: Option<JoinHandle<anyhow::Result<Vec<FaultRecord>>>>,
    recorded: Arc<Mutex<Recorded>>,
    start: Instant,
    /// Set to end the sensor's current TCP connection ([`SensorLink::Tcp`]).
    drop_link: Arc<AtomicBool>,
    /// TCP connections the simulator accepted.
    connections: Arc<std::sync::atomic::AtomicU32>,
    /// The SLCAN link to UART1 ([`Uart1::Connect`] only).
    pub can: Option<SlcanLink>,
}

impl std::fmt::Debug for Emulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Emulation")
            .field("qemu", &self.qemu.id())
            .finish_non_exhaustive()
    }
}

/// Writes to the QEMU connection and records what was written.
struct Tee {
    inner: TcpStream,
    recorded: Arc<Mutex<Recorded>>,
    start: Instant,
}

impl Write for Tee {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        let ms = self.start.elapsed().as_millis() as u64;
        if let (Ok(mut rec), Some(bytes)) = (self.recorded.lock(), buf.get(..n)) {
            rec.push((ms, bytes.to_vec()));
        }
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// QEMU's connection to `listener` (a socket chardev), without Nagle's delay; gives up
/// after `timeout`, or once `stop` is set.
pub(crate) fn accept(
    listener: &TcpListener,
    stop: &AtomicBool,
    timeout: Duration,
) -> io::Result<TcpStream> {
    listener.set_nonblocking(true)?;
    let until = Instant::now() + timeout;
    loop {
        match listener.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false)?;
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                if stop.load(Ordering::Relaxed) || Instant::now() > until {
                    return Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        "QEMU did not connect",
                    ));
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e),
        }
    }
}

impl Emulation {
    /// Starts the simulator and QEMU and waits until QEMU has connected its UARTs.
    pub fn start(setup: &Setup) -> anyhow::Result<Emulation> {
        let sim_listener = TcpListener::bind("127.0.0.1:0").context("binding the simulator")?;
        let sim_addr = sim_listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let recorded = Arc::new(Mutex::new(Vec::new()));
        let start = Instant::now();
        // Built here, so that bad options fail before QEMU starts.
        let mut sensor = setup.sim.build()?;
        let speed = setup.sim.speed;
        let drop_link = Arc::new(AtomicBool::new(false));
        let connections = Arc::new(std::sync::atomic::AtomicU32::new(0));
        let sim = if setup.link == SensorLink::Tcp {
            let (stop, recorded) = (Arc::clone(&stop), Arc::clone(&recorded));
            let (drop_link, connections) = (Arc::clone(&drop_link), Arc::clone(&connections));
            std::thread::spawn(move || -> anyhow::Result<Vec<FaultRecord>> {
                let clock = Clock::new(speed);
                // One connection after another, as the board makes them.
                while !stop.load(Ordering::Relaxed) {
                    let Ok(stream) = accept(&sim_listener, &stop, Duration::from_secs(3600)) else {
                        break;
                    };
                    connections.fetch_add(1, Ordering::Relaxed);
                    drop_link.store(false, Ordering::Relaxed);
                    let reader = stream.try_clone()?;
                    reader.set_read_timeout(Some(Duration::from_millis(50)))?;
                    let conn_stop = Arc::new(AtomicBool::new(false));
                    let input = reader_thread(reader, Arc::clone(&conn_stop));
                    let mut out = Tee {
                        inner: stream.try_clone()?,
                        recorded: Arc::clone(&recorded),
                        start,
                    };
                    let mut log = |_: &str| {};
                    // Ends on `drop_link` (which stopping sets too), when the board
                    // closes, or when the sensor reboots (an Ethernet sensor drops its
                    // connection).
                    let _ = serve_connection(
                        &mut sensor,
                        &clock,
                        &input,
                        &mut out,
                        false,
                        &drop_link,
                        &mut log,
                    );
                    conn_stop.store(true, Ordering::Relaxed);
                    sensor.disconnect();
                    let _ = stream.shutdown(std::net::Shutdown::Both);
                }
                Ok(sensor.fault_log().to_vec())
            })
        } else {
            let (stop, recorded) = (Arc::clone(&stop), Arc::clone(&recorded));
            std::thread::spawn(move || -> anyhow::Result<Vec<FaultRecord>> {
                let stream = accept(&sim_listener, &stop, Duration::from_secs(20))?;
                let reader = stream.try_clone()?;
                reader.set_read_timeout(Some(Duration::from_millis(50)))?;
                let conn_stop = Arc::new(AtomicBool::new(false));
                let input = reader_thread(reader, Arc::clone(&conn_stop));
                let clock = Clock::new(speed);
                let mut out = Tee {
                    inner: stream,
                    recorded,
                    start,
                };
                let mut log = |_: &str| {};
                let r = serve_connection(
                    &mut sensor,
                    &clock,
                    &input,
                    &mut out,
                    false,
                    &stop,
                    &mut log,
                );
                conn_stop.store(true, Ordering::Relaxed);
                // QEMU going away ends the connection with an error: not a failure.
                let _ = r;
                Ok(sensor.fault_log().to_vec())
            })
        };
        let (can_listener, uart1) = match setup.uart1 {
            Uart1::Connect => {
                let l = TcpListener::bind("127.0.0.1:0").context("binding the SLCAN port")?;
                let addr: SocketAddr = l.local_addr()?;
                (Some(l), format!("tcp:{addr}"))
            }
            Uart1::Server(port) => (None, format!("tcp:127.0.0.1:{port},server=on,wait=off")),
        };
        let mut cmd = Process::new(&setup.qemu);
        cmd.args([
            "-machine",
            "mps2-an386",
            "-display",
            "none",
            "-monitor",
            "none",
        ]);
        match setup.link {
            SensorLink::Uart => {
                cmd.args(["-no-reboot", "-serial", &format!("tcp:{sim_addr}")])
                    .args(["-serial", &uart1]);
            }
            SensorLink::Tcp => {
                let [a, b, c, d] = SENSOR_IP;
                // The board's boot block (its bootcfg.rs): magic "S2CE", the port, the
                // address. The gateway of QEMU's user network is the sensor's address, and
                // a connection to it reaches 127.0.0.1 on the same port.
                let port = u64::from(sim_addr.port());
                let ip = u32::from_be_bytes(SENSOR_IP);
                cmd.args(["-no-reboot", "-serial", "null", "-serial", &uart1])
                    .args([
                        "-nic",
                        &format!("user,model=lan9118,net={a}.{b}.{c}.0/24,host={a}.{b}.{c}.{d}"),
                    ])
                    .args([
                        "-device",
                        &format!(
                            "loader,addr=0x21000000,data={:#x},data-len=8",
                            (port << 32) | 0x5332_4345
                        ),
                    ])
                    .args([
                        "-device",
                        &format!("loader,addr=0x21000008,data={ip:#x},data-len=4"),
                    ]);
            }
        }
        if setup.icount {
            cmd.args(["-icount", "shift=0"]);
        }
        cmd.arg("-kernel")
            .arg(&setup.firmware)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit());
        let qemu = cmd.spawn().with_context(|| {
            format!("starting {} (apt-get install qemu-system-arm)", setup.qemu)
        })?;
        let mut emu = Emulation {
            qemu,
            stop,
            sim: Some(sim),
            recorded,
            start,
            drop_link,
            connections,
            can: None,
        };
        if let Some(l) = can_listener {
            let stream = accept(&l, &emu.stop, Duration::from_secs(20))
                .context("waiting for QEMU to connect UART1")?;
            emu.can = Some(SlcanLink::new(stream)?);
        }
        Ok(emu)
    }

    /// Time since the emulation started.
    pub fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }

    /// Ends the sensor's current TCP connection ([`SensorLink::Tcp`]): the simulator
    /// closes it, as a sensor whose cable is pulled and put back would after a reset,
    /// and accepts the board's next one.
    pub fn drop_sensor_link(&self) {
        self.drop_link.store(true, Ordering::Relaxed);
    }

    /// TCP connections the simulator accepted so far ([`SensorLink::Tcp`]).
    pub fn sensor_connections(&self) -> u32 {
        self.connections.load(Ordering::Relaxed)
    }

    /// Whether QEMU is still running.
    pub fn running(&mut self) -> bool {
        matches!(self.qemu.try_wait(), Ok(None))
    }

    /// What the simulator sent towards UART0 so far, with times.
    pub fn sensor_stream(&self) -> Recorded {
        self.recorded.lock().map(|r| r.clone()).unwrap_or_default()
    }

    /// Stops QEMU and the simulator; returns the simulator's fault log.
    pub fn stop(mut self) -> anyhow::Result<Vec<FaultRecord>> {
        self.shutdown();
        match self.sim.take().map(|h| h.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(anyhow!("the simulator thread panicked")),
            None => Ok(Vec::new()),
        }
    }

    fn shutdown(&mut self) {
        let _ = self.qemu.kill();
        let _ = self.qemu.wait();
        self.stop.store(true, Ordering::Relaxed);
        self.drop_link.store(true, Ordering::Relaxed);
    }
}

impl Drop for Emulation {
    fn drop(&mut self) {
        self.shutdown();
    }
}
