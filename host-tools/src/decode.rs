//! `scip2can decode`: a candump log → scans (JSON lines or CSV), status and control
//! frames (JSON), and the loss statistics of every bridge.
//!
//! Frames are fed in log order to `can_wire::reassembly::Decoder`, which handles any
//! interleaving of up to 16 bridges of one identifier window; frames outside the window
//! (other devices), remote and error frames are skipped. A scan is printed when its
//! trailer or abort arrives, when its bridge's next scan begins, or at the end of the log
//! (then as incomplete). Each item is written (and standard output flushed) as soon as
//! it is complete, so `candump -L can0 | scip2can decode -` shows scans live.
//!
//! Live inputs: a CAN port with the `bridge`'s syntax and code ([`crate::live::port`];
//! frames stamped with the host's time since start), read until Ctrl-C or until the port
//! closes or fails (the reason is printed; the input then ends as a log does), and a
//! growing file with `--follow` ([`Follow`]). `--foxglove` also serves what is decoded
//! on a Foxglove WebSocket ([`crate::live::ws`]).
//!
//! A malformed log line (or one longer than [`crate::candump::MAX_LINE`]) is reported on
//! standard error with its line number and reason, counted in the summary, and skipped;
//! decoding goes on with the next line. A frame of the window that is not a valid
//! scip2can frame (another protocol on the same identifiers) is reported the same way
//! (its time and bytes) and counted as rejected. See [`json`] for the output formats.

pub mod json;

use std::collections::BTreeMap;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use can_wire::bandwidth::BitRates;
use can_wire::reassembly::{Completeness, Decoder, Event, LossStats, Point, Scan};
use can_wire::{Answer, Control, IdWindow, ScanHeader, Status, TrailerFlags, MAX_POINTS};

use crate::candump::{CandumpError, Reader, Record};
use crate::live::ws::{LiveView, LoadMeter};

/// Points per scan the decoder holds (every point a header can announce).
pub const POINTS: usize = MAX_POINTS as usize;
/// Bridges one decoder follows at once.
pub const BRIDGES: usize = 16;

/// The identifier window flags shared by replay, decode and plot.
#[derive(Debug, Clone, clap::Args)]
pub struct WindowArgs {
    /// Base identifier of the window (hex with 0x, or decimal).
    #[arg(long, default_value = "0x100", value_parser = parse_id)]
    pub base_id: u32,
    /// 29-bit identifiers.
    #[arg(long)]
    pub extended: bool,
}

fn parse_id(s: &str) -> Result<u32, String> {
    let parsed = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => s.parse(),
    };
    parsed.map_err(|_| format!("{s:?} is not a number (0x100 or 256)"))
}

impl WindowArgs {
    /// The window.
    pub fn window(&self) -> anyhow::Result<IdWindow> {
        let w = if self.extended {
            IdWindow::extended(self.base_id)
        } else {
            u16::try_from(self.base_id)
                .map_err(|_| can_wire::Error::BadIdWindow)
                .and_then(IdWindow::standard)
        };
        w.map_err(|_| {
            anyhow!(
                "--base-id {:#x}: the window of 128 identifiers does not fit {} IDs",
                self.base_id,
                if self.extended { "29-bit" } else { "11-bit" }
            )
        })
    }
}

/// A reassembled scan, owned.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedScan {
    /// The bridge's node number.
    pub node: u8,
    /// Log time of the frame that completed it, µs.
    pub time_us: u64,
    /// Its header.
    pub header: ScanHeader,
    /// The verdict.
    pub completeness: Completeness,
    /// The trailer's flags, if the trailer arrived.
    pub flags: Option<TrailerFlags>,
    /// Every point, `None` where it did not arrive.
    pub points: Vec<Option<Point>>,
}

impl DecodedScan {
    /// The owned copy of `scan` of bridge `node`, completed at `time_us` (what
    /// [`crate::view::laser_scan`] converts).
    pub fn new<const P: usize>(node: u8, time_us: u64, scan: &Scan<P>) -> Self {
        Self {
            node,
            time_us,
            header: *scan.header(),
            completeness: scan.completeness(),
            flags: scan.trailer().map(|t| t.flags),
            points: scan.points().collect(),
        }
    }
}

