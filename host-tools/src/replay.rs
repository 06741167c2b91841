//! `scip2can replay`: the bridge core (`bridge::engine::Bridge`) on a recorded sensor
//! stream or an in-process simulated sensor, its CAN frames written as a candump log,
//! and the bus load they make.
//!
//! **Recordings** (raw sensor → host streams or `scip2can record` files): the session is
//! not started, so the bridge only listens, and publishes every measurement response it
//! decodes. The stream is fed line by line; the time of a line is its end position in
//! the stream at `--uart-baud` (10 bits per byte), so the same input always gives the
//! same log, and the governor's bus-time budget sees the stream at the pace a UART at
//! that rate delivers it. The input is read in chunks and each frame is written as it
//! leaves the bus, so memory does not grow with the input (a line longer than
//! [`LINE_CAP`] bytes, which SCIP never sends, is fed in pieces of that size). A recording
//! without a PP answer gives scans whose geometry is unknown (SPEC 3.2: no angles) and
//! whose error codes are read for an unknown model; `--model` names the sensor, whose
//! parameters the bridge then assumes (`Bridge::assume_sensor`; a PP answer in the
//! stream still wins).
//!
//! **`sim:key=value,...`** (the keys of `scip2can sim`): the bridge's session is started
//! and talks to a simulated sensor in virtual time (1 ms steps): it probes, identifies
//! and starts the stream itself; the run ends when `--scans` scans have begun and ended.
//! The sensor's answers reach the bridge at `--uart-baud` (so a sensor that measures
//! faster than the UART carries falls behind, as a real one on a serial line would; use
//! the USB or Ethernet rate for those sensors, e.g. `--uart-baud 12000000`). Times are
//! the simulator's.
//!
//! **The bus** ([`bus`]) has one sender, the bridge: frames leave its transmit queue in
//! order when the bus is free, each taking its worst-case length (bit stuffing included,
//! `can_wire::bandwidth::frame_bits`) at `--bitrate`/`--data-bitrate`. A frame's log
//! time is the end of its transmission.

pub mod args;
pub mod bus;

use std::fmt::Write as _;
use std::fs::File;
use std::io::{self, BufWriter, Read, Write};

use anyhow::{bail, Context};
use bridge::engine::{Bridge, BridgeConfig, BridgeStats};
use bridge::governor::GovernorStats;
use bridge::session::Action;
use can_wire::{Frame, Kind};

use self::args::ReplayArgs;
use self::bus::{Bus, BusTotals};
use crate::candump::{write_record, Record};
use crate::sim::SimOptions;

/// Capacity of the bridge's transmit queue, frames (what a board would give it).
pub const QUEUE: usize = 128;
/// The most of one stream line a replay holds before feeding it to the bridge, bytes.
pub const LINE_CAP: usize = 64 * 1024;
/// Bytes a replay reads from its input at a time.
const READ_CHUNK: usize = 64 * 1024;

/// A frame and the end of its transmission.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimedFrame {
    /// End of transmission, ns since the stream began.
    pub time_ns: u64,
    /// The frame.
    pub frame: Frame,
}

/// Everything a replay produced.
#[derive(Debug, Clone)]
pub struct Replayed {
    /// The bridge's configuration.
    pub config: BridgeConfig,
    /// Frames in transmit order (empty when they went to a sink as they were sent:
    /// [`replay_reader`]).
    pub frames: Vec<TimedFrame>,
    /// End of the last frame's transmission, ns (0 without frames).
    pub last_frame_ns: u64,
    /// The bridge's scan counters.
    pub stats: BridgeStats,
    /// The governor's counters.
    pub governor: GovernorStats,
    /// What went over the bus.
    pub bus: BusTotals,
    /// Length of the input: stream bytes at the UART rate, or the simulated time, ns.
    pub stream_ns: u64,
    /// The sensor's scan rate, when known (PP `SCAN`, or the simulator's).
    pub scan_hz: Option<f64>,
    /// The decimation the governor chose when the stream started (`sim:` runs with
    /// automatic decimation).
    pub plan: Option<bridge::governor::Plan>,
}

/// Where a replay's frames go, in transmit order, as they leave the bus.
pub type FrameSink<'a> = &'a mut dyn FnMut(&TimedFrame) -> io::Result<()>;

