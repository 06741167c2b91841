//! `scip2can bridge`, live: the in-process simulator to a candump log, and to an SLCAN
//! adapter on a real TCP socket (the adapter side is the `slcan` crate's `Adapter`, as a
//! board runs it), with a control frame sent back over the bus.

use std::io::{Read, Write};
use std::net::TcpListener;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use can_wire::control::{Command as Ctl, DecimationMode};
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Control, Frame, IdWindow, Kind, ScanHeader};
use clap::Parser;
use scip2can_host::live::{self, BridgeArgs};

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: BridgeArgs,
}

fn args(extra: &[&str]) -> BridgeArgs {
    let mut argv = vec!["bridge", "--quiet"];
    argv.extend_from_slice(extra);
    Cli::parse_from(argv).args
}

/// The scans of a frame sequence: each header and whether the scan is intact.
fn decoded(frames: &[Frame]) -> Vec<(ScanHeader, bool)> {
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Vec::new();
    for f in frames {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
            out.push((*scan.header(), scan.is_intact()));
        }
    }
    out
}

/// Scans of a frame sequence: (step increment, points, intact).
fn scans(frames: &[Frame]) -> Vec<(u8, u16, bool)> {
    decoded(frames)
        .into_iter()
        .map(|(h, ok)| (h.step_increment, h.point_count, ok))
        .collect()
}

/// `scip2can bridge` with `extra` arguments into a candump log of its own (`name`),
/// and the frames the log holds.
fn bridge_to_log(name: &str, extra: &[&str]) -> Vec<Frame> {
    let dir = std::env::temp_dir().join(format!("scip2can-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("bridge.log");
    let can = format!("candump:{}", log.display());
    let mut argv = vec!["--can", can.as_str()];
    argv.extend_from_slice(extra);
    live::run(args(&argv)).expect("bridge runs");
    std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .filter_map(|l| scip2can_host::candump::parse_line(l).ok()?.to_frame())
        .collect()
}

#[test]
fn the_simulator_streams_into_a_candump_log() {
    let frames = bridge_to_log("live", &["sim:model=urg04lx,speed=4", "--seconds", "2"]);
    let s = scans(&frames);
    // URG-04LX at 10 Hz × speed 4 for 2 s: ~80 scans; the simulator starts in SCIP 1.1.
    assert!(s.len() >= 20, "only {} scans", s.len());
    assert!(s.iter().all(|&(_, n, ok)| ok && n == 682), "{s:?}");
}

/// An SLCAN adapter on a TCP socket: answers commands, keeps transmitted frames, and
/// once `trigger` frames went by, puts a control frame on the bus.
fn adapter(listener: TcpListener, trigger: usize, control: Frame, done: mpsc::Sender<Vec<Frame>>) {
    let (mut sock, _) = listener.accept().unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let mut adapter = slcan::Adapter::new(*b"0100", *b"TEST", true);
    let mut lines = slcan::LineBuffer::new();
    let mut sent = Vec::new();
    let mut injected = false;
    let mut buf = [0u8; 4096];
    let deadline = Instant::now() + Duration::from_secs(20);
    // The bridge closes the socket when its run ends: a failed write ends the adapter.
    'run: while Instant::now() < deadline {
        let n = match sock.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(_) => 0,
        };
        let mut input = &buf[..n];
        while !input.is_empty() {
            let (used, line) = lines.feed(input);
            input = &input[used..];
            if let Some(line) = line {
                let outcome = adapter.line(line);
                if let slcan::Outcome::Transmit(f, _) = outcome {
                    let fd = f.kind() != slcan::FrameKind::Data;
                    sent.push(Frame::new(f.id(), f.data(), fd).unwrap());
                }
                let mut out = [0u8; slcan::LINE_MAX];
                let m = outcome.reply().emit(&mut out).unwrap();
                if sock.write_all(&out[..m]).is_err() {
                    break 'run;
                }
            }
        }
        if !injected && sent.len() >= trigger {
            injected = true;
            let f =
                slcan::Frame::new(control.id(), slcan::FrameKind::Data, control.data()).unwrap();
            let mut out = [0u8; slcan::LINE_MAX];
            let m = adapter.received(&f, 0, &mut out).expect("channel open");
            if sock.write_all(&out[..m]).is_err() {
                break 'run;
            }
        }
    }
    done.send(sent).unwrap();
}

#[test]
fn an_slcan_adapter_carries_the_scans_and_a_control_frame_changes_decimation() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let ids = IdWindow::DEFAULT.node(0).unwrap();
    let mut data = [0u8; 8];
    let n = Control {
        token: 9,
        command: Ctl::AngularDecimation {
            k: 4,
            mode: DecimationMode::Mean,
        },
    }
    .emit(&mut data)
    .unwrap();
    let control = Frame::new(ids.id(Kind::Control), &data[..n], false).unwrap();
    let (tx, rx) = mpsc::channel();
    let server = std::thread::spawn(move || adapter(listener, 1500, control, tx));
    let can = format!("slcan:tcp://{addr}");
    live::run(args(&[
        "sim:model=urg04lx,speed=4",
        "--can",
        &can,
        "--encoding",
        "d12",
        "--seconds",
        "4",
    ]))
    .expect("bridge runs");
    let frames = rx.recv_timeout(Duration::from_secs(30)).unwrap();
    server.join().unwrap();
    // The control frame was answered (accepted) on the bus.
    let answers: Vec<can_wire::Answer> = frames
        .iter()
        .filter(|f| f.id() == ids.id(Kind::ControlAnswer))
        .map(|f| can_wire::Answer::parse(f.data()).unwrap())
        .collect();
    assert_eq!(answers.len(), 1);
    assert_eq!(
        (answers[0].token, answers[0].outcome),
        (9, can_wire::Outcome::Accepted)
    );
    let s = scans(&frames);
    assert!(s.iter().all(|&(_, _, ok)| ok), "{s:?}");
    // Full resolution first, decimated by 4 after the control frame.
    assert_eq!(s.first().map(|x| (x.0, x.1)), Some((1, 682)));
    assert_eq!(s.last().map(|x| (x.0, x.1)), Some((4, 171)));
}

