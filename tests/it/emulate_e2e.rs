//! End to end on the emulated board: the simulator, the real firmware ELF in
//! `qemu-system-arm` (mps2-an386), and the host decoder over SLCAN.
//!
//! - every scan that arrives is identical to the host replay of the same sensor bytes
//!   through the same core with the same configuration (the firmware's own `config.rs`);
//! - with UART faults and a sensor reboot, no damaged response comes out as an intact
//!   scan, and streaming resumes by itself;
//! - a control frame written to the SLCAN port changes the decimation of the next scans;
//! - python-can's `slcan` interface, unmodified, works on the port.
//!
//! They need `qemu-system-arm` (under `CI=true` its absence fails the tests, otherwise
//! they say so and pass) and build the firmware in `firmware/boards` (its own target
//! folder) first.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use bridge::engine::Bridge;
use can_wire::control::{Command as Ctl, DecimationMode};
use can_wire::{Answer, Completeness, Control, Frame, IdWindow, Kind, Outcome};
use scip2can_host::candump::Record;
use scip2can_host::decode::{DecodedScan, Item, LogDecoder};
use scip2can_host::emulate::{self, Emulation, Incoming, Setup, SlcanLink, Uart1};
use scip2can_host::sim::faults::FaultKind;
use scip2can_host::sim::SimOptions;
use slcan::{Command, FrameKind, Reply};

/// The firmware's own configuration, compiled for the host.
use scip2can_host::icount::qemu_config;

use crate::qemu::QEMU;

/// The firmware ELF, built once per test run; `None` (test skipped) without QEMU.
fn firmware() -> Option<PathBuf> {
    static ELF: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    crate::qemu::firmware(&ELF, emulate::build_firmware)
}

fn start(firmware: PathBuf, sim: &str) -> Emulation {
    let setup = Setup {
        sim: SimOptions::from_spec(sim).unwrap(),
        firmware,
        qemu: QEMU.into(),
        icount: false,
        uart1: Uart1::Connect,
        link: emulate::SensorLink::Uart,
    };
    Emulation::start(&setup).unwrap()
}

/// A frame received over SLCAN and when (ms since the emulation started).
struct Received {
    ms: u64,
    frame: Frame,
}

/// Something to do once with the link, at a time in seconds.
type Action<'a> = (f64, &'a mut dyn FnMut(&mut SlcanLink));

/// Receives for `secs`, doing `at` once when its time has come.
fn collect(
    emu: &Emulation,
    link: &mut SlcanLink,
    secs: f64,
    mut at: Option<Action<'_>>,
    replies: &mut Vec<Reply>,
) -> Vec<Received> {
    let until = Instant::now() + Duration::from_secs_f64(secs);
    let start = Instant::now();
    let mut out = Vec::new();
    while Instant::now() < until {
        if let Some((t, f)) = at.as_mut() {
            if start.elapsed().as_secs_f64() >= *t {
                f(link);
                at = None;
            }
        }
        match link.recv(Duration::from_millis(50)).unwrap() {
            Some(Incoming::Reply(Reply::Frame(f, _))) => out.push(Received {
                ms: emu.elapsed().as_millis() as u64,
                frame: Frame::new(f.id(), f.data(), f.kind().is_fd()).unwrap(),
            }),
            Some(Incoming::Reply(r)) => replies.push(r),
            Some(other) => panic!("unexpected line on the SLCAN port: {other:?}"),
            None => {}
        }
    }
    out
}

/// Reassembled scans of a frame sequence, with the time of their last frame.
fn scans(frames: &[Received]) -> Vec<(u64, DecodedScan)> {
    let mut dec = LogDecoder::new(IdWindow::DEFAULT);
    let mut out = Vec::new();
    for r in frames {
        let rec = Record::from_frame(r.ms * 1000, "can0", &r.frame, r.frame.is_fd());
        if let Some(Item::Scan(s)) = dec.push(&rec) {
            out.push((r.ms, s));
        }
    }
    out
}

/// The same sensor bytes through the same core on the host, in the pieces the board
/// handles (its receive ring hands out at most 64 bytes), frames taken after each.
fn replay(stream: &[(u64, Vec<u8>)]) -> Vec<Received> {
    let config = qemu_config::bridge().unwrap();
    let mut b: Bridge<{ qemu_config::QUEUE }> = Bridge::new(config).unwrap();
    b.set_bus_state(can_wire::BusState::ErrorActive);
    b.start(0);
    let mut out = Vec::new();
    for (ms, bytes) in stream {
        // What falls due by now (a stale partial response dropped, a timeout) comes
        // before the bytes of this moment, as on the board, which polls between reads.
        while b.poll(*ms).is_some() {}
        for piece in bytes.chunks(16) {
            b.on_uart(piece, *ms);
            while b.poll(*ms).is_some() {}
            while let Some(frame) = b.pop_frame() {
                out.push(Received { ms: *ms, frame });
            }
        }
    }
    out
}

