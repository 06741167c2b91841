//! Output formats of `scip2can decode`.
//!
//! **JSON lines**, one object per item, with a `"type"`:
//! - `"scan"`: `node`, `seq`, `time` (log time of the completing frame, s), `timestamp`
//!   (the header's field: sensor time, ms; bridge ms when `time_synced`; µs when
//!   `time_estimated`), `time_estimated`, `scan_time_us` (with `time_estimated`: the
//!   bridge's estimate of point 0's time, µs of its clock modulo 2^32; else null),
//!   `completeness` (`"intact"`, `"incomplete"`, `"crc_mismatch"`,
//!   `"corrupt"`, `"aborted"`) with `missing_points`/`trailer_missing` or
//!   `abort_reason`/`abort_detail` where they apply, `flags` (the trailer's, null without
//!   it), `point_count`, `received`, the geometry (`first_step` relative to the sensor's
//!   front, `step_increment`, `ares`, `first_angle_rad`, `angle_increment_rad`, angles
//!   counter-clockwise from the front; with `ares` 0 the geometry is unknown, the angles
//!   null and `first_step` the sensor step), `grouping`, `encoding`, `unit_mm`, `time_synced`,
//!   `distances` (mm; null for invalid and missing points; one per point the scan
//!   lists: the trailer's `points_sent` when it arrived, so a truncated scan has fewer
//!   than `point_count`, and none for an aborted scan, whose points a receiver discards
//!   (SPEC 3.5)), `out_of_range` (indices of
//!   points beyond what the encoding expresses, when any), `missing` (indices of points
//!   that did not arrive, when any), `intensities` (when the channel is present; null
//!   for missing points).
//! - `"status"`: `node`, `time`, `page` and the page's fields.
//! - `"answer"`: `node`, `time`, `opcode`, `token`, `outcome`, `detail`.
//! - `"control"`: `node`, `time`, `token`, `command`.
//!
//! **CSV**: `seq,index,angle_rad,distance_mm,intensity,valid`, one row per point of
//! every scan; angle (geometry unknown), distance and intensity are empty where
//! unknown, `valid` is 1 for a range.
//!
//! **Summary** (standard error): frames read, malformed log lines skipped, and per
//! bridge `LossStats`.

use std::io::{self, Write};

use can_wire::reassembly::Completeness;
use can_wire::{Distance, Status};
use serde_json::{json, Map, Value};

use super::{DecodedScan, Item, LogDecoder};

fn seconds(time_us: u64) -> f64 {
    time_us as f64 / 1e6
}

fn completeness(c: &Completeness, obj: &mut Map<String, Value>) {
    let (name, details): (&str, Vec<(&str, Value)>) = match *c {
        Completeness::Intact => ("intact", vec![]),
        Completeness::Incomplete {
            missing_points,
            trailer_missing,
        } => (
            "incomplete",
            vec![
                ("missing_points", missing_points.into()),
                ("trailer_missing", trailer_missing.into()),
            ],
        ),
        Completeness::CrcMismatch => ("crc_mismatch", vec![]),
        Completeness::Corrupt => ("corrupt", vec![]),
        Completeness::Aborted { reason, detail } => (
            "aborted",
            vec![
                ("abort_reason", format!("{reason:?}").into()),
                ("abort_detail", detail.into()),
            ],
        ),
    };
    obj.insert("completeness".into(), name.into());
    for (k, v) in details {
        obj.insert(k.into(), v);
    }
}

/// The whole time (µs) of a scan stamped in the time master's clock (SPEC 3.1): the
/// value congruent to `stamp` modulo 2^32 nearest to `received_us`, the time the scan
/// was received (a candump log's Unix time; the `timesync` master sends Unix time).
pub fn robot_time_us(stamp: u32, received_us: u64) -> u64 {
    let low = received_us as u32;
    // The signed distance from the receive time's low bits to the stamp, |d| < 2^31.
    let d = i64::from(stamp.wrapping_sub(low) as i32);
    received_us.saturating_add_signed(d)
}

