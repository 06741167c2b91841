//! `scip2can icount`: instructions per UART byte of the bridge core on the emulated
//! Cortex-M4, deterministic and checked against the host.
//!
//! ```text
//!  simulator (virtual time) ─▶ stream ─┬─▶ qemu-system-arm -icount shift=0 ─▶ bench line
//!  or a raw capture (--stream)         │    scip2can-qemu-bench, UART0 → UART1   ticks, frames, hash
//!                                      └─▶ the same core on the host ─────────▶ frames, hash (must match)
//! ```
//! The firmware `scip2can-qemu-bench` feeds the stream to `Bridge::on_uart` in chunks of
//! exactly [`CHUNK`] bytes, with the core's time taken from the stream position, and
//! counts SysTick ticks around each call. Under `-icount shift=0` one instruction takes
//! 1 ns of virtual time and SysTick runs at 25 MHz, so one tick is
//! [`INSTRUCTIONS_PER_TICK`] instructions. The work is deterministic; only where each
//! call starts within a tick is not (the bytes reach the guest at host-dependent
//! moments, so the SysTick phase differs), and each chunk's count can be off by one
//! tick either way. Two runs of one stream differ by a few ticks, growing like the
//! square root of the chunk count: a few tens of ticks in 327 000 (0.01 %) for 50
//! URG-04LX scans (1673 chunks), never more than that order.
//!
//! The host runs the same core with the firmware's own configuration, the same chunks
//! and the same times, and hashes the frames the same way (FNV-1a over each frame's raw
//! identifier, FD flag, length and data): the firmware's frame count and hash must be
//! the host's, or the measurement is refused.
//!
//! The simulated stream is made in virtual time only, so one seed gives one byte
//! sequence: `SCIP2.0` (to a sensor that boots in SCIP 1.1), `PP`, a full-range
//! endless `MD` (AMIN..AMAX, cluster 1, no skip), then the stream frames up to the end
//! of the N-th one.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use bridge::engine::{Bridge, BridgeStats};
use can_wire::IdWindow;
use scip::{Command, Event, Request, ScanMode, ScanRequest, Summary};
use serde_json::json;

use crate::emulate::{build_firmware, qemu_available, BUILD_COMMAND};
use crate::sim::model::ModelKind;
use crate::sim::SimOptions;

/// The emulated board's bridge settings: the very file the firmware compiles.
#[path = "../../firmware/boards/qemu-mps2/src/config.rs"]
pub mod qemu_config;

/// The benchmark firmware binary's name (built with the other QEMU binaries): the
/// board's configuration in its default encoding, the lossless coding.
pub const BENCH_FIRMWARE: &str = "scip2can-qemu-bench";

/// The same benchmark with plain 16-bit millimetres.
pub const BENCH_FIRMWARE_D16: &str = "scip2can-qemu-bench-d16";

/// The scan encodings the benchmark firmware is built in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BenchEncoding {
    /// The lossless predictive coding (the board's default).
    Dl,
    /// Plain 16-bit millimetres.
    D16,
}

impl BenchEncoding {
    /// The encoding the firmware and the host core run.
    pub fn encoding(self) -> can_wire::Encoding {
        match self {
            BenchEncoding::Dl => qemu_config::ENCODING,
            BenchEncoding::D16 => can_wire::Encoding::PLAIN_MM,
        }
    }

    /// The benchmark binary built for it.
    pub fn firmware_name(self) -> &'static str {
        match self {
            BenchEncoding::Dl => BENCH_FIRMWARE,
            BenchEncoding::D16 => BENCH_FIRMWARE_D16,
        }
    }
}

/// Bytes per `on_uart` call, as in the bench firmware: what the STM32 boards read from
/// their UART's DMA ring per call at the streaming rate (board-common's `UART_CHUNK`).
pub const CHUNK: usize = 128;

/// The byte that ends the stream for the firmware (never part of SCIP).
pub const EOT: u8 = 0x04;

/// The byte that begins a control frame ahead of the stream (see `bench.rs`).
pub const SOH: u8 = 0x01;

/// Instructions per SysTick tick under `-icount shift=0` (1 ns per instruction, a
/// 25 MHz SysTick).
pub const INSTRUCTIONS_PER_TICK: u64 = 40;

