//! The sensor clock model (bridge `clock`, SPEC 3.1 `time_estimated`) against a
//! simulated sensor whose oscillator drifts, whose output jitters and whose true scan
//! times are known: the header time of each scan's first point is compared with when
//! the simulator measured it.

use std::collections::VecDeque;

use bridge::engine::{Bridge, BridgeConfig};
use bridge::session::Action;
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Encoding, FrameFormat, IdWindow, ScanHeader};
use scip2can_host::sim::SimOptions;

const Q: usize = 512;
/// UART of the test rig: 5 Mbit/s, 2 µs a byte (a UTM-30LX scan takes 7 ms of 25).
const BYTE_US: u64 = 2;
/// Simulation step, µs.
const STEP_US: u64 = 50;

/// A header and the bridge time (µs) it was decoded at.
struct Run {
    seen: Vec<(ScanHeader, u64)>,
    /// True times of the first points of the scans the sensor sent, µs.
    truth: Vec<u64>,
    resets: u32,
}

/// A time master (SPEC 9) on the bridge's bus whose clock runs `offset_us` ahead of the
/// bridge's: a SYNC and its FOLLOW-UP every `period_us`, taken by the bridge as sent
/// (an in-process bus: no transmission delay).
#[derive(Clone, Copy)]
struct Master {
    offset_us: u64,
    period_us: u64,
}

/// Runs a bridge estimating scan times against `spec` for `secs` seconds, bytes
/// crossing a 5 Mbit/s UART one by one.
fn run(spec: &str, secs: u64) -> Run {
    run_with(spec, secs, None)
}

/// [`run`] with a time master.
fn run_with(spec: &str, secs: u64, master: Option<Master>) -> Run {
    let sim = SimOptions::from_spec(spec).unwrap();
    let config = BridgeConfig {
        encoding: Encoding::PLAIN_MM,
        uart_bit_rate: 5_000_000,
        status_period_ms: 0,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).unwrap(), FrameFormat::FD64)
    };
    let mut sensor = sim.build().unwrap();
    sensor.record_truth(true);
    let mut bridge: Box<Bridge<Q>> = Box::new(Bridge::new(config).unwrap());
    bridge.set_time_estimation(true);
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    bridge.start(0);
    let mut seen = Vec::new();
    let mut truth = Vec::new();
    let mut wire: VecDeque<u8> = VecDeque::new();
    let mut wire_t = 0u64;
    let mut chunk = Vec::new();
    let time_id = can_wire::timesync::time_id(0x0FF, &IdWindow::DEFAULT).unwrap();
    for step in 0..secs * 1_000_000 / STEP_US {
        let now = step * STEP_US;
        if let Some(m) = master.filter(|m| now % m.period_us == 0) {
            let seq = ((now / m.period_us) % 16) as u8;
            let sync = can_wire::timesync::TimeFrame::Sync { seq };
            let follow_up = can_wire::timesync::TimeFrame::FollowUp {
                seq,
                master_us: now + m.offset_us,
            };
            bridge.on_can_frame_at(&sync.to_frame(time_id).unwrap(), now);
            bridge.on_can_frame_at(&follow_up.to_frame(time_id).unwrap(), now + 300);
        }
        // Bytes made since the last step start on an idle wire now (at most a step
        // late, like a UART interrupt's latency).
        if wire.is_empty() {
            wire_t = now;
        }
        wire.extend(sensor.take_output(now));
        truth.extend(sensor.take_truth().iter().map(|t| t.first_step_us));
        chunk.clear();
        while !wire.is_empty() && wire_t + BYTE_US <= now {
            chunk.push(wire.pop_front().unwrap());
            wire_t += BYTE_US;
        }
        if !chunk.is_empty() {
            bridge.on_uart_at(&chunk, wire_t);
        }
        while let Some(action) = bridge.poll_at(now) {
            if let Action::Send(request) = action {
                let mut buf = [0u8; scip::REQUEST_MAX];
                let n = scip::Request::encode(&request, &mut buf).unwrap();
                sensor.receive(now + n as u64 * BYTE_US, &buf[..n]);
            }
        }
        while let Some(f) = bridge.pop_frame() {
            if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(&f) {
                seen.push((*scan.header(), now));
            }
        }
    }
    Run {
        seen,
        truth,
        resets: bridge.scan_clock().resets(),
    }
}