/// Every intact scan of the board is the replay's scan of the same sequence number,
/// header and points alike; no intact replay scan between the first and last one the
/// board delivered is missing. Returns the number compared.
fn assert_same_as_replay(board: &[(u64, DecodedScan)], stream: &[(u64, Vec<u8>)]) -> usize {
    let replayed: BTreeMap<u16, DecodedScan> = scans(&replay(stream))
        .into_iter()
        .filter(|(_, s)| s.completeness == Completeness::Intact)
        .map(|(_, s)| (s.header.seq, s))
        .collect();
    let intact: Vec<&DecodedScan> = board
        .iter()
        .map(|(_, s)| s)
        .filter(|s| s.completeness == Completeness::Intact)
        .collect();
    for s in &intact {
        let r = replayed
            .get(&s.header.seq)
            .unwrap_or_else(|| panic!("scan {} is not in the host replay", s.header.seq));
        assert_eq!(s.header, r.header, "header of scan {}", s.header.seq);
        assert_eq!(s.points, r.points, "points of scan {}", s.header.seq);
    }
    if let (Some(first), Some(last)) = (intact.first(), intact.last()) {
        let delivered: Vec<u16> = intact.iter().map(|s| s.header.seq).collect();
        for seq in replayed
            .keys()
            .filter(|&&q| q > first.header.seq && q < last.header.seq)
        {
            assert!(delivered.contains(seq), "replay scan {seq} never arrived");
        }
    }
    intact.len()
}

fn open(emu: &mut Emulation) -> SlcanLink {
    let mut link = emu.can.take().unwrap();
    link.send(&Command::BitRate(8)).unwrap();
    link.send(&Command::Open).unwrap();
    link
}

#[test]
fn every_scan_matches_the_host_replay_of_the_same_bytes() {
    let Some(elf) = firmware() else { return };
    let mut emu = start(elf, "model=urg04lx,seed=3");
    let mut link = open(&mut emu);
    let mut replies = Vec::new();
    let frames = collect(&emu, &mut link, 8.0, None, &mut replies);
    let stream = emu.sensor_stream();
    emu.stop().unwrap();
    assert_eq!(replies.first(), Some(&Reply::Ok), "S8 answered CR");
    let board = scans(&frames);
    let n = assert_same_as_replay(&board, &stream);
    assert!(n >= 5, "only {n} intact scans in 8 s");
    // URG-04LX, full range AMIN..AMAX learned from PP: 682 points of 16-bit mm.
    let first = &board
        .iter()
        .find(|(_, s)| s.completeness == Completeness::Intact)
        .unwrap()
        .1;
    assert_eq!(first.header.point_count, 682);
    assert_eq!(first.header.first_step, 44 - 384);
}

#[test]
fn faults_never_pass_as_intact_scans_and_streaming_resumes_after_a_reboot() {
    let Some(elf) = firmware() else { return };
    let mut emu = start(
        elf,
        "model=urg04lx,seed=5,flip=0.15,drop=0.1,insert=0.1,reboot_at=30,fault_seed=7",
    );
    let mut link = open(&mut emu);
    let mut replies = Vec::new();
    let frames = collect(&emu, &mut link, 14.0, None, &mut replies);
    let stream = emu.sensor_stream();
    let faults = emu.stop().unwrap();
    let board = scans(&frames);
    assert_same_as_replay(&board, &stream);

    // Independently of the core: every intact scan's timestamp belongs to a response
    // that the SCIP decoder read without any error.
    let mut clean = std::collections::BTreeSet::new();
    let mut dec = scip::Decoder::new();
    let (mut ts, mut bad) = (None, false);
    let all: Vec<u8> = stream.iter().flat_map(|(_, b)| b.iter().copied()).collect();
    let mut rest = all.as_slice();
    while !rest.is_empty() {
        let (used, ev) = dec.feed(rest);
        rest = &rest[used..];
        match ev {
            Some(scip::Event::Start { .. }) => (ts, bad) = (None, false),
            Some(scip::Event::Timestamp(t)) => ts = Some(t),
            Some(scip::Event::Error(_)) => bad = true,
            Some(scip::Event::End(_)) if !bad => clean.extend(ts),
            _ => {}
        }
    }
    let intact: Vec<&(u64, DecodedScan)> = board
        .iter()
        .filter(|(_, s)| s.completeness == Completeness::Intact)
        .collect();
    for (_, s) in &intact {
        assert!(
            clean.contains(&s.header.timestamp_ms),
            "scan {} (timestamp {}) is intact but its response was damaged",
            s.header.seq,
            s.header.timestamp_ms
        );
    }
    let damaging = faults.iter().filter(|f| f.detected_as.is_some()).count();
    let aborted = board
        .iter()
        .filter(|(_, s)| matches!(s.completeness, Completeness::Aborted { .. }))
        .count();
    assert!(
        damaging > 0 && aborted > 0,
        "faults {damaging}, aborted scans {aborted}"
    );

    // The reboot (URG-04LX comes back in SCIP 1.1) is recovered: intact scans again.
    let reboot = faults
        .iter()
        .find(|f| matches!(f.kind, FaultKind::Reboot { .. }))
        .expect("the sensor rebooted");
    let after = intact
        .iter()
        .filter(|(ms, _)| *ms > reboot.at_us / 1000 + 500)
        .count();
    assert!(
        after >= 3,
        "{after} intact scans after the reboot at {} ms",
        reboot.at_us / 1000
    );
}

