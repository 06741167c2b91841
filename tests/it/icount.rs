//! `scip2can icount`: the instruction-count harness of the core on the emulated board.
//!
//! - the simulated stream is the same bytes for the same seed, ends right after the N-th
//!   stream frame, and the SCIP decoder finds N intact full-range frames in it;
//! - the benchmark firmware in `qemu-system-arm -icount shift=0` sends exactly the
//!   frames (count and FNV-1a hash) that this test's own replay of the same stream
//!   through the same core gets, every scan of the stream sent, none aborted;
//! - two runs of one stream count the same work to within the SysTick phase.
//!
//! The QEMU tests need `qemu-system-arm` (under `CI=true` its absence fails them,
//! otherwise they say so and pass) and build the firmware in `firmware/boards` first.
//! No test here asserts a performance figure.

use std::path::PathBuf;
use std::sync::OnceLock;

use bridge::engine::Bridge;
use embedded_can::Id;
use scip::{Command, Event, ScanMode, ScanRequest, Status};
use scip2can_host::icount::{self, qemu_config};
use scip2can_host::sim::model::ModelKind;
use scip2can_host::sim::SimOptions;

use crate::qemu::QEMU;

/// The benchmark ELF, built once per test run; `None` (test skipped) without QEMU.
fn bench_firmware() -> Option<PathBuf> {
    static ELF: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    crate::qemu::firmware(&ELF, || {
        icount::bench_firmware(None, icount::BenchEncoding::Dl)
    })
}

fn stream(model: ModelKind, seed: u64, scans: usize) -> Vec<u8> {
    let options = SimOptions {
        model,
        seed,
        ..SimOptions::default()
    };
    icount::sim_stream(&options, scans).unwrap()
}

/// FNV-1a (32 bit), written out here again so that the library's copy is checked too.
fn fnv(mut h: u32, bytes: &[u8]) -> u32 {
    for &b in bytes {
        h ^= u32::from(b);
        h = h.wrapping_mul(16_777_619);
    }
    h
}

/// Bytes per `on_uart` call in the bench firmware: the STM32 boards' UART read size
/// (board-common's `UART_CHUNK`), written out here again so the bench's is checked too.
const BOARD_CHUNK: usize = 128;

/// The stream through the core as the bench firmware feeds it: [`BOARD_CHUNK`]-byte calls at the
/// time the chunk's last byte arrives at 10 bits per byte, frames popped after each.
/// Returns the frame count and hash.
fn replay(stream: &[u8]) -> (u64, u32) {
    let mut core: Bridge<{ qemu_config::QUEUE }> =
        Bridge::new(qemu_config::bridge().unwrap()).unwrap();
    let (mut frames, mut hash) = (0u64, 0x811C_9DC5u32);
    let mut pos = 0u64;
    for chunk in stream.chunks(BOARD_CHUNK) {
        pos += chunk.len() as u64;
        core.on_uart(chunk, pos * 10_000 / u64::from(qemu_config::BAUD));
        while let Some(f) = core.pop_frame() {
            let raw = match f.id() {
                Id::Standard(id) => u32::from(id.as_raw()),
                Id::Extended(id) => id.as_raw() | 1 << 31,
            };
            hash = fnv(hash, &raw.to_le_bytes());
            hash = fnv(hash, &[u8::from(f.is_fd()), f.data().len() as u8]);
            hash = fnv(hash, f.data());
            frames += 1;
        }
    }
    (frames, hash)
}

fn firmware_matches_the_host_core_and_repeats(model: ModelKind, scans: usize) {
    let Some(elf) = bench_firmware() else { return };
    let s = stream(model, 7, scans);
    let m = icount::measure(QEMU, &elf, &s, icount::BenchEncoding::Dl).unwrap();
    let fw = m.firmware;
    let (frames, hash) = replay(&s);
    assert!(frames > 0);
    assert_eq!(
        (fw.frames, fw.frame_hash),
        (frames, hash),
        "{}",
        model.name()
    );
    assert_eq!((m.host.frames, m.host.hash.0), (frames, hash));
    assert_eq!(fw.bytes, s.len() as u64);
    assert_eq!(fw.chunks, s.len().div_ceil(BOARD_CHUNK) as u64);
    assert_eq!(
        (fw.scans_in, fw.scans_sent, fw.scans_aborted),
        (scans as u64, scans as u64, 0),
        "{}",
        model.name()
    );
    assert_eq!(m.scans, scans);
    assert!(fw.ticks > 0 && fw.max_chunk_ticks <= fw.ticks);

    // Again: the same frames, the same work but for the phase of SysTick at each call
    // (at most one tick per chunk either way, independent from call to call: the sum
    // spreads like the square root of the chunk count).
    let again = icount::run_firmware(QEMU, &elf, &s, icount::timeout_for(&s)).unwrap();
    assert_eq!((again.frames, again.frame_hash), (frames, hash));
    let tolerance = 4 * (fw.chunks as f64).sqrt() as u64 + 4;
    assert!(
        fw.ticks.abs_diff(again.ticks) <= tolerance,
        "{}: {} then {} ticks (tolerance {tolerance})",
        model.name(),
        fw.ticks,
        again.ticks
    );
}