/// What the log held, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// A scan.
    Scan(DecodedScan),
    /// A status frame.
    Status {
        /// Node.
        node: u8,
        /// Log time, µs.
        time_us: u64,
        /// Content.
        status: Status,
    },
    /// A control answer.
    Answer {
        /// Node.
        node: u8,
        /// Log time, µs.
        time_us: u64,
        /// Content.
        answer: Answer,
    },
    /// A control request.
    Control {
        /// Addressed node.
        node: u8,
        /// Log time, µs.
        time_us: u64,
        /// Content.
        control: Control,
    },
}

/// Frame counts of a decoded log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameCounts {
    /// Data frames in the log.
    pub frames: u64,
    /// Frames of the window (fed to the decoder).
    pub ours: u64,
    /// Frames the decoder rejected (bad layout; counted as corrupt).
    pub rejected: u64,
    /// Remote and error frames (skipped).
    pub skipped: u64,
    /// Malformed log lines (skipped).
    pub lines_skipped: u64,
}

/// Malformed lines reported one by one on standard error; later ones are only counted.
pub const LINE_WARNINGS: u64 = 100;

/// A candump log decoder: records in, [`Item`]s out.
pub struct LogDecoder {
    window: IdWindow,
    decoder: Box<Decoder<POINTS, BRIDGES>>,
    nodes: BTreeMap<u8, ()>,
    counts: FrameCounts,
    last_us: u64,
    warn: bool,
}

impl std::fmt::Debug for LogDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogDecoder")
            .field("window", &self.window)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

impl LogDecoder {
    /// A decoder for the bridges of `window`.
    pub fn new(window: IdWindow) -> Self {
        // The decoder is ~650 kB and `Decoder::new` returns it by value: built on a
        // thread with a stack large enough for it (and its unoptimised copies), so that
        // callers on small stacks (test threads have 2 MB) do not overflow.
        let decoder = std::thread::Builder::new()
            .stack_size(16 << 20)
            .spawn(move || Box::new(Decoder::new(window)))
            .ok()
            .and_then(|t| t.join().ok());
        let decoder = decoder.unwrap_or_else(|| Box::new(Decoder::new(window)));
        Self {
            window,
            decoder,
            nodes: BTreeMap::new(),
            counts: FrameCounts::default(),
            last_us: 0,
            warn: false,
        }
    }

    /// Report rejected frames on standard error (the first [`LINE_WARNINGS`] of them;
    /// off by default: they are counted either way).
    pub fn set_warnings(&mut self, on: bool) {
        self.warn = on;
    }

    /// One log record; returns what it completed.
    pub fn push(&mut self, record: &Record) -> Option<Item> {
        let Some(frame) = record.to_frame() else {
            self.counts.skipped += 1;
            return None;
        };
        self.push_frame(record.time_us, &frame)
    }

    /// One data frame received at `t` µs (a CAN port's); returns what it completed.
    pub fn push_frame(&mut self, t: u64, frame: &can_wire::Frame) -> Option<Item> {
        self.counts.frames += 1;
        let (node, _) = self.window.classify(frame.id())?;
        self.counts.ours += 1;
        self.nodes.insert(node, ());
        self.last_us = t;
        match self.decoder.push_frame(frame) {
            Err(e) => {
                // E.g. another protocol's frames on the window's identifiers.
                self.counts.rejected += 1;
                let n = self.counts.rejected;
                if self.warn && n <= LINE_WARNINGS {
                    let rec = Record::from_frame(t, "", frame, false);
                    let text = rec.to_string();
                    let text = text.rsplit(' ').next().unwrap_or_default();
                    eprintln!(
                        "warning: frame {text} at {:.6} s is not a valid scip2can frame ({e}); counted as corrupt, skipped",
                        t as f64 / 1e6
                    );
                    if n == LINE_WARNINGS {
                        eprintln!("warning: further rejected frames are counted, not listed");
                    }
                }
                None
            }
            Ok(None) => None,
            Ok(Some(event)) => Some(match event {
                Event::Scan { node, scan } => Item::Scan(DecodedScan::new(node, t, scan)),
                Event::Status { node, status } => Item::Status {
                    node,
                    time_us: t,
                    status,
                },
                Event::Answer { node, answer } => Item::Answer {
                    node,
                    time_us: t,
                    answer,
                },
                Event::Control { node, control } => Item::Control {
                    node,
                    time_us: t,
                    control,
                },
            }),
        }
    }

