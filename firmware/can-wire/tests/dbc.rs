//! Cross-check of scip2can.dbc: frames made by the Rust encoders are decoded by cantools
//! (tests/dbc_decode.py) and must agree field by field with the Rust decoders.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::Command as Process;

use can_wire::*;
use embedded_can::Id;

fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether python3 with cantools is usable; fails under CI=true if not.
fn cantools_available() -> bool {
    let ok = Process::new("python3")
        .args(["-c", "import cantools"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("python3 with cantools is required under CI (pip install cantools)");
        }
        eprintln!("skipping DBC cross-check: python3 or cantools missing (pip install cantools)");
    }
    ok
}

type Signals = BTreeMap<String, i64>;

fn sig(pairs: &[(&str, i64)]) -> Signals {
    pairs.iter().map(|(k, v)| (k.to_string(), *v)).collect()
}

/// Expected (message name, raw signals) from the Rust decoders.
fn rust_decode(frame: &Frame) -> (String, Signals) {
    let time_id = can_wire::timesync::time_id(0x0FF, &IdWindow::DEFAULT).unwrap();
    if frame.id() == time_id {
        let t = TimeFrame::parse(frame.data()).unwrap();
        let mut s = sig(&[("seq", t.seq().into())]);
        match t {
            TimeFrame::Sync { .. } => {
                s.insert("type".into(), 1);
            }
            TimeFrame::FollowUp { master_us, .. } => {
                s.insert("type".into(), 2);
                s.insert("master_time".into(), master_us as i64);
            }
        }
        return ("TimeSync".into(), s);
    }
    let (node, kind) = IdWindow::DEFAULT.classify(frame.id()).expect("our id");
    assert_eq!(node, 0);
    let d = frame.data();
    match kind {
        Kind::Control => {
            let c = Control::parse(d).unwrap();
            let mut s = sig(&[
                ("opcode", i64::from(c.command.opcode())),
                ("token", i64::from(c.token)),
            ]);
            let params: Vec<(&str, i64)> = match c.command {
                can_wire::Command::RangeWindow { min_mm, max_mm } => vec![
                    ("range_min_mm", min_mm.into()),
                    ("range_max_mm", max_mm.into()),
                ],
                can_wire::Command::Speckle { enabled } => {
                    vec![("speckle_enabled", enabled.into())]
                }
                can_wire::Command::Median { window } => {
                    vec![("median_window", window as i64)]
                }
                can_wire::Command::IntensityThreshold { threshold } => {
                    vec![("intensity_threshold", threshold.into())]
                }
                can_wire::Command::AngularDecimation { k, mode } => {
                    vec![("decimation_k", k.into()), ("decimation_mode", mode as i64)]
                }
                can_wire::Command::RegionOfInterest {
                    start_step,
                    end_step,
                } => vec![
                    ("roi_start_step", start_step.into()),
                    ("roi_end_step", end_step.into()),
                ],
                can_wire::Command::TemporalDecimation {
                    every_nth,
                    max_rate_centihz,
                } => vec![
                    ("temporal_every_nth", every_nth.into()),
                    ("temporal_max_rate", max_rate_centihz.into()),
                ],
                can_wire::Command::Encoding(e) => vec![
                    ("encoding_distance", e.distance.code().into()),
                    ("encoding_intensity", e.intensity.code().into()),
                    ("encoding_unit_exp", e.unit_exp.into()),
                ],
                can_wire::Command::FrameSize { max_len } => {
                    vec![("frame_max_len", max_len.into())]
                }
                _ => vec![],
            };
            s.extend(params.into_iter().map(|(k, v)| (k.to_string(), v)));
            ("Control".into(), s)
        }
        Kind::ControlAnswer => {
            let a = Answer::parse(d).unwrap();
            (
                "ControlAnswer".into(),
                sig(&[
                    ("opcode", a.opcode.into()),
                    ("token", a.token.into()),
                    ("result", u8::from(a.outcome).into()),
                    ("detail", a.detail.into()),
                ]),
            )
        }
        Kind::Status => {
            let st = Status::parse(d).unwrap();
            let mut s = sig(&[("page", st.page().into())]);
            let fields: Vec<(&str, i64)> = match st {
                Status::Heartbeat {
                    state,
                    cpu_load,
                    bus_load,
                    uptime_s,
                } => vec![
                    ("state", u8::from(state).into()),
                    ("cpu_load", cpu_load.into()),
                    ("bus_load", bus_load.into()),
                    ("uptime", uptime_s.into()),
                ],
                Status::SensorCounters {
                    sum_errors,
                    resyncs,
                    dropped_scans,
                    recoveries,
                } => vec![
                    ("sum_errors", sum_errors.into()),
                    ("resyncs", resyncs.into()),
                    ("dropped_scans", dropped_scans.into()),
                    ("recoveries", recoveries.into()),
                ],
                Status::BusCounters {
                    bus_errors,
                    bus_off_events,
                    tx_overflows,
                    error_state,
                } => vec![
                    ("bus_errors", bus_errors.into()),
                    ("bus_off_events", bus_off_events.into()),
                    ("tx_overflows", tx_overflows.into()),
                    ("error_state", u8::from(error_state).into()),
                ],
                Status::Firmware {
                    protocol,
                    major,
                    minor,
                    patch,
                    build,
                } => vec![
                    ("protocol", protocol.into()),
                    ("fw_major", major.into()),
                    ("fw_minor", minor.into()),
                    ("fw_patch", patch.into()),
                    ("fw_build", build.into()),
                ],
                Status::SensorRange {
                    model,
                    dmin_mm,
                    dmax_mm,
                } => vec![
                    ("model", u8::from(model).into()),
                    ("dmin", dmin_mm.into()),
                    ("dmax", dmax_mm.into()),
                ],
                Status::SensorSteps { ares, amin, amax } => vec![
                    ("ares", ares.into()),
                    ("amin", amin.into()),
                    ("amax", amax.into()),
                ],
                Status::SensorTiming { afrt, scan_rpm } => {
                    vec![("afrt", afrt.into()), ("scan_rpm", scan_rpm.into())]
                }
                Status::TimeSync {
                    synced,
                    error_us,
                    master_time,
                } => vec![
                    ("time_synced", synced.into()),
                    ("time_error", error_us.into()),
                    ("master_time_low", master_time.into()),
                ],
            };
            s.extend(fields.into_iter().map(|(k, v)| (k.to_string(), v)));
            ("Status".into(), s)
        }
        Kind::HeaderA => {
            let a = can_wire::header::HeaderA::parse(d).unwrap();
            (
                "ScanHeaderA".into(),
                sig(&[
                    ("seq", a.seq.into()),
                    ("timestamp", a.timestamp_ms.into()),
                    ("point_count", a.point_count.into()),
                    ("unit_exp", a.unit_exp.into()),
                ]),
            )
        }
        Kind::HeaderB => {
            let b = can_wire::header::HeaderB::parse(d).unwrap();
            (
                "ScanHeaderB".into(),
                sig(&[
                    ("seq_low", b.seq_low.into()),
                    ("distance_encoding", b.distance.code().into()),
                    ("intensity_encoding", b.intensity.code().into()),
                    ("time_synced", b.time_synced.into()),
                    ("grouping", b.grouping as i64),
                    ("time_estimated", b.time_estimated.into()),
                    ("time_master", b.time_master.into()),
                    ("step_increment", b.step_increment.into()),
                    ("first_step", b.first_step.into()),
                    ("ares", b.ares.into()),
                ]),
            )
        }
        Kind::Data => {
            let h = can_wire::data::DataHeader::parse(d).unwrap();
            (
                "ScanData".into(),
                sig(&[
                    ("first_index", h.first_index.into()),
                    ("seq_low4", h.seq_low.into()),
                ]),
            )
        }
        Kind::Trailer => {
            let t = Trailer::parse(d).unwrap();
            (
                "ScanTrailer".into(),
                sig(&[
                    ("seq", t.seq.into()),
                    ("points_sent", t.points_sent.into()),
                    ("truncated", t.flags.truncated.into()),
                    ("sensor_error", t.flags.sensor_error.into()),
                    ("filtered", t.flags.filtered.into()),
                    ("points_valid", t.points_valid.into()),
                    ("crc", t.crc.into()),
                ]),
            )
        }
        Kind::Abort => {
            let a = Abort::parse(d).unwrap();
            (
                "ScanAbort".into(),
                sig(&[
                    ("seq", a.seq.into()),
                    ("reason", u8::from(a.reason).into()),
                    ("detail", a.detail.into()),
                    ("points_sent", a.points_sent.into()),
                ]),
            )
        }
    }
}

