//! The `scip2can emulate` command: its flags, and the run that wires the simulator, the
//! firmware in QEMU and the decoder, and reports once a second.

use std::io::{self, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail};
use can_wire::bandwidth::{frame_bits, BitRates};
use can_wire::{Frame, IdWindow, Status};
use serde_json::json;
use slcan::{Command, Reply};

use super::report::{add, report, Tally};
use super::{
    build_firmware_eth, firmware, qemu_available, Emulation, Incoming, SensorLink, Setup, Uart1,
};
use crate::candump::Record;
use crate::decode::{Item, LogDecoder};
use crate::sim::SimOptions;

/// Flags of `scip2can emulate`.
#[derive(Debug, Clone, clap::Args)]
pub struct EmulateArgs {
    /// Sensor model: urg04lx, utm30lx, ust10lx, uxm30lxe.
    #[arg(long, default_value = "urg04lx")]
    pub model: String,
    /// Fault injection, the simulator's `key=value,...` options
    /// (e.g. `flip=0.05,drop=0.02,hwfault=0.01,reboot_at=40,stall=0.01`).
    #[arg(long, default_value = "")]
    pub faults: String,
    /// Seed of the scene.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sensor time runs this many times faster than real time. QEMU's UART takes about
    /// 40 kB/s: a 40 Hz UTM-30LX (134 kB/s) needs about 0.25 to keep up.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// One JSON object per second (and a final summary) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also print every decoded scan as a JSON line.
    #[arg(long)]
    pub scans: bool,
    /// The firmware ELF (default: the board workspace's release build, built if missing).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// The QEMU binary.
    #[arg(long, default_value = "qemu-system-arm")]
    pub qemu: String,
    /// Run QEMU with `-icount shift=0` (virtual time = instructions; slower).
    #[arg(long)]
    pub icount: bool,
    /// How the sensor is connected: `uart` (UART0, URG-04LX class) or `tcp` (emulated
    /// Ethernet, UST-10LX class: use `--model ust10lx`; the firmware is then
    /// scip2can-qemu-eth).
    #[arg(long, value_enum, default_value_t = SensorLink::Uart)]
    pub link: SensorLink,
}

