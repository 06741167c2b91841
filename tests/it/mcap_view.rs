//! `decode --mcap`: the MCAP file read back by independent readers (the rosbags
//! library as a ROS 2 bag; the mcap library with its ROS 2 CDR and protobuf decoders,
//! tests/support/mcap_read.py) holds every scan `decode` prints as JSON, with the
//! values REP 117 and SPEC 3.2 give; status frames as diagnostics; a bad target path
//! is a clear error before any input is read.
//!
//! Logs: `replay` of the real captures (URG-04LX GD with the sensor's error codes kept
//! by the lossless coding, UTM-30LX ME with intensities, a tagged GD without geometry,
//! an aborted scan) and of the simulator (UTM-30LX with intensities, two bridges).

use std::path::{Path, PathBuf};
use std::process::Command;

use bridge::engine::BridgeConfig;
use can_wire::{DistanceEncoding, Encoding, FrameFormat, IdWindow, IntensityEncoding};
use clap::Parser;
use scip::DataSet;
use scip2can_host::decode::{decode_log, json, DecodeArgs};
use scip2can_host::replay::{replay_sim, replay_stream, Replayed};
use scip2can_host::sim::SimOptions;
use scip2can_host::view::mcap::{McapCounts, McapSchema, McapSink};
use scip2can_tests::recordings_or_skip;
use serde_json::Value;

use crate::bridge_replay;

fn config(distance: DistanceEncoding, unit_exp: u8, node: u8) -> BridgeConfig {
    let mut c = bridge_replay::config(
        FrameFormat::FD64,
        Encoding {
            distance,
            intensity: IntensityEncoding::I16,
            unit_exp,
        },
    );
    c.ids = IdWindow::DEFAULT.node(node).expect("node");
    c.status_period_ms = 1000;
    c.uart_bit_rate = 12_000_000;
    c
}

fn log_text(r: &Replayed) -> String {
    r.records("can0", true)
        .iter()
        .map(|rec| format!("{rec}\n"))
        .collect()
}

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("scip2can-{}-{name}", std::process::id()))
}

const TOPIC: &str = "/robot/lidar{node}/scan";
const FRAME: &str = "lidar{node}";

/// Decodes `log`, writes the MCAP file as `decode --mcap` does; returns decode's JSON
/// lines of the same log and what the sink counted.
fn write_mcap(log: &str, path: &Path, schema: McapSchema) -> (Vec<Value>, McapCounts) {
    let (items, _) = decode_log(log.as_bytes(), IdWindow::DEFAULT).expect("log");
    let mut sink = McapSink::create(path, TOPIC, FRAME, "/diagnostics", schema).expect("create");
    for item in &items {
        sink.push(item).expect("write");
    }
    let counts = sink.finish().expect("finish");
    (items.iter().map(json::item).collect(), counts)
}

/// Runs tests/support/mcap_read.py; `None` (with a message) when a Python library is
/// missing, which fails under CI=true.
fn read_back(reader: &str, path: &Path) -> Option<Vec<Value>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new("python3")
        .arg(root.join("support/mcap_read.py"))
        .arg(reader)
        .arg(path)
        .output()
        .expect("run python3");
    if out.status.code() == Some(3) {
        let msg = format!(
            "{}; python3 with rosbags, mcap, mcap-ros2-support and mcap-protobuf-support \
             is needed (pip install rosbags mcap mcap-ros2-support mcap-protobuf-support)",
            String::from_utf8_lossy(&out.stderr).trim()
        );
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("{msg}; CI=true, so this is a failure");
        }
        eprintln!("{msg}; not run");
        return None;
    }
    assert!(
        out.status.success(),
        "{reader}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(
        String::from_utf8(out.stdout)
            .expect("utf-8")
            .lines()
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect(),
    )
}

/// A float the reader printed ("nan", "inf", "-inf" or a number).
fn float(v: &Value) -> f64 {
    match v {
        Value::String(s) if s == "nan" => f64::NAN,
        Value::String(s) if s == "inf" => f64::INFINITY,
        Value::String(s) if s == "-inf" => f64::NEG_INFINITY,
        other => other.as_f64().expect("a number"),
    }
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(float).collect()
}

