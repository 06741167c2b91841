//! Lockstep co-simulation: the simulator on the host and the firmware
//! `scip2can-qemu-cosim` in QEMU (`-icount shift=N,sleep=off`) advance together, one
//! slot of virtual time at a time, so that the firmware's clock and the simulator's time
//! are one (the protocol: the board README, "Lockstep co-simulation").
//!
//! ```text
//!  simulator ◀── pipes (semihosting): requests, ──▶ qemu-system-arm -icount shift=N,sleep=off
//!  (simulated time)   slots of sensor bytes          scip2can-qemu-cosim ──UART1──▶ SLCAN lines
//! ```
//! The exchange goes through two named pipes in QEMU's working folder, which the
//! firmware reads and writes with semihosting calls: a call is one instruction to the
//! guest, so virtual time stands still while the host answers, and a slot costs two
//! system calls (QEMU's UART takes one byte per main-loop round, some 0.1 ms each on a
//! busy 2-core machine: 13 s of wall time per simulated second of a UTM-30LX stream).
//!
//! The simulator's wire is a 5 Mbit/s UART (2 µs a byte, as the host-level test of the
//! clock model assumes); its bytes are cut into chunks of at most 64 bytes, or shorter
//! where the line goes idle or the slot ends, each due when its last byte has arrived.
//! The firmware hands each chunk to the core when its clock reaches that time.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};

use crate::sim::SimOptions;

/// The firmware binary's name (package `scip2can-qemu`, feature `time-estimate`).
pub const FIRMWARE: &str = "scip2can-qemu-cosim";

/// The firmware's requests: a pipe in QEMU's working folder.
pub const REQUESTS: &str = "cosim-requests";
/// The answers to the firmware.
pub const ANSWERS: &str = "cosim-answers";

/// A slot of virtual time while the sensor streams, µs: the firmware's SysTick period
/// (slots end on its ticks).
pub const SLOT_US: u64 = 1000;
/// The simulator's step within a slot, µs, and the slot while the sensor is idle or
/// answers commands (a `TM1` answer then arrives within a step, as in the host-level
/// test, not a millisecond late).
pub const STEP_US: u64 = 50;
/// How long after a command slots stay short, µs.
pub const SHORT_AFTER_US: u64 = 5_000;
/// The wire: 5 Mbit/s, 10 bits a byte.
pub const BYTE_US: u64 = 2;
/// Largest answer the firmware takes (after its 11-byte head), bytes: a slot of the
/// wire (500 bytes a millisecond) and its chunk heads.
pub const ANSWER_MAX: usize = 1024;
/// Largest chunk (a DMA half-buffer).
pub const CHUNK: usize = 64;

/// The command that builds the firmware, for messages.
pub const BUILD_COMMAND: &str = "(cd firmware/boards && CARGO_TARGET_DIR=target cargo build \
     --release -p scip2can-qemu --features time-estimate --bin scip2can-qemu-cosim)";

/// Builds the co-simulation firmware in the board workspace (its own target folder, as
/// [`crate::emulate::build_firmware`]); returns the ELF's path.
pub fn build_firmware() -> anyhow::Result<PathBuf> {
    let args = [
        "-p",
        "scip2can-qemu",
        "--features",
        "time-estimate",
        "--bin",
        FIRMWARE,
    ];
    crate::emulate::build_in_boards(&args, "the co-simulation firmware", BUILD_COMMAND)?;
    Ok(crate::emulate::boards_dir()
        .join("target/thumbv7em-none-eabihf/release")
        .join(FIRMWARE))
}

/// A co-simulation to run.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The simulated sensor (its clock: `drift_ppm`, `clock_phase_us`, `jitter_us`).
    pub sim: SimOptions,
    /// The `scip2can-qemu-cosim` ELF.
    pub firmware: PathBuf,
    /// The QEMU binary.
    pub qemu: String,
    /// `-icount shift=N`: one instruction takes 2^N ns of virtual time.
    pub shift: u8,
    /// Virtual time to run, µs.
    pub duration_us: u64,
}