/// The bridge and the bus, stepped together.
struct Driver<'a> {
    bridge: Box<Bridge<QUEUE>>,
    bus: Bus,
    sink: FrameSink<'a>,
    last_frame_ns: u64,
}

impl<'a> Driver<'a> {
    fn new(config: BridgeConfig, sink: FrameSink<'a>) -> anyhow::Result<Self> {
        let bridge = Bridge::new(config).map_err(|e| anyhow::anyhow!("bridge settings: {e}"))?;
        Ok(Self {
            bridge: Box::new(bridge),
            bus: Bus::new(config.budget.rates, config.ids.window()),
            sink,
            last_frame_ns: 0,
        })
    }

    fn send(&mut self, ready_ns: u64, frame: Frame) -> io::Result<()> {
        let time_ns = self.bus.transmit(ready_ns, &frame);
        self.last_frame_ns = time_ns;
        (self.sink)(&TimedFrame { time_ns, frame })
    }

    /// Sends queued frames while the bus is free by `now_ns`; a frame cannot start before
    /// `ready_ns`.
    fn drain(&mut self, now_ns: u64, ready_ns: u64) -> io::Result<()> {
        while self.bus.free_at_ns() <= now_ns {
            let Some(frame) = self.bridge.pop_frame() else {
                break;
            };
            self.send(ready_ns, frame)?;
        }
        Ok(())
    }

    /// UART bytes arriving at `now_ns`; returns the session's actions.
    fn input(&mut self, now_ns: u64, bytes: &[u8]) -> io::Result<Vec<Action>> {
        // Frames queued earlier leave as the bus frees up, before the new ones exist.
        self.drain(now_ns, 0)?;
        let ms = now_ns / 1_000_000;
        self.bridge.on_uart(bytes, ms);
        let actions: Vec<Action> = std::iter::from_fn(|| self.bridge.poll(ms))
            .take(16)
            .collect();
        self.drain(now_ns, now_ns)?;
        Ok(actions)
    }

    fn finish(mut self, stream_ns: u64, scan_hz: Option<f64>) -> io::Result<Replayed> {
        while let Some(frame) = self.bridge.pop_frame() {
            self.send(0, frame)?;
        }
        Ok(Replayed {
            config: *self.bridge.config(),
            frames: Vec::new(),
            last_frame_ns: self.last_frame_ns,
            stats: *self.bridge.stats(),
            governor: *self.bridge.governor().stats(),
            bus: *self.bus.totals(),
            stream_ns,
            scan_hz,
            plan: self.bridge.plan().copied(),
        })
    }
}

/// Time of stream position `bytes` at `baud` (10 bits per byte), ns.
pub fn uart_time_ns(bytes: u64, baud: u32) -> u64 {
    bytes * 10 * 1_000_000_000 / u64::from(baud.max(1))
}

/// Watches a stream for the scan rate its PP answer gives (`SCAN` rpm / 60), until it
/// is found.
#[derive(Debug, Default)]
struct PpWatch {
    decoder: scip::Decoder,
    collector: crate::parse::Collector,
    done: Vec<crate::parse::ResponseJson>,
    scan_hz: Option<f64>,
}

impl PpWatch {
    fn look(&mut self) {
        self.scan_hz = self.done.drain(..).find_map(|r| {
            let rpm = r.fields.get("SCAN")?.as_str()?.parse::<f64>().ok()?;
            (r.command.as_deref() == Some("PP") && rpm > 0.0).then_some(rpm / 60.0)
        });
    }

    fn feed(&mut self, bytes: &[u8]) {
        if self.scan_hz.is_none() {
            self.collector
                .feed(&mut self.decoder, bytes, &mut self.done);
            self.look();
        }
    }

    fn finish(mut self) -> Option<f64> {
        if self.scan_hz.is_none() {
            self.collector.finish(&mut self.decoder, &mut self.done);
            self.look();
        }
        self.scan_hz
    }
}

/// Replays a sensor → host stream through a listening bridge, line by line; the frames
/// are collected in [`Replayed::frames`].
pub fn replay_stream(bytes: &[u8], config: BridgeConfig) -> anyhow::Result<Replayed> {
    replay_stream_as(bytes, config, None)
}

