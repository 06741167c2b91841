//! The sensor clock model (SPEC 3.1 `time_estimated`) run by the firmware on its own
//! clock, in exact virtual time: `scip2can-qemu-cosim` in QEMU (`-icount
//! shift=N,sleep=off`) in lockstep with the simulator (`scip2can_host::cosim`), whose
//! time is the board clock's. Each published scan header's time (µs modulo 2^32 of the
//! board clock) is compared with when the simulator measured the scan's first point.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Frame, IdWindow, ScanHeader};
use scip2can_host::cosim::{self, Run, Setup};
use scip2can_host::sim::SimOptions;

use crate::qemu::QEMU;

/// `-icount shift=3`: 8 ns an instruction, a 125 MIPS core.
const SHIFT: u8 = 3;

fn firmware() -> Option<PathBuf> {
    static ELF: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    crate::qemu::firmware(&ELF, cosim::build_firmware)
}

fn run(elf: &Path, spec: &str, secs: u64) -> Run {
    let setup = Setup {
        sim: SimOptions::from_spec(spec).unwrap(),
        firmware: elf.to_owned(),
        qemu: QEMU.into(),
        shift: SHIFT,
        duration_us: secs * 1_000_000,
    };
    cosim::run(&setup).unwrap()
}

/// The scan headers in the firmware's SLCAN output, in order.
fn headers(uart1: &[u8]) -> Vec<ScanHeader> {
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Vec::new();
    for line in uart1.split(|&b| b == slcan::CR).filter(|l| !l.is_empty()) {
        let (f, _) = slcan::Frame::parse(line, false).unwrap();
        let frame = Frame::new(f.id(), f.data(), f.kind().is_fd()).unwrap();
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(&frame) {
            out.push(*scan.header());
        }
    }
    out
}

/// Per estimated header: the truth it is nearest to (virtual µs; scans are 25 ms apart,
/// errors far smaller) and the error, µs.
fn matched(headers: &[ScanHeader], truth: &[u64]) -> Vec<(u64, u64)> {
    headers
        .iter()
        .filter(|h| h.time_estimated && !h.time_master)
        .map(|h| {
            truth
                .iter()
                .map(|&t| (t, u64::from((t as u32).abs_diff(h.timestamp_ms))))
                .min_by_key(|&(_, e)| e)
                .unwrap()
        })
        .collect()
}

#[test]
fn firmware_estimates_scan_times_in_exact_virtual_time() {
    let Some(elf) = firmware() else { return };
    // Issue 11's bound: p99 ≤ 0.3 ms from 10 s on.
    const FROM_US: u64 = 10_000_000;
    // Every scan estimated from here on (less the few scans a late TM exchange stops).
    const CONVERGED_US: u64 = FROM_US;
    const SECS: u64 = 22;
    // The sensor's 24-bit millisecond clock wraps 17 s into the -100 ppm run (after the
    // estimate converged), 5 s into the +100 ppm one (before).
    for (drift, phase, clock) in [(-100, 300, 16_760_216), (100, 500, 16_772_216)] {
        let spec = format!(
            "model=utm30lx,scene=wall:2000,noise=0,clock={clock},drift_ppm={drift},\
             clock_phase_us={phase},jitter_us=2000"
        );
        let r = run(&elf, &spec, SECS);
        let h = headers(&r.uart1);
        let m = matched(&h, &r.truth);
        let first = m.first().map(|&(t, _)| t);
        let mut e: Vec<u64> = m
            .iter()
            .filter(|&&(t, _)| t >= FROM_US)
            .map(|&(_, e)| e)
            .collect();
        e.sort();
        let p99 = e.get(e.len() * 99 / 100).copied();
        eprintln!(
            "{drift} ppm: {} scans, {} estimated, first estimate at {first:?} µs, \
             p99 {p99:?} µs, worst {:?} µs from {FROM_US} µs; {} slots, {} sensor bytes, \
             wall {:?}",
            h.len(),
            m.len(),
            e.last(),
            r.slots,
            r.sensor_bytes,
            r.wall
        );
        // 40 scans a second: every scan estimated once converged (12 s: 480 scans; a TM
        // exchange stops the stream for a few).
        let converged = m.iter().filter(|&&(t, _)| t >= CONVERGED_US).count();
        let expected = (SECS - CONVERGED_US / 1_000_000) * 40;
        assert!(
            converged + 20 >= expected as usize,
            "{drift} ppm: {converged} estimated scans from {CONVERGED_US} µs on (the first \
             at {first:?} µs; issue 11 asks for {FROM_US} µs)",
        );
        assert!(p99.unwrap() <= 300, "{drift} ppm: p99 {p99:?} µs");
        // Published times never go back.
        let times: Vec<u32> = h
            .iter()
            .filter(|h| h.time_estimated)
            .map(|h| h.timestamp_ms)
            .collect();
        assert!(times.windows(2).all(|w| w[0] < w[1]));
    }
}

#[test]
fn cosimulation_is_deterministic() {
    let Some(elf) = firmware() else { return };
    let spec = "model=utm30lx,scene=wall:2000,noise=0,drift_ppm=100,clock_phase_us=500,\
                jitter_us=2000";
    let a = run(&elf, spec, 3);
    let b = run(&elf, spec, 3);
    assert!(!headers(&a.uart1).is_empty(), "no scans in 3 s");
    assert_eq!(
        a.commands, b.commands,
        "the firmware's commands and their times"
    );
    assert!(a.uart1 == b.uart1, "two runs, different frames");
}