fn scan_frames(format: FrameFormat, seq: u16, abort: bool) -> Vec<Frame> {
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let mut enc = ScanEncoder::new(ids, format).unwrap();
    let header = ScanHeader {
        seq,
        timestamp_ms: 0xDEAD_BEEF,
        point_count: 40,
        encoding: Encoding {
            distance: DistanceEncoding::D14,
            intensity: IntensityEncoding::I12,
            unit_exp: 3,
        },
        time_synced: true,
        time_estimated: true,
        time_master: false,
        grouping: Grouping::Mean,
        step_increment: 3,
        first_step: -135,
        ares: 1440,
    };
    let mut out: Vec<Frame> = enc.begin(&header).unwrap().into();
    for i in 0..30u32 {
        let d = match i % 7 {
            0 => Distance::Invalid,
            1 => Distance::OutOfRange,
            _ => Distance::Mm(i * 977),
        };
        out.extend(enc.push_point(d, (i * 2111) as u16).unwrap());
    }
    if abort {
        out.push(enc.abort(AbortReason::SensorError, 0x21).unwrap());
    } else {
        out.extend(
            enc.finish(TrailerFlags {
                truncated: false,
                sensor_error: true,
                filtered: true,
            })
            .unwrap(),
        );
    }
    out
}

/// The header and trailer frames of a lossless (DL) scan: the DBC describes those; its
/// data frames are a Rice-coded stream a DBC cannot (SPEC 4.2).
fn lossless_scan_frames() -> Vec<Frame> {
    struct Sink(Vec<Frame>);
    impl FrameSink for Sink {
        fn data_slot(&mut self) -> Option<&mut Frame> {
            self.0.push(Frame::default());
            self.0.last_mut()
        }
    }
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let mut enc = ScanEncoder::new(ids, FrameFormat::Classic).unwrap();
    let header = ScanHeader {
        seq: 0x0304,
        timestamp_ms: 12,
        point_count: 200,
        encoding: Encoding {
            distance: DistanceEncoding::Lossless,
            intensity: IntensityEncoding::I16,
            unit_exp: 0,
        },
        time_synced: false,
        time_estimated: false,
        time_master: false,
        grouping: Grouping::Single,
        step_increment: 1,
        first_step: -540,
        ares: 1440,
    };
    let mut out: Vec<Frame> = enc.begin(&header).unwrap().into();
    let mut data = Sink(vec![]);
    for i in 0..200u32 {
        let d = if i % 50 == 7 {
            Distance::SensorError(1)
        } else {
            Distance::Mm(3000 + i)
        };
        enc.push_point_to(d, i as u16, &mut data).unwrap();
    }
    assert!(!data.0.is_empty());
    out.extend(enc.finish(TrailerFlags::default()).unwrap());
    out
}

