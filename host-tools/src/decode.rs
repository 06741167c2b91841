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
//! A malformed log line (or one longer than [`crate::candump::MAX_LINE`]) is reported on
//! standard error with its line number and reason, counted in the summary, and skipped;
//! decoding goes on with the next line. See [`json`] for the output formats.

pub mod json;

use std::collections::BTreeMap;
use std::io::{self, BufRead, BufReader, Write};

use anyhow::{anyhow, Context};
use can_wire::reassembly::{Completeness, Decoder, Event, LossStats, Point, Scan};
use can_wire::{Answer, Control, IdWindow, ScanHeader, Status, TrailerFlags, MAX_POINTS};

use crate::candump::{CandumpError, Reader, Record};

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
        }
    }

    /// One log record; returns what it completed.
    pub fn push(&mut self, record: &Record) -> Option<Item> {
        let Some(frame) = record.to_frame() else {
            self.counts.skipped += 1;
            return None;
        };
        self.counts.frames += 1;
        let (node, _) = self.window.classify(frame.id())?;
        self.counts.ours += 1;
        self.nodes.insert(node, ());
        self.last_us = record.time_us;
        let t = record.time_us;
        match self.decoder.push_frame(&frame) {
            Err(_) => {
                self.counts.rejected += 1;
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
    /// The candump log, or `-` for standard input.
    pub log: String,
    /// One CSV row per point (seq,index,angle_rad,distance_mm,intensity,valid) instead of
    /// JSON lines; status and control frames are left out.
    #[arg(long)]
    pub csv: bool,
    /// The summary as one JSON object on standard error.
    #[arg(long)]
    pub stats: bool,
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

/// `scip2can decode`.
pub fn run(args: DecodeArgs) -> anyhow::Result<()> {
    let window = args.window.window()?;
    // The MCAP file is created first: a bad path fails before any input is read.
    let mut mcap = crate::view::mcap::McapSink::from_args(&args.mcap)?;
    let input = open_log(&args.log)?;
    let mut out = io::BufWriter::new(io::stdout().lock());
    let mut dec = LogDecoder::new(window);
    if args.csv {
        json::write_csv_header(&mut out)?;
    }
    // Each item goes out as soon as it is complete (a live log shows scans as they
    // arrive).
    let emit = |item: &Item, out: &mut dyn Write| -> io::Result<()> {
        if args.csv {
            match item {
                Item::Scan(s) => json::write_csv(out, s)?,
                _ => return Ok(()),
            }
        } else {
            serde_json::to_writer(&mut *out, &json::item(item))?;
            out.write_all(b"\n")?;
        }
        out.flush()
    };
    if args.csv {
        out.flush()?;
    }
    for read in Reader::new(input) {
        let item = dec
            .push_read(read)
            .with_context(|| format!("reading {}", args.log))?;
        if let Some(item) = item {
            emit(&item, &mut out)?;
            if let Some(m) = &mut mcap {
                m.push(&item)?;
            }
        }
    }
    for item in dec.finish() {
        emit(&item, &mut out)?;
        if let Some(m) = &mut mcap {
            m.push(&item)?;
        }
    }
    out.flush()?;
    let mcap = mcap.map(|m| m.finish()).transpose()?;
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
