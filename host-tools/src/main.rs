//! The `scip2can` command.

use std::fs::File;
use std::io::{self, BufWriter};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

/// scip2can: Hokuyo SCIP 2.x laser range finders onto a CAN bus.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Decode a raw sensor-to-host SCIP stream; print one JSON object per response.
    ///
    /// Damaged responses are reported in their `errors`; the rest is decoded. The exit
    /// code is non-zero only when the input cannot be read.
    Parse {
        /// The stream file, or `-` for standard input.
        file: PathBuf,
    },
    /// A simulated Hokuyo sensor on TCP (default 127.0.0.1:10940), a pty, or stdio.
    Sim(scip2can_host::sim::cli::SimArgs),
    /// VV, PP and II of a sensor, pretty.
    Info(scip2can_host::sensor::cli::InfoArgs),
    /// N scans of a sensor as JSON lines or CSV.
    Scan(scip2can_host::sensor::cli::ScanCmdArgs),
    /// Record a session (both directions, timestamps) until Ctrl-C or -n scans.
    Record(scip2can_host::sensor::cli::RecordArgs),
    /// Run the bridge core on a recorded stream (or `sim:...`); write its CAN frames as a
    /// candump log and print the bus load.
    Replay(scip2can_host::replay::args::ReplayArgs),
    /// Reassemble the scans of a candump log; JSON lines (or CSV) and loss statistics.
    Decode(scip2can_host::decode::DecodeArgs),
    /// Draw scans of a candump log to a PNG (sensor frame, metres, x forward).
    Plot(scip2can_host::plot::PlotArgs),
    /// Run the bridge live: a sensor (default: the simulator) to a CAN port (default: a
    /// candump log on standard output), until Ctrl-C or --seconds.
    Bridge(scip2can_host::live::BridgeArgs),
    /// The simulator, the real firmware in QEMU (mps2-an386) and the decoder, wired:
    /// scans arriving, rates, bus load, error counters, once a second.
    Emulate(scip2can_host::emulate::EmulateArgs),
    /// Instructions per UART byte of the bridge core on the emulated Cortex-M4: a
    /// deterministic stream through the real firmware in QEMU (`-icount shift=0`),
    /// its CAN frames checked against the same core on the host.
    Icount(scip2can_host::icount::IcountArgs),
    /// The time master of the bus (SPEC 9): SYNC and FOLLOW-UP with this host's clock
    /// (Unix time, µs), periodically, so that the bridges publish in the robot's clock;
    /// prints the bridges' status page 7 (sync state, error) as JSON lines.
    Timesync(scip2can_host::timesync::TimesyncArgs),
    /// Statistics that decide a predictive coder's gain (range noise, edges, no-return
    /// runs, intensities, ideal Rice cost), for recordings and simulators side by side.
    Noise(scip2can_host::noise::NoiseArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("scip2can: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Cmd::Sim(args) => scip2can_host::sim::cli::run(args),
        Cmd::Info(args) => scip2can_host::sensor::cli::run_info(args),
        Cmd::Scan(args) => scip2can_host::sensor::cli::run_scan(args),
        Cmd::Record(args) => scip2can_host::sensor::cli::run_record(args),
        Cmd::Replay(args) => scip2can_host::replay::run(args),
        Cmd::Decode(args) => scip2can_host::decode::run(args),
        Cmd::Plot(args) => scip2can_host::plot::run(args),
        Cmd::Bridge(args) => scip2can_host::live::run(args),
        Cmd::Emulate(args) => scip2can_host::emulate::run(args),
        Cmd::Icount(args) => scip2can_host::icount::run(args),
        Cmd::Timesync(args) => scip2can_host::timesync::run(args),
        Cmd::Noise(args) => scip2can_host::noise::run(args),
        Cmd::Parse { file } => {
            let out = BufWriter::new(io::stdout().lock());
            if file.as_os_str() == "-" {
                scip2can_host::parse::run(io::stdin().lock(), out)
                    .context("reading standard input")?;
            } else {
                let f = File::open(&file).with_context(|| format!("opening {}", file.display()))?;
                scip2can_host::parse::run(f, out)
                    .with_context(|| format!("reading {}", file.display()))?;
            }
            Ok(())
        }
    }
}
