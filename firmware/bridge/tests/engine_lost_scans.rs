//! Stream frames the bridge never starts (their echo, status or timestamp line damaged)
//! are not lost silently: the scan sequence skips a number for each, so a receiver counts
//! them as lost scans, and status page 1's `dropped_scans` counts them.

use bridge::engine::{Bridge, BridgeConfig};
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Frame, FrameFormat, IdWindow, Kind, Status};
use scip::{Command, Request, ResponseWriter, ScanMode, ScanRequest};

const Q: usize = 256;

fn config() -> BridgeConfig {
    BridgeConfig {
        encoding: can_wire::Encoding::PLAIN_MM,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(3).unwrap(), FrameFormat::FD64)
    }
}

/// One stream frame of 100 steps with timestamp `ts`, and where its lines start:
/// (echo, status, timestamp) byte offsets.
fn stream_frame(ts: u32) -> (Vec<u8>, [usize; 3]) {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    let mut s = ScanRequest::distance(ScanMode::Continuous, 0, 99);
    s.count = 0;
    w.echo(&Request::new(Command::Scan(s)));
    w.status(*b"99");
    w.timestamp(ts);
    for i in 0..100 {
        w.step(1000 + i, 0);
    }
    w.end();
    let _ = w.into_inner();
    // "MD0000009901000\n" is 16 bytes, "99b\n" 4.
    (out, [0, 16, 20])
}

/// The frames of a stream, frame `k` damaged in line `line` (0 echo, 1 status,
/// 2 timestamp) where `damage` says so; the timestamps of the frames are 25 ms apart.
fn stream(damage: &[(usize, usize)]) -> Vec<Vec<u8>> {
    let mut frames = Vec::new();
    for k in 0..6 {
        let (mut f, lines) = stream_frame(1000 + 25 * k as u32);
        if let Some(&(_, line)) = damage.iter().find(|(i, _)| *i == k) {
            // Echo: 'M' becomes 'm' (no such command); status and timestamp: the first
            // char changes, so the line fails its sum.
            f[lines[line]] ^= 0x20;
        }
        frames.push(f);
    }
    frames
}

#[test]
fn frames_never_started_leave_a_sequence_gap_and_a_count() {
    // Frames 1, 2 and 3 damaged in the echo, the status and the timestamp line.
    let mut bridge: Bridge<Q> = Bridge::new(config()).unwrap();
    bridge.poll(0);
    let mut frames: Vec<Frame> = Vec::new();
    for (k, bytes) in stream(&[(1, 0), (2, 1), (3, 2)]).iter().enumerate() {
        bridge.on_uart(bytes, 10 + 25 * k as u64);
        frames.extend(std::iter::from_fn(|| bridge.pop_frame()));
    }
    bridge.poll(1000);
    frames.extend(std::iter::from_fn(|| bridge.pop_frame()));

    // The receiver: scans 0, 4 and 5 of the sensor arrive, with the sequence numbers
    // 0, 4 and 5, and it counts three lost.
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut got = Vec::new();
    for f in &frames {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
            assert!(scan.is_intact());
            got.push((scan.header().seq, scan.header().timestamp_ms));
        }
    }
    if let Some(scan) = dec.flush(3) {
        assert!(scan.is_intact());
        got.push((scan.header().seq, scan.header().timestamp_ms));
    }
    assert_eq!(got, [(0, 1000), (4, 1100), (5, 1125)]);
    assert_eq!(dec.stats(3).unwrap().scans_lost, 3);
    assert_eq!(bridge.stats().scans_lost, 3);

    // Status page 1 of the period.
    let status_id = config().ids.id(Kind::Status);
    let dropped: Vec<u16> = frames
        .iter()
        .filter(|f| f.id() == status_id)
        .filter_map(|f| match Status::parse(f.data()) {
            Ok(Status::SensorCounters { dropped_scans, .. }) => Some(dropped_scans),
            _ => None,
        })
        .collect();
    assert_eq!(dropped.last(), Some(&3));
}

#[test]
fn a_damaged_answer_to_another_command_is_not_a_lost_scan() {
    // A stream frame, then a damaged VV answer (its echo): not a scan.
    let (mut bytes, _) = stream_frame(1000);
    let vv = b"Vv\n00P\nVEND:Hokuyo Automatic Co.,Ltd.;[\n\n";
    bytes.extend_from_slice(b"II\n00P\nLASR:ON;9\n\n");
    bytes.extend_from_slice(vv);
    let mut bridge: Bridge<Q> = Bridge::new(config()).unwrap();
    bridge.on_uart(&bytes, 10);
    assert_eq!(bridge.stats().scans_lost, 0);
}
