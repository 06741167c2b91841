//! `scip2can scan`: N scans as JSON lines or CSV.

use std::io::Write;
use std::time::Duration;

use anyhow::bail;
use scip::{Command, DataSet, Range, RangeLimits, Request, ScanMode, ScanRequest, Status};

use super::client::{Client, Response};

/// Output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One JSON object per scan.
    Json,
    /// One row per value: `scan,timestamp,step,distance,intensity`.
    Csv,
}

/// What to measure.
#[derive(Debug, Clone, clap::Args)]
pub struct ScanArgs {
    /// Number of scans.
    #[arg(short = 'n', long, default_value_t = 1)]
    pub count: u32,
    /// Distance and intensity (ME) instead of distance only (MD).
    #[arg(long)]
    pub intensity: bool,
    /// First step (default: the sensor's AMIN).
    #[arg(long)]
    pub start: Option<u16>,
    /// Last step (default: the sensor's AMAX).
    #[arg(long)]
    pub end: Option<u16>,
    /// Neighbouring steps merged into one value.
    #[arg(long, default_value_t = 1)]
    pub cluster: u8,
    /// Output format.
    #[arg(long, value_enum, default_value = "json")]
    pub format: Format,
}

/// One decoded scan.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ScanOut {
    /// Scan number in this run, from 0.
    pub scan: u32,
    /// Sensor timestamp, ms (24-bit).
    pub timestamp: u32,
    /// Step of the first value.
    pub start: u16,
    /// Steps per value.
    pub cluster: u8,
    /// Distances in mm; `null` for error codes.
    pub distances: Vec<Option<u32>>,
    /// Intensities (with `--intensity`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub intensities: Vec<u32>,
}

/// What a scan run saw besides the scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ScanReport {
    /// Scans written.
    pub scans: u32,
    /// Damaged frames passed over.
    pub damaged: u32,
    /// Frames with another status (hardware faults).
    pub faulty: u32,
}

/// Reads PP and builds the request for `args`; `endless` asks for count `00` (until
/// QT) whatever the number of scans.
pub fn request(client: &mut Client, args: &ScanArgs, endless: bool) -> anyhow::Result<ScanRequest> {
    let pp = client.command(&Request::new(Command::Parameters))?;
    if !pp.is_intact() {
        bail!("damaged PP answer");
    }
    let p = client.params();
    let amin = p.amin.unwrap_or(0);
    let amax = p.amax.unwrap_or(0);
    let start = args.start.unwrap_or(u16::try_from(amin).unwrap_or(0));
    let end = args.end.unwrap_or(u16::try_from(amax).unwrap_or(0));
    Ok(ScanRequest {
        mode: ScanMode::Continuous,
        data: if args.intensity {
            DataSet::DistanceIntensity
        } else {
            DataSet::Distance
        },
        multi_echo: false,
        start,
        end,
        cluster: args.cluster.max(1),
        skip: 0,
        count: if args.count <= 99 && !endless {
            u8::try_from(args.count).unwrap_or(0)
        } else {
            0
        },
    })
}

/// Streams `args.count` scans, calling `each` with every intact one; stops early when
/// `stop` returns true. Sends QT at the end when the stream is endless.
pub fn stream(
    client: &mut Client,
    args: &ScanArgs,
    endless: bool,
    stop: &dyn Fn() -> bool,
    each: &mut dyn FnMut(&ScanOut) -> anyhow::Result<()>,
) -> anyhow::Result<ScanReport> {
    let scan = request(client, args, endless)?;
    let period = client
        .params()
        .scan_period_us()
        .map_or(Duration::from_millis(100), |us| {
            Duration::from_micros(u64::from(us))
        });
    let ack = client.command(&Request::new(Command::Scan(scan)))?;
    if ack.status != Some(Status::OK) {
        bail!("{} refused: status {}", ack.echo_str(), ack.status_str());
    }
    let limits = client_limits(client);
    let mut report = ScanReport::default();
    let wait = client.timeout + period * 2;
    while report.scans < args.count && !stop() {
        let Some(r) = client.next_response(wait)? else {
            bail!("no scan within {wait:?} (after {} scans)", report.scans);
        };
        if !matches!(r.request.map(|q| q.command), Some(Command::Scan(s)) if s.mode == ScanMode::Continuous)
        {
            continue;
        }
        if !r.is_intact() {
            report.damaged += 1;
            continue;
        }
        if !r.status.is_some_and(|s| s.carries_data()) {
            report.faulty += 1;
            continue;
        }
        let out = scan_out(report.scans, &scan, &r, limits);
        each(&out)?;
        report.scans += 1;
    }
    if scan.count == 0 || report.scans < args.count {
        client.command(&Request::new(Command::LaserOff))?;
    }
    Ok(report)
}

fn client_limits(client: &Client) -> RangeLimits {
    let p = client.params();
    RangeLimits {
        dmin: p.dmin.unwrap_or(20),
        family: p.family.unwrap_or(scip::ModelFamily::Unknown),
    }
}

/// A scan as output: error codes become `null`.
pub fn scan_out(n: u32, scan: &ScanRequest, r: &Response, limits: RangeLimits) -> ScanOut {
    let width = scan.data.distance_width();
    let first = r.readings.iter().filter(|x| x.echo == 0);
    let distances = first
        .clone()
        .map(|x| match limits.classify(x.distance, width) {
            Range::Mm(mm) => Some(mm),
            Range::Error(_) => None,
        })
        .collect();
    let intensities = if scan.data.aux_width() > 0 {
        first.map(|x| x.aux).collect()
    } else {
        Vec::new()
    };
    ScanOut {
        scan: n,
        timestamp: r.timestamp.unwrap_or(0),
        start: scan.start,
        cluster: scan.cluster,
        distances,
        intensities,
    }
}

/// Writes one scan in `format` (CSV header before scan 0).
pub fn write_scan(out: &mut dyn Write, s: &ScanOut, format: Format) -> std::io::Result<()> {
    match format {
        Format::Json => {
            serde_json::to_writer(&mut *out, s)?;
            writeln!(out)
        }
        Format::Csv => {
            if s.scan == 0 {
                writeln!(out, "scan,timestamp,step,distance,intensity")?;
            }
            for (i, d) in s.distances.iter().enumerate() {
                let step = u32::from(s.start) + i as u32 * u32::from(s.cluster.max(1));
                let d = d.map_or(String::new(), |d| d.to_string());
                let a = s
                    .intensities
                    .get(i)
                    .map_or(String::new(), |a| a.to_string());
                writeln!(out, "{},{},{},{},{}", s.scan, s.timestamp, step, d, a)?;
            }
            Ok(())
        }
    }
}