/// A scan as a JSON object.
pub fn scan(s: &DecodedScan) -> Value {
    let h = &s.header;
    let mut o = Map::new();
    o.insert("type".into(), "scan".into());
    o.insert("node".into(), s.node.into());
    o.insert("seq".into(), h.seq.into());
    o.insert("time".into(), seconds(s.time_us).into());
    o.insert("timestamp".into(), h.timestamp_ms.into());
    o.insert("time_estimated".into(), h.time_estimated.into());
    o.insert(
        "scan_time_us".into(),
        h.time_estimated
            .then_some(h.timestamp_ms)
            .map_or(Value::Null, Value::from),
    );
    o.insert("time_master".into(), h.time_master.into());
    o.insert(
        "robot_time_us".into(),
        h.time_master
            .then(|| robot_time_us(h.timestamp_ms, s.time_us))
            .map_or(Value::Null, Value::from),
    );
    completeness(&s.completeness, &mut o);
    o.insert(
        "flags".into(),
        s.flags.map_or(Value::Null, |f| {
            json!({"truncated": f.truncated, "sensor_error": f.sensor_error, "filtered": f.filtered})
        }),
    );
    o.insert("point_count".into(), h.point_count.into());
    o.insert(
        "received".into(),
        s.points.iter().filter(|p| p.is_some()).count().into(),
    );
    o.insert("first_step".into(), h.first_step.into());
    o.insert("step_increment".into(), h.step_increment.into());
    o.insert("ares".into(), h.ares.into());
    o.insert("first_angle_rad".into(), f64::from(h.angle_rad(0)).into());
    // Geometry unknown (ares 0): no angles, null.
    let inc = (h.ares != 0)
        .then(|| std::f64::consts::TAU * f64::from(h.step_increment) / f64::from(h.ares));
    o.insert("angle_increment_rad".into(), inc.into());
    o.insert("grouping".into(), format!("{:?}", h.grouping).into());
    let e = &h.encoding;
    o.insert(
        "encoding".into(),
        format!("{:?}+{:?}", e.distance, e.intensity).into(),
    );
    o.insert("unit_mm".into(), e.unit_mm().into());
    o.insert("time_synced".into(), h.time_synced.into());
    let distances: Vec<Value> = s
        .points
        .iter()
        .map(|p| match p.map(|p| p.distance) {
            Some(Distance::Mm(mm)) => mm.into(),
            _ => Value::Null,
        })
        .collect();
    o.insert("distances".into(), distances.into());
    let indices = |f: &dyn Fn(&Option<can_wire::Point>) -> bool| -> Vec<usize> {
        s.points
            .iter()
            .enumerate()
            .filter(|(_, p)| f(p))
            .map(|(i, _)| i)
            .collect()
    };
    let out_of_range = indices(&|p| matches!(p.map(|p| p.distance), Some(Distance::OutOfRange)));
    if !out_of_range.is_empty() {
        o.insert("out_of_range".into(), out_of_range.into());
    }
    // The sensor's error codes by point (the lossless coding keeps them): {"index": code}.
    let errors: Map<String, Value> = s
        .points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| match p.map(|p| p.distance) {
            Some(Distance::SensorError(code)) => Some((i.to_string(), code.into())),
            _ => None,
        })
        .collect();
    if !errors.is_empty() {
        o.insert("sensor_errors".into(), errors.into());
    }
    let missing = indices(&|p| p.is_none());
    if !missing.is_empty() {
        o.insert("missing".into(), missing.into());
    }
    if e.intensity.is_present() {
        let intensities: Vec<Value> = s
            .points
            .iter()
            .map(|p| p.and_then(|p| p.intensity).map_or(Value::Null, Value::from))
            .collect();
        o.insert("intensities".into(), intensities.into());
    }
    Value::Object(o)
}

/// A status frame's fields.
pub fn status(status: &Status) -> Value {
    match *status {
        Status::Heartbeat {
            state,
            cpu_load,
            bus_load,
            uptime_s,
        } => json!({"page": "heartbeat", "state": format!("{state:?}"),
            "cpu_load_percent": f64::from(cpu_load) / 2.0,
            "bus_load_percent": f64::from(bus_load) / 2.0, "uptime_s": uptime_s}),
        Status::SensorCounters {
            sum_errors,
            resyncs,
            dropped_scans,
            recoveries,
        } => json!({"page": "sensor_counters", "sum_errors": sum_errors, "resyncs": resyncs,
            "dropped_scans": dropped_scans, "recoveries": recoveries}),
        Status::BusCounters {
            bus_errors,
            bus_off_events,
            tx_overflows,
            error_state,
        } => json!({"page": "bus_counters", "bus_errors": bus_errors,
            "bus_off_events": bus_off_events, "tx_overflows": tx_overflows,
            "error_state": format!("{error_state:?}")}),
        Status::Firmware {
            protocol,
            major,
            minor,
            patch,
            build,
        } => json!({"page": "firmware", "protocol": protocol,
            "version": format!("{major}.{minor}.{patch}"), "build": build}),
        Status::SensorRange {
            model,
            dmin_mm,
            dmax_mm,
        } => json!({"page": "sensor_range", "model": format!("{model:?}"),
            "dmin_mm": dmin_mm, "dmax_mm": dmax_mm}),
        Status::SensorSteps { ares, amin, amax } => {
            json!({"page": "sensor_steps", "ares": ares, "amin": amin, "amax": amax})
        }
        Status::SensorTiming { afrt, scan_rpm } => {
            json!({"page": "sensor_timing", "afrt": afrt, "scan_rpm": scan_rpm})
        }
        Status::TimeSync {
            synced,
            error_us,
            master_time,
        } => json!({"page": "time_sync", "synced": synced, "error_us": error_us,
            "master_time_low_us": master_time}),
    }
}

