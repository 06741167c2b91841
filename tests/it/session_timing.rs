//! The bridge against the simulated sensor in virtual time (1 ms steps): a sensor that
//! reboots in the middle of a frame is streaming again soon after it first answers, and
//! a stream that stalls for 300 ms and resumes is taken as it is, without a recovery.
//! The times are the simulator's own (its fault log) and the bridge's CAN output.

use bridge::engine::{Bridge, BridgeConfig};
use bridge::session::{Action, Notice};
use can_wire::{FrameFormat, IdWindow, Kind};
use scip2can_host::sim::faults::FaultKind;
use scip2can_host::sim::options::SimOptions;

const Q: usize = 512;

fn config(uart_bit_rate: u32) -> BridgeConfig {
    BridgeConfig {
        encoding: can_wire::Encoding::PLAIN_MM,
        uart_bit_rate,
        status_period_ms: 0,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).unwrap(), FrameFormat::FD64)
    }
}

/// What a run gave, times in ms.
#[derive(Debug, Default)]
struct Run {
    /// When each scan's header A was queued.
    scans: Vec<u64>,
    /// When the sensor's output was non-empty.
    output: Vec<u64>,
    /// The bridge's notices.
    notices: Vec<(u64, Notice)>,
    /// The simulator's fault log: (time ms, fault).
    faults: Vec<(u64, FaultKind)>,
    /// Stream frames the sensor sent (echo and `99` status lines in its output).
    frames_sent: usize,
    /// The bridge's counters at the end.
    stats: bridge::engine::BridgeStats,
}

/// Runs the bridge against `sim` for `ms` of virtual time. The sensor's bytes arrive
/// in the millisecond they leave it (a USB or Ethernet link).
fn run(sim: &str, ms: u64) -> Run {
    let opts = SimOptions::from_spec(sim).expect("sim spec");
    let mut sensor = opts.build().expect("sensor");
    let cfg = config(12_000_000);
    let header_a = cfg.ids.id(Kind::HeaderA);
    let mut bridge: Bridge<Q> = Bridge::new(cfg).expect("config");
    let mut out = Run::default();
    bridge.start(0);
    for t in 0..ms {
        let now_us = t * 1000;
        let bytes = sensor.take_output(now_us);
        if !bytes.is_empty() {
            out.output.push(t);
            out.frames_sent += bytes
                .windows(20)
                .filter(|w| w == b"MD0000108001000\n99b\n")
                .count();
            bridge.on_uart(&bytes, t);
        }
        while let Some(action) = bridge.poll(t) {
            if let Action::Send(request) = action {
                let mut buf = [0u8; scip::REQUEST_MAX];
                let n = request.encode(&mut buf).expect("encodable");
                sensor.receive(now_us, &buf[..n]);
            }
        }
        if let Some(n) = bridge.take_notice() {
            out.notices.push((t, n));
        }
        while let Some(f) = bridge.pop_frame() {
            if f.id() == header_a {
                out.scans.push(t);
            }
        }
    }
    out.stats = *bridge.stats();
    out.faults = sensor
        .fault_log()
        .iter()
        .map(|r| (r.at_us / 1000, r.kind))
        .collect();
    out
}

#[test]
fn a_rebooted_sensor_streams_again_within_a_second_of_its_first_answer() {
    for model in ["utm30lx", "ust10lx", "urg04lx"] {
        let r = run(&format!("model={model},reboot_at=20,scene=wall:2000"), 6000);
        let reboot = r
            .faults
            .iter()
            .find(|(_, k)| matches!(k, FaultKind::Reboot { .. }))
            .map(|(t, _)| *t)
            .expect("the simulator rebooted");
        // The sensor's first answer after the reboot (it boots for 500 ms).
        let answer = *r
            .output
            .iter()
            .find(|&&t| t > reboot)
            .expect("the sensor answers again");
        let back = *r
            .scans
            .iter()
            .find(|&&t| t > reboot)
            .expect("scans again after the reboot");
        let last_before = r.scans.iter().rev().find(|&&t| t <= reboot).copied();
        eprintln!(
            "{model}: reboot at {reboot} ms, first answer {} ms later, scans again {} ms \
             after it ({} ms without scans); notices {:?}",
            answer - reboot,
            back - answer,
            back - last_before.unwrap_or(0),
            r.notices
        );
        assert!(
            back - answer <= 1000,
            "{model}: streaming {} ms after the first answer",
            back - answer
        );
    }
}

#[test]
fn stalls_of_300_ms_keep_the_stream_and_begin_every_late_scan() {
    let r = run(
        "model=utm30lx,scene=wall:2000,stall=0.03,stall_ms=300,fault_seed=7",
        8000,
    );
    let stalls = r
        .faults
        .iter()
        .filter(|(_, k)| matches!(k, FaultKind::Stall { ms: 300 }))
        .count();
    assert!(stalls >= 3, "the simulator stalled {stalls} times");
    // The longest silence of the sensor's output while streaming.
    let longest = r
        .output
        .windows(2)
        .skip(5)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap();
    eprintln!(
        "{stalls} stalls, longest silence {longest} ms, {} frames sent, {} scans out, \
         {:?}, notices {:?}",
        r.frames_sent,
        r.scans.len(),
        r.stats,
        r.notices
    );
    assert!(longest >= 300, "a stall of 300 ms happened ({longest} ms)");
    // Every frame the sensor sent began a scan, and each is accounted for.
    let st = r.stats;
    assert!(r.frames_sent > 250, "{} frames", r.frames_sent);
    assert_eq!(st.scans_in as usize, r.frames_sent, "{st:?}");
    assert_eq!(
        (st.scans_sent + st.scans_dropped + st.scans_skipped + st.scans_aborted) as usize,
        r.frames_sent,
        "{st:?}"
    );
    assert!(
        r.notices
            .iter()
            .all(|(_, n)| !matches!(n, Notice::Recovering(_))),
        "{:?}",
        r.notices
    );
}