/// Same f32 value, NaN equal to NaN (every value compared is an f32 widened; the
/// readers' decimal text is compared after rounding back to f32).
fn same(a: f64, b: f64) -> bool {
    let (a, b) = (a as f32, b as f32);
    (a.is_nan() && b.is_nan()) || a == b
}

fn assert_floats(got: &[f64], want: &[f64], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(same(*g, *w), "{what}[{i}]: {g} != {w}");
    }
}

/// What the sensor told through status pages 4 and 6 (for the expected values).
#[derive(Default, Clone, Copy)]
struct Sensor {
    /// model name as decode prints it, dmin, dmax (mm).
    range: Option<(&'static str, f64, f64)>,
    rpm: Option<f64>,
}

/// REP 117 value of a sensor error code (the table in the view module docs).
fn error_code(code: u64, model: Option<&str>) -> f64 {
    match (model, code) {
        (_, 65533) => f64::INFINITY,
        (Some("Urg04lx"), 0) => f64::INFINITY,
        (Some("Urg04lx") | None, _) => f64::NAN,
        (Some(_), 1 | 4) => f64::INFINITY,
        (Some(_), 2) => f64::NEG_INFINITY,
        (Some(_), _) => f64::NAN,
    }
}

/// The LaserScan fields a JSON scan of `decode` gives (f32 values widened).
struct Want {
    node: u64,
    log_time: u64,
    stamp_ns: u64,
    angle_min: f64,
    angle_max: f64,
    angle_increment: f64,
    scan_time: f64,
    time_increment: f64,
    range_min: f64,
    range_max: f64,
    ranges: Vec<f64>,
    intensities: Vec<f64>,
}

fn f32w(x: f64) -> f64 {
    f64::from(x as f32)
}

fn want_scan(s: &Value, sensor: Sensor) -> Want {
    let u = |k: &str| s[k].as_u64().unwrap_or_else(|| panic!("{k}"));
    let n = s["distances"].as_array().expect("distances").len();
    let (first, step, ares) = (
        s["first_step"].as_i64().expect("first_step") as f64,
        u("step_increment") as f64,
        u("ares") as f64,
    );
    let tau = std::f64::consts::TAU;
    let model = sensor.range.map(|r| r.0).filter(|m| *m != "Unidentified");
    let oor: Vec<u64> = s["out_of_range"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_u64).collect())
        .unwrap_or_default();
    let ranges = (0..n)
        .map(|i| {
            if let Some(mm) = s["distances"][i].as_u64() {
                f32w(mm as f64 / 1000.0)
            } else if oor.contains(&(i as u64)) {
                f64::INFINITY
            } else if let Some(code) = s["sensor_errors"][i.to_string()].as_u64() {
                error_code(code, model)
            } else {
                f64::NAN
            }
        })
        .collect();
    let intensities = s["intensities"]
        .as_array()
        .map(|a| {
            a.iter()
                .take(n)
                .map(|v| v.as_f64().unwrap_or(f64::NAN))
                .collect()
        })
        .unwrap_or_default();
    let unit = u("unit_mm") as f64;
    let (range_min, range_max) = match sensor.range {
        Some((_, dmin, dmax)) => (f32w(dmin / 1000.0), f32w(dmax / 1000.0)),
        // SPEC 4.1 / 4.2.1: the smallest and largest range codes.
        None => match s["encoding"].as_str().expect("encoding") {
            e if e.starts_with("Lossless") => (0.0, f32w(((1 << 20) - 129) as f64 * unit / 1e3)),
            e if e.starts_with("D12") => (f32w(unit / 1e3), f32w(4094.0 * unit / 1e3)),
            e if e.starts_with("D14") => (f32w(unit / 1e3), f32w(16382.0 * unit / 1e3)),
            _ => (f32w(unit / 1e3), f32w(65534.0 * unit / 1e3)),
        },
    };
    let (scan_time, time_increment) = match sensor.rpm {
        Some(rpm) => (f32w(60.0 / rpm), f32w(60.0 / rpm * step / ares)),
        None => (0.0, 0.0),
    };
    Want {
        node: u("node"),
        log_time: (s["time"].as_f64().expect("time") * 1e6).round() as u64 * 1000,
        stamp_ns: u("timestamp") * 1_000_000,
        angle_min: s["first_angle_rad"].as_f64().expect("angle"),
        angle_max: (first + (n as f64 - 1.0) * step) * tau / ares,
        angle_increment: f32w(tau * step / ares),
        scan_time,
        time_increment,
        range_min,
        range_max,
        ranges,
        intensities,
    }
}