/// [`replay_stream`] of a sensor whose parameters are known where the stream has no PP
/// answer (`Bridge::assume_sensor`).
pub fn replay_stream_as(
    bytes: &[u8],
    config: BridgeConfig,
    assumed: Option<scip::SensorParams>,
) -> anyhow::Result<Replayed> {
    let mut frames = Vec::new();
    let mut sink = |f: &TimedFrame| {
        frames.push(*f);
        Ok(())
    };
    let mut r = replay_reader(bytes, config, assumed, &mut sink)?;
    r.frames = frames;
    Ok(r)
}

/// Replays a sensor → host stream read from `input` through a listening bridge, line
/// by line, in constant memory: each frame goes to `sink` as it leaves the bus
/// ([`Replayed::frames`] stays empty). A sink error stops the replay.
pub fn replay_reader(
    mut input: impl Read,
    config: BridgeConfig,
    assumed: Option<scip::SensorParams>,
    sink: FrameSink<'_>,
) -> anyhow::Result<Replayed> {
    let mut driver = Driver::new(config, sink)?;
    if let Some(params) = assumed {
        driver.bridge.assume_sensor(params);
    }
    let mut pp = PpWatch::default();
    let mut chunk = vec![0u8; READ_CHUNK];
    // The start of a line whose end has not been read yet.
    let mut pending: Vec<u8> = Vec::with_capacity(LINE_CAP);
    let mut pos = 0u64;
    let baud = config.uart_bit_rate;
    let mut feed = |driver: &mut Driver<'_>, pos: &mut u64, line: &[u8]| -> anyhow::Result<()> {
        *pos += line.len() as u64;
        pp.feed(line);
        driver
            .input(uart_time_ns(*pos, baud), line)
            .map(drop)
            .context("writing the frames")
    };
    loop {
        let n = match input.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e).context("reading the stream"),
        };
        let mut rest = chunk.get(..n).unwrap_or(&[]);
        while !rest.is_empty() {
            let end = rest.iter().position(|&b| b == b'\n');
            let take = end.map_or(rest.len(), |i| i + 1);
            // `pending` always holds less than LINE_CAP bytes.
            let room = LINE_CAP - pending.len();
            if pending.is_empty() && end.is_some() && take <= LINE_CAP {
                // A whole line in the chunk: fed from there.
                let (line, after) = rest.split_at(take);
                feed(&mut driver, &mut pos, line)?;
                rest = after;
            } else if take < room || (end.is_some() && take == room) {
                let (part, after) = rest.split_at(take);
                pending.extend_from_slice(part);
                rest = after;
                if end.is_some() {
                    feed(&mut driver, &mut pos, &pending)?;
                    pending.clear();
                }
            } else {
                // A line longer than LINE_CAP: fed LINE_CAP bytes at a time.
                let (part, after) = rest.split_at(room);
                pending.extend_from_slice(part);
                rest = after;
                feed(&mut driver, &mut pos, &pending)?;
                pending.clear();
            }
        }
    }
    if !pending.is_empty() {
        feed(&mut driver, &mut pos, &pending)?;
    }
    let end = uart_time_ns(pos, baud);
    driver
        .finish(end, pp.finish())
        .context("writing the frames")
}

/// A UART in virtual time: bytes queue up and leave at `baud` (10 bits per byte).
#[derive(Debug)]
struct Uart {
    baud: u32,
    /// Bit·ms of sending credit (one byte costs 10 000).
    credit: u64,
    pending: std::collections::VecDeque<u8>,
}

impl Uart {
    /// The bytes that leave in the next millisecond.
    fn tick(&mut self, incoming: Vec<u8>) -> Vec<u8> {
        self.pending.extend(incoming);
        self.credit += u64::from(self.baud);
        let n = usize::try_from(self.credit / 10_000)
            .unwrap_or(usize::MAX)
            .min(self.pending.len());
        self.credit -= n as u64 * 10_000;
        if self.pending.len() == n {
            // An idle line saves no credit for later.
            self.credit = self.credit.min(10_000);
        }
        self.pending.drain(..n).collect()
    }
}