/// Runs `scip2can emulate`.
pub fn run(args: EmulateArgs) -> anyhow::Result<()> {
    if !qemu_available(&args.qemu) {
        bail!(
            "{} not found: install QEMU (Debian/Ubuntu: apt-get install qemu-system-arm)",
            args.qemu
        );
    }
    let mut spec = format!(
        "model={},seed={},speed={}",
        args.model, args.seed, args.speed
    );
    if !args.faults.is_empty() {
        spec.push(',');
        spec.push_str(&args.faults);
    }
    let sim = SimOptions::from_spec(&spec)?;
    let setup = Setup {
        sim,
        firmware: match (args.link, args.firmware.as_deref()) {
            (SensorLink::Tcp, None) => build_firmware_eth()?,
            (_, path) => firmware(path)?,
        },
        qemu: args.qemu.clone(),
        icount: args.icount,
        uart1: Uart1::Connect,
        link: args.link,
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed));
    }
    let mut emu = Emulation::start(&setup)?;
    let mut link = emu.can.take().ok_or_else(|| anyhow!("no SLCAN link"))?;
    link.send(&Command::BitRate(8))?;
    link.send(&Command::Open)?;
    if !args.json {
        eprintln!(
            "scip2can emulate: {} simulator ↔ {} in QEMU ↔ SLCAN decoder{}",
            args.model,
            setup.firmware.display(),
            if args.faults.is_empty() {
                String::new()
            } else {
                format!(" (faults {})", args.faults)
            }
        );
    }
    let mut dec = LogDecoder::new(IdWindow::DEFAULT);
    let mut out = io::stdout().lock();
    let (mut period, mut total) = (Tally::default(), Tally::default());
    let mut last_report = Instant::now();
    let mut flags: Option<u8> = None;
    let mut statuses: Vec<Status> = Vec::new();
    let deadline = args
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    let handle = |i: Incoming,
                  dec: &mut LogDecoder,
                  period: &mut Tally,
                  flags: &mut Option<u8>,
                  statuses: &mut Vec<Status>,
                  out: &mut dyn Write,
                  t_us: u64|
     -> anyhow::Result<()> {
        match i {
            Incoming::Reply(Reply::Frame(f, _)) => {
                let Ok(frame) = Frame::new(f.id(), f.data(), f.kind().is_fd()) else {
                    return Ok(());
                };
                period.frames += 1;
                let ext = matches!(frame.id(), embedded_can::Id::Extended(_));
                period.bus_ns += frame_bits(frame.data().len(), frame.is_fd(), ext)
                    .time_ns(BitRates::CLASSIC_1M);
                let rec = Record::from_frame(t_us, "can0", &frame, frame.is_fd());
                match dec.push(&rec) {
                    Some(Item::Scan(s)) => {
                        match s.completeness {
                            can_wire::Completeness::Intact => period.intact += 1,
                            can_wire::Completeness::Aborted { .. } => period.aborted += 1,
                            _ => period.damaged += 1,
                        }
                        if args.scans {
                            writeln!(out, "{}", crate::decode::json::scan(&s))?;
                        }
                    }
                    Some(Item::Status { status, .. }) => statuses.push(status),
                    _ => {}
                }
            }
            Incoming::Reply(Reply::Flags(f)) => *flags = Some(f),
            Incoming::Garbage(_) | Incoming::Bell => period.bad_lines += 1,
            _ => {}
        }
        Ok(())
    };
    loop {
        if stop.load(Ordering::Relaxed) || deadline.is_some_and(|d| Instant::now() >= d) {
            break;
        }
        let t_us = emu.elapsed().as_micros() as u64;
        match link.recv(Duration::from_millis(50)) {
            Ok(Some(i)) => handle(
                i,
                &mut dec,
                &mut period,
                &mut flags,
                &mut statuses,
                &mut out,
                t_us,
            )?,
            Ok(None) => {}
            Err(e) => {
                if !emu.running() {
                    bail!("QEMU stopped: {e}");
                }
                return Err(e);
            }
        }
        if last_report.elapsed() >= Duration::from_secs(1) {
            let secs = last_report.elapsed().as_secs_f64();
            last_report = Instant::now();
            report(
                &mut out,
                args.json,
                emu.elapsed().as_secs_f64(),
                secs,
                &period,
                &dec,
                flags,
                &statuses,
            )?;
            add(&mut total, &period);
            period = Tally::default();
            statuses.clear();
            // The flags for the next line.
            link.send(&Command::StatusFlags)?;
        }
    }
    add(&mut total, &period);
    let mut rest = Vec::new();
    let diag = link.diagnostics(Duration::from_secs(2), &mut |i| rest.push(i));
    let faults = emu.stop()?;
    let run_s = last_report.elapsed().as_secs_f64();
    let _ = run_s;
    let stats = dec.stats().first().map(|(_, s)| *s).unwrap_or_default();
    let summary = json!({
        "summary": true,
        "scans_intact": total.intact,
        "scans_damaged": total.damaged,
        "scans_aborted": total.aborted,
        "scans_lost": stats.scans_lost,
        "frames": total.frames,
        "frames_lost": stats.frames_lost,
        "faults_injected": faults.len(),
        "board": diag.as_ref().map(|d| d.0.iter().map(|(k, v)| (k.clone(), json!(v))).collect::<serde_json::Map<_, _>>()).ok(),
    });
    if args.json {
        writeln!(out, "{summary}")?;
    } else {
        writeln!(
            out,
            "total: {} scans intact, {} damaged, {} aborted, {} lost; {} frames; {} faults injected",
            total.intact, total.damaged, total.aborted, stats.scans_lost, total.frames, faults.len()
        )?;
        if let Err(e) = &diag {
            writeln!(out, "board: no diagnostics ({e:#})")?;
        }
        if let Ok(d) = diag {
            let get = |k: &str| d.get(k).unwrap_or(0);
            writeln!(
                out,
                "board: stack {} of {} bytes used, {} sensor bytes, {} scans in, {} sent, {} aborted, {} dropped",
                get("stack"),
                get("stack_size"),
                get("bytes"),
                get("scans_in"),
                get("scans_sent"),
                get("scans_aborted"),
                get("dropped_budget") + get("dropped_queue"),
            )?;
        }
    }
    Ok(())
}