#[test]
fn urg04lx_firmware_frames_are_the_host_cores_and_the_count_repeats() {
    firmware_matches_the_host_core_and_repeats(ModelKind::Urg04lx, 5);
}

#[test]
fn utm30lx_firmware_frames_are_the_host_cores_and_the_count_repeats() {
    firmware_matches_the_host_core_and_repeats(ModelKind::Utm30lx, 4);
}

#[test]
fn the_simulated_stream_is_fixed_by_the_seed_and_holds_n_intact_full_range_scans() {
    // AMIN..AMAX of the models: URG-04LX 44..725, UTM-30LX 0..1080.
    for (model, start, end) in [(ModelKind::Urg04lx, 44, 725), (ModelKind::Utm30lx, 0, 1080)] {
        let a = stream(model, 11, 4);
        assert_eq!(a, stream(model, 11, 4), "{}", model.name());
        assert_ne!(
            a,
            stream(model, 12, 4),
            "{}: the seed is used",
            model.name()
        );
        // One more scan only appends.
        let longer = stream(model, 11, 5);
        assert!(longer.len() > a.len() && longer.starts_with(&a));
        assert!(!a.contains(&icount::EOT));

        let mut dec = scip::Decoder::new();
        let mut rest = a.as_slice();
        let (mut intact, mut acks) = (0, 0);
        while !rest.is_empty() {
            let (used, event) = dec.feed(rest);
            rest = &rest[used..];
            match event {
                Some(Event::Error(e)) => panic!("{}: {e}", model.name()),
                Some(Event::End(s)) => {
                    let Some(req) = s.request else { continue };
                    let Command::Scan(scan) = req.command else {
                        continue;
                    };
                    let want = ScanRequest {
                        count: 0,
                        ..ScanRequest::distance(ScanMode::Continuous, start, end)
                    };
                    assert_eq!(scan, want, "{}", model.name());
                    if s.status == Status::STREAM {
                        assert_eq!(usize::from(s.values), usize::from(end - start + 1));
                        intact += 1;
                    } else {
                        assert_eq!((s.status, s.values), (Status::OK, 0));
                        acks += 1;
                    }
                }
                _ => {}
            }
        }
        assert_eq!((intact, acks), (4, 1), "{}", model.name());
        // It ends with the 4th frame's empty line.
        assert!(dec.between_responses() && a.ends_with(b"\n\n"));
    }
}

#[test]
fn can_fd_frames_from_the_firmware_are_the_host_cores_in_both_encodings() {
    // The board switched to 64-byte CAN FD frames by a control frame (SPEC 6, 0x21)
    // ahead of the stream, as `icount --pipeline frame=64` does; both cores take it.
    let Some(elf) = bench_firmware() else { return };
    let d16 = elf.with_file_name(icount::BenchEncoding::D16.firmware_name());
    let controls = icount::parse_pipeline_spec("frame=64").unwrap().frames;
    let s = stream(ModelKind::Urg04lx, 7, 3);
    for (elf, encoding) in [
        (&elf, icount::BenchEncoding::Dl),
        (&d16, icount::BenchEncoding::D16),
    ] {
        let m = icount::measure_with(QEMU, elf, &s, encoding, &controls).unwrap();
        // `measure_with` fails unless the firmware's frames are the host core's.
        assert_eq!((m.firmware.scans_sent, m.firmware.scans_aborted), (3, 0));
        // FD frames: a classic frame holds at most 8 data bytes, so 3 scans of 682
        // points need far more frames than 3 x 682 x 2 / 64 if they were classic.
        let classic = icount::measure(QEMU, elf, &s, encoding).unwrap();
        assert!(
            m.firmware.frames * 3 < classic.firmware.frames,
            "{encoding:?}: {} FD frames, {} classic",
            m.firmware.frames,
            classic.firmware.frames
        );
    }
}
