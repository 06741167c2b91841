//! `scip2can timesync`: the time master of SPEC section 9 — SYNC and FOLLOW-UP frames on
//! a CAN port, periodically, carrying this host's clock, so that every bridge on the bus
//! maps its clock to the robot's.
//!
//! The clock is the host's system clock (`CLOCK_REALTIME`: Unix time in µs, what ROS and
//! most robot software stamp with); a step of it (NTP, manual) is seen by the bridges as
//! outliers, then taken after three exchanges (SPEC 9.3). The SYNC's send time is taken
//! right after the write of its frame returned (the SLCAN line or SocketCAN frame handed
//! to the operating system): USB adapters add their own queueing after that, up to about
//! a millisecond, which the bridges' filter averages (SPEC 9.4).
//!
//! Bridges answer each FOLLOW-UP with status page 7; the master prints, per bridge, its
//! state, its mean error, and the **check**: the FOLLOW-UP's reception time in the
//! master's clock as the bridge mapped it, minus the time this host wrote the FOLLOW-UP
//! (the transmission delay, plus the bridge's mapping error).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, Context};
use can_wire::timesync::{time_id, SEQ_MODULUS};
use can_wire::{Frame, IdWindow, Kind, Status, TimeFrame};
use embedded_can::Id;
use serde_json::json;

use crate::decode::WindowArgs;
use crate::live::port;

/// `scip2can timesync` flags.
#[derive(Debug, Clone, clap::Args)]
pub struct TimesyncArgs {
    /// The CAN port: `candump:-` (standard output), `candump:FILE`, `slcan:DEVICE[@BAUD]`,
    /// `slcan:tcp://HOST:PORT`, or `socketcan:IFACE` (Linux, built with `--features
    /// socketcan`).
    #[arg(long, default_value = "candump:-")]
    pub can: String,
    /// The time identifier (SPEC 9.1), in the format of the bridges' window.
    #[arg(long, default_value = "0x0FF", value_parser = parse_number)]
    pub time_id: u32,
    /// The bridges' identifier window (to check the time identifier against it and to
    /// read their status page 7).
    #[command(flatten)]
    pub window: WindowArgs,
    /// Period of the exchange, ms.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(10..=60_000))]
    pub period_ms: u64,
    /// Nominal CAN bit rate (an SLCAN adapter is set to it).
    #[arg(long, default_value_t = 1_000_000)]
    pub bitrate: u32,
    /// Stop after this many exchanges (default: run until Ctrl-C or --seconds).
    #[arg(long)]
    pub count: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Print nothing on standard error (the bridges' page 7 lines still go to standard
    /// output as JSON).
    #[arg(long)]
    pub quiet: bool,
}

fn parse_number(s: &str) -> Result<u32, String> {
    let parsed = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => s.parse(),
    };
    parsed.map_err(|_| format!("{s:?} is not a number (0x0FF or 255)"))
}

/// The host's clock as the master sends it: Unix time, µs (`CLOCK_REALTIME`).
pub fn unix_us() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// The master's side of the exchange: sequence numbers and the two frames.
#[derive(Debug, Clone)]
pub struct Master {
    id: Id,
    seq: u8,
}

/// What one exchange sent, master clock µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exchange {
    /// Sequence of the pair.
    pub seq: u8,
    /// When the SYNC was written (what its FOLLOW-UP carries).
    pub sync_us: u64,
    /// When the FOLLOW-UP was written.
    pub follow_up_us: u64,
}

impl Master {
    /// A master on identifier `id`; the first pair has sequence 0.
    pub fn new(id: Id) -> Self {
        Self { id, seq: 0 }
    }

    /// One exchange: the SYNC through `send`, its send time from `clock` as soon as
    /// `send` returned, then the FOLLOW-UP carrying it.
    pub fn exchange(
        &mut self,
        mut clock: impl FnMut() -> u64,
        mut send: impl FnMut(&Frame) -> anyhow::Result<()>,
    ) -> anyhow::Result<Exchange> {
        let seq = self.seq;
        self.seq = (seq + 1) % SEQ_MODULUS;
        let sync = TimeFrame::Sync { seq }
            .to_frame(self.id)
            .map_err(|e| anyhow!("SYNC: {e}"))?;
        send(&sync).context("sending SYNC")?;
        let sync_us = clock();
        let follow_up = TimeFrame::FollowUp {
            seq,
            master_us: sync_us,
        }
        .to_frame(self.id)
        .map_err(|e| anyhow!("FOLLOW-UP (time {sync_us} µs): {e}"))?;
        send(&follow_up).context("sending FOLLOW-UP")?;
        let follow_up_us = clock();
        Ok(Exchange {
            seq,
            sync_us,
            follow_up_us,
        })
    }
}