    /// The end of the log: every bridge's scan in progress, as incomplete.
    pub fn finish(&mut self) -> Vec<Item> {
        let nodes: Vec<u8> = self.nodes.keys().copied().collect();
        let t = self.last_us;
        nodes
            .into_iter()
            .filter_map(|n| {
                let scan = self.decoder.flush(n)?;
                Some(Item::Scan(DecodedScan::new(n, t, scan)))
            })
            .collect()
    }

    /// Loss statistics of every bridge seen, by node.
    pub fn stats(&self) -> Vec<(u8, LossStats)> {
        self.nodes
            .keys()
            .filter_map(|&n| Some((n, *self.decoder.stats(n)?)))
            .collect()
    }

    /// Frame counts.
    pub fn counts(&self) -> FrameCounts {
        self.counts
    }

    /// One item of a [`Reader`]: a record is pushed; a malformed line is counted,
    /// reported on standard error (the first [`LINE_WARNINGS`] of them) and skipped.
    /// A read error is returned.
    pub fn push_read(&mut self, read: Result<Record, CandumpError>) -> io::Result<Option<Item>> {
        match read {
            Ok(record) => Ok(self.push(&record)),
            Err(CandumpError::Io(e)) => Err(e),
            Err(e @ CandumpError::Line { .. }) => {
                self.counts.lines_skipped += 1;
                let n = self.counts.lines_skipped;
                if n <= LINE_WARNINGS {
                    eprintln!("warning: {e}; skipped");
                }
                if n == LINE_WARNINGS {
                    eprintln!("warning: further malformed lines are counted, not listed");
                }
                Ok(None)
            }
        }
    }
}

/// Decodes a whole log into items (for tests and `plot`); malformed lines are skipped
/// as [`LogDecoder::push_read`] does. Fails only if reading fails.
pub fn decode_log(
    input: impl BufRead,
    window: IdWindow,
) -> Result<(Vec<Item>, LogDecoder), CandumpError> {
    let mut dec = LogDecoder::new(window);
    let mut items = Vec::new();
    for read in Reader::new(input) {
        items.extend(dec.push_read(read).map_err(CandumpError::Io)?);
    }
    items.extend(dec.finish());
    Ok((items, dec))
}

/// `scip2can decode` flags.
#[derive(Debug, Clone, clap::Args)]
pub struct DecodeArgs {
    /// The input: a candump log FILE, `-` for standard input, or a CAN port as `bridge`
    /// names it: `slcan:DEVICE[@BAUD]`, `slcan:tcp://HOST:PORT`, `socketcan:IFACE`
    /// (Linux, built with `--features socketcan`). `candump:FILE` is FILE.
    pub log: String,
    /// Follow FILE as it grows (like `tail -f`): at its end, wait for more; stop at
    /// Ctrl-C, or when the file is truncated, removed or replaced by another.
    #[arg(long)]
    pub follow: bool,
    /// One CSV row per point (seq,index,angle_rad,distance_mm,intensity,valid) instead of
    /// JSON lines; status and control frames are left out.
    #[arg(long)]
    pub csv: bool,
    /// The summary as one JSON object on standard error.
    #[arg(long)]
    pub stats: bool,
    /// Also serve the scans, the bridges' status frames and the decoder's counters to
    /// Foxglove on a WebSocket at HOST:PORT (e.g. 127.0.0.1:8765; port 0 picks one).
    #[arg(long, value_name = "HOST:PORT")]
    pub foxglove: Option<String>,
    /// Nominal bit rate of the bus, bit/s: the SLCAN `S` command of a port, and the bus
    /// load shown in Foxglove.
    #[arg(long, default_value_t = 1_000_000)]
    pub bitrate: u32,
    /// CAN FD data phase bit rate, bit/s (SLCAN `Y` command with --fd).
    #[arg(long, default_value_t = 5_000_000)]
    pub data_bitrate: u32,
    /// Open an SLCAN port for CAN FD frames with bit rate switch.
    #[arg(long)]
    pub fd: bool,
    /// Identifier window.
    #[command(flatten)]
    pub window: WindowArgs,
    /// MCAP output.
    #[command(flatten)]
    pub mcap: crate::view::mcap::McapArgs,
}

