//! Header timestamps against a simulated sensor whose clock and the bridge's are known:
//! extended past the sensor's 24-bit wrap (SPEC 3.1), and after a `TM` time sync in the
//! bridge's clock with `time_synced` set (SPEC 3.2).

use bridge::engine::{Bridge, BridgeConfig};
use bridge::session::Action;
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Encoding, FrameFormat, IdWindow, ScanHeader};
use scip2can_host::sim::SimOptions;

const Q: usize = 512;
/// The sensor's clock at power-on: it wraps (2^24 = 16_777_216 ms) 216 ms later.
const CLOCK_START: u32 = 16_777_000;

/// A header and the bridge time (ms) its frames were taken at.
type Seen = (ScanHeader, u64);

/// Runs a started bridge against a simulated UTM-30LX in 1 ms steps for `ms`
/// milliseconds; at `sync_at` ms asks for a time sync.
fn run(ms: u64, sync_at: Option<u64>) -> Vec<Seen> {
    let sim = SimOptions {
        clock: CLOCK_START,
        ..SimOptions::from_spec("model=utm30lx,scene=wall:2000,noise=0").unwrap()
    };
    run_sim(&sim, ms, sync_at)
}

fn run_sim(sim: &SimOptions, ms: u64, sync_at: Option<u64>) -> Vec<Seen> {
    let config = BridgeConfig {
        encoding: Encoding::PLAIN_MM,
        uart_bit_rate: 1_000_000,
        status_period_ms: 0,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).unwrap(), FrameFormat::FD64)
    };
    let mut sensor = sim.build().unwrap();
    let mut bridge: Box<Bridge<Q>> = Box::new(Bridge::new(config).unwrap());
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    bridge.start(0);
    let mut seen = Vec::new();
    let mut actions: Vec<Action> = Vec::new();
    for now in 0..ms {
        if Some(now) == sync_at {
            bridge.request_time_sync(now);
        }
        for action in actions.drain(..) {
            if let Action::Send(request) = action {
                let mut buf = [0u8; scip::REQUEST_MAX];
                let n = scip::Request::encode(&request, &mut buf).unwrap();
                sensor.receive(now * 1000, &buf[..n]);
            }
        }
        // At 1 Mbit/s a scan's bytes arrive within the millisecond.
        let bytes = sensor.take_output(now * 1000);
        bridge.on_uart(&bytes, now);
        actions.extend(std::iter::from_fn(|| bridge.poll(now)).take(16));
        while let Some(f) = bridge.pop_frame() {
            if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(&f) {
                seen.push((*scan.header(), now));
            }
        }
    }
    seen
}

#[test]
fn timestamps_run_on_past_the_sensors_wrap() {
    let seen = run(1500, None);
    assert!(seen.len() >= 20, "{} scans", seen.len());
    // The sensor's clock at bridge time t is CLOCK_START + t (mod 2^24); a scan's
    // timestamp is its start, less than one scan period (25 ms) plus the UART time
    // before its header goes out.
    for (h, now) in &seen {
        assert!(!h.time_synced);
        let sensor_now = u64::from(CLOCK_START) + now;
        let ts = u64::from(h.timestamp_ms);
        assert!(
            ts <= sensor_now && sensor_now - ts <= 30,
            "timestamp {ts} at sensor time {sensor_now}"
        );
    }
    assert!(seen.iter().any(|(h, _)| h.timestamp_ms > 1 << 24));
}

#[test]
fn a_time_sync_puts_timestamps_in_the_bridge_clock() {
    let seen = run(2000, Some(500));
    let synced: Vec<_> = seen.iter().filter(|(h, _)| h.time_synced).collect();
    assert!(synced.len() >= 10, "{} synced scans", synced.len());
    // Before the sync: sensor time; after: every scan synced.
    let first = seen.iter().position(|(h, _)| h.time_synced).unwrap();
    assert!(seen[..first].iter().all(|(_, now)| *now <= 600));
    assert!(seen[first..].iter().all(|(h, _)| h.time_synced));
    // Synced timestamps are the bridge time of the scan's start: shortly before the
    // header went out (the sync's own error is a millisecond or two of UART time).
    for (h, now) in synced {
        let ts = u64::from(h.timestamp_ms);
        assert!(
            ts <= now + 3 && now - ts.min(*now) <= 30,
            "timestamp {ts} at bridge time {now}"
        );
    }
}

#[test]
fn a_sensor_reboot_voids_the_sync_and_restarts_the_extension() {
    // A URG-04LX (it boots in SCIP 1.1, so the bridge sees its reboot) rebooting in its
    // 20th stream frame, its clock just before the wrap and restarting at 0.
    let sim = SimOptions {
        clock: CLOCK_START,
        ..SimOptions::from_spec("model=urg04lx,scene=wall:2000,noise=0,reboot_at=20").unwrap()
    };
    let seen = run_sim(&sim, 8000, Some(500));
    let synced = seen.iter().filter(|(h, _)| h.time_synced).count();
    assert!(synced >= 5, "{synced} synced scans");
    let last_synced = seen.iter().rposition(|(h, _)| h.time_synced).unwrap();
    let after = &seen[last_synced + 1..];
    assert!(after.len() >= 5, "{} scans after the reboot", after.len());
    // After the reboot: sensor time again, from the sensor's new clock (0 at the
    // reboot, some seconds before the end), not extended past 2^24.
    for (h, now) in after {
        assert!(!h.time_synced);
        assert!(
            u64::from(h.timestamp_ms) < *now,
            "{} at {now}",
            h.timestamp_ms
        );
    }
}
