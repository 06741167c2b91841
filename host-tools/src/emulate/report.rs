//! What `scip2can emulate` reports: the counters of a period and the line (text or
//! JSON) it prints for each.

use std::io::Write;

use can_wire::Status;
use serde_json::json;

use crate::decode::LogDecoder;

/// Counters of one reporting period (and of the whole run).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Tally {
    pub(super) frames: u64,
    pub(super) bus_ns: u64,
    pub(super) intact: u64,
    pub(super) damaged: u64,
    pub(super) aborted: u64,
    pub(super) bad_lines: u64,
}

pub(super) fn add(total: &mut Tally, p: &Tally) {
    total.frames += p.frames;
    total.bus_ns += p.bus_ns;
    total.intact += p.intact;
    total.damaged += p.damaged;
    total.aborted += p.aborted;
    total.bad_lines += p.bad_lines;
}

#[allow(clippy::too_many_arguments)]
pub(super) fn report(
    out: &mut dyn Write,
    json_out: bool,
    t: f64,
    secs: f64,
    p: &Tally,
    dec: &LogDecoder,
    flags: Option<u8>,
    statuses: &[Status],
) -> anyhow::Result<()> {
    let rate = |n: u64| n as f64 / secs.max(1e-3);
    let bus = p.bus_ns as f64 / (secs * 1e9) * 100.0;
    let loss = dec.stats().first().map(|(_, s)| *s).unwrap_or_default();
    let mut heartbeat = None;
    let mut sensor = None;
    for s in statuses {
        match s {
            Status::Heartbeat { .. } => heartbeat = Some(*s),
            Status::SensorCounters { .. } => sensor = Some(*s),
            _ => {}
        }
    }
    if json_out {
        let v = json!({
            "t_s": (t * 10.0).round() / 10.0,
            "scans_per_s": rate(p.intact + p.damaged + p.aborted),
            "intact": p.intact,
            "damaged": p.damaged,
            "aborted": p.aborted,
            "scans_lost_total": loss.scans_lost,
            "frames_per_s": rate(p.frames),
            "bus_load_pct": bus,
            "slcan_flags": flags,
            "bad_lines": p.bad_lines,
            "heartbeat": heartbeat.map(|s| crate::decode::json::status(&s)),
            "sensor_counters": sensor.map(|s| crate::decode::json::status(&s)),
        });
        writeln!(out, "{v}")?;
        return Ok(());
    }
    let mut line = format!(
        "{t:6.1} s  scans {:5.1}/s (intact {}, damaged {}, aborted {}, lost {})  frames {:6.0}/s  bus {bus:4.1} %",
        rate(p.intact + p.damaged + p.aborted),
        p.intact,
        p.damaged,
        p.aborted,
        loss.scans_lost,
        rate(p.frames),
    );
    if let Some(Status::Heartbeat {
        state, cpu_load, ..
    }) = heartbeat
    {
        line.push_str(&format!(
            "  bridge {state:?} cpu {:.1} %",
            f64::from(cpu_load) / 2.0
        ));
    }
    if let Some(Status::SensorCounters {
        sum_errors,
        resyncs,
        dropped_scans,
        recoveries,
    }) = sensor
    {
        line.push_str(&format!(
            "  sum errors {sum_errors} resyncs {resyncs} dropped {dropped_scans} recoveries {recoveries}"
        ));
    }
    if let Some(f) = flags {
        line.push_str(&format!("  F{f:02X}"));
    }
    writeln!(out, "{line}")?;
    Ok(())
}
