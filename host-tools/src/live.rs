//! `scip2can bridge`: the bridge core as a host process — a real sensor link (serial,
//! TCP, or the in-process simulator) to a real CAN port (SLCAN adapter, SocketCAN, or a
//! candump log), in real time, with the same `bridge::engine::Bridge` the firmware runs.
//!
//! The loop: bytes from the sensor go to `Bridge::on_uart`; the session's commands go
//! back to the sensor (and a bit-rate change to the serial port); frames leave through
//! the CAN port in queue order; frames received on the port (control frames addressed to
//! this bridge) go to `Bridge::on_can_frame_at`, which answers them, and a time master's
//! SYNC / FOLLOW-UP frames on the bus (`scip2can timesync`, SPEC 9) map the bridge's
//! clock to the robot's ([`bridge::engine::Bridge::to_master`]). Once a second a
//! summary line goes to standard error (`--quiet` turns it off). With `--foxglove`, every
//! frame on the bus is also decoded and the scans, status frames and the bridge's own
//! state go to a Foxglove WebSocket server ([`ws`]), which can never hold the loop up.

pub mod port;
pub mod ws;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use bridge::engine::Bridge;
use bridge::session::Action;

use crate::replay::args::{CanArgs, PipelineArgs};
use crate::sensor::link;
use crate::sensor::spec::SensorSpec;

/// Transmit queue of the host bridge, frames.
pub const QUEUE: usize = 256;

/// Sensor bytes handed to the core at a time (a DMA half-buffer's worth on a board).
const SLICE: usize = 64;

/// `scip2can bridge` flags.
#[derive(Debug, Clone, clap::Args)]
pub struct BridgeArgs {
    /// The sensor: `tcp://host:port`, a serial device (with --baud), or `sim:key=value,...`
    /// (an in-process simulated sensor; `sim:` alone is a UTM-30LX).
    #[arg(default_value = "sim:")]
    pub sensor: String,
    /// Bit rate of a serial sensor.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// The CAN port: `candump:-` (standard output), `candump:FILE`, `slcan:DEVICE[@BAUD]`,
    /// `slcan:tcp://HOST:PORT`, or `socketcan:IFACE` (Linux, built with `--features
    /// socketcan`).
    #[arg(long, default_value = "candump:-")]
    pub can: String,
    /// Bus and wire encoding.
    #[command(flatten)]
    pub bus: CanArgs,
    /// Scan pipeline.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// What the session streams: D (distance), S (short), E (distance and intensity).
    #[arg(long, default_value = "D", value_parser = crate::replay::args::parse_data_set)]
    pub sensor_data: scip::DataSet,
    /// Period of the status frames, ms (0: none).
    #[arg(long, default_value_t = 1000)]
    pub status_period: u32,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// No summary lines on standard error.
    #[arg(long)]
    pub quiet: bool,
    /// Serve the scans on the bus, the status frames and the bridge's own state,
    /// counters and bus load to Foxglove on a WebSocket at HOST:PORT (e.g.
    /// 127.0.0.1:8765; port 0 picks one). A slow or closed client never holds the
    /// bridge up.
    #[arg(long, value_name = "HOST:PORT")]
    pub foxglove: Option<String>,
    /// Estimate each scan's time in this host's monotonic clock (µs since the bridge
    /// started; a TM calibration at session start) and send it in scan headers once
    /// calibrated (SPEC 3.1 `time_estimated`).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub time_estimate: bool,
    /// Run on the simulator's time instead of the host's (a `sim:` sensor only): time
    /// moves straight to the sensor's next event whenever the bridge waits for it, so a
    /// run takes only its work's time, `--seconds` counts simulated seconds, and every
    /// time the bridge sees (scan arrivals, TM answers, status periods) is that of an
    /// ideal host, the same on any machine (e.g. for CI).
    #[arg(long)]
    pub virtual_time: bool,
}

/// The bridge's clock: the host's, or the simulator's virtual one.
enum LiveClock {
    Real(Instant),
    Virtual(link::VirtualClock),
}

impl LiveClock {
    /// Time since the bridge started.
    fn elapsed(&self) -> Duration {
        match self {
            LiveClock::Real(start) => start.elapsed(),
            LiveClock::Virtual(clock) => Duration::from_micros(clock.now_us()),
        }
    }

    /// µs since the bridge started.
    fn now_us(&self) -> u64 {
        u64::try_from(self.elapsed().as_micros()).unwrap_or(u64::MAX)
    }
}

/// The Foxglove side of the bridge: every frame on the bus (sent and received) is
/// decoded as `decode` would, and the scans and status go to the server.
struct Viewer {
    view: ws::LiveView,
    dec: crate::decode::LogDecoder,
    load: ws::LoadMeter,
}

impl Viewer {
    /// A frame on the bus at `t_us` (µs since the bridge started).
    fn frame(&mut self, frame: &can_wire::Frame, t_us: u64) {
        self.load.add(frame);
        if let Some(item) = self.dec.push_frame(t_us, frame) {
            self.view.item(&item);
        }
    }