/// Runs a started bridge against a simulated sensor in 1 ms steps until `scans` scans
/// have begun and ended (sent, aborted, skipped or dropped), or fails if that takes more
/// than a minute of simulated time beyond the scans' own. The sensor's bytes reach the
/// bridge at the configured UART bit rate. With `auto_decimation` the governor chooses
/// the decimation when the stream starts (`Bridge::set_auto_decimation`); without, the
/// configured pipeline runs as it is.
pub fn replay_sim(
    sim: &SimOptions,
    scans: u32,
    config: BridgeConfig,
    auto_decimation: bool,
) -> anyhow::Result<Replayed> {
    let mut frames = Vec::new();
    let mut sink = |f: &TimedFrame| {
        frames.push(*f);
        Ok(())
    };
    let mut r = replay_sim_into(sim, scans, config, auto_decimation, &mut sink)?;
    r.frames = frames;
    Ok(r)
}

/// [`replay_sim`] with each frame going to `sink` as it leaves the bus
/// ([`Replayed::frames`] stays empty).
pub fn replay_sim_into(
    sim: &SimOptions,
    scans: u32,
    config: BridgeConfig,
    auto_decimation: bool,
    sink: FrameSink<'_>,
) -> anyhow::Result<Replayed> {
    let mut sensor = sim.build()?;
    let mut driver = Driver::new(config, sink)?;
    driver.bridge.set_auto_decimation(auto_decimation);
    let mut uart = Uart {
        baud: config.uart_bit_rate,
        credit: 0,
        pending: Default::default(),
    };
    driver.bridge.start(0);
    let limit_ms = 60_000 + u64::from(scans) * 2 * sensor.scan_period_us() / 1000;
    let mut ms = 0u64;
    let mut actions = Vec::new();
    let ended =
        |st: &BridgeStats| st.scans_sent + st.scans_aborted + st.scans_skipped + st.scans_dropped;
    while ended(driver.bridge.stats()) < scans {
        if ms > limit_ms {
            bail!(
                "the simulated sensor gave {} of {scans} scans in {} s (session {:?})",
                ended(driver.bridge.stats()),
                limit_ms / 1000,
                driver.bridge.session().state()
            );
        }
        let now_us = ms * 1000;
        for action in actions.drain(..) {
            if let Action::Send(request) = action {
                let mut buf = [0u8; scip::REQUEST_MAX];
                let n = scip::Request::encode(&request, &mut buf)
                    .map_err(|e| anyhow::anyhow!("encoding {request:?}: {e:?}"))?;
                sensor.receive(now_us, buf.get(..n).unwrap_or(&[]));
            }
        }
        let bytes = uart.tick(sensor.take_output(now_us));
        actions = driver
            .input(ms * 1_000_000, &bytes)
            .context("writing the frames")?;
        ms += 1;
    }
    driver.bridge.stop(ms);
    let hz = 1e6 / sensor.scan_period_us().max(1) as f64;
    driver
        .finish(ms * 1_000_000, Some(hz))
        .context("writing the frames")
}

impl Replayed {
    /// The frames as candump records.
    pub fn records(&self, interface: &str, brs: bool) -> Vec<Record> {
        self.frames
            .iter()
            .map(|f| Record::from_frame(f.time_ns / 1000, interface, &f.frame, brs))
            .collect()
    }

    /// Scans that went out (whole or aborted).
    pub fn scans_out(&self) -> u64 {
        self.bus.by_kind[Kind::HeaderA as usize]
    }

