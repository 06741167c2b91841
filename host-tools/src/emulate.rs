//! `scip2can emulate`: the simulator, the real firmware in QEMU, and the decoder, wired.
//!
//! ```text
//!  simulator (in-process, TCP) ◀──UART0── qemu-system-arm mps2-an386 ──UART1──▶ this process
//!   SCIP sensor, faults          (client)   scip2can-qemu firmware      (SLCAN)   S8, O, F; frames
//!                                                                                  ─▶ reassembly
//! ```
//! QEMU connects to two TCP listeners of this process: the simulator's (its first
//! `-serial`, UART0, the sensor) and the SLCAN port's (its second, UART1, the CAN port).
//! Nothing is listening in between, so no byte is lost and no port number needs to be
//! known in advance. [`Uart1::Server`] makes QEMU the server of UART1 instead, for an
//! outside SLCAN client (python-can's `slcan` interface with `socket://host:port`).
//!
//! The simulator's bytes towards UART0 are recorded with their time, so that a test can
//! run the same stream through the same core on the host ([`Emulation::sensor_stream`]).
//!
//! With [`SensorLink::Tcp`] the sensor is an Ethernet one instead: the firmware
//! `scip2can-qemu-eth` connects over the emulated LAN9118 to 192.168.0.10 (QEMU's user
//! networking, whose gateway address reaches this host's loopback), on the simulator's
//! port, which it is told at boot (a word block QEMU's loader device writes). The
//! simulator serves one connection after another, so the board can reconnect after
//! [`Emulation::drop_sensor_link`] or a sensor reboot (which drops the connection, as
//! Ethernet sensors do).

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command as Process, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use can_wire::bandwidth::{frame_bits, BitRates};
use can_wire::{Frame, IdWindow, Status};
use serde_json::json;
use slcan::{Command, Reply};

use crate::candump::Record;
use crate::decode::{Item, LogDecoder};
use crate::sim::faults::FaultRecord;
use crate::sim::transport::{reader_thread, serve_connection, Clock};
use crate::sim::SimOptions;

/// The firmware binary's name.
pub const FIRMWARE: &str = "scip2can-qemu";

/// The Ethernet firmware binary's name (same package as [`FIRMWARE`]).
pub const FIRMWARE_ETH: &str = "scip2can-qemu-eth";

/// The sensor's address as the Ethernet firmware sees it (the default of the real
/// sensors); QEMU's user networking maps it to this host's loopback.
pub const SENSOR_IP: [u8; 4] = [192, 168, 0, 10];

/// How the simulated sensor reaches the firmware.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SensorLink {
    /// UART0 (a URG-04LX-class sensor), firmware [`FIRMWARE`].
    #[default]
    Uart,
    /// TCP over the emulated Ethernet controller (UST-10LX class), firmware
    /// [`FIRMWARE_ETH`].
    Tcp,
}

/// The board workspace, from this crate's folder.
pub fn boards_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/boards")
}

/// Where `cargo build --release` in the board workspace puts the firmware (its own
/// target folder, whatever `CARGO_TARGET_DIR` says: see [`build_firmware`]).
pub fn default_firmware() -> PathBuf {
    boards_dir()
        .join("target/thumbv7em-none-eabihf/release")
        .join(FIRMWARE)
}

/// The command that builds the firmware, for messages.
pub const BUILD_COMMAND: &str =
    "(cd firmware/boards && CARGO_TARGET_DIR=target cargo build --release -p scip2can-qemu)";

/// Builds the firmware in the board workspace, into that workspace's own `target`
/// folder (a nested cargo with its own target folder cannot wait on the lock of the
/// cargo that runs us). Returns the ELF's path.
pub fn build_firmware() -> anyhow::Result<PathBuf> {
    build_in_boards(&["-p", FIRMWARE], "the firmware", BUILD_COMMAND)?;
    Ok(default_firmware())
}

/// Runs `cargo build --release ARGS` in the board workspace, into its own `target`
/// folder; on failure says that building `what` failed and which command to try.
pub fn build_in_boards(args: &[&str], what: &str, hint: &str) -> anyhow::Result<()> {
    let dir = boards_dir();
    let status = Process::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(["build", "--release"])
        .args(args)
        .current_dir(&dir)
        .env("CARGO_TARGET_DIR", dir.join("target"))
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .status()
        .with_context(|| format!("running cargo in {}", dir.display()))?;
    if !status.success() {
        bail!("building {what} failed; try {hint}");
    }
    Ok(())
}