    /// The bridge's state at `t` since it started.
    fn status(&mut self, bridge: &Bridge<QUEUE>, state: &str, t: Duration) {
        let (frames_per_s, load) = self.load.take(t);
        let s = bridge.stats();
        let c = self.dec.counts();
        let plan = bridge.plan().map(|p| {
            serde_json::json!({"points": p.points, "decimation": p.factor,
                "every_nth": p.every_nth, "worst_case_load_percent": p.load_ppm as f64 / 10_000.0})
        });
        self.view.status(serde_json::json!({
            "time": t.as_secs_f64(),
            "state": state,
            "plan": plan,
            "scans_sent": s.scans_sent,
            "scans_aborted": s.scans_aborted,
            "scans_dropped": s.scans_dropped + s.scans_skipped,
            "frames": s.frames,
            "frames_per_s": frames_per_s,
            "bus_load_percent": load,
            "queued": bridge.queued(),
            "decoder_errors": bridge.decoder().stats().errors,
            "bus_frames_rejected": c.rejected,
            "foxglove_dropped": self.view.dropped(),
            "foxglove_clients": self.view.clients(),
        }));
    }
}

/// Runs the bridge until Ctrl-C or `--seconds`.
pub fn run(args: BridgeArgs) -> anyhow::Result<()> {
    let mut config = crate::replay::args::bridge_config(
        &args.bus,
        &args.pipeline,
        args.baud,
        args.status_period,
        args.sensor_data,
    )?;
    let spec = SensorSpec::parse(&args.sensor, args.baud)?;
    // A TCP sensor, and the in-process simulator (whose answers and scans leave it
    // whole, as an Ethernet sensor's do), bring a response at once: no byte time to
    // date its bytes back by, no UART time for frames to drain in (`bridge::link`).
    let burst = !matches!(spec, SensorSpec::Serial { .. });
    if burst {
        // As the Ethernet boards configure it.
        config = config.on_network();
    }
    let virtual_clock = args.virtual_time.then(link::VirtualClock::new);
    let mut link = match &virtual_clock {
        Some(clock) => link::open_virtual(&spec, clock.clone()),
        None => link::open(&spec, Duration::from_secs(2)),
    }
    .with_context(|| format!("opening the sensor {}", args.sensor))?;
    let mut can = port::open(
        &args.can,
        config.budget.rates.nominal,
        config.budget.rates.data,
        args.bus.fd,
    )?;
    let mut bridge: Box<Bridge<QUEUE>> =
        Box::new(Bridge::new(config).map_err(|e| anyhow::anyhow!("{e}"))?);
    let p = &args.pipeline;
    if p.decimate.is_some() || p.every_nth.is_some() || p.max_rate.is_some() {
        bridge.set_auto_decimation(false);
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        // A second handler (e.g. in tests) is not an error worth failing for.
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst));
    }
    if !args.quiet {
        eprintln!("scip2can bridge: {} → {}", link.describe(), can.describe());
    }
    let clock = match virtual_clock {
        Some(clock) => LiveClock::Virtual(clock),
        None => LiveClock::Real(Instant::now()),
    };
    let mut viewer = match &args.foxglove {
        Some(addr) => {
            let view = ws::LiveView::start(addr, "bridge")?;
            // Printed even with --quiet: the address is how one connects.
            eprintln!(
                "scip2can bridge: Foxglove WebSocket server on ws://{}",
                view.local_addr()
            );
            Some(Viewer {
                view,
                dec: crate::decode::LogDecoder::new(config.ids.window()),
                load: ws::LoadMeter::new(config.budget.rates),
            })
        }
        None => None,
    };
    let mut state = String::from("Starting");
    let deadline = args.seconds.map(|s| Duration::from_secs_f64(s.max(0.0)));
    let now_ms = || clock.elapsed().as_millis() as u64;
    let now_us = || clock.now_us();
    bridge.set_time_estimation(args.time_estimate);
    bridge.start(now_ms());
    if burst {
        // Connected (or built) by `link::open` above.
        bridge.link_up(now_ms());
    }
    // µs per byte at the sensor link's rate (10 bits a byte); none on a burst link.
    let byte_us = if burst {
        0
    } else {
        10_000_000 / u64::from(args.baud.max(1))
    };
    let mut buf = vec![0u8; 4096];
    let mut next_report = Duration::from_secs(1);
    let mut last = Summary::default();
    // TimeSync notices in a row.
    let mut tm_readings = 0u32;
    // The governor's plan last printed: factor, every n-th scan, points.
    let mut shown_plan = None;
    while !stop.load(Ordering::SeqCst) && deadline.is_none_or(|d| clock.elapsed() < d) {
        let n = link
            .recv(&mut buf, Duration::from_millis(2))
            .context("reading the sensor")?;
        // In UART-sized pieces, with the queue drained between them, as on the MCU;
        // the last byte arrived when `recv` returned, earlier ones a byte time apart.
        let arrived = now_us();
        let mut left = n;
        for piece in buf.get(..n).unwrap_or(&[]).chunks(SLICE) {
            left -= piece.len();
            bridge.on_uart_at(piece, arrived.saturating_sub(left as u64 * byte_us));
            while let Some(frame) = bridge.pop_frame() {
                can.send(&frame).context("writing to the CAN port")?;
                if let Some(v) = &mut viewer {
                    v.frame(&frame, now_us());
                }
            }
        }
        while let Some(action) = bridge.poll_at(now_us()) {
            match action {
                Action::Send(request) => send(link.as_mut(), &request)?,
                Action::SetBitRate(rate) => link
                    .set_bit_rate(rate)
                    .with_context(|| format!("switching the sensor link to {rate} bit/s"))?,
            }
        }
        if let Some(notice) = bridge.take_notice() {
            state = format!("{notice:?}");
            // A TM calibration reads the sensor's clock many times: its first reading is
            // printed, the number of the others with the next notice.
            let reading = matches!(notice, bridge::session::Notice::TimeSync { .. });
            let repeat = reading && tm_readings > 0;
            if !args.quiet && !reading && tm_readings > 1 {
                eprintln!("           ({tm_readings} TM readings of the sensor clock)");
            }
            tm_readings = if reading { tm_readings + 1 } else { 0 };
            if !args.quiet && !repeat {
                eprintln!("[{:8.3} s] {notice:?}", clock.elapsed().as_secs_f64());
            }
        }
        // The governor's plan when the stream starts, and again whenever it changes
        // (with the lossless coding it plans from the bits per point it has seen).
        if let Some(plan) = bridge.plan().filter(|_| !args.quiet) {
            let now = (plan.factor, plan.every_nth, plan.points);
            if shown_plan != Some(now) {
                shown_plan = Some(now);
                eprintln!(
                    "[{:8.3} s] governor: {} points per scan (1 in {} steps kept), 1 scan in {} sent, worst-case bus load {:.1} %",
                    clock.elapsed().as_secs_f64(),
                    plan.points,
                    plan.factor,
                    plan.every_nth,
                    plan.load_ppm as f64 / 10_000.0
                );
            }
        }
        while let Some(frame) = bridge.pop_frame() {
            can.send(&frame).context("writing to the CAN port")?;
            if let Some(v) = &mut viewer {
                v.frame(&frame, now_us());
            }
        }
        while let Some(frame) = can.recv().context("reading the CAN port")? {
            // µs of the same clock: time frames (SPEC 9) are stamped at that resolution.
            bridge.on_can_frame_at(&frame, now_us());
            if let Some(v) = &mut viewer {
                v.frame(&frame, now_us());
            }
        }
        if clock.elapsed() >= next_report {
            next_report += Duration::from_secs(1);
            if let Some(v) = &mut viewer {
                v.status(&bridge, &state, clock.elapsed());
            }
            if !args.quiet {
                let now = Summary::of(&bridge);
                eprintln!("{}", now.line(&last, clock.elapsed().as_secs_f64()));
                last = now;
            }
        }
    }
    // Leave the sensor quiet: stop the stream and give the QT a moment to go out.
    bridge.stop(now_ms());
    while let Some(action) = bridge.poll(now_ms()) {
        if let Action::Send(request) = action {
            // Best effort: the sensor may already be gone.
            let _ = send(link.as_mut(), &request);
        }
    }
    while let Some(frame) = bridge.pop_frame() {
        can.send(&frame)?;
    }
    if !args.quiet {
        let s = Summary::of(&bridge);
        eprintln!(
            "scip2can bridge: {} scans sent, {} aborted, {} dropped, {} decoder errors",
            s.sent, s.aborted, s.dropped, s.errors
        );
    }
    Ok(())
}