/// The benchmark firmware: `path` if given (it must exist), else the board workspace's
/// release build, brought up to date first.
pub fn bench_firmware(path: Option<&Path>, encoding: BenchEncoding) -> anyhow::Result<PathBuf> {
    match path {
        Some(p) if p.exists() => Ok(p.to_owned()),
        Some(p) => bail!(
            "firmware {} not found; build it with {BUILD_COMMAND}",
            p.display()
        ),
        None => {
            let elf = build_firmware()?.with_file_name(encoding.firmware_name());
            if !elf.exists() {
                bail!(
                    "{} is missing after the build; build it with {BUILD_COMMAND}",
                    elf.display()
                );
            }
            Ok(elf)
        }
    }
}

/// Whether an intact response is a measurement with data (a G* answer or an M* stream
/// frame; not the M* acknowledgement, not a fault status).
fn is_measurement(s: &Summary) -> bool {
    matches!(
        s.request,
        Some(Request {
            command: Command::Scan(_),
            ..
        })
    ) && s.values > 0
}

/// Counts intact measurement responses in a stream fed piece by piece, and where each
/// ends (the offset just after its empty line).
#[derive(Debug, Default)]
struct ScanEnds {
    decoder: scip::Decoder,
    pos: usize,
    ends: Vec<usize>,
}

impl ScanEnds {
    fn feed(&mut self, bytes: &[u8]) {
        let mut rest = bytes;
        while !rest.is_empty() {
            let (used, event) = self.decoder.feed(rest);
            self.pos += used;
            if let Some(Event::End(s)) = event {
                if is_measurement(&s) {
                    self.ends.push(self.pos);
                }
            }
            match rest.get(used..) {
                Some(r) if used > 0 || event.is_some() => rest = r,
                _ => break,
            }
        }
    }
}

/// Intact measurement responses (with data) in a sensor-to-host stream.
pub fn measurement_responses(stream: &[u8]) -> usize {
    let mut ends = ScanEnds::default();
    ends.feed(stream);
    ends.ends.len()
}

/// The bytes a simulated sensor sends to a host that switches it to SCIP 2.0 if needed,
/// reads `PP` and asks for an endless full-range `MD`, up to the end of the `scans`-th
/// stream frame. Virtual time only: the same options give the same bytes.
pub fn sim_stream(options: &SimOptions, scans: usize) -> anyhow::Result<Vec<u8>> {
    if scans == 0 {
        bail!("--scans must be at least 1");
    }
    let mut sensor = options.build()?;
    let model = sensor.model();
    let name = model.kind.name();
    let (amin, amax) = (
        u16::try_from(model.amin).context("AMIN")?,
        u16::try_from(model.amax).context("AMAX")?,
    );
    let md = Request::new(Command::Scan(ScanRequest::distance(
        ScanMode::Continuous,
        amin,
        amax,
    )));
    let mut line = [0u8; 32];
    let n = md.encode(&mut line).map_err(|e| anyhow!("MD: {e}"))?;
    let mut commands: Vec<&[u8]> = Vec::new();
    if !sensor.is_scip2() {
        commands.push(b"SCIP2.0\n");
    }
    commands.push(b"PP\n");
    commands.push(line.get(..n).unwrap_or_default());

    let mut out = Vec::new();
    let mut ends = ScanEnds::default();
    let mut now = 0u64;
    for c in commands {
        sensor.receive(now, c);
        let bytes = sensor.take_output(now);
        ends.feed(&bytes);
        out.extend_from_slice(&bytes);
        now += 1_000;
    }
    // Generous: the acknowledgement, then one frame per scan period.
    let give_up = now + (scans as u64 + 10) * 4 * sensor.scan_period_us();
    while ends.ends.len() < scans {
        let Some(next) = sensor.next_wakeup().filter(|&t| t <= give_up) else {
            bail!(
                "the simulated {name} sent {} of {scans} scans, then nothing more",
                ends.ends.len()
            );
        };
        now = now.max(next);
        let bytes = sensor.take_output(now);
        ends.feed(&bytes);
        out.extend_from_slice(&bytes);
    }
    let end = ends.ends.get(scans - 1).copied().unwrap_or(out.len());
    out.truncate(end);
    Ok(out)
}

/// The frame hash the firmware computes: its own code, compiled for the host.
#[path = "../../firmware/boards/qemu-mps2/src/frame_hash.rs"]
mod frame_hash;
pub use frame_hash::FrameHash;