/// [`build_firmware`], returning the Ethernet binary's path.
pub fn build_firmware_eth() -> anyhow::Result<PathBuf> {
    build_firmware()?;
    Ok(default_firmware().with_file_name(FIRMWARE_ETH))
}

/// The ELF to run: `path` if given (it must exist), else the board workspace's release
/// build, brought up to date first (cargo does nothing when it is; a stale ELF of an
/// older checkout is never run).
pub fn firmware(path: Option<&Path>) -> anyhow::Result<PathBuf> {
    match path {
        Some(p) if p.exists() => Ok(p.to_owned()),
        Some(p) => bail!(
            "firmware {} not found; build it with {BUILD_COMMAND}",
            p.display()
        ),
        None => build_firmware(),
    }
}

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

fn accept(listener: &TcpListener, stop: &AtomicBool, timeout: Duration) -> io::Result<TcpStream> {
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

/// One line from the SLCAN port, with the time it arrived.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Incoming {
    /// An SLCAN reply or frame.
    Reply(Reply),
    /// BEL: the last command failed.
    Bell,
    /// The board's `?` diagnostics line (without the `?`).
    Diagnostics(String),
    /// A line that is not SLCAN.
    Garbage(Vec<u8>),
}

/// The host end of an SLCAN port over TCP: commands out, replies and frames in.
#[derive(Debug)]
pub struct SlcanLink {
    stream: TcpStream,
    line: Vec<u8>,
    buf: Vec<u8>,
    pos: usize,
    queue: VecDeque<Incoming>,
}

impl SlcanLink {
    /// Wraps a connected stream.
    pub fn new(stream: TcpStream) -> io::Result<Self> {
        stream.set_nodelay(true)?;
        Ok(Self {
            stream,
            line: Vec::new(),
            buf: Vec::new(),
            pos: 0,
            queue: VecDeque::new(),
        })
    }

    /// Sends one command.
    pub fn send(&mut self, cmd: &Command) -> anyhow::Result<()> {
        let mut line = [0u8; slcan::LINE_MAX];
        let n = cmd.emit(&mut line).map_err(|e| anyhow!("{e}"))?;
        self.send_raw(line.get(..n).unwrap_or_default())
    }

    /// Sends bytes as they are (e.g. the board's `?\r`).
    pub fn send_raw(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        self.stream
            .write_all(bytes)
            .context("writing to the SLCAN port")
    }

    /// The next line, waiting at most `timeout`; `Ok(None)` on time-out. An error when
    /// the port closed.
    pub fn recv(&mut self, timeout: Duration) -> anyhow::Result<Option<Incoming>> {
        let until = Instant::now() + timeout;
        loop {
            if let Some(i) = self.queue.pop_front() {
                return Ok(Some(i));
            }
            // Lines from what was read before. (Not `slcan::LineBuffer`: the board's
            // diagnostics line is longer than an SLCAN line may be.)
            while let Some(rest) = self.buf.get(self.pos..) {
                let Some(end) = rest.iter().position(|&b| b == slcan::CR || b == slcan::BEL) else {
                    self.line.extend(rest.iter().filter(|&&b| b != b'\n'));
                    self.pos = self.buf.len();
                    break;
                };
                self.line
                    .extend(rest.iter().take(end).filter(|&&b| b != b'\n'));
                let bell = rest.get(end) == Some(&slcan::BEL);
                self.pos += end + 1;
                let text = std::mem::take(&mut self.line);
                if bell {
                    // An error answer has no CR; any text before it is a broken line.
                    if !text.is_empty() {
                        self.queue.push_back(Incoming::Garbage(text));
                    }
                    self.queue.push_back(Incoming::Bell);
                    continue;
                }
                self.queue.push_back(match text.split_first() {
                    Some((b'?', diag)) => {
                        Incoming::Diagnostics(String::from_utf8_lossy(diag).into_owned())
                    }
                    _ => match Reply::parse(&text) {
                        Ok(r) => Incoming::Reply(r),
                        Err(_) => Incoming::Garbage(text),
                    },
                });
            }
            if let Some(i) = self.queue.pop_front() {
                return Ok(Some(i));
            }
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.stream
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))?;
            self.buf.resize(1 << 16, 0);
            match self.stream.read(&mut self.buf) {
                Ok(0) => bail!("the SLCAN port closed (QEMU stopped)"),
                Ok(n) => {
                    self.buf.truncate(n);
                    self.pos = 0;
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) =>
                {
                    self.buf.truncate(0);
                    self.pos = 0;
                }
                Err(e) => return Err(e).context("reading the SLCAN port"),
            }
        }
    }

    /// Sends `?` and waits for the board's diagnostics; other lines that arrive
    /// meanwhile are handed to `other`.
    pub fn diagnostics(
        &mut self,
        timeout: Duration,
        other: &mut dyn FnMut(Incoming),
    ) -> anyhow::Result<Diagnostics> {
        self.send_raw(b"?\r")?;
        let until = Instant::now() + timeout;
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            match self.recv(left)? {
                Some(Incoming::Diagnostics(text)) => return Ok(Diagnostics::parse(&text)),
                Some(i) => other(i),
                None => break,
            }
        }
        bail!("no diagnostics from the board")
    }
}