fn all_frames() -> Vec<Frame> {
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let mut frames = scan_frames(FrameFormat::Classic, 0xFFF3, false);
    frames.extend(scan_frames(FrameFormat::Fd { max_len: 24 }, 7, true));
    frames.extend(lossless_scan_frames());
    let commands = [
        can_wire::Command::Start,
        can_wire::Command::Stop,
        can_wire::Command::RequestSensorInfo,
        can_wire::Command::ResetCounters,
        can_wire::Command::RangeWindow {
            min_mm: 23,
            max_mm: 0xAB_CDEF,
        },
        can_wire::Command::Speckle { enabled: true },
        can_wire::Command::Median {
            window: MedianWindow::Three,
        },
        can_wire::Command::IntensityThreshold { threshold: 0xBEEF },
        can_wire::Command::AngularDecimation {
            k: 200,
            mode: DecimationMode::Min,
        },
        can_wire::Command::RegionOfInterest {
            start_step: 44,
            end_step: 4095,
        },
        can_wire::Command::TemporalDecimation {
            every_nth: 3,
            max_rate_centihz: 4000,
        },
        can_wire::Command::Encoding(Encoding {
            distance: DistanceEncoding::D12,
            intensity: IntensityEncoding::I8,
            unit_exp: 15,
        }),
        can_wire::Command::FrameSize { max_len: 48 },
        can_wire::Command::Encoding(Encoding {
            distance: DistanceEncoding::Lossless,
            intensity: IntensityEncoding::None,
            unit_exp: 0,
        }),
    ];
    for (token, command) in commands.into_iter().enumerate() {
        let mut buf = [0u8; 8];
        let c = Control {
            token: token as u8 * 17,
            command,
        };
        let len = c.emit(&mut buf).unwrap();
        frames.push(Frame::new(ids.id(Kind::Control), &buf[..len], false).unwrap());
        let answer = if token % 2 == 0 {
            Answer::accept(&c)
        } else {
            Answer {
                opcode: command.opcode(),
                token: c.token,
                outcome: Outcome::OutOfRange,
                detail: 3,
            }
        };
        frames.push(Frame::new(ids.id(Kind::ControlAnswer), &answer.emit(), false).unwrap());
    }
    let statuses = [
        Status::Heartbeat {
            state: BridgeState::Recovering,
            cpu_load: 199,
            bus_load: 71,
            uptime_s: 0xFEDC_BA98,
        },
        Status::SensorCounters {
            sum_errors: 65535,
            resyncs: 2,
            dropped_scans: 300,
            recoveries: 255,
        },
        Status::BusCounters {
            bus_errors: 9,
            bus_off_events: 1,
            tx_overflows: 40000,
            error_state: BusState::BusOff,
        },
        Status::Firmware {
            protocol: 1,
            major: 2,
            minor: 3,
            patch: 4,
            build: 0x00AB_CDEF,
        },
        Status::SensorRange {
            model: SensorModel::Uxm30lxE,
            dmin_mm: 100,
            dmax_mm: 100_000,
        },
        Status::SensorSteps {
            ares: 1440,
            amin: 0,
            amax: 760,
        },
        Status::SensorTiming {
            afrt: 380,
            scan_rpm: 1200,
        },
        Status::TimeSync {
            synced: true,
            error_us: 65535,
            master_time: 0x8765_4321,
        },
    ];
    for s in statuses {
        frames.push(Frame::new(ids.id(Kind::Status), &s.emit().unwrap(), false).unwrap());
    }
    let time_id = can_wire::timesync::time_id(0x0FF, &IdWindow::DEFAULT).unwrap();
    for t in [
        TimeFrame::Sync { seq: 0 },
        TimeFrame::FollowUp {
            seq: 0,
            master_us: 1_767_225_600_123_456,
        },
        TimeFrame::Sync { seq: 15 },
        TimeFrame::FollowUp {
            seq: 15,
            master_us: (1 << 56) - 1,
        },
    ] {
        frames.push(t.to_frame(time_id).unwrap());
    }
    frames
}