/// What a run gave.
#[derive(Debug, Clone, Default)]
pub struct Run {
    /// Every byte the firmware wrote to UART1 (SLCAN frame lines).
    pub uart1: Vec<u8>,
    /// True times (virtual µs) of the first points of the scans the sensor sent.
    pub truth: Vec<u64>,
    /// Commands the firmware sent the sensor, with their send times (virtual µs).
    pub commands: Vec<(u64, Vec<u8>)>,
    /// Slots served.
    pub slots: u64,
    /// Sensor bytes sent to the firmware.
    pub sensor_bytes: u64,
    /// Wall time of the run.
    pub wall: Duration,
}

/// The simulator's wire: bytes with the time their last bit arrives.
struct Wire {
    queue: VecDeque<u8>,
    /// When the wire is next free, µs.
    free_us: u64,
    /// Bytes that arrived and are not yet in a chunk: (end time, byte).
    arrived: Vec<(u64, u8)>,
}

impl Wire {
    /// Steps the sensor to `now` and the wire with it (bytes made since the last step
    /// start on an idle wire now, as in the host-level test).
    fn step(&mut self, sensor: &mut crate::sim::session::Sensor, now: u64, truth: &mut Vec<u64>) {
        if self.queue.is_empty() {
            self.free_us = self.free_us.max(now);
        }
        self.queue.extend(sensor.take_output(now));
        truth.extend(sensor.take_truth().iter().map(|t| t.first_step_us));
        while !self.queue.is_empty() && self.free_us + BYTE_US <= now {
            self.free_us += BYTE_US;
            if let Some(b) = self.queue.pop_front() {
                self.arrived.push((self.free_us, b));
            }
        }
    }

    /// The arrived bytes as chunks, encoded for the answer: count, then per chunk the
    /// due time (u64 LE), length (u8) and bytes.
    fn chunks(&mut self) -> (usize, Vec<u8>) {
        let mut out = Vec::new();
        let mut count = 0;
        let mut start = 0;
        let bytes = std::mem::take(&mut self.arrived);
        while start < bytes.len() {
            let mut end = start + 1;
            while end < bytes.len()
                && end - start < CHUNK
                && bytes[end].0 == bytes[end - 1].0 + BYTE_US
            {
                end += 1;
            }
            out.extend_from_slice(&bytes[end - 1].0.to_le_bytes());
            out.push((end - start) as u8);
            out.extend(bytes[start..end].iter().map(|&(_, b)| b));
            count += 1;
            start = end;
        }
        (count, out)
    }
}

/// A folder of its own for one run's pipes, removed when dropped.
struct PipeDir(PathBuf);

impl PipeDir {
    fn new() -> anyhow::Result<PipeDir> {
        use std::sync::atomic::{AtomicU32, Ordering};
        static RUNS: AtomicU32 = AtomicU32::new(0);
        let dir = std::env::temp_dir().join(format!(
            "scip2can-cosim-{}-{}",
            std::process::id(),
            RUNS.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let dir = PipeDir(dir);
        for name in [REQUESTS, ANSWERS] {
            let status = Process::new("mkfifo")
                .arg(dir.0.join(name))
                .status()
                .context("running mkfifo")?;
            if !status.success() {
                bail!("mkfifo {name} failed");
            }
        }
        Ok(dir)
    }
}

impl Drop for PipeDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Opens the run's pipes as the firmware does, in the same order (each open waits for
/// the other end), within 20 s.
fn open_pipes(dir: &std::path::Path) -> anyhow::Result<(File, File)> {
    let (req, ans) = (dir.join(REQUESTS), dir.join(ANSWERS));
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let pipes = File::open(&req).and_then(|r| {
            let a = std::fs::OpenOptions::new().write(true).open(&ans)?;
            Ok((r, a))
        });
        let _ = tx.send(pipes);
    });
    match rx.recv_timeout(Duration::from_secs(20)) {
        Ok(pipes) => Ok(pipes.context("opening the co-simulation pipes")?),
        Err(_) => bail!("the firmware did not open its pipes (semihosting) within 20 s"),
    }
}

fn accept(listener: &TcpListener, what: &str) -> anyhow::Result<TcpStream> {
    // No stop flag: the co-simulation waits for QEMU or gives up after 20 s.
    let never = std::sync::atomic::AtomicBool::new(false);
    crate::emulate::qemu::accept(listener, &never, Duration::from_secs(20))
        .with_context(|| format!("QEMU did not connect {what}"))
}

fn u64_le(r: &mut impl Read) -> std::io::Result<u64> {
    let mut b = [0u8; 8];
    r.read_exact(&mut b)?;
    Ok(u64::from_le_bytes(b))
}

