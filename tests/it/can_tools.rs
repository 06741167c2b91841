//! `scip2can replay` → candump log → `scip2can decode` / `plot`, on the real recordings
//! and the simulator: the scans that come back are what an independent reader finds in
//! the captured bytes and what the simulated scene puts in front of the sensor; the log
//! is read by python-can and its fixed-layout frames by cantools with the project's DBC;
//! a deleted frame is reported; the plot is a PNG.

use std::io::BufRead;
use std::path::PathBuf;
use std::process::Command;

use bridge::engine::BridgeConfig;
use can_wire::reassembly::Completeness;
use can_wire::{
    Distance, DistanceEncoding, Encoding, FrameFormat, IdWindow, IntensityEncoding, Point,
};
use scip2can_host::candump::Record;
use scip2can_host::decode::{decode_log, DecodedScan, Item, LogDecoder};
use scip2can_host::replay::{replay_sim, replay_stream, Replayed};
use scip2can_host::sim::SimOptions;
use scip2can_tests::{oracle, recordings_or_skip, sensor_streams};
use serde_json::Value;

fn config(format: FrameFormat, distance: DistanceEncoding) -> BridgeConfig {
    BridgeConfig {
        encoding: Encoding {
            distance,
            intensity: IntensityEncoding::I16,
            unit_exp: 0,
        },
        fd_capable: true,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).expect("node 0"), format)
    }
}

/// The candump log text of a replay.
fn log_text(r: &Replayed, brs: bool) -> String {
    r.records("can0", brs)
        .iter()
        .map(|rec| format!("{rec}\n"))
        .collect()
}

fn decode(text: &str) -> (Vec<Item>, LogDecoder) {
    decode_log(text.as_bytes(), IdWindow::DEFAULT).expect("a well-formed log")
}

fn scans(items: &[Item]) -> Vec<&DecodedScan> {
    items
        .iter()
        .filter_map(|i| match i {
            Item::Scan(s) => Some(s),
            _ => None,
        })
        .collect()
}

/// The measurement responses of a capture, read by the tests' independent SCIP reader
/// (not the decoder under test): (damaged, distances with error codes as None,
/// intensities).
type Expected = (bool, Vec<Option<u32>>, Vec<u32>);

fn parsed_scans(bytes: &[u8]) -> Vec<Expected> {
    let dmin = oracle::dmin(bytes);
    oracle::scans(bytes)
        .into_iter()
        .map(|s| {
            let d = s
                .distances
                .iter()
                .map(|&d| oracle::is_range(d, s.width, dmin).then_some(d))
                .collect();
            (s.damaged, d, s.intensities)
        })
        .collect()
}

fn distances(s: &DecodedScan) -> Vec<Option<u32>> {
    s.points
        .iter()
        .map(|p| match p.map(|p| p.distance) {
            Some(Distance::Mm(mm)) => Some(mm),
            _ => None,
        })
        .collect()
}

#[test]
fn every_recording_replays_and_decodes_to_what_the_capture_holds() {
    let Some(dir) = recordings_or_skip("replay → decode") else {
        return;
    };
    let streams = sensor_streams(&dir);
    let mut checked = 0;
    for path in streams {
        let bytes = std::fs::read(&path).expect("read");
        let want = parsed_scans(&bytes);
        for format in [FrameFormat::Classic, FrameFormat::FD64] {
            let r = replay_stream(&bytes, config(format, DistanceEncoding::D16)).expect("replay");
            let (items, dec) = decode(&log_text(&r, true));
            let got = scans(&items);
            let name = format!("{} {format:?}", path.display());
            assert_eq!(got.len(), want.len(), "{name}");
            for (g, (damaged, d, i)) in got.iter().zip(&want) {
                if *damaged {
                    assert!(
                        matches!(g.completeness, Completeness::Aborted { .. }),
                        "{name}: {:?}",
                        g.completeness
                    );
                    continue;
                }
                checked += 1;
                assert_eq!(g.completeness, Completeness::Intact, "{name}");
                assert_eq!(&distances(g), d, "{name}");
                let gi: Vec<u32> = g
                    .points
                    .iter()
                    .filter_map(|p| p.and_then(|p| p.intensity).map(u32::from))
                    .collect();
                // SPEC 4: the 16-bit intensity is min(4 × raw, 65535).
                let wi: Vec<u32> = i.iter().map(|&v| (v * 4).min(65535)).collect();
                assert_eq!(gi, wi, "{name}");
            }
            let lost: u32 = dec.stats().iter().map(|(_, s)| s.frames_lost).sum();
            assert_eq!(lost, 0, "{name}");
        }
    }
    // URG-04LX GD, UTM-30LX ME, the tagged GD, each over classic and FD.
    assert_eq!(checked, 6);
}