/// The board's `?` line: `key=value` pairs (see the firmware's `main.rs`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Diagnostics(pub Vec<(String, String)>);

impl Diagnostics {
    /// Parses `key=value key=value ...`.
    pub fn parse(text: &str) -> Self {
        Diagnostics(
            text.split_whitespace()
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| (k.to_owned(), v.to_owned()))
                .collect(),
        )
    }

    /// A numeric value.
    pub fn get(&self, key: &str) -> Option<u64> {
        self.0
            .iter()
            .find(|(k, _)| k == key)
            .and_then(|(_, v)| v.parse().ok())
    }
}

/// Flags of `scip2can emulate`.
#[derive(Debug, Clone, clap::Args)]
pub struct EmulateArgs {
    /// Sensor model: urg04lx, utm30lx, ust10lx, uxm30lxe.
    #[arg(long, default_value = "urg04lx")]
    pub model: String,
    /// Fault injection, the simulator's `key=value,...` options
    /// (e.g. `flip=0.05,drop=0.02,hwfault=0.01,reboot_at=40,stall=0.01`).
    #[arg(long, default_value = "")]
    pub faults: String,
    /// Seed of the scene.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sensor time runs this many times faster than real time. QEMU's UART takes about
    /// 40 kB/s: a 40 Hz UTM-30LX (134 kB/s) needs about 0.25 to keep up.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// One JSON object per second (and a final summary) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also print every decoded scan as a JSON line.
    #[arg(long)]
    pub scans: bool,
    /// The firmware ELF (default: the board workspace's release build, built if missing).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// The QEMU binary.
    #[arg(long, default_value = "qemu-system-arm")]
    pub qemu: String,
    /// Run QEMU with `-icount shift=0` (virtual time = instructions; slower).
    #[arg(long)]
    pub icount: bool,
    /// How the sensor is connected: `uart` (UART0, URG-04LX class) or `tcp` (emulated
    /// Ethernet, UST-10LX class: use `--model ust10lx`; the firmware is then
    /// scip2can-qemu-eth).
    #[arg(long, value_enum, default_value_t = SensorLink::Uart)]
    pub link: SensorLink,
}

/// Counters of one reporting period (and of the whole run).
#[derive(Debug, Clone, Copy, Default)]
struct Tally {
    frames: u64,
    bus_ns: u64,
    intact: u64,
    damaged: u64,
    aborted: u64,
    bad_lines: u64,
}

