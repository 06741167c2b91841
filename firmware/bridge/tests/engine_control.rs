//! The engine's CAN side: control frames applied and answered, status frames, priority
//! over scan frames, decimation changes showing in the next scan.

use bridge::engine::{Bridge, BridgeConfig};
use can_wire::control::{Command as Ctl, DecimationMode};
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Answer, BridgeState, Control, Frame, FrameFormat, IdWindow, Kind, Outcome, Status};
use scip::{Command, Request, ResponseWriter, ScanMode, ScanRequest};

const Q: usize = 256;

fn config() -> BridgeConfig {
    BridgeConfig {
        encoding: can_wire::Encoding::PLAIN_MM,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(3).unwrap(), FrameFormat::FD64)
    }
}

/// One stream frame of `n` points (steps 0..n-1), distances 1000 + i.
fn scan_frame(n: u16, ts: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    let mut s = ScanRequest::distance(ScanMode::Continuous, 0, n - 1);
    s.count = 0;
    w.echo(&Request::new(Command::Scan(s)));
    w.status(*b"99");
    w.timestamp(ts);
    for i in 0..u32::from(n) {
        w.step(1000 + i, 0);
    }
    w.end();
    let _ = w.into_inner();
    out
}

fn control_frame(token: u8, command: Ctl) -> Frame {
    let ids = config().ids;
    let mut buf = [0u8; 8];
    let n = Control { token, command }.emit(&mut buf).unwrap();
    Frame::new(ids.id(Kind::Control), &buf[..n], false).unwrap()
}

fn drain(b: &mut Bridge<Q>) -> Vec<Frame> {
    std::iter::from_fn(|| b.pop_frame()).collect()
}

fn answers(frames: &[Frame]) -> Vec<Answer> {
    let id = config().ids.id(Kind::ControlAnswer);
    frames
        .iter()
        .filter(|f| f.id() == id)
        .map(|f| Answer::parse(f.data()).unwrap())
        .collect()
}

fn scans(frames: &[Frame]) -> Vec<(u16, u8, Vec<u32>)> {
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Vec::new();
    for f in frames {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
            assert!(scan.is_intact());
            let d = scan
                .points()
                .map(|p| match p.map(|p| p.distance) {
                    Some(can_wire::Distance::Mm(mm)) => mm,
                    _ => 0,
                })
                .collect();
            out.push((scan.header().point_count, scan.header().step_increment, d));
        }
    }
    out
}

#[test]
fn decimation_by_control_frame_shows_in_the_next_scan() {
    let mut b: Bridge<Q> = Bridge::new(config()).unwrap();
    b.on_uart(&scan_frame(100, 10), 0);
    // The control frame arrives while a scan is half received: it applies to the next.
    let next = scan_frame(100, 35);
    b.on_uart(&next[..150], 1);
    assert!(b.on_can_frame(
        &control_frame(
            7,
            Ctl::AngularDecimation {
                k: 4,
                mode: DecimationMode::Min
            }
        ),
        1
    ));
    b.on_uart(&next[150..], 2);
    b.on_uart(&scan_frame(100, 60), 3);
    let frames = drain(&mut b);
    let a = answers(&frames);
    assert_eq!(a.len(), 1);
    assert_eq!((a[0].token, a[0].outcome), (7, Outcome::Accepted));
    let s = scans(&frames);
    assert_eq!(s.len(), 3);
    assert_eq!((s[0].0, s[0].1), (100, 1));
    assert_eq!((s[1].0, s[1].1), (100, 1));
    // Min of 4: 1000, 1004, 1008, ...
    assert_eq!((s[2].0, s[2].1), (25, 4));
    assert_eq!(&s[2].2[..3], &[1000, 1004, 1008]);
}