/// Runs tests/support/candump_check.py; `None` (with a message) when python-can or
/// cantools is missing, which fails under CI=true.
fn python_check(log: &std::path::Path) -> Option<Vec<Value>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let ok = Command::new("python3")
        .args(["-c", "import can, cantools"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        let msg =
            "python3 with python-can and cantools is needed (pip install python-can cantools)";
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("{msg}; CI=true, so this is a failure");
        }
        eprintln!("{msg}; not run");
        return None;
    }
    let out = Command::new("python3")
        .arg(root.join("support/candump_check.py"))
        .arg(root.join("../firmware/can-wire/scip2can.dbc"))
        .arg(log)
        .output()
        .expect("run python3");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(
        out.stdout
            .lines()
            .map(|l| serde_json::from_str(&l.expect("utf-8")).expect("json"))
            .collect(),
    )
}

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("scip2can-{}-{name}", std::process::id()))
}

#[test]
fn python_can_reads_the_log_and_cantools_decodes_headers_and_trailers() {
    let Some(dir) = recordings_or_skip("python-can") else {
        return;
    };
    let bytes = std::fs::read(dir.join("hokuyoaist_example_utm_30lx.rx.scip")).expect("read");
    for (format, brs) in [(FrameFormat::Classic, false), (FrameFormat::FD64, true)] {
        let r = replay_stream(&bytes, config(format, DistanceEncoding::D14)).expect("replay");
        let records: Vec<Record> = r.records("can0", brs);
        let text = log_text(&r, brs);
        let path = temp_path(&format!("{format:?}.log"));
        std::fs::write(&path, &text).expect("write log");
        let Some(py) = python_check(&path) else {
            return;
        };
        let _ = std::fs::remove_file(&path);
        assert_eq!(py.len(), records.len());
        for (p, rec) in py.iter().zip(&records) {
            let frame = rec.to_frame().expect("data frame");
            let line = rec.to_string();
            let id_text = line
                .split_whitespace()
                .nth(2)
                .and_then(|f| f.split('#').next());
            let raw = u32::from_str_radix(id_text.expect("id field"), 16).expect("hex id");
            assert_eq!(p["id"], raw);
            assert_eq!(p["extended"], false);
            assert_eq!(p["fd"], format.is_fd());
            assert_eq!(p["brs"], brs);
            let hex: String = frame.data().iter().map(|b| format!("{b:02x}")).collect();
            assert_eq!(p["data"], hex);
            let t = p["time"].as_f64().expect("time");
            assert!((t - rec.time_us as f64 / 1e6).abs() < 1e-6, "{t} {rec}");
        }
        // The fixed-layout frames, as cantools reads them with the DBC, hold what the
        // capture says: the first scan (seq 0), its timestamp `BI9Y` read by hand
        // (18 << 18 | 25 << 12 | 9 << 6 | 41), the PP geometry (AMIN 0, AFRT 540, ARES
        // 1440), 1081 points of which the ranges (at least DMIN 23, below the D14
        // out-of-range code 16383) are valid.
        let signals = |name: &str| -> &Value {
            &py.iter().find(|p| p["name"] == name).expect(name)["signals"]
        };
        let a = signals("ScanHeaderA");
        assert_eq!(a["seq"], 0);
        assert_eq!(a["timestamp"], 4_821_609);
        assert_eq!(a["point_count"], 1081);
        assert_eq!(a["unit_exp"], 0);
        let b = signals("ScanHeaderB");
        assert_eq!(b["distance_encoding"], 2, "D14 (SPEC section 4)");
        assert_eq!(b["intensity_encoding"], 1, "I16");
        assert_eq!(b["step_increment"], 1);
        assert_eq!(b["first_step"], -540);
        assert_eq!(b["ares"], 1440);
        let t = signals("ScanTrailer");
        assert_eq!(t["seq"], 0);
        assert_eq!(t["points_sent"], 1081);
        let want = parsed_scans(&bytes).remove(0);
        let valid = want.1.iter().flatten().filter(|&&d| d < 16383).count();
        assert!(valid > 1000, "{valid}");
        assert_eq!(t["points_valid"], valid);
        assert_eq!(t["truncated"], 0);
        let heartbeat = signals("Status");
        assert_eq!(heartbeat["page"], 0);
    }
}