/// Runs `scip2can emulate`.
pub fn run(args: EmulateArgs) -> anyhow::Result<()> {
    if !qemu_available(&args.qemu) {
        bail!(
            "{} not found: install QEMU (Debian/Ubuntu: apt-get install qemu-system-arm)",
            args.qemu
        );
    }
    let mut spec = format!(
        "model={},seed={},speed={}",
        args.model, args.seed, args.speed
    );
    if !args.faults.is_empty() {
        spec.push(',');
        spec.push_str(&args.faults);
    }
    let sim = SimOptions::from_spec(&spec)?;
    let setup = Setup {
        sim,
        firmware: match (args.link, args.firmware.as_deref()) {
            (SensorLink::Tcp, None) => build_firmware_eth()?,
            (_, path) => firmware(path)?,
        },
        qemu: args.qemu.clone(),
        icount: args.icount,
        uart1: Uart1::Connect,
        link: args.link,
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed));
    }
    let mut emu = Emulation::start(&setup)?;
    let mut link = emu.can.take().ok_or_else(|| anyhow!("no SLCAN link"))?;
    link.send(&Command::BitRate(8))?;
    link.send(&Command::Open)?;
    if !args.json {
        eprintln!(
            "scip2can emulate: {} simulator ↔ {} in QEMU ↔ SLCAN decoder{}",
            args.model,
            setup.firmware.display(),
            if args.faults.is_empty() {
                String::new()
            } else {
                format!(" (faults {})", args.faults)
            }
        );
    }
    let mut dec = LogDecoder::new(IdWindow::DEFAULT);
    let mut out = io::stdout().lock();
    let (mut period, mut total) = (Tally::default(), Tally::default());
    let mut last_report = Instant::now();
    let mut flags: Option<u8> = None;
    let mut statuses: Vec<Status> = Vec::new();
    let deadline = args
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    let handle = |i: Incoming,
                  dec: &mut LogDecoder,
                  period: &mut Tally,
                  flags: &mut Option<u8>,
                  statuses: &mut Vec<Status>,
                  out: &mut dyn Write,
                  t_us: u64|
     -> anyhow::Result<()> {
        match i {
            Incoming::Reply(Reply::Frame(f, _)) => {
                let Ok(frame) = Frame::new(f.id(), f.data(), f.kind().is_fd()) else {
                    return Ok(());
                };
                period.frames += 1;
                let ext = matches!(frame.id(), embedded_can::Id::Extended(_));
                period.bus_ns += frame_bits(frame.data().len(), frame.is_fd(), ext)
                    .time_ns(BitRates::CLASSIC_1M);
                let rec = Record::from_frame(t_us, "can0", &frame, frame.is_fd());
                match dec.push(&rec) {
                    Some(Item::Scan(s)) => {
                        match s.completeness {
                            can_wire::Completeness::Intact => period.intact += 1,
                            can_wire::Completeness::Aborted { .. } => period.aborted += 1,
                            _ => period.damaged += 1,
                        }
                        if args.scans {
                            writeln!(out, "{}", crate::decode::json::scan(&s))?;
                        }
                    }
                    Some(Item::Status { status, .. }) => statuses.push(status),
                    _ => {}
                }
            }
            Incoming::Reply(Reply::Flags(f)) => *flags = Some(f),
            Incoming::Garbage(_) | Incoming::Bell => period.bad_lines += 1,
            _ => {}
        }
        Ok(())
    };
    loop {
        if stop.load(Ordering::Relaxed) || deadline.is_some_and(|d| Instant::now() >= d) {
            break;
        }
        let t_us = emu.elapsed().as_micros() as u64;
        match link.recv(Duration::from_millis(50)) {
            Ok(Some(i)) => handle(
                i,
                &mut dec,
                &mut period,
                &mut flags,
                &mut statuses,
                &mut out,
                t_us,
            )?,
            Ok(None) => {}
            Err(e) => {
                if !emu.running() {
                    bail!("QEMU stopped: {e}");
                }
                return Err(e);
            }
        }
        if last_report.elapsed() >= Duration::from_secs(1) {
            let secs = last_report.elapsed().as_secs_f64();
            last_report = Instant::now();
            report(
                &mut out,
                args.json,
                emu.elapsed().as_secs_f64(),
                secs,
                &period,
                &dec,
                flags,
                &statuses,
            )?;
            add(&mut total, &period);
            period = Tally::default();
            statuses.clear();
            // The flags for the next line.
            link.send(&Command::StatusFlags)?;
        }
    }
    add(&mut total, &period);
    let mut rest = Vec::new();
    let diag = link.diagnostics(Duration::from_secs(2), &mut |i| rest.push(i));
    let faults = emu.stop()?;
    let run_s = last_report.elapsed().as_secs_f64();
    let _ = run_s;
    let stats = dec.stats().first().map(|(_, s)| *s).unwrap_or_default();
    let summary = json!({
        "summary": true,
        "scans_intact": total.intact,
        "scans_damaged": total.damaged,
        "scans_aborted": total.aborted,
        "scans_lost": stats.scans_lost,
        "frames": total.frames,
        "frames_lost": stats.frames_lost,
        "faults_injected": faults.len(),
        "board": diag.as_ref().map(|d| d.0.iter().map(|(k, v)| (k.clone(), json!(v))).collect::<serde_json::Map<_, _>>()).ok(),
    });
    if args.json {
        writeln!(out, "{summary}")?;
    } else {
        writeln!(
            out,
            "total: {} scans intact, {} damaged, {} aborted, {} lost; {} frames; {} faults injected",
            total.intact, total.damaged, total.aborted, stats.scans_lost, total.frames, faults.len()
        )?;
        if let Err(e) = &diag {
            writeln!(out, "board: no diagnostics ({e:#})")?;
        }
        if let Ok(d) = diag {
            let get = |k: &str| d.get(k).unwrap_or(0);
            writeln!(
                out,
                "board: stack {} of {} bytes used, {} sensor bytes, {} scans in, {} sent, {} aborted, {} dropped",
                get("stack"),
                get("stack_size"),
                get("bytes"),
                get("scans_in"),
                get("scans_sent"),
                get("scans_aborted"),
                get("dropped_budget") + get("dropped_queue"),
            )?;
        }
    }
    Ok(())
}