fn with_head(kind: &str, node: u8, time_us: u64, body: Value) -> Value {
    let mut o = Map::new();
    o.insert("type".into(), kind.into());
    o.insert("node".into(), node.into());
    o.insert("time".into(), seconds(time_us).into());
    if let Value::Object(fields) = body {
        o.extend(fields);
    }
    Value::Object(o)
}

/// Any item as a JSON object.
pub fn item(item: &Item) -> Value {
    match item {
        Item::Scan(s) => scan(s),
        Item::Status {
            node,
            time_us,
            status: st,
        } => with_head("status", *node, *time_us, status(st)),
        Item::Answer {
            node,
            time_us,
            answer: a,
        } => with_head(
            "answer",
            *node,
            *time_us,
            json!({"opcode": a.opcode, "token": a.token,
                "outcome": format!("{:?}", a.outcome), "detail": a.detail}),
        ),
        Item::Control {
            node,
            time_us,
            control: c,
        } => with_head(
            "control",
            *node,
            *time_us,
            json!({"token": c.token, "command": format!("{:?}", c.command)}),
        ),
    }
}

/// The CSV header line.
pub fn write_csv_header(out: &mut dyn Write) -> io::Result<()> {
    writeln!(out, "seq,index,angle_rad,distance_mm,intensity,valid")
}

/// One CSV row per point of `s`.
pub fn write_csv(out: &mut dyn Write, s: &DecodedScan) -> io::Result<()> {
    let h = &s.header;
    for (i, p) in s.points.iter().enumerate() {
        let index = u16::try_from(i).unwrap_or(u16::MAX);
        let angle = h.angle(index).map_or(String::new(), |a| format!("{a:.6}"));
        let (dist, valid) = match p.map(|p| p.distance) {
            Some(Distance::Mm(mm)) => (mm.to_string(), 1),
            _ => (String::new(), 0),
        };
        let intensity = p
            .and_then(|p| p.intensity)
            .map_or(String::new(), |v| v.to_string());
        writeln!(out, "{},{i},{angle},{dist},{intensity},{valid}", h.seq)?;
    }
    Ok(())
}

/// The summary as JSON: frame counts and per-bridge loss statistics.
pub fn summary(dec: &LogDecoder) -> Value {
    let c = dec.counts();
    let nodes: Vec<Value> = dec
        .stats()
        .iter()
        .map(|(node, s)| {
            json!({"node": node, "scans_intact": s.scans_intact,
                "scans_damaged": s.scans_damaged, "scans_aborted": s.scans_aborted,
                "scans_lost": s.scans_lost, "frames_lost": s.frames_lost,
                "frames_orphaned": s.frames_orphaned, "duplicates": s.duplicates,
                "corrupt": s.corrupt, "sequence_resets": s.sequence_resets})
        })
        .collect();
    json!({"frames": c.frames, "frames_ours": c.ours, "frames_rejected": c.rejected,
        "frames_skipped": c.skipped, "lines_skipped": c.lines_skipped, "bridges": nodes})
}