#[test]
fn a_deleted_frame_is_one_lost_frame_and_an_incomplete_scan() {
    let Some(dir) = recordings_or_skip("lost frame") else {
        return;
    };
    let bytes = std::fs::read(dir.join("hokuyoaist_example_utm_30lx.rx.scip")).expect("read");
    let r =
        replay_stream(&bytes, config(FrameFormat::FD64, DistanceEncoding::D16)).expect("replay");
    let text = log_text(&r, true);
    // Delete the fifth data frame (ID 0x150 = node 0's data frames).
    let lines: Vec<&str> = text.lines().collect();
    let victim = lines
        .iter()
        .enumerate()
        .filter(|(_, l)| l.contains(" 150##"))
        .nth(4)
        .map(|(i, _)| i)
        .expect("data frames");
    let kept: String = lines
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != victim)
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    let (items, dec) = decode(&kept);
    let got = scans(&items);
    assert_eq!(got.len(), 1);
    // 64-byte frames of D16+I16 points: (64 - 2) * 8 / 32 = 15 points each.
    assert_eq!(
        got[0].completeness,
        Completeness::Incomplete {
            missing_points: 15,
            trailer_missing: false
        }
    );
    let stats = dec.stats();
    assert_eq!(stats.len(), 1);
    let (node, s) = stats[0];
    assert_eq!(node, 0);
    assert_eq!((s.frames_lost, s.scans_damaged, s.scans_intact), (1, 1, 0));
    // Exactly points 60..75 are gone; the others are what the capture holds.
    let (_, d, inten) = parsed_scans(&bytes).remove(0);
    assert_eq!(got[0].points.len(), d.len());
    for (i, p) in got[0].points.iter().enumerate() {
        let want = (!(60..75).contains(&i)).then(|| Point {
            distance: d[i].map_or(Distance::Invalid, Distance::Mm),
            // SPEC 4: the 16-bit intensity is min(4 × raw, 65535).
            intensity: Some(u16::try_from(inten[i].saturating_mul(4)).unwrap_or(u16::MAX)),
        });
        assert_eq!(*p, want, "point {i}");
    }
}