#[test]
fn bad_control_frames_are_rejected_with_a_reason() {
    let mut b: Bridge<Q> = Bridge::new(config()).unwrap();
    let ids = config().ids;
    let raw = |data: &[u8]| Frame::new(ids.id(Kind::Control), data, false).unwrap();
    b.on_can_frame(&raw(&[0xEE, 1]), 0);
    b.on_can_frame(&raw(&[]), 0);
    b.on_can_frame(
        &control_frame(
            2,
            Ctl::TemporalDecimation {
                every_nth: 3,
                max_rate_centihz: 500,
            },
        ),
        0,
    );
    // A reversed region of interest (the encoder refuses to emit one: swap by hand).
    let mut roi = control_frame(
        3,
        Ctl::RegionOfInterest {
            start_step: 5,
            end_step: 10,
        },
    )
    .data()
    .to_vec();
    roi[2..6].copy_from_slice(&[10, 0, 5, 0]);
    b.on_can_frame(&raw(&roi), 0);
    // Another bridge's control frame is not ours.
    let other = IdWindow::DEFAULT.node(4).unwrap().id(Kind::Control);
    assert!(!b.on_can_frame(&Frame::new(other, &[1, 0], false).unwrap(), 0));
    let a = answers(&drain(&mut b));
    let outcomes: Vec<Outcome> = a.iter().map(|a| a.outcome).collect();
    // Answers go to the front of the queue: newest first.
    assert_eq!(
        outcomes,
        [
            Outcome::OutOfRange,
            Outcome::Unsupported,
            Outcome::BadLength,
            Outcome::UnknownOpcode
        ]
    );
}

#[test]
fn status_frames_are_periodic_and_go_before_scan_frames() {
    let mut b: Bridge<Q> = Bridge::new(config()).unwrap();
    b.poll(0);
    b.on_uart(&scan_frame(500, 10), 10);
    b.poll(500);
    assert_eq!(
        drain(&mut b)
            .iter()
            .filter(|f| f.id() == config().ids.id(Kind::Status))
            .count(),
        3,
        "one set at start, none before the period"
    );
    b.on_uart(&scan_frame(500, 35), 900);
    b.poll(1000);
    let frames = drain(&mut b);
    let status_id = config().ids.id(Kind::Status);
    // The status pages lead the queue even though the scan was queued first.
    assert!(frames[..3].iter().all(|f| f.id() == status_id));
    match Status::parse(frames[0].data()).unwrap() {
        Status::Heartbeat {
            state, uptime_s, ..
        } => {
            assert_eq!(state, BridgeState::Idle);
            assert_eq!(uptime_s, 1);
        }
        other => panic!("{other:?}"),
    }
    b.on_can_frame(&control_frame(1, Ctl::RequestSensorInfo), 1001);
    let frames = drain(&mut b);
    assert_eq!(frames.iter().filter(|f| f.id() == status_id).count(), 4);
}

/// The encoding control (opcode 0x20, bytes written from SPEC 6: distance 4 = DL,
/// intensity 0, unit 0) switches the next scan to the lossless coding: its header B says
/// so, its data frames have one framing byte, and its values arrive exactly.
#[test]
fn the_lossless_coding_by_control_frame() {
    let mut b: Bridge<Q> = Bridge::new(config()).unwrap();
    b.on_uart(&scan_frame(300, 10), 0);
    let ids = config().ids;
    let raw = Frame::new(ids.id(Kind::Control), &[0x20, 9, 4, 0, 0], false).unwrap();
    assert!(b.on_can_frame(&raw, 1));
    b.on_uart(&scan_frame(300, 35), 2);
    let frames = drain(&mut b);
    let a = answers(&frames);
    assert_eq!((a[0].token, a[0].outcome), (9, Outcome::Accepted));
    let header_b: Vec<&Frame> = frames
        .iter()
        .filter(|f| f.id() == ids.id(Kind::HeaderB))
        .collect();
    assert_eq!(header_b.len(), 2);
    assert_eq!(header_b[0].data()[1] & 0xF, 1, "D16 first");
    assert_eq!(header_b[1].data()[1] & 0xF, 4, "then DL");
    let s = scans(&frames);
    assert_eq!(s.len(), 2);
    let want: Vec<u32> = (0..300).map(|i| 1000 + i).collect();
    assert_eq!(s[0].2, want);
    assert_eq!(s[1].2, want);
    // 300 points of a ramp: D16 takes 300 × 2 bytes of points; DL a small part of it.
    let data_bytes = |scan: usize| -> usize {
        let mut seen = 0;
        let mut bytes = 0;
        for f in &frames {
            if f.id() == ids.id(Kind::HeaderA) {
                seen += 1;
            } else if f.id() == ids.id(Kind::Data) && seen == scan + 1 {
                bytes += f.len();
            }
        }
        bytes
    };
    assert!(
        data_bytes(1) * 4 < data_bytes(0),
        "{} vs {}",
        data_bytes(1),
        data_bytes(0)
    );
}