/// Opens a log path or `-`.
pub fn open_log(path: &str) -> anyhow::Result<Box<dyn BufRead>> {
    if path == "-" {
        return Ok(Box::new(BufReader::new(io::stdin())));
    }
    let f = std::fs::File::open(path).with_context(|| format!("opening {path}"))?;
    Ok(Box::new(BufReader::new(f)))
}

/// A growing file read like `tail -f`: at its end, waits for more until stopped, or until
/// the file is truncated, removed or replaced (then it ends, with a note on standard
/// error).
pub struct Follow {
    file: std::fs::File,
    path: std::path::PathBuf,
    pos: u64,
    identity: Option<(u64, u64)>,
    stop: Arc<AtomicBool>,
}

impl std::fmt::Debug for Follow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Follow")
            .field("path", &self.path)
            .field("pos", &self.pos)
            .finish_non_exhaustive()
    }
}

/// How often a followed file is looked at when nothing new is in it.
pub const FOLLOW_POLL: Duration = Duration::from_millis(50);

#[cfg(unix)]
fn identity(m: &std::fs::Metadata) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    Some((m.dev(), m.ino()))
}

#[cfg(not(unix))]
fn identity(_: &std::fs::Metadata) -> Option<(u64, u64)> {
    None
}

impl Follow {
    /// Opens `path` to follow it from its start; `stop` ends it at its current end.
    pub fn open(path: &str, stop: Arc<AtomicBool>) -> anyhow::Result<Self> {
        let file = std::fs::File::open(path).with_context(|| format!("opening {path}"))?;
        let identity = file.metadata().ok().as_ref().and_then(identity);
        Ok(Self {
            file,
            path: path.into(),
            pos: 0,
            identity,
            stop,
        })
    }

    /// Why following must end, if it must.
    fn ended(&self) -> Option<&'static str> {
        match std::fs::metadata(&self.path) {
            Err(_) => Some("was removed"),
            Ok(m) if self.identity.is_some() && identity(&m) != self.identity => {
                Some("was replaced by another file")
            }
            Ok(m) if m.len() < self.pos => Some("was truncated"),
            Ok(_) => None,
        }
    }
}

impl Read for Follow {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            let n = self.file.read(buf)?;
            if n > 0 {
                self.pos = self.pos.saturating_add(n as u64);
                return Ok(n);
            }
            if self.stop.load(Ordering::SeqCst) {
                return Ok(0);
            }
            if let Some(why) = self.ended() {
                eprintln!("decode: {} {why}; stopping", self.path.display());
                return Ok(0);
            }
            std::thread::sleep(FOLLOW_POLL);
        }
    }
}

/// The items' way out: standard output, the MCAP file and the Foxglove view, those
/// there are.
struct Output<'a> {
    out: &'a mut dyn Write,
    csv: bool,
    mcap: Option<crate::view::mcap::McapSink>,
    view: Option<LiveView>,
    load: LoadMeter,
    start: Instant,
    next_status: Duration,
}

impl Output<'_> {
    fn emit(&mut self, item: &Item) -> anyhow::Result<()> {
        if let Some(v) = &self.view {
            v.item(item);
        }
        if let Some(m) = &mut self.mcap {
            m.push(item)?;
        }
        if self.csv {
            match item {
                Item::Scan(s) => json::write_csv(self.out, s)?,
                _ => return Ok(()),
            }
        } else {
            serde_json::to_writer(&mut *self.out, &json::item(item))?;
            self.out.write_all(b"\n")?;
        }
        // Each item goes out as soon as it is complete (a live log shows scans as they
        // arrive).
        Ok(self.out.flush()?)
    }

    /// The decoder's counters to the view, once a second.
    fn tick(&mut self, dec: &LogDecoder) {
        let Some(view) = &self.view else { return };
        let t = self.start.elapsed();
        if t < self.next_status {
            return;
        }
        self.next_status = t + Duration::from_secs(1);
        let (frames, load) = self.load.take(t);
        let mut v = json::summary(dec);
        if let Some(o) = v.as_object_mut() {
            o.insert("time".into(), t.as_secs_f64().into());
            o.insert("frames_per_s".into(), frames.into());
            o.insert("bus_load_percent".into(), load.into());
            o.insert("foxglove_dropped".into(), view.dropped().into());
            o.insert("foxglove_clients".into(), view.clients().into());
        }
        view.status(v);
    }
}