#[test]
fn the_simulator_streams_through_a_started_session() {
    let sim = SimOptions::from_spec("model=urg04lx,seed=3").expect("spec");
    // The same simulated scans in plain mm and in 12-bit codes of 2 mm.
    let plain = replay_sim(
        &sim,
        3,
        config(FrameFormat::Classic, DistanceEncoding::D16),
        true,
    );
    let mut packed = config(FrameFormat::Classic, DistanceEncoding::D12);
    packed.encoding.unit_exp = 1;
    let packed = replay_sim(&sim, 3, packed, true).expect("sim");
    assert_eq!(packed.stats.scans_in, 3);
    let (plain_items, _) = decode(&log_text(&plain.expect("sim"), false));
    let (items, dec) = decode(&log_text(&packed, false));
    let (want, got) = (scans(&plain_items), scans(&items));
    assert_eq!((want.len(), got.len()), (3, 3));
    for (k, (s, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(s.completeness, Completeness::Intact);
        assert_eq!(s.header.seq, k as u16);
        // The session learned the geometry from PP: AMIN..AMAX = 44..725, AFRT 384,
        // ARES 1024.
        assert_eq!(s.header.point_count, 682);
        assert_eq!((s.header.first_step, s.header.ares), (44 - 384, 1024));
        assert_eq!(s.header.timestamp_ms, w.header.timestamp_ms);
        // 2 mm codes, rounded half up: within 1 mm of the plain ranges, and even.
        let (d, wd) = (distances(s), distances(w));
        assert!(wd.iter().filter(|x| x.is_some()).count() > 300);
        for (x, y) in d.iter().zip(&wd) {
            match (x, y) {
                (Some(x), Some(y)) => assert!(x % 2 == 0 && x.abs_diff(*y) <= 1, "{x} {y}"),
                (None, None) => {}
                other => panic!("{other:?}"),
            }
        }
    }
    assert_eq!(dec.stats()[0].1.scans_intact, 3);
}

/// The simulator's ground truth: a flat wall 2000 mm ahead, no noise. The beam of step
/// `s` leaves at `θ = (s - AFRT) · 2π / ARES` and meets the wall at `2000 / cos θ`,
/// rounded to the mm; beyond the URG-04LX's DMAX (5600 mm) or facing away, no echo.
fn wall_truth(step: u32) -> Option<u32> {
    let theta = (f64::from(step) - 384.0) * std::f64::consts::TAU / 1024.0;
    let cos = theta.cos();
    let mm = (cos > 1e-9).then(|| (2000.0 / cos).round())?;
    (mm <= 5600.0).then_some(mm as u32)
}

#[test]
fn a_simulated_wall_arrives_where_the_geometry_puts_it() {
    let sim = SimOptions::from_spec("model=urg04lx,scene=wall:2000,noise=0").expect("spec");
    // In 1 mm (D16) and in 2 mm codes (D12, unit 2^1): SPEC section 4 rounds a range r
    // to the code (r + 1) >> 1, received as twice that.
    let mut packed = config(FrameFormat::Classic, DistanceEncoding::D12);
    packed.encoding.unit_exp = 1;
    for (c, unit) in [
        (config(FrameFormat::FD64, DistanceEncoding::D16), 1),
        (packed, 2),
    ] {
        let r = replay_sim(&sim, 2, c, true).expect("sim");
        let (items, _) = decode(&log_text(&r, c.budget.format.is_fd()));
        let got = scans(&items);
        assert_eq!(got.len(), 2, "unit {unit}");
        for s in got {
            assert_eq!(s.completeness, Completeness::Intact);
            assert_eq!(s.header.point_count, 682);
            let want: Vec<Option<u32>> = (44..=725)
                .map(|step| wall_truth(step).map(|mm| (mm + unit / 2) / unit * unit))
                .collect();
            // Straight ahead (step 384, point 340) the wall is at 2000 mm; ±90° it is out
            // of reach.
            assert_eq!(want[340], Some(2000));
            assert!(want.iter().filter(|w| w.is_none()).count() > 100);
            assert_eq!(distances(s), want, "unit {unit}");
        }
    }
}

#[test]
fn the_governor_decimates_a_utm30lx_to_fit_half_a_classic_bus() {
    let sim = SimOptions::from_spec("model=utm30lx,seed=5").expect("spec");
    let mut c = config(FrameFormat::Classic, DistanceEncoding::D16);
    c.uart_bit_rate = 12_000_000;
    c.budget.share_permille = 500;
    // 1081 points at 40 Hz need 196 % of the bus; every 5th point is the finest
    // decimation that fits 50 %.
    let r = replay_sim(&sim, 4, c, true).expect("sim");
    let plan = r.plan.expect("a plan");
    assert_eq!((plan.factor, plan.every_nth, plan.points), (5, 1, 217));
    assert!(plan.load_ppm <= 500_000);
    let (items, _) = decode(&log_text(&r, false));
    let got = scans(&items);
    assert_eq!(got.len(), 4);
    for s in got {
        assert_eq!(s.completeness, Completeness::Intact);
        assert_eq!((s.header.point_count, s.header.step_increment), (217, 5));
    }
    // Told to keep every point, the bridge cannot queue a 364-frame scan: each is
    // dropped whole, none is sent in part.
    let r = replay_sim(&sim, 4, c, false).expect("sim");
    assert_eq!((r.stats.scans_sent, r.stats.scans_dropped), (0, 4));
    assert_eq!(r.scans_out(), 0);
}

#[test]
fn plot_writes_a_png_of_the_requested_size() {
    let sim = SimOptions::from_spec("model=utm30lx,seed=2").expect("spec");
    let r = replay_sim(
        &sim,
        2,
        config(FrameFormat::FD64, DistanceEncoding::D16),
        true,
    )
    .expect("sim");
    let (items, _) = decode(&log_text(&r, true));
    let chosen: Vec<DecodedScan> = scans(&items).into_iter().cloned().collect();
    let path = temp_path("plot.png");
    scip2can_host::plot::draw(&chosen, &path, 321, 8.0).expect("draw");
    let png = std::fs::read(&path).expect("png");
    let _ = std::fs::remove_file(&path);
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert_eq!(&png[12..16], b"IHDR");
    let dim = |at: usize| u32::from_be_bytes(png[at..at + 4].try_into().expect("4 bytes"));
    assert_eq!((dim(16), dim(20)), (321, 321));
    assert!(png.len() > 1000);
}