/// Runs the firmware against the simulator for `setup.duration_us` of virtual time.
pub fn run(setup: &Setup) -> anyhow::Result<Run> {
    let mut sensor = setup.sim.build()?;
    sensor.record_truth(true);
    let pipes = PipeDir::new()?;
    let uart1 = TcpListener::bind("127.0.0.1:0").context("binding UART1's port")?;
    let start = Instant::now();
    let mut qemu = Process::new(&setup.qemu)
        .args([
            "-machine",
            "mps2-an386",
            "-display",
            "none",
            "-monitor",
            "none",
        ])
        .args(["-no-reboot", "-serial", "null", "-serial"])
        .arg(format!("tcp:{},nodelay=on", uart1.local_addr()?))
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-icount")
        .arg(format!("shift={},sleep=off", setup.shift))
        .arg("-kernel")
        .arg(&setup.firmware)
        .current_dir(&pipes.0)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .with_context(|| format!("starting {} (apt-get install qemu-system-arm)", setup.qemu))?;
    let result = (|| {
        let can = accept(&uart1, "UART1")?;
        let (requests, mut tx) = open_pipes(&pipes.0)?;
        // QEMU exits at the end (and closes the port); a minute of silence ends a hung run.
        can.set_read_timeout(Some(Duration::from_secs(60)))?;
        let reader = std::thread::spawn(move || {
            let mut all = Vec::new();
            let mut can = can;
            let _ = can.read_to_end(&mut all);
            all
        });
        let mut run = Run::default();
        let mut rx = BufReader::new(requests);
        let mut wire = Wire {
            queue: VecDeque::new(),
            free_us: 0,
            arrived: Vec::new(),
        };
        let mut expect = 0u64;
        let mut last_command = 0u64;
        loop {
            let mut tag = [0u8; 1];
            rx.read_exact(&mut tag).context("reading a request")?;
            if tag[0] != b'Q' {
                bail!("slot {}: a request starting {:#04x}", run.slots, tag[0]);
            }
            let t = u64_le(&mut rx)?;
            if t != expect {
                bail!("the firmware asked for slot {t} µs, {expect} µs expected");
            }
            let mut n = [0u8; 1];
            rx.read_exact(&mut n)?;
            for _ in 0..n[0] {
                let at = u64_le(&mut rx)?;
                let mut len = [0u8; 1];
                rx.read_exact(&mut len)?;
                let mut cmd = vec![0u8; usize::from(len[0])];
                rx.read_exact(&mut cmd)?;
                // Received when its last byte is in.
                sensor.receive(at + cmd.len() as u64 * BYTE_US, &cmd);
                run.commands.push((at, cmd));
                last_command = at;
            }
            if t >= setup.duration_us {
                let mut end = vec![b'E'];
                end.extend_from_slice(&t.to_le_bytes());
                end.extend_from_slice(&[0, 0]);
                tx.write_all(&end)?;
                break;
            }
            let idle = sensor.next_wakeup().is_none();
            let end = if idle || t < last_command + SHORT_AFTER_US || run.commands.is_empty() {
                t + STEP_US
            } else {
                (t / SLOT_US + 1) * SLOT_US
            };
            let mut now = t;
            while now < end {
                now += STEP_US;
                wire.step(&mut sensor, now, &mut run.truth);
            }
            let (count, chunks) = wire.chunks();
            run.sensor_bytes += (chunks.len() - 9 * count) as u64;
            if chunks.len() > ANSWER_MAX {
                bail!(
                    "slot {t} µs: {} bytes of chunks, the firmware takes {ANSWER_MAX}",
                    chunks.len()
                );
            }
            let mut answer = vec![b'A'];
            answer.extend_from_slice(&end.to_le_bytes());
            answer.extend_from_slice(&(chunks.len() as u16).to_le_bytes());
            answer.extend_from_slice(&chunks);
            tx.write_all(&answer)?;
            run.slots += 1;
            expect = end;
        }
        run.uart1 = reader.join().unwrap_or_default();
        Ok(run)
    })();
    let until = Instant::now() + Duration::from_secs(10);
    while qemu.try_wait()?.is_none() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = qemu.kill();
    let _ = qemu.wait();
    let mut run = result?;
    run.wall = start.elapsed();
    Ok(run)
}