/// The same core on the host, fed like the firmware feeds it.
#[derive(Debug, Clone)]
pub struct HostRun {
    /// `on_uart` calls.
    pub chunks: u64,
    /// Frames popped.
    pub frames: u64,
    /// Their hash.
    pub hash: FrameHash,
    /// The core's counters at the end.
    pub stats: BridgeStats,
}

/// Runs the stream through the bridge core with the emulated board's configuration:
/// [`CHUNK`]-byte calls at the time the chunk's last byte arrives at the board's bit
/// rate (10 bits per byte), every frame popped after each call.
pub fn host_run(stream: &[u8], encoding: BenchEncoding) -> anyhow::Result<HostRun> {
    host_run_with(stream, encoding, &[])
}

/// [`host_run`] after the control frames `controls` (their data), each of which the
/// core must accept; their answers are not counted.
pub fn host_run_with(
    stream: &[u8],
    encoding: BenchEncoding,
    controls: &[Vec<u8>],
) -> anyhow::Result<HostRun> {
    let config = qemu_config::bridge_with(encoding.encoding())
        .ok_or_else(|| anyhow!("the board's configuration is invalid"))?;
    let mut bridge = Bridge::<{ qemu_config::QUEUE }>::new(config)
        .map_err(|e| anyhow!("the board's configuration: {e}"))?;
    let ids = IdWindow::DEFAULT
        .node(qemu_config::NODE)
        .map_err(|e| anyhow!("the board's node: {e:?}"))?;
    for data in controls {
        let frame = can_wire::Frame::new(ids.id(can_wire::Kind::Control), data, data.len() > 8)
            .map_err(|e| anyhow!("control frame {data:02x?}: {e:?}"))?;
        bridge.on_can_frame(&frame, 0);
        while let Some(answer) = bridge.pop_frame() {
            let a = can_wire::Answer::parse(answer.data())
                .map_err(|e| anyhow!("the answer to {data:02x?}: {e:?}"))?;
            if a.outcome != can_wire::Outcome::Accepted {
                bail!(
                    "the bridge refused control frame {data:02x?}: {:?}",
                    a.outcome
                );
            }
        }
    }
    let mut run = HostRun {
        chunks: 0,
        frames: 0,
        hash: FrameHash::default(),
        stats: BridgeStats::default(),
    };
    let mut bytes = 0u64;
    for chunk in stream.chunks(CHUNK) {
        bytes += chunk.len() as u64;
        let now = bytes * 10 * 1000 / u64::from(qemu_config::BAUD);
        bridge.on_uart(chunk, now);
        run.chunks += 1;
        while let Some(frame) = bridge.pop_frame() {
            run.hash.frame(&frame);
            run.frames += 1;
        }
    }
    run.stats = *bridge.stats();
    Ok(run)
}

/// The firmware's result line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BenchLine {
    /// Stream bytes read.
    pub bytes: u64,
    /// `on_uart` calls.
    pub chunks: u64,
    /// SysTick ticks inside `on_uart`, summed.
    pub ticks: u64,
    /// The most ticks of one call.
    pub max_chunk_ticks: u64,
    /// Scans the core began.
    pub scans_in: u64,
    /// Scans it sent whole.
    pub scans_sent: u64,
    /// Scans it aborted.
    pub scans_aborted: u64,
    /// Frames popped.
    pub frames: u64,
    /// Their hash.
    pub frame_hash: u32,
    /// UART receive overruns (bytes lost before the core).
    pub overruns: u64,
    /// SysTick ticks inside `pop_frame`, summed (every frame, and the call that found
    /// the queue empty after each chunk).
    pub pop_ticks: u64,
}

impl BenchLine {
    /// Finds and parses the `bench key=value ...` line in what UART1 printed.
    pub fn find(text: &str) -> Option<Self> {
        let line = text.lines().find_map(|l| l.trim().strip_prefix("bench "))?;
        let get = |key: &str| -> Option<&str> {
            line.split_whitespace()
                .filter_map(|kv| kv.split_once('='))
                .find(|(k, _)| *k == key)
                .map(|(_, v)| v)
        };
        let num = |key: &str| get(key)?.parse::<u64>().ok();
        let hash = get("frame_hash")?;
        let hash = hash.strip_prefix("0x").unwrap_or(hash);
        Some(Self {
            bytes: num("bytes")?,
            chunks: num("chunks")?,
            ticks: num("ticks")?,
            max_chunk_ticks: num("max_chunk_ticks")?,
            scans_in: num("scans_in")?,
            scans_sent: num("scans_sent")?,
            scans_aborted: num("scans_aborted")?,
            frames: num("frames")?,
            frame_hash: u32::from_str_radix(hash, 16).ok()?,
            overruns: num("overruns")?,
            pop_ticks: num("pop_ticks")?,
        })
    }
}