/// `scip2can decode`.
pub fn run(args: DecodeArgs) -> anyhow::Result<()> {
    let window = args.window.window()?;
    // The MCAP file is created first: a bad path fails before any input is read.
    let mcap = crate::view::mcap::McapSink::from_args(&args.mcap)?;
    let source = args.log.strip_prefix("candump:").unwrap_or(&args.log);
    let is_port = source.starts_with("slcan:") || source.starts_with("socketcan:");
    if args.follow && (is_port || source == "-") {
        bail!("--follow takes a FILE (standard input and CAN ports are followed anyway)");
    }
    let stop = Arc::new(AtomicBool::new(false));
    if args.follow || is_port {
        // Ctrl-C ends the input; what is decoded so far and the summary are printed.
        let stop = stop.clone();
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst));
    }
    let view = match &args.foxglove {
        Some(addr) => {
            let v = LiveView::start(addr, "decode")?;
            eprintln!(
                "decode: Foxglove WebSocket server on ws://{}",
                v.local_addr()
            );
            Some(v)
        }
        None => None,
    };
    let mut stdout = io::BufWriter::new(io::stdout().lock());
    if args.csv {
        json::write_csv_header(&mut stdout)?;
        stdout.flush()?;
    }
    let rates = BitRates {
        nominal: args.bitrate,
        data: args.data_bitrate,
    };
    let mut out = Output {
        out: &mut stdout,
        csv: args.csv,
        mcap,
        view,
        load: LoadMeter::new(rates),
        start: Instant::now(),
        next_status: Duration::ZERO,
    };
    let mut dec = LogDecoder::new(window);
    dec.set_warnings(true);
    if is_port {
        let mut port = crate::live::port::open(source, args.bitrate, args.data_bitrate, args.fd)?;
        eprintln!("decode: reading {}", port.describe());
        while !stop.load(Ordering::SeqCst) {
            match port.recv() {
                Ok(Some(frame)) => {
                    let t = out.start.elapsed();
                    out.load.add(&frame);
                    let t_us = u64::try_from(t.as_micros()).unwrap_or(u64::MAX);
                    if let Some(item) = dec.push_frame(t_us, &frame) {
                        out.emit(&item)?;
                    }
                }
                Ok(None) => std::thread::sleep(Duration::from_millis(1)),
                Err(e) => {
                    // The port closing ends the input (as the end of a log does).
                    eprintln!("decode: {e:#}; end of input");
                    break;
                }
            }
            out.tick(&dec);
        }
    } else {
        let input: Box<dyn BufRead> = if args.follow {
            Box::new(BufReader::new(Follow::open(source, stop.clone())?))
        } else {
            open_log(source)?
        };
        for read in Reader::new(input) {
            let item = match read {
                Ok(record) => match record.to_frame() {
                    Some(frame) => {
                        out.load.add(&frame);
                        dec.push_frame(record.time_us, &frame)
                    }
                    None => dec.push(&record),
                },
                Err(e) => dec
                    .push_read(Err(e))
                    .with_context(|| format!("reading {}", args.log))?,
            };
            if let Some(item) = item {
                out.emit(&item)?;
            }
            out.tick(&dec);
        }
    }
    for item in dec.finish() {
        out.emit(&item)?;
    }
    out.next_status = Duration::ZERO;
    out.tick(&dec);
    let mcap = out.mcap.take().map(|m| m.finish()).transpose()?;
    drop(out);
    stdout.flush()?;
    if args.stats {
        let mut summary = json::summary(&dec);
        if let (Some(c), Some(o)) = (mcap, summary.as_object_mut()) {
            o.insert(
                "mcap".into(),
                serde_json::json!({"scans": c.scans, "diagnostics": c.diagnostics,
                    "geometry_unknown": c.geometry_unknown, "damaged": c.damaged}),
            );
        }
        eprintln!("{summary}");
    } else {
        eprint!("{}", json::summary_text(&dec));
        if let Some(c) = mcap {
            eprintln!(
                "mcap: {} scans, {} diagnostics written; {} scans without geometry and {} \
                 damaged left out",
                c.scans, c.diagnostics, c.geometry_unknown, c.damaged
            );
        }
    }
    Ok(())
}