/// The scans decode printed that belong in the file (intact or incomplete, with
/// geometry), with the sensor facts the status items before each had told.
fn wanted(lines: &[Value]) -> Vec<Want> {
    let mut sensors = std::collections::BTreeMap::<u64, Sensor>::new();
    let mut out = Vec::new();
    for l in lines {
        let node = l["node"].as_u64().unwrap_or(0);
        match (l["type"].as_str(), l["page"].as_str()) {
            (Some("status"), Some("sensor_range")) => {
                let model = match l["model"].as_str() {
                    Some("Urg04lx") => "Urg04lx",
                    Some("Unidentified") => "Unidentified",
                    _ => "Other",
                };
                sensors.entry(node).or_default().range = Some((
                    model,
                    l["dmin_mm"].as_f64().expect("dmin"),
                    l["dmax_mm"].as_f64().expect("dmax"),
                ));
            }
            (Some("status"), Some("sensor_timing")) => {
                sensors.entry(node).or_default().rpm = l["scan_rpm"].as_f64();
            }
            (Some("scan"), _) => {
                let ok = matches!(l["completeness"].as_str(), Some("intact" | "incomplete"));
                if ok && l["ares"].as_u64() != Some(0) {
                    let s = sensors.get(&node).copied().unwrap_or_default();
                    out.push(want_scan(l, s));
                }
            }
            _ => {}
        }
    }
    out
}

fn check_ros_scan(got: &Value, w: &Want) {
    let topic = format!("/robot/lidar{}/scan", w.node);
    assert_eq!(got["topic"], topic.as_str());
    assert_eq!(got["log_time"].as_u64(), Some(w.log_time), "log time");
    assert_eq!(got["stamp_ns"].as_u64(), Some(w.stamp_ns), "stamp");
    assert_eq!(got["frame_id"], format!("lidar{}", w.node).as_str());
    let f = |k: &str| float(&got[k]);
    for (k, v) in [
        ("angle_min", w.angle_min),
        ("angle_increment", w.angle_increment),
        ("scan_time", w.scan_time),
        ("time_increment", w.time_increment),
        ("range_min", w.range_min),
        ("range_max", w.range_max),
    ] {
        assert!(same(f(k), v), "{k}: {} != {v}", f(k));
    }
    assert!((f("angle_max") - w.angle_max).abs() < 1e-6, "angle_max");
    assert_floats(&floats(&got["ranges"]), &w.ranges, "ranges");
    assert_floats(&floats(&got["intensities"]), &w.intensities, "intensities");
}

fn check_foxglove_scan(got: &Value, w: &Want, topic: &str) {
    assert_eq!(got["topic"], topic);
    assert_eq!(got["log_time"].as_u64(), Some(w.log_time), "log time");
    assert_eq!(got["stamp_ns"].as_u64(), Some(w.stamp_ns), "stamp");
    assert_eq!(got["frame_id"], format!("lidar{}", w.node).as_str());
    assert_eq!(
        floats(&got["pose"]),
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        "identity pose"
    );
    assert!(same(float(&got["start_angle"]), w.angle_min));
    assert!((float(&got["end_angle"]) - w.angle_max).abs() < 1e-6);
    assert_floats(&floats(&got["ranges"]), &w.ranges, "ranges");
    assert_floats(&floats(&got["intensities"]), &w.intensities, "intensities");
}