fn add(total: &mut Tally, p: &Tally) {
    total.frames += p.frames;
    total.bus_ns += p.bus_ns;
    total.intact += p.intact;
    total.damaged += p.damaged;
    total.aborted += p.aborted;
    total.bad_lines += p.bad_lines;
}

#[allow(clippy::too_many_arguments)]
fn report(
    out: &mut dyn Write,
    json_out: bool,
    t: f64,
    secs: f64,
    p: &Tally,
    dec: &LogDecoder,
    flags: Option<u8>,
    statuses: &[Status],
) -> anyhow::Result<()> {
    let rate = |n: u64| n as f64 / secs.max(1e-3);
    let bus = p.bus_ns as f64 / (secs * 1e9) * 100.0;
    let loss = dec.stats().first().map(|(_, s)| *s).unwrap_or_default();
    let mut heartbeat = None;
    let mut sensor = None;
    for s in statuses {
        match s {
            Status::Heartbeat { .. } => heartbeat = Some(*s),
            Status::SensorCounters { .. } => sensor = Some(*s),
            _ => {}
        }
    }
    if json_out {
        let v = json!({
            "t_s": (t * 10.0).round() / 10.0,
            "scans_per_s": rate(p.intact + p.damaged + p.aborted),
            "intact": p.intact,
            "damaged": p.damaged,
            "aborted": p.aborted,
            "scans_lost_total": loss.scans_lost,
            "frames_per_s": rate(p.frames),
            "bus_load_pct": bus,
            "slcan_flags": flags,
            "bad_lines": p.bad_lines,
            "heartbeat": heartbeat.map(|s| crate::decode::json::status(&s)),
            "sensor_counters": sensor.map(|s| crate::decode::json::status(&s)),
        });
        writeln!(out, "{v}")?;
        return Ok(());
    }
    let mut line = format!(
        "{t:6.1} s  scans {:5.1}/s (intact {}, damaged {}, aborted {}, lost {})  frames {:6.0}/s  bus {bus:4.1} %",
        rate(p.intact + p.damaged + p.aborted),
        p.intact,
        p.damaged,
        p.aborted,
        loss.scans_lost,
        rate(p.frames),
    );
    if let Some(Status::Heartbeat {
        state, cpu_load, ..
    }) = heartbeat
    {
        line.push_str(&format!(
            "  bridge {state:?} cpu {:.1} %",
            f64::from(cpu_load) / 2.0
        ));
    }
    if let Some(Status::SensorCounters {
        sum_errors,
        resyncs,
        dropped_scans,
        recoveries,
    }) = sensor
    {
        line.push_str(&format!(
            "  sum errors {sum_errors} resyncs {resyncs} dropped {dropped_scans} recoveries {recoveries}"
        ));
    }
    if let Some(f) = flags {
        line.push_str(&format!("  F{f:02X}"));
    }
    writeln!(out, "{line}")?;
    Ok(())
}