fn candump_line(out: &mut String, i: usize, f: &Frame) {
    let raw = match f.id() {
        Id::Standard(s) => format!("{:03X}", s.as_raw()),
        Id::Extended(e) => format!("{:08X}", e.as_raw()),
    };
    let hex: String = f.data().iter().map(|b| format!("{b:02X}")).collect();
    let sep = if f.is_fd() { "##1" } else { "#" };
    writeln!(out, "({}.{:06}) can0 {raw}{sep}{hex}", 1000 + i, 0).unwrap();
}

#[test]
fn cantools_agrees_with_rust_decoders() {
    if !cantools_available() {
        return;
    }
    let frames = all_frames();
    let mut log = String::new();
    for (i, f) in frames.iter().enumerate() {
        candump_line(&mut log, i, f);
    }
    let path = std::env::temp_dir().join(format!("can-wire-dbc-{}.log", std::process::id()));
    std::fs::write(&path, &log).unwrap();
    let out = Process::new("python3")
        .arg(manifest().join("tests/dbc_decode.py"))
        .arg(manifest().join("scip2can.dbc"))
        .arg(&path)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&path);
    assert!(
        out.status.success(),
        "cantools failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), frames.len());
    let mut kinds = std::collections::BTreeSet::new();
    for (line, frame) in lines.iter().zip(&frames) {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let (name, want) = rust_decode(frame);
        assert_eq!(v["name"], name.as_str(), "{frame:?}");
        let got: Signals = v["signals"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(k, v)| (k.clone(), v.as_i64().unwrap()))
            .collect();
        assert_eq!(got, want, "{frame:?}");
        kinds.insert(name);
    }
    // Every message of the DBC was exercised.
    assert_eq!(kinds.len(), 9, "{kinds:?}");
}