    /// The human-readable summary: counters and bus load.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let st = &self.stats;
        let g = &self.governor;
        let b = &self.bus;
        let k = |kind: Kind| b.by_kind[kind as usize];
        let budget = &self.config.budget;
        let bus = if budget.format.is_fd() {
            format!(
                "CAN FD {}/{} Mbit/s, {}-byte frames",
                mbit(budget.rates.nominal),
                mbit(budget.rates.data),
                budget.format.max_len()
            )
        } else {
            format!("classic CAN {} Mbit/s", mbit(budget.rates.nominal))
        };
        let _ = writeln!(
            s,
            "scans: {} in, {} sent, {} aborted, {} skipped, {} dropped ({} budget, {} queue), \
             {} lost (never started)",
            st.scans_in,
            st.scans_sent,
            st.scans_aborted,
            st.scans_skipped,
            st.scans_dropped,
            g.dropped_budget,
            g.dropped_queue,
            st.scans_lost
        );
        let _ = writeln!(
            s,
            "frames: {} ({} header, {} data, {} trailer, {} abort, {} status, {} answer), {} payload bytes",
            b.frames,
            k(Kind::HeaderA) + k(Kind::HeaderB),
            k(Kind::Data),
            k(Kind::Trailer),
            k(Kind::Abort),
            k(Kind::Status),
            k(Kind::ControlAnswer),
            b.payload_bytes
        );
        let span = self.stream_ns.max(self.last_frame_ns);
        let _ = writeln!(
            s,
            "bus: {bus}, worst-case stuffing: {} + {} bits, {:.3} ms busy in {:.3} s = {:.2} % load",
            b.nominal_bits,
            b.data_bits,
            b.busy_ns as f64 / 1e6,
            span as f64 / 1e9,
            percent(b.busy_ns as f64, span as f64)
        );
        if let Some(p) = &self.plan {
            let _ = writeln!(
                s,
                "governor plan: every {} point(s), every {} scan(s): {} points per scan, {:.2} % average load",
                p.factor,
                p.every_nth,
                p.points,
                p.load_ppm as f64 / 1e4
            );
        }
        let scans = self.scans_out();
        if scans > 0 {
            let per_scan = b.scan_ns as f64 / scans as f64;
            let _ = write!(
                s,
                "per scan: {:.1} frames, {:.1} µs of bus",
                (k(Kind::HeaderA)
                    + k(Kind::HeaderB)
                    + k(Kind::Data)
                    + k(Kind::Trailer)
                    + k(Kind::Abort)) as f64
                    / scans as f64,
                per_scan / 1e3
            );
            if let Some(hz) = self.scan_hz {
                let _ = write!(
                    s,
                    "; at {hz:.2} scans/s: {:.2} % load",
                    percent(per_scan * hz, 1e9)
                );
            }
            s.push('\n');
        }
        s
    }
}

fn mbit(rate: u32) -> String {
    let m = f64::from(rate) / 1e6;
    format!("{m}")
}

fn percent(part: f64, whole: f64) -> f64 {
    if whole > 0.0 {
        100.0 * part / whole
    } else {
        0.0
    }
}

/// `scip2can replay`: the candump log is written frame by frame as the replay runs.
pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let config = args.bridge_config()?;
    let (interface, brs) = (args.interface.as_str(), args.can.brs());
    let mut out: BufWriter<Box<dyn Write>> = BufWriter::new(match &args.output {
        Some(path) => {
            Box::new(File::create(path).with_context(|| format!("creating {}", path.display()))?)
        }
        None => Box::new(io::stdout().lock()),
    });
    let mut sink = |f: &TimedFrame| {
        write_record(
            &mut out,
            &Record::from_frame(f.time_ns / 1000, interface, &f.frame, brs),
        )
    };
    let assumed = args.model.map(|m| m.params());
    let mut replayed = if let Some(spec) = args.input.strip_prefix("sim:") {
        if args.model.is_some() {
            bail!("--model is for recorded streams; a sim: sensor has its own model");
        }
        let sim = SimOptions::from_spec(spec)?;
        let p = &args.pipeline;
        let user_decimation = p.decimate.is_some() || p.every_nth.is_some() || p.max_rate.is_some();
        replay_sim_into(&sim, args.scans, config, !user_decimation, &mut sink)?
    } else {
        let input: Box<dyn Read> = if args.input == "-" {
            Box::new(io::stdin().lock())
        } else {
            Box::new(File::open(&args.input).with_context(|| format!("opening {}", args.input))?)
        };
        let stream = crate::sensor::record_file::sensor_side(input)
            .with_context(|| format!("reading {}", args.input))?;
        replay_reader(stream, config, assumed, &mut sink)
            .with_context(|| format!("replaying {}", args.input))?
    };
    out.flush().context("writing the log")?;
    if args.scan_hz.is_some() {
        replayed.scan_hz = args.scan_hz;
    }
    if replayed.scan_hz.is_none() {
        replayed.scan_hz = assumed
            .and_then(|p| p.scan_rpm)
            .map(|rpm| f64::from(rpm) / 60.0);
    }
    eprint!("{}", replayed.report());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uart_time_is_ten_bits_per_byte() {
        assert_eq!(uart_time_ns(11_520, 115_200), 1_000_000_000);
        assert_eq!(uart_time_ns(1, 1_000_000), 10_000);
    }
}