/// The diagnostics: one per status line of decode, its fields as key/value text (a
/// reader may order the bridges' messages of one time either way: each status line is
/// matched to a diagnostic of its time, node and page).
fn check_diagnostics(got: &[&Value], lines: &[Value]) {
    let statuses: Vec<&Value> = lines.iter().filter(|l| l["type"] == "status").collect();
    assert_eq!(got.len(), statuses.len(), "one diagnostic per status frame");
    assert!(!got.is_empty());
    let mut used = vec![false; got.len()];
    for s in statuses {
        let log_time = (s["time"].as_f64().expect("time") * 1e6).round() as u64 * 1000;
        let node = s["node"].as_u64().expect("node");
        let name = format!("scip2can node {node}");
        let page = s["page"].as_str().expect("page");
        let k = (0..got.len())
            .find(|&k| {
                let st = &got[k]["status"][0];
                !used[k]
                    && got[k]["log_time"].as_u64() == Some(log_time)
                    && st["name"] == name.as_str()
                    && st["message"].as_str().is_some_and(|m| m.starts_with(page))
            })
            .unwrap_or_else(|| panic!("no diagnostic for {s}"));
        used[k] = true;
        let g = got[k];
        assert_eq!(g["stamp_ns"].as_u64(), Some(log_time));
        let st = &g["status"][0];
        assert_eq!(st["level"], 0, "{s}");
        assert_eq!(st["hardware_id"], st["name"]);
        let values = st["values"].as_object().expect("values");
        for (k, v) in s.as_object().expect("object") {
            if ["type", "node", "time", "page"].contains(&k.as_str()) {
                continue;
            }
            let text = v.as_str().map_or_else(|| v.to_string(), str::to_owned);
            assert_eq!(values.get(k), Some(&Value::String(text)), "{page}.{k}");
        }
    }
}

/// The messages of `schema` in the order of `want`: file order per topic (a reader may
/// interleave the bridges by time), each scan matched to the next of its node.
fn in_order<'a>(got: &'a [Value], schema: &str, want: &[Want]) -> Vec<&'a Value> {
    let mut by_topic = std::collections::BTreeMap::<String, Vec<&Value>>::new();
    for m in got.iter().filter(|m| m["schema"] == schema) {
        by_topic
            .entry(m["topic"].as_str().expect("topic").to_owned())
            .or_default()
            .push(m);
    }
    let total: usize = by_topic.values().map(Vec::len).sum();
    assert_eq!(total, want.len(), "{schema}: messages");
    let mut next = std::collections::BTreeMap::<u64, usize>::new();
    want.iter()
        .map(|w| {
            let k = next.entry(w.node).or_default();
            let topic = by_topic
                .iter()
                .find(|(t, _)| t.starts_with(&format!("/robot/lidar{}/", w.node)))
                .map(|(_, v)| v)
                .expect("the node's topic");
            *k += 1;
            topic[*k - 1]
        })
        .collect()
}

/// Writes the MCAP of `log` in every schema choice and checks what the readers find.
/// Returns the sink's counts, or `None` when the Python readers are missing.
fn check_log(name: &str, log: &str, scans_expected: usize) -> Option<McapCounts> {
    let ros2 = temp_path(&format!("{name}-ros2.mcap"));
    let both = temp_path(&format!("{name}-both.mcap"));
    let fox = temp_path(&format!("{name}-foxglove.mcap"));
    let (lines, counts) = write_mcap(log, &ros2, McapSchema::Ros2);
    write_mcap(log, &both, McapSchema::Both);
    write_mcap(log, &fox, McapSchema::Foxglove);
    let want = wanted(&lines);
    assert_eq!(want.len(), scans_expected, "{name}: scans to write");
    assert_eq!(counts.scans as usize, scans_expected);

    // The ROS 2 bag, by rosbags and by the mcap library.
    for reader in ["rosbags", "mcap"] {
        let got = read_back(reader, &ros2)?;
        let scans = in_order(&got, "sensor_msgs/msg/LaserScan", &want);
        for (g, w) in scans.iter().zip(&want) {
            check_ros_scan(g, w);
        }
        let diags: Vec<&Value> = got
            .iter()
            .filter(|m| m["schema"] == "diagnostic_msgs/msg/DiagnosticArray")
            .collect();
        check_diagnostics(&diags, &lines);
        assert_eq!(scans.len() + diags.len(), got.len(), "nothing else");
        if reader == "mcap" {
            assert!(got.iter().all(|m| m["profile"] == "ros2"));
        }
    }

    // Both message types: each scan on two channels.
    let got = read_back("mcap", &both)?;
    let ros = in_order(&got, "sensor_msgs/msg/LaserScan", &want);
    let fx = in_order(&got, "foxglove.LaserScan", &want);
    for ((r, f), w) in ros.iter().zip(&fx).zip(&want) {
        check_ros_scan(r, w);
        check_foxglove_scan(f, w, &format!("/robot/lidar{}/scan/foxglove", w.node));
    }

    // Foxglove only: the scans on the topic itself, no ROS 2 LaserScan.
    let got = read_back("mcap", &fox)?;
    let fx = in_order(&got, "foxglove.LaserScan", &want);
    for (f, w) in fx.iter().zip(&want) {
        check_foxglove_scan(f, w, &format!("/robot/lidar{}/scan", w.node));
    }
    assert!(got
        .iter()
        .all(|m| m["schema"] != "sensor_msgs/msg/LaserScan"));
    for p in [ros2, both, fox] {
        let _ = std::fs::remove_file(p);
    }
    Some(counts)
}