#[test]
fn a_control_frame_over_slcan_changes_the_decimation_of_the_next_scans() {
    let Some(elf) = firmware() else { return };
    let mut emu = start(elf, "model=urg04lx,seed=9");
    let mut link = open(&mut emu);
    let ids = IdWindow::DEFAULT.node(qemu_config::NODE).unwrap();
    let control = Control {
        token: 0x33,
        command: Ctl::AngularDecimation {
            k: 4,
            mode: DecimationMode::Min,
        },
    };
    let mut buf = [0u8; 8];
    let n = control.emit(&mut buf).unwrap();
    let line = slcan::Frame::new(ids.id(Kind::Control), FrameKind::Data, &buf[..n]).unwrap();
    let mut send = |l: &mut SlcanLink| l.send(&Command::Transmit(line)).unwrap();
    let mut replies = Vec::new();
    let frames = collect(&emu, &mut link, 8.0, Some((4.0, &mut send)), &mut replies);
    emu.stop().unwrap();
    assert!(
        replies.contains(&Reply::Transmitted { extended: false }),
        "{replies:?}"
    );
    let answer_id = ids.id(Kind::ControlAnswer);
    let answer_at = frames
        .iter()
        .position(|r| r.frame.id() == answer_id)
        .expect("the board answered the control frame");
    let answer = Answer::parse(frames[answer_at].frame.data()).unwrap();
    assert_eq!((answer.token, answer.outcome), (0x33, Outcome::Accepted));
    let before = scans(&frames[..answer_at]);
    let after = scans(&frames[answer_at..]);
    let intact = |v: &[(u64, DecodedScan)]| -> Vec<(u8, u16)> {
        v.iter()
            .filter(|(_, s)| s.completeness == Completeness::Intact)
            .map(|(_, s)| (s.header.step_increment, s.header.point_count))
            .collect()
    };
    let (before, after) = (intact(&before), intact(&after));
    assert!(
        !before.is_empty() && before.iter().all(|&s| s == (1, 682)),
        "{before:?}"
    );
    // The scan under way when the answer left keeps its geometry; the ones after it
    // have a quarter of the points (682 / 4 rounded up).
    assert!(after.len() >= 3, "{after:?}");
    assert!(after[1..].iter().all(|&s| s == (4, 171)), "{after:?}");
}

#[test]
fn python_can_slcan_client_works_on_the_can_port() {
    let Some(elf) = firmware() else { return };
    let have_python = std::process::Command::new("python3")
        .args(["-c", "import can, serial"])
        .status()
        .is_ok_and(|s| s.success());
    if !have_python {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "python3 with python-can and pyserial is missing (CI=true)"
        );
        eprintln!("skipped: needs python3 -m pip install python-can pyserial");
        return;
    }
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let setup = Setup {
        sim: SimOptions::from_spec("model=urg04lx,seed=2").unwrap(),
        firmware: elf,
        qemu: QEMU.into(),
        icount: false,
        uart1: Uart1::Server(port),
        link: emulate::SensorLink::Uart,
    };
    let emu = Emulation::start(&setup).unwrap();
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("slcan_client.py");
    // QEMU opens its listening socket shortly after it starts.
    std::thread::sleep(Duration::from_millis(500));
    let out = std::process::Command::new("python3")
        .arg(&script)
        .arg(format!("socket://127.0.0.1:{port}"))
        .arg("6")
        .output()
        .unwrap();
    emu.stop().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["version"], serde_json::json!([1, 0]), "{v}");
    assert_eq!(v["serial"], "QEMU", "{v}");
    assert!(v["frames"].as_u64().unwrap() > 100, "{v}");
    // Scan frames of node 0: header A 0x130, header B 0x140, data 0x150, trailer 0x160.
    for id in ["130", "140", "150", "160"] {
        assert!(
            v["ids"][id].as_u64().unwrap_or(0) > 0,
            "no {id} frames: {v}"
        );
    }
    let answers = v["answers"].as_array().unwrap();
    assert_eq!(answers.len(), 1, "{v}");
    let bytes: Vec<u8> = (0..4)
        .map(|i| u8::from_str_radix(&answers[0].as_str().unwrap()[2 * i..2 * i + 2], 16).unwrap())
        .collect();
    let answer = Answer::parse(&bytes).unwrap();
    assert_eq!(
        (answer.opcode, answer.token, answer.outcome),
        (0x14, 0x5A, Outcome::Accepted)
    );
}
