//! Command-line fronts of `scip2can info`, `scan` and `record`.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use super::client::Client;
use super::scan::ScanArgs;
use super::spec::SensorSpec;
use super::{info, record, scan};

/// How to reach the sensor.
#[derive(Debug, Clone, clap::Args)]
pub struct SensorArgs {
    /// tcp://host:port, a serial device path, or sim:key=value,... (an in-process simulator).
    pub sensor: String,
    /// Bit rate of a serial device.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// Seconds to wait for an answer.
    #[arg(long, default_value_t = 2.0)]
    pub timeout: f64,
}

impl SensorArgs {
    fn open(&self) -> anyhow::Result<Client> {
        let spec = SensorSpec::parse(&self.sensor, self.baud)?;
        let c = Client::open(&spec, self.timeout())?;
        for n in &c.notes {
            eprintln!("scip2can: {n}");
        }
        Ok(c)
    }

    fn timeout(&self) -> Duration {
        Duration::from_secs_f64(self.timeout.max(0.01))
    }
}

/// Flags of `scip2can info`.
#[derive(Debug, Clone, clap::Args)]
pub struct InfoArgs {
    /// The sensor.
    #[command(flatten)]
    pub sensor: SensorArgs,
    /// One JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Flags of `scip2can scan`.
#[derive(Debug, Clone, clap::Args)]
pub struct ScanCmdArgs {
    /// The sensor.
    #[command(flatten)]
    pub sensor: SensorArgs,
    /// What to measure and how to print it.
    #[command(flatten)]
    pub scan: ScanArgs,
}

/// Flags of `scip2can record`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    /// The sensor.
    #[command(flatten)]
    pub sensor: SensorArgs,
    /// The record file to write.
    #[arg(short = 'o', long)]
    pub output: PathBuf,
    /// Stop after this many scans (default: at Ctrl-C).
    #[arg(short = 'n', long)]
    pub count: Option<u32>,
    /// Record ME (distance + intensity) instead of MD.
    #[arg(long)]
    pub intensity: bool,
}

/// `scip2can info`.
pub fn run_info(args: InfoArgs) -> anyhow::Result<()> {
    let mut client = args.sensor.open()?;
    let info = info::query(&mut client)?;
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &info::to_json(&info))?;
        writeln!(out)?;
    } else {
        info::write_pretty(&info, &mut out)?;
    }
    Ok(())
}

/// `scip2can scan`.
pub fn run_scan(args: ScanCmdArgs) -> anyhow::Result<()> {
    let mut client = args.sensor.open()?;
    let bar = indicatif::ProgressBar::new(u64::from(args.scan.count));
    if !std::io::stderr().is_terminal() {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let format = args.scan.format;
    let report = scan::stream(&mut client, &args.scan, false, &|| false, &mut |s| {
        scan::write_scan(&mut out, s, format)?;
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();
    out.flush()?;
    if report.damaged > 0 || report.faulty > 0 {
        eprintln!(
            "scip2can: {} damaged and {} fault-status frames passed over",
            report.damaged, report.faulty
        );
    }
    Ok(())
}

/// `scip2can record`: ends cleanly on Ctrl-C.
pub fn run_record(args: RecordArgs) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))?;
    }
    let spec = SensorSpec::parse(&args.sensor.sensor, args.sensor.baud)?;
    let (report, notes) = record::record(
        &spec,
        &args.sensor.sensor,
        &args.output,
        args.count,
        args.intensity,
        args.sensor.timeout(),
        &|| stop.load(Ordering::SeqCst),
    )?;
    for n in notes {
        eprintln!("scip2can: {n}");
    }
    eprintln!(
        "scip2can: recorded {} scans ({} damaged) into {}",
        report.scans,
        report.damaged,
        args.output.display()
    );
    Ok(())
}