/// Status frames of node 0 written from SPEC 5: page 4 (model, DMIN, DMAX) and page 6
/// (AFRT, scan rpm), at the log's start.
fn status_lines(model: u8, dmin: u16, dmax: u32, afrt: u16, rpm: u16) -> String {
    let d = dmin.to_le_bytes();
    let m = dmax.to_le_bytes();
    let a = afrt.to_le_bytes();
    let r = rpm.to_le_bytes();
    format!(
        "(0.000000) can0 120#04{model:02X}{:02X}{:02X}{:02X}{:02X}{:02X}00\n\
         (0.000000) can0 120#06{:02X}{:02X}{:02X}{:02X}000000\n",
        d[0], d[1], m[0], m[1], m[2], a[0], a[1], r[0], r[1]
    )
}

fn recording(dir: &Path, name: &str, distance: DistanceEncoding, unit_exp: u8) -> String {
    let bytes = std::fs::read(dir.join(name)).expect("read recording");
    log_text(&replay_stream(&bytes, config(distance, unit_exp, 0)).expect("replay"))
}

#[test]
fn mcap_of_real_captures_reads_back_as_decode_prints_them() {
    let Some(dir) = recordings_or_skip("decode --mcap") else {
        return;
    };
    // URG-04LX GD, lossless: the sensor's error codes 0, 7 and 10 kept. With status
    // page 4 naming the URG-04LX, code 0 (no echo) is +inf and the others NaN; DMIN and
    // DMAX are the range limits; page 6's 600 rpm gives the timing.
    let urg = recording(
        &dir,
        "hokuyoaist_example_urg_04lx.rx.scip",
        DistanceEncoding::Lossless,
        0,
    );
    let with_status = status_lines(1, 20, 5600, 384, 600) + &urg;
    let Some(c) = check_log("urg-status", &with_status, 1) else {
        return;
    };
    assert_eq!((c.geometry_unknown, c.damaged), (0, 0));
    // Without status pages: codes NaN, limits of the encoding, no timing.
    check_log("urg", &urg, 1);
    // UTM-30LX ME: intensities; in D12 at 1 mm, ranges beyond 4.094 m are out of
    // range (+inf); status page 4 as a UTM-30LX.
    let utm = recording(
        &dir,
        "hokuyoaist_example_utm_30lx.rx.scip",
        DistanceEncoding::D12,
        0,
    );
    let (lines, _) = write_mcap(&utm, &temp_path("utm-probe.mcap"), McapSchema::Ros2);
    let scan = lines.iter().find(|l| l["type"] == "scan").expect("a scan");
    assert!(scan["out_of_range"]
        .as_array()
        .is_some_and(|a| !a.is_empty()));
    assert!(scan["intensities"].is_array());
    check_log("utm", &(status_lines(2, 23, 60000, 540, 2400) + &utm), 1);
    // The tagged GD stream has no PP answer: geometry unknown, left out (and counted);
    // the aborted scan of the eeros capture is left out as damaged.
    let tag = recording(
        &dir,
        "snark_gd_0000_0010_tag.scip",
        DistanceEncoding::Lossless,
        0,
    );
    let c = check_log("tag", &tag, 0).expect("readers");
    assert_eq!((c.scans, c.geometry_unknown), (0, 1));
    let eeros = recording(&dir, "eeros_md_0046_0600.scip", DistanceEncoding::D16, 0);
    let c = check_log("eeros", &eeros, 0).expect("readers");
    assert_eq!((c.scans, c.damaged), (0, 1));
}