/// Writes a session command to the sensor.
fn send(link: &mut dyn link::Link, request: &scip::Request) -> anyhow::Result<()> {
    let mut line = [0u8; scip::REQUEST_MAX];
    let len = request
        .encode(&mut line)
        .map_err(|e| anyhow::anyhow!("encoding {request:?}: {e}"))?;
    link.send(line.get(..len).unwrap_or(&[]))
        .context("writing to the sensor")
}

/// Counters for the once-a-second line.
#[derive(Debug, Clone, Copy, Default)]
struct Summary {
    sent: u32,
    aborted: u32,
    dropped: u32,
    frames: u32,
    errors: u32,
}

impl Summary {
    fn of(b: &Bridge<QUEUE>) -> Self {
        let s = b.stats();
        Self {
            sent: s.scans_sent,
            aborted: s.scans_aborted,
            dropped: s.scans_dropped + s.scans_skipped,
            frames: s.frames,
            errors: b.decoder().stats().errors,
        }
    }

    fn line(&self, last: &Summary, t: f64) -> String {
        format!(
            "[{t:8.3} s] scans {:3}/s sent ({} total), {} aborted, {} dropped, {} frames/s, {} decoder errors",
            self.sent - last.sent,
            self.sent,
            self.aborted,
            self.dropped,
            self.frames - last.frames,
            self.errors
        )
    }
}