/// Errors (µs) of the estimated scans decoded after `from_us`: against the truth
/// nearest to each (scans are 25 ms or more apart, errors far smaller), sorted.
fn errors(r: &Run, from_us: u64) -> Vec<u64> {
    let mut e: Vec<u64> = r
        .seen
        .iter()
        .filter(|(h, at)| h.time_estimated && *at >= from_us)
        .map(|(h, _)| {
            let t = u64::from(h.timestamp_ms);
            r.truth.iter().map(|&x| x.abs_diff(t)).min().unwrap()
        })
        .collect();
    e.sort();
    e
}

fn p99(e: &[u64]) -> u64 {
    e[e.len() * 99 / 100]
}

#[test]
fn scan_times_within_a_third_of_a_millisecond_of_the_truth() {
    // Limitation: a sensor whose ticks fall exactly on the scan starts (phase 0, with
    // the simulator's integer period) is not calibrated within a minute; not tested.
    for (drift, phase) in [(100, 500), (-100, 300)] {
        // The sensor's clock wraps (2^24 ms) 5 s into the run.
        let spec = format!(
            "model=utm30lx,scene=wall:2000,noise=0,clock=16772216,drift_ppm={drift},\
             clock_phase_us={phase},jitter_us=2000"
        );
        let r = run(&spec, 24);
        let e = errors(&r, 10_000_000);
        let first = r
            .seen
            .iter()
            .find(|(h, _)| h.time_estimated)
            .map(|(_, at)| *at);
        eprintln!(
            "{drift} ppm: first estimate at {first:?} µs, p99 {} µs, worst {} µs after 10 s",
            p99(&e),
            e[e.len() - 1]
        );
        // Valid once the scans crossed a tick of the sensor's clock and the TM that
        // followed answered (at 100 ppm within 10 s of the stream's start, whatever
        // the phase); from 10 s on, 14 s at 40 scans a second, all estimated but the
        // few the TM's stop costs.
        assert!(
            first.is_some_and(|t| t <= 10_000_000),
            "{drift} ppm: first {first:?}"
        );
        assert!(e.len() >= 540, "{drift} ppm: {} estimated scans", e.len());
        assert!(p99(&e) <= 300, "{drift} ppm: p99 {} µs", p99(&e));
        // Published times never go back.
        let times: Vec<u32> = r
            .seen
            .iter()
            .filter(|(h, _)| h.time_estimated)
            .map(|(h, _)| h.timestamp_ms)
            .collect();
        assert!(times.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(r.resets, 0);
    }
}

#[test]
fn scan_times_in_the_time_masters_clock() {
    // The master's clock (Unix µs, as `scip2can timesync` sends) is 1 795 985 999 s ahead
    // of the bridge's; SYNC every second. Once calibrated, each header carries the
    // first point's time in the master's clock modulo 2^32 (`time_master`), within the
    // estimate's bound of the truth mapped by the same offset.
    let offset_us: u64 = 1_795_985_999_000_000;
    let m = Master {
        offset_us,
        period_us: 1_000_000,
    };
    let spec = "model=utm30lx,scene=wall:2000,noise=0,drift_ppm=100,clock_phase_us=500,\
                jitter_us=2000";
    let r = run_with(spec, 24, Some(m));
    let mut e: Vec<u64> = r
        .seen
        .iter()
        .filter(|(h, at)| h.time_estimated && *at >= 10_000_000)
        .map(|(h, _)| {
            assert!(h.time_master, "an estimated scan in the bridge's clock");
            r.truth
                .iter()
                .map(|&x| u64::from(((x + offset_us) as u32).abs_diff(h.timestamp_ms)))
                .min()
                .unwrap()
        })
        .collect();
    e.sort();
    assert!(e.len() >= 540, "{} estimated scans", e.len());
    assert!(p99(&e) <= 300, "p99 {} µs", p99(&e));
}