/// Removes a file when dropped.
struct TempFile(PathBuf);

impl TempFile {
    fn new(what: &str) -> Self {
        static N: AtomicU32 = AtomicU32::new(0);
        let n = N.fetch_add(1, Ordering::Relaxed);
        Self(
            std::env::temp_dir().join(format!("scip2can-icount-{}-{n}-{what}", std::process::id())),
        )
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Runs the benchmark firmware once on `stream` under `qemu -icount shift=0`: the
/// stream and an EOT on UART0 (standard input), UART1 to a temporary file. QEMU is
/// killed after `timeout`.
pub fn run_firmware(
    qemu: &str,
    firmware: &Path,
    stream: &[u8],
    timeout: Duration,
) -> anyhow::Result<BenchLine> {
    run_firmware_with(qemu, firmware, &[], stream, timeout)
}

/// The bytes ahead of the stream that give the firmware the control frames `controls`
/// (their data): per frame, 0x01 (SOH), its length and its data.
pub fn control_header(controls: &[Vec<u8>]) -> Vec<u8> {
    let mut out = Vec::new();
    for data in controls {
        out.push(SOH);
        out.push(data.len() as u8);
        out.extend_from_slice(data);
    }
    out
}

/// [`run_firmware`] with `header` (see [`control_header`]) ahead of the stream.
pub fn run_firmware_with(
    qemu: &str,
    firmware: &Path,
    header: &[u8],
    stream: &[u8],
    timeout: Duration,
) -> anyhow::Result<BenchLine> {
    if let Some(at) = stream.iter().position(|&b| b == EOT) {
        bail!("the stream holds an EOT byte (0x04) at offset {at}: the firmware would stop there");
    }
    let uart1 = TempFile::new("uart1.txt");
    let mut child = Process::new(qemu)
        .args(["-machine", "mps2-an386", "-icount", "shift=0"])
        .args(["-display", "none", "-monitor", "none", "-no-reboot"])
        .args(["-serial", "stdio", "-serial"])
        .arg(format!("file:{}", uart1.0.display()))
        .arg("-kernel")
        .arg(firmware)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("starting {qemu} (apt-get install qemu-system-arm)"))?;
    let mut input = child.stdin.take().context("QEMU's standard input")?;
    let mut bytes = Vec::with_capacity(header.len() + stream.len() + 1);
    bytes.extend_from_slice(header);
    bytes.extend_from_slice(stream);
    bytes.push(EOT);
    // QEMU takes the bytes as the guest reads them; a QEMU that died early makes the
    // write fail, which the missing result line then explains.
    let writer = std::thread::spawn(move || {
        let _ = input.write_all(&bytes);
    });
    let mut stderr = child.stderr.take().context("QEMU's standard error")?;
    let errors = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut stderr, &mut s);
        s
    });
    let until = Instant::now() + timeout;
    let exited = loop {
        if child.try_wait()?.is_some() {
            break true;
        }
        if Instant::now() >= until {
            let _ = child.kill();
            let _ = child.wait();
            break false;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let _ = writer.join();
    let errors = errors.join().unwrap_or_default();
    let printed = std::fs::read_to_string(&uart1.0).unwrap_or_default();
    match BenchLine::find(&printed) {
        Some(line) => Ok(line),
        None => {
            let why = if exited {
                "QEMU exited"
            } else {
                "QEMU timed out"
            };
            bail!(
                "{why} without a `bench` line on UART1 ({} with {}); UART1: {:?}; stderr: {:?}",
                qemu,
                firmware.display(),
                printed.trim(),
                errors.trim()
            )
        }
    }
}

/// How long one firmware run may take: QEMU's start plus a generous rate.
pub fn timeout_for(stream: &[u8]) -> Duration {
    Duration::from_secs(20) + Duration::from_millis(stream.len() as u64 / 10)
}

/// One checked measurement.
#[derive(Debug, Clone)]
pub struct Measurement {
    /// Stream bytes.
    pub bytes: u64,
    /// Intact measurement responses in the stream.
    pub scans: usize,
    /// What the firmware printed.
    pub firmware: BenchLine,
    /// What the host core did with the same stream.
    pub host: HostRun,
}

impl Measurement {
    /// Instructions inside `on_uart`, all chunks.
    pub fn instructions(&self) -> u64 {
        self.firmware.ticks * INSTRUCTIONS_PER_TICK
    }

    /// Instructions per stream byte.
    pub fn per_byte(&self) -> f64 {
        self.instructions() as f64 / self.bytes.max(1) as f64
    }

    /// Instructions per measurement response of the stream (0 without one).
    pub fn per_scan(&self) -> u64 {
        self.instructions()
            .checked_div(self.scans as u64)
            .unwrap_or(0)
    }

    /// Instructions inside `pop_frame`, all calls.
    pub fn pop_instructions(&self) -> u64 {
        self.firmware.pop_ticks * INSTRUCTIONS_PER_TICK
    }

    /// Instructions of `pop_frame` per frame taken.
    pub fn pop_per_frame(&self) -> f64 {
        self.pop_instructions() as f64 / self.firmware.frames.max(1) as f64
    }

    /// Instructions per stream byte of `on_uart` and `pop_frame` together.
    pub fn total_per_byte(&self) -> f64 {
        (self.instructions() + self.pop_instructions()) as f64 / self.bytes.max(1) as f64
    }

    /// The most instructions of one chunk.
    pub fn max_per_chunk(&self) -> u64 {
        self.firmware.max_chunk_ticks * INSTRUCTIONS_PER_TICK
    }
}

/// Runs the firmware and the host core on `stream` and checks that they agree: every
/// byte reached the firmware's core, and its frames (count and hash) are the host's.
pub fn measure(
    qemu: &str,
    firmware: &Path,
    stream: &[u8],
    encoding: BenchEncoding,
) -> anyhow::Result<Measurement> {
    measure_with(qemu, firmware, stream, encoding, &[])
}

/// [`measure`] with the pipeline set up by the control frames `controls` (their data)
/// first, on both the firmware and the host core.
pub fn measure_with(
    qemu: &str,
    firmware: &Path,
    stream: &[u8],
    encoding: BenchEncoding,
    controls: &[Vec<u8>],
) -> anyhow::Result<Measurement> {
    let host = host_run_with(stream, encoding, controls)?;
    let header = control_header(controls);
    let line = run_firmware_with(qemu, firmware, &header, stream, timeout_for(stream))?;
    if line.bytes != stream.len() as u64 || line.overruns != 0 {
        bail!(
            "the firmware's core got {} of {} stream bytes ({} UART overruns)",
            line.bytes,
            stream.len(),
            line.overruns
        );
    }
    if (line.frames, line.frame_hash) != (host.frames, host.hash.0) {
        bail!(
            "the firmware's frames differ from the host core's: firmware {} frames, hash \
             {:#010x}; host {} frames, hash {:#010x}",
            line.frames,
            line.frame_hash,
            host.frames,
            host.hash.0
        );
    }
    Ok(Measurement {
        bytes: stream.len() as u64,
        scans: measurement_responses(stream),
        firmware: line,
        host,
    })
}

/// Flags of `scip2can icount`.
#[derive(Debug, Clone, clap::Args)]
pub struct IcountArgs {
    /// Sensor model of the simulated stream: urg04lx, utm30lx, ust10lx, uxm30lxe.
    #[arg(long, default_value = "urg04lx")]
    pub model: String,
    /// Stream frames (scans) in the simulated stream.
    #[arg(long, default_value_t = 50)]
    pub scans: usize,
    /// Seed of the simulated scene.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// A raw sensor-to-host stream (a capture, or a `scip2can record` file) instead of
    /// the simulator.
    #[arg(long, conflicts_with_all = ["model", "scans", "seed"])]
    pub stream: Option<PathBuf>,
    /// The benchmark firmware ELF (default: the board workspace's release
    /// `scip2can-qemu-bench`, built if missing or stale).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// The scan encoding of the board's configuration: dl (the lossless coding, the
    /// board's default) or d16.
    #[arg(long, value_enum, default_value = "dl")]
    pub encoding: BenchEncoding,
    /// Pipeline stages, set up by control frames (SPEC 6) before the stream, e.g.
    /// `window=100:30000,speckle,median=3,decimate=2:min,roi=100:900,intensity=500`
    /// (window MIN:MAX mm; speckle; median 3 or 5; decimate K[:first|min|mean]; roi
    /// FIRST:LAST steps; intensity threshold on the 16-bit scale; and, not a stage, frame
    /// N: the largest frame, 8 for classic CAN or 12..=64 for CAN FD, e.g. `frame=64`).
    /// Default: none.
    #[arg(long, value_parser = parse_pipeline_spec)]
    pub pipeline: Option<PipelineSpec>,
    /// The QEMU binary.
    #[arg(long, default_value = "qemu-system-arm")]
    pub qemu: String,
    /// One JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also write the exact bytes given to the firmware's UART0 (the control frames
    /// ahead of the stream, then the stream; without the closing EOT) to this file, e.g.
    /// for `firmware/boards/on_uart_profile.py`.
    #[arg(long)]
    pub save_input: Option<PathBuf>,
}

/// Runs `scip2can icount`.
pub fn run(args: IcountArgs) -> anyhow::Result<()> {
    if !qemu_available(&args.qemu) {
        bail!(
            "{} not found: install QEMU (Debian/Ubuntu: apt-get install qemu-system-arm)",
            args.qemu
        );
    }
    let (source, model, stream) = match &args.stream {
        Some(path) => {
            let bytes =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            let stream = crate::sensor::record_file::sensor_bytes(&bytes)
                .with_context(|| format!("reading {}", path.display()))?;
            (path.display().to_string(), None, stream)
        }
        None => {
            let kind = ModelKind::parse(&args.model).ok_or_else(|| {
                let names: Vec<_> = ModelKind::ALL.iter().map(|m| m.name()).collect();
                anyhow!(
                    "unknown model {:?} (one of {})",
                    args.model,
                    names.join(", ")
                )
            })?;
            let options = SimOptions {
                model: kind,
                seed: args.seed,
                ..SimOptions::default()
            };
            let stream = sim_stream(&options, args.scans)?;
            (
                format!("simulated {}, seed {}", kind.name(), args.seed),
                Some(kind.name()),
                stream,
            )
        }
    };
    let firmware = bench_firmware(args.firmware.as_deref(), args.encoding)?;
    let (spec, controls) = match &args.pipeline {
        Some(p) => (p.text.clone(), p.frames.clone()),
        None => ("none".to_string(), Vec::new()),
    };
    if let Some(path) = &args.save_input {
        let mut input = control_header(&controls);
        input.extend_from_slice(&stream);
        std::fs::write(path, input).with_context(|| format!("writing {}", path.display()))?;
    }
    let m = measure_with(&args.qemu, &firmware, &stream, args.encoding, &controls)?;
    let f = &m.firmware;
    let mut out = std::io::stdout().lock();
    if args.json {
        let v = json!({
            "source": source,
            "model": model,
            "encoding": format!("{:?}", args.encoding.encoding().distance),
            "pipeline": spec,
            "stream_file": args.stream.as_ref().map(|p| p.display().to_string()),
            "seed": args.stream.is_none().then_some(args.seed),
            "bytes": m.bytes,
            "scans": m.scans,
            "chunks": f.chunks,
            "chunk_bytes": CHUNK,
            "ticks": f.ticks,
            "instructions_per_tick": INSTRUCTIONS_PER_TICK,
            "instructions": m.instructions(),
            "instructions_per_byte": (m.per_byte() * 10.0).round() / 10.0,
            "instructions_per_scan": m.per_scan(),
            "max_instructions_per_chunk": m.max_per_chunk(),
            "pop_frame_instructions": m.pop_instructions(),
            "pop_frame_instructions_per_frame": (m.pop_per_frame() * 10.0).round() / 10.0,
            "with_pop_frame_instructions_per_byte": (m.total_per_byte() * 10.0).round() / 10.0,
            "frames": f.frames,
            "frame_hash": format!("{:#010x}", f.frame_hash),
            "frames_match_host": true,
            "scans_in": f.scans_in,
            "scans_sent": f.scans_sent,
            "scans_aborted": f.scans_aborted,
            "overruns": f.overruns,
        });
        writeln!(out, "{v}")?;
        return Ok(());
    }
    writeln!(
        out,
        "scip2can icount: {source}, {} under {} -icount shift=0",
        firmware.display(),
        args.qemu
    )?;
    writeln!(out, "pipeline           {spec}")?;
    writeln!(
        out,
        "stream             {} bytes, {} scans, {} chunks of {CHUNK} bytes",
        m.bytes, m.scans, f.chunks
    )?;
    writeln!(
        out,
        "instructions       {} ({} SysTick ticks of {INSTRUCTIONS_PER_TICK})",
        m.instructions(),
        f.ticks
    )?;
    writeln!(out, "per UART byte      {:.1} (on_uart)", m.per_byte())?;
    writeln!(
        out,
        "pop_frame          {:.1} per frame; {:.1} per UART byte with on_uart",
        m.pop_per_frame(),
        m.total_per_byte()
    )?;
    writeln!(out, "per scan           {}", m.per_scan())?;
    writeln!(out, "max per chunk      {}", m.max_per_chunk())?;
    writeln!(
        out,
        "frames             {} (hash {:#010x}), the same as the host core's",
        f.frames, f.frame_hash
    )?;
    writeln!(
        out,
        "core               {} scans in, {} sent, {} aborted",
        f.scans_in, f.scans_sent, f.scans_aborted
    )?;
    writeln!(
        out,
        "(one tick = {INSTRUCTIONS_PER_TICK} instructions; runs differ by a few ticks, about \
         the square root of the chunk count: the SysTick phase at each call)"
    )?;
    Ok(())
}

/// A pipeline given to `--pipeline`: its text and the control frames (data) that set
/// it up.
#[derive(Debug, Clone)]
pub struct PipelineSpec {
    /// As given.
    pub text: String,
    /// One control frame per stage.
    pub frames: Vec<Vec<u8>>,
}

/// Parses a `--pipeline` text into control frames (tokens 1, 2, ... in order).
pub fn parse_pipeline_spec(text: &str) -> Result<PipelineSpec, String> {
    use can_wire::control::{Command as C, DecimationMode as M, MedianWindow};
    fn num<T: std::str::FromStr>(v: &str) -> Result<T, String> {
        v.trim()
            .parse()
            .map_err(|_| format!("{v:?} is not a number"))
    }
    fn pair<T: std::str::FromStr>(v: &str) -> Result<(T, T), String> {
        let (a, b) = v.split_once(':').ok_or(format!("{v:?} is not A:B"))?;
        Ok((num(a)?, num(b)?))
    }
    let mut frames = Vec::new();
    for (i, item) in text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .enumerate()
    {
        let (key, value) = item.split_once('=').unwrap_or((item, ""));
        let command = match key {
            "window" => {
                let (min_mm, max_mm) = pair(value)?;
                C::RangeWindow { min_mm, max_mm }
            }
            "speckle" => C::Speckle { enabled: true },
            "median" => C::Median {
                window: match value {
                    "3" => MedianWindow::Three,
                    "5" => MedianWindow::Five,
                    _ => return Err(format!("median={value:?}: 3 or 5")),
                },
            },
            "decimate" => {
                let (k, mode) = value.split_once(':').unwrap_or((value, "first"));
                let mode = match mode {
                    "first" => M::Every,
                    "min" => M::Min,
                    "mean" => M::Mean,
                    m => return Err(format!("decimate mode {m:?}: first, min or mean")),
                };
                C::AngularDecimation { k: num(k)?, mode }
            }
            "roi" => {
                let (start_step, end_step) = pair(value)?;
                C::RegionOfInterest {
                    start_step,
                    end_step,
                }
            }
            "intensity" => C::IntensityThreshold {
                threshold: num(value)?,
            },
            "frame" => C::FrameSize {
                max_len: num(value)?,
            },
            _ => {
                return Err(format!(
                    "{key:?}: one of window, speckle, median, decimate, roi, intensity, frame"
                ))
            }
        };
        let control = can_wire::Control {
            token: (i + 1) as u8,
            command,
        };
        let mut buf = [0u8; can_wire::control::MAX_CONTROL_LEN];
        let len = control
            .emit(&mut buf)
            .map_err(|e| format!("{item:?}: {e:?}"))?;
        frames.push(buf[..len].to_vec());
    }
    Ok(PipelineSpec {
        text: text.to_string(),
        frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pipeline_specs_become_the_control_frames_of_spec_6() {
        // Bytes written from SPEC 6: opcode, token, then the fields (little endian).
        let p = parse_pipeline_spec(
            "window=100:30000,speckle,median=5,decimate=2:min,roi=100:900,intensity=500",
        )
        .unwrap();
        let want: Vec<Vec<u8>> = vec![
            vec![0x10, 1, 100, 0, 0, 0x30, 0x75, 0],
            vec![0x11, 2, 1],
            vec![0x12, 3, 5],
            vec![0x14, 4, 2, 1],
            vec![0x15, 5, 100, 0, 0x84, 0x03],
            vec![0x13, 6, 0xF4, 0x01],
        ];
        assert_eq!(p.frames, want);
        assert_eq!(
            control_header(&p.frames[1..2]),
            [SOH, 3, 0x11, 2, 1],
            "SOH, length, data"
        );
        // SPEC 6, 0x21 frame size: `max_len` 64 (CAN FD).
        assert_eq!(
            parse_pipeline_spec("frame=64").unwrap().frames,
            [vec![0x21, 1, 64]]
        );
        for bad in ["median=4", "decimate=2:max", "window=5", "blur", "frame=x"] {
            assert!(parse_pipeline_spec(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_bench_line_parses() {
        let text = "scip2can-qemu-bench 0.1.0 mps2-an386: ...\r\n\
                    bench bytes=7814 chunks=123 ticks=14647 max_chunk_ticks=299 scans_in=1 \
                    scans_sent=1 scans_aborted=0 frames=364 frame_hash=0x64e23ebe overruns=0 \
                    pop_ticks=812\r\n";
        assert_eq!(
            BenchLine::find(text),
            Some(BenchLine {
                bytes: 7814,
                chunks: 123,
                ticks: 14647,
                max_chunk_ticks: 299,
                scans_in: 1,
                scans_sent: 1,
                scans_aborted: 0,
                frames: 364,
                frame_hash: 0x64e2_3ebe,
                overruns: 0,
                pop_ticks: 812,
            })
        );
        assert_eq!(BenchLine::find("bench bytes=1 chunks=1\r\n"), None);
        assert_eq!(BenchLine::find("panic: oops\r\n"), None);
    }

    #[test]
    fn a_stream_with_an_eot_byte_is_refused_before_qemu_starts() {
        let e = run_firmware(
            "no-such-qemu",
            Path::new("none.elf"),
            b"PP\n\x04\n",
            Duration::ZERO,
        )
        .unwrap_err();
        assert!(
            format!("{e}").contains("EOT byte (0x04) at offset 3"),
            "{e}"
        );
    }

    #[cfg(unix)]
    #[test]
    fn no_result_line_is_an_error_that_quotes_uart1() {
        // `true` stands in for a QEMU that exits at once and prints nothing.
        let e = run_firmware(
            "true",
            Path::new("none.elf"),
            b"PP\n",
            Duration::from_secs(5),
        )
        .unwrap_err();
        let text = format!("{e}");
        assert!(
            text.starts_with("QEMU exited without a `bench` line"),
            "{text}"
        );
        assert!(text.contains("UART1: \"\""), "{text}");
    }

    #[test]
    fn fnv1a_of_one_frame_by_hand() {
        // 0x123, classic, 2 bytes AA BB: FNV-1a over 23 01 00 00 00 02 AA BB.
        let id = embedded_can::StandardId::new(0x123).unwrap();
        let frame =
            can_wire::Frame::new(embedded_can::Id::Standard(id), &[0xAA, 0xBB], false).unwrap();
        let mut h = FrameHash::default();
        h.frame(&frame);
        let mut want: u32 = 0x811C_9DC5;
        for b in [0x23u8, 0x01, 0, 0, 0, 2, 0xAA, 0xBB] {
            want = (want ^ u32::from(b)).wrapping_mul(16_777_619);
        }
        assert_eq!(h.0, want);
        // The published FNV-1a 32 test vector: "a" → 0xe40c292c.
        let mut a = FrameHash::default();
        a.bytes(b"a");
        assert_eq!(a.0, 0xe40c_292c);
    }
}