/// A bridge's status page 7, checked against the last exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Report {
    /// The bridge's node in the window.
    pub node: u8,
    /// It follows the master.
    pub synced: bool,
    /// Its mean prediction error, µs.
    pub error_us: u16,
    /// Its mapped reception time of the FOLLOW-UP minus the time this host wrote it, µs
    /// (computed modulo 2^32: exact for differences within ±35 minutes).
    pub check_us: Option<i64>,
}

impl Report {
    /// The report of `frame` if it is a status page 7 of a bridge of `window`;
    /// `follow_up_us` is when the master wrote the last FOLLOW-UP.
    pub fn of(frame: &Frame, window: &IdWindow, follow_up_us: Option<u64>) -> Option<Report> {
        let (node, kind) = window.classify(frame.id())?;
        if kind != Kind::Status {
            return None;
        }
        let Ok(Status::TimeSync {
            synced,
            error_us,
            master_time,
        }) = Status::parse(frame.data())
        else {
            return None;
        };
        let check_us = follow_up_us
            .filter(|_| synced)
            .map(|t| i64::from(master_time.wrapping_sub(t as u32) as i32));
        Some(Report {
            node,
            synced,
            error_us,
            check_us,
        })
    }

    /// One JSON line.
    pub fn json(&self) -> String {
        json!({"type": "time_sync", "node": self.node, "synced": self.synced,
            "error_us": self.error_us, "check_us": self.check_us})
        .to_string()
    }
}

/// Runs the master until Ctrl-C, `--count` or `--seconds`.
pub fn run(args: TimesyncArgs) -> anyhow::Result<()> {
    let window = args.window.window()?;
    let id =
        time_id(args.time_id, &window).map_err(|_| {
            anyhow!(
            "--time-id {:#x} lies inside the window {:#x}..={:#x} or does not fit {} identifiers",
            args.time_id,
            window.base(),
            window.base() + 0x7F,
            if window.is_extended() { "29-bit" } else { "11-bit" }
        )
        })?;
    let mut can = port::open(&args.can, args.bitrate, args.bitrate, false)?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst));
    }
    if !args.quiet {
        eprintln!(
            "scip2can timesync: master on {} id {:#x}, every {} ms, Unix time in µs",
            can.describe(),
            args.time_id,
            args.period_ms
        );
    }
    let start = Instant::now();
    let deadline = args
        .seconds
        .map(|s| start + Duration::from_secs_f64(s.max(0.0)));
    let period = Duration::from_millis(args.period_ms);
    let mut master = Master::new(id);
    let mut last: Option<Exchange> = None;
    let mut next = Instant::now();
    let mut sent = 0u64;
    while !stop.load(Ordering::SeqCst) && deadline.is_none_or(|d| Instant::now() < d) {
        if Instant::now() >= next {
            if args.count.is_some_and(|c| sent >= c) {
                break;
            }
            let x = master.exchange(unix_us, |f| can.send(f))?;
            sent += 1;
            last = Some(x);
            next += period;
        }
        while let Some(frame) = can.recv().context("reading the CAN port")? {
            if let Some(r) = Report::of(&frame, &window, last.map(|x| x.follow_up_us)) {
                println!("{}", r.json());
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    if !args.quiet {
        eprintln!("scip2can timesync: {sent} exchanges sent");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::StandardId;

    #[test]
    fn exchange_sends_sync_then_follow_up_with_the_sync_time() {
        let id = Id::Standard(StandardId::new(0x0FF).unwrap());
        let mut m = Master::new(id);
        let mut sent = Vec::new();
        let mut t = 1_767_225_600_000_000u64;
        for _ in 0..17 {
            m.exchange(
                || {
                    t += 10;
                    t
                },
                |f| {
                    sent.push(f.data().to_vec());
                    Ok(())
                },
            )
            .unwrap();
        }
        // Written from SPEC 9.2: SYNC = [1 | seq << 4]; FOLLOW-UP = [2 | seq << 4] and
        // the time of the SYNC (the first clock reading, +10) in 7 bytes LE.
        assert_eq!(sent[0], vec![0x01]);
        let t0 = 1_767_225_600_000_010u64.to_le_bytes();
        let mut fu = vec![0x02];
        fu.extend_from_slice(&t0[..7]);
        assert_eq!(sent[1], fu);
        assert_eq!(sent[2], vec![0x11]);
        assert_eq!(sent[30], vec![0xF1]);
        assert_eq!(sent[32], vec![0x01], "the sequence wraps after 15");
    }
}
