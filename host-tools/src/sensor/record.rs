//! `scip2can record`: a sensor session, both directions with timestamps, into a record
//! file (see [`super::record_file`]).
//!
//! The session: QT (and SCIP2.0 when needed), VV, PP, II, then an endless MD (ME with
//! `--intensity`) until `-n` scans arrived or `stop` is set (Ctrl-C), then QT and its
//! answer. Every chunk is flushed as it arrives, so nothing is lost on a clean stop.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use scip::{Command, Request};

use super::client::Client;
use super::link::{self, RecordingLink};
use super::record_file::RecordWriter;
use super::scan::{self, ScanArgs, ScanReport};
use super::spec::SensorSpec;

/// Records a session with `spec` into `path`.
pub fn record(
    spec: &SensorSpec,
    spec_text: &str,
    path: &Path,
    scans: Option<u32>,
    intensity: bool,
    timeout: Duration,
    stop: &dyn Fn() -> bool,
) -> anyhow::Result<(ScanReport, Vec<String>)> {
    let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let writer = RecordWriter::new(BufWriter::new(file), &[format!("sensor: {spec_text}")])?;
    let inner = link::open(spec, timeout)?;
    let rec = RecordingLink::new(inner, writer);
    let mut client = Client::new(Box::new(rec), timeout);
    client.connect()?;
    for cmd in [Command::Version, Command::Parameters, Command::Info] {
        client.command(&Request::new(cmd))?;
    }
    let args = ScanArgs {
        count: scans.unwrap_or(u32::MAX),
        intensity,
        start: None,
        end: None,
        cluster: 1,
        format: scan::Format::Json,
    };
    let report = scan::stream(&mut client, &args, true, stop, &mut |_| Ok(()))?;
    Ok((report, client.notes.clone()))
}