/// The README's main job (the default simulated UTM-30LX, classic CAN, the lossless
/// coding, the governor planning): every scan the sensor sends is published, from the
/// first on. The simulator's scans leave it whole, as an Ethernet sensor's do; they were
/// dated back as if each byte had crossed a 115 200 bit/s UART, so for the first quarter
/// second every scan seemed to arrive at time 0, the governor's budget never refilled
/// and nine scans were dropped. On virtual time (as on an ideal host: in real time, a
/// host loaded by other tests hands the bridge two scans at once now and then, and the
/// governor's budget of two scans' worth can refuse a third).
#[test]
fn the_default_simulator_loses_no_scan_from_the_first() {
    let frames = bridge_to_log(
        "live-first",
        &[
            "--seconds",
            "1.5",
            "--time-estimate",
            "false",
            "--virtual-time",
        ],
    );
    let mut stamps = Vec::new();
    for (header, intact) in decoded(&frames) {
        assert!(intact, "a damaged scan");
        stamps.push(header.timestamp_ms);
    }
    // A UTM-30LX turns at 2 400 rpm: a scan every 25 ms of its clock (1 ms resolution).
    assert!(stamps.len() >= 40, "only {} scans in 1.5 s", stamps.len());
    let gaps: Vec<u32> = stamps.windows(2).map(|w| w[1].wrapping_sub(w[0])).collect();
    // Scans the sensor sent between consecutive published ones (the start-up fault
    // lost nine).
    let missing: u32 = gaps.iter().map(|g| ((g + 12) / 25).saturating_sub(1)).sum();
    assert!(
        missing == 0,
        "{missing} scans missing between published ones: gaps {gaps:?} ms"
    );
}

/// `scip2can bridge` estimates scan times as the firmware does: the simulated sensor
/// drifts (+100 ppm) against the bridge's clock, 500 µs into its millisecond, so its
/// 25 ms scans cross a tick of its clock after 500 µs / 2.5 µs a scan = 200 scans (5 s);
/// the fresh TM readings that follow pin the latency, and the headers carry times from
/// then on. The run is on virtual time (`--virtual-time`): what the bridge sees does not
/// depend on how busy the host is (in real time, a host loaded by other tests delayed the
/// calibration's TM readings so much that no scan was estimated). The simulator used to
/// answer a TM1 in the instant it arrived, so that a calibration's 24 readings fell at one
/// phase of the sensor's millisecond and pinned nothing: no scan was ever estimated.
#[test]
fn the_live_bridge_estimates_scan_times() {
    let frames = bridge_to_log(
        "live-time",
        &[
            "sim:drift_ppm=100,clock_phase_us=500",
            "--seconds",
            "12",
            "--virtual-time",
        ],
    );
    let scans = decoded(&frames);
    // 40 scans a second of simulated time, every one published.
    assert!(scans.len() >= 470, "only {} scans in 12 s", scans.len());
    let first = scans.iter().position(|(h, _)| h.time_estimated);
    let first = first.expect("no scan estimated in 12 s");
    // From the crossing at 5 s on, and every scan after the first estimated one.
    let t0 = scans[first].0.timestamp_ms;
    assert!(
        (5_000_000..7_000_000).contains(&t0),
        "first estimate at {t0} µs"
    );
    assert!(
        scans[first..].iter().all(|(h, _)| h.time_estimated),
        "a scan after the first estimate was not estimated"
    );
    // The simulated UTM-30LX's scans start every 25 ms from time 0 (the bridge's clock
    // and the simulator's are one on virtual time), at the first step requested (step
    // 0): each estimate is within the model's ±300 µs (its 600 µs validity span).
    for (h, _) in &scans[first..] {
        let off = (h.timestamp_ms + 12_500) % 25_000;
        assert!(
            (12_200..=12_800).contains(&off),
            "scan {} estimated at {} µs: {} µs from its start",
            h.seq,
            h.timestamp_ms,
            i64::from(off) - 12_500
        );
    }
}

/// Virtual time is the simulator's: a real sensor is refused, with the reason.
#[test]
fn virtual_time_needs_the_simulator() {
    let err = live::run(args(&[
        "tcp://127.0.0.1:9",
        "--virtual-time",
        "--seconds",
        "1",
    ]))
    .expect_err("a TCP sensor on virtual time");
    let text = format!("{err:#}");
    assert!(
        text.contains("virtual time needs the simulated sensor"),
        "{text}"
    );
}