#[test]
fn mcap_of_two_simulated_bridges_with_intensities() {
    let sim = SimOptions::from_spec("model=utm30lx,seed=4").expect("spec");
    let mut text = String::new();
    for (node, distance) in [(0, DistanceEncoding::D16), (3, DistanceEncoding::Lossless)] {
        let mut c = config(distance, 0, node);
        c.session.scan.data = DataSet::DistanceIntensity;
        let r = replay_sim(&sim, 3, c, false).expect("sim");
        text += &log_text(&r);
    }
    let Some(c) = check_log("sim", &text, 6) else {
        return;
    };
    assert_eq!(c.scans, 6);
    // Intensities are there, and one channel per bridge.
    let path = temp_path("sim-probe.mcap");
    let (lines, _) = write_mcap(&text, &path, McapSchema::Ros2);
    assert!(lines
        .iter()
        .filter(|l| l["type"] == "scan")
        .all(|l| l["intensities"].is_array()));
    let got = read_back("mcap", &path).expect("readers");
    let topics: std::collections::BTreeSet<&str> =
        got.iter().filter_map(|m| m["topic"].as_str()).collect();
    assert_eq!(
        topics.into_iter().collect::<Vec<_>>(),
        ["/diagnostics", "/robot/lidar0/scan", "/robot/lidar3/scan"]
    );
    // A topic without {node} cannot hold two bridges: a clear error.
    let (items, _) = decode_log(text.as_bytes(), IdWindow::DEFAULT).expect("log");
    let mut sink =
        McapSink::create(&path, "/scan", FRAME, "/diagnostics", McapSchema::Ros2).expect("create");
    let err = items
        .iter()
        .find_map(|i| sink.push(i).err())
        .expect("an error at the second bridge");
    assert!(err.to_string().contains("has no {node}"), "{err}");
    let _ = std::fs::remove_file(path);
}

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    decode: DecodeArgs,
}

/// `scip2can decode LOG --mcap PATH` with a bad PATH: the error names the problem, and
/// no input is read (the log does not exist either).
fn decode_error(mcap: &str) -> String {
    let cli =
        Cli::try_parse_from(["decode", "/nonexistent-log.txt", "--mcap", mcap]).expect("arguments");
    let err = scip2can_host::decode::run(cli.decode).expect_err("a bad path");
    format!("{err:#}")
}

#[test]
fn a_bad_mcap_path_is_a_clear_error() {
    let e = decode_error("/nonexistent-dir/out.mcap");
    assert!(
        e.contains("the directory /nonexistent-dir does not exist"),
        "{e}"
    );
    let dir = std::env::temp_dir();
    let e = decode_error(dir.to_str().expect("utf-8"));
    assert!(e.contains("is a directory"), "{e}");
    let file = temp_path("plain-file");
    std::fs::write(&file, "x").expect("write");
    let e = decode_error(file.join("out.mcap").to_str().expect("utf-8"));
    assert!(e.contains("is not a directory"), "{e}");
    let _ = std::fs::remove_file(file);
    // /proc takes no new files, even from root.
    let e = decode_error("/proc/scip2can-test.mcap");
    assert!(e.contains("cannot create the file"), "{e}");
    // Items without an MCAP path are refused by the parser, not ignored.
    assert!(Cli::try_parse_from(["decode", "x.log", "--topic", "/scan"]).is_err());
}