/// The summary as text lines.
pub fn summary_text(dec: &LogDecoder) -> String {
    let c = dec.counts();
    let mut s = format!(
        "frames: {} ({} of the window, {} rejected), {} remote/error frames skipped; \
         {} malformed lines skipped\n",
        c.frames, c.ours, c.rejected, c.skipped, c.lines_skipped
    );
    for (node, l) in dec.stats() {
        s += &format!(
            "node {node}: scans {} intact, {} damaged, {} aborted, {} lost; frames {} lost, \
             {} orphaned, {} duplicate, {} corrupt; {} sequence resets\n",
            l.scans_intact,
            l.scans_damaged,
            l.scans_aborted,
            l.scans_lost,
            l.frames_lost,
            l.frames_orphaned,
            l.duplicates,
            l.corrupt,
            l.sequence_resets
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use can_wire::{DistanceEncoding, Encoding, Grouping, IntensityEncoding, Point, ScanHeader};

    fn sample() -> DecodedScan {
        let p = |distance, intensity| {
            Some(Point {
                distance,
                intensity: Some(intensity),
            })
        };
        DecodedScan {
            node: 2,
            time_us: 1_500_000,
            header: ScanHeader {
                seq: 7,
                timestamp_ms: 1234,
                point_count: 4,
                encoding: Encoding {
                    distance: DistanceEncoding::D12,
                    intensity: IntensityEncoding::I8,
                    unit_exp: 1,
                },
                time_synced: false,
                time_estimated: false,
                time_master: false,
                grouping: Grouping::Single,
                step_increment: 2,
                first_step: -1,
                ares: 4,
            },
            completeness: Completeness::Incomplete {
                missing_points: 1,
                trailer_missing: true,
            },
            flags: None,
            points: vec![
                p(Distance::Mm(1000), 256),
                p(Distance::Invalid, 0),
                None,
                p(Distance::OutOfRange, 512),
            ],
        }
    }

    #[test]
    fn an_estimated_time_is_printed_in_us() {
        let mut s = sample();
        s.header.time_estimated = true;
        s.header.time_synced = true;
        let v = scan(&s);
        assert_eq!(v["time_estimated"], true);
        assert_eq!(v["scan_time_us"], 1234);
        assert_eq!(v["time_synced"], true);
    }

    #[test]
    fn scan_json_golden() {
        let text = serde_json::to_string(&scan(&sample())).unwrap();
        assert_eq!(
            text,
            concat!(
                r#"{"type":"scan","node":2,"seq":7,"time":1.5,"timestamp":1234,"time_estimated":false,"scan_time_us":null,"time_master":false,"robot_time_us":null,"#,
                r#""completeness":"incomplete","missing_points":1,"trailer_missing":true,"#,
                r#""flags":null,"point_count":4,"received":3,"first_step":-1,"#,
                r#""step_increment":2,"ares":4,"first_angle_rad":-1.5707963705062866,"#,
                r#""angle_increment_rad":3.141592653589793,"grouping":"Single","#,
                r#""encoding":"D12+I8","unit_mm":2,"time_synced":false,"#,
                r#""distances":[1000,null,null,null],"out_of_range":[3],"missing":[2],"#,
                r#""intensities":[256,0,null,512]}"#
            )
        );
    }

    #[test]
    fn csv_rows_golden() {
        let mut out = Vec::new();
        write_csv_header(&mut out).unwrap();
        write_csv(&mut out, &sample()).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "seq,index,angle_rad,distance_mm,intensity,valid\n\
             7,0,-1.570796,1000,256,1\n\
             7,1,1.570796,,0,0\n\
             7,2,4.712389,,,0\n\
             7,3,7.853982,,512,0\n"
        );
    }

    #[test]
    fn status_and_answer_json() {
        let st = Status::SensorSteps {
            ares: 1440,
            amin: 0,
            amax: 1080,
        };
        let v = item(&Item::Status {
            node: 1,
            time_us: 20,
            status: st,
        });
        assert_eq!(
            v.to_string(),
            r#"{"type":"status","node":1,"time":0.00002,"page":"sensor_steps","ares":1440,"amin":0,"amax":1080}"#
        );
        let a = can_wire::Answer {
            opcode: 0x20,
            token: 9,
            outcome: can_wire::Outcome::OutOfRange,
            detail: 2,
        };
        let v = item(&Item::Answer {
            node: 0,
            time_us: 0,
            answer: a,
        });
        assert_eq!(
            v.to_string(),
            r#"{"type":"answer","node":0,"time":0.0,"opcode":32,"token":9,"outcome":"OutOfRange","detail":2}"#
        );
    }

    #[test]
    fn robot_time_is_the_stamp_nearest_the_receive_time() {
        // A scan at 1 795 985 999 960 000 µs of Unix time (40 ms before 21:00:00 UTC on
        // 2026-11-24), stamped with that modulo 2^32 = 2 475 464 640, received 40 ms later.
        let t: u64 = 1_795_985_999_960_000;
        let stamp: u32 = 2_475_464_640;
        assert_eq!(robot_time_us(stamp, t + 40_000), t);
        // Received before the stamp (a receive clock 1 s behind the master's).
        assert_eq!(robot_time_us(stamp, t - 1_000_000), t);
        // Across a wrap of the low 32 bits.
        let w: u64 = (1_795_986 << 32) - 10;
        assert_eq!(robot_time_us(w as u32, w + 20), w);
    }
}
