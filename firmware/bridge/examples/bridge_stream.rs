//! Runs the whole bridge core on a long UTM-30LX stream N times, for instruction counts
//! under callgrind.
//!
//! `bridge_stream <N> [frames] [off|typical] [chunk] [d16|dl]`
//!
//! The stream: the `ME0000108001100` scan frame of the real UTM-30LX capture
//! (`../shared/recordings/hokuyoaist_example_utm_30lx.rx.scip` beside the repository:
//! 1081 steps, distance and intensity), decoded with `scip::Decoder` and written again
//! `frames` times (default 1000) with `scip::ResponseWriter`: same echo (remaining count
//! `00`), status `99`, timestamps 25 ms apart, the recorded values. Each of the N runs
//! feeds it to a fresh `Bridge<128>` (CAN FD 1/5 Mbit/s, D16+I16, status every second,
//! pipeline `off` or `typical` = range window + speckle + median of 3) in `chunk`-byte
//! pieces (default 64) with the time advancing 25 ms per scan frame, and takes every
//! frame from its queue. Under `valgrind --tool=callgrind`, the instruction counts of N
//! and 2N runs differ by N × the core's cost of one stream, start-up (reading and writing
//! the stream) excluded. See BENCHMARKS.md at the repository root.

use std::hint::black_box;
use std::path::PathBuf;

use bridge::engine::{Bridge, BridgeConfig};
use bridge::pipeline::{MedianWidth, PipelineConfig, RangeWindow, SpeckleFilter};
use can_wire::{DistanceEncoding, Encoding, FrameFormat, IdWindow, IntensityEncoding};
use scip::{Command, Decoder, Event, Request, ResponseWriter};

/// The recorded scan frame: its request and (distance, intensity) per step.
fn recorded_frame() -> (Request, u32, Vec<(u32, u32)>) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/recordings/hokuyoaist_example_utm_30lx.rx.scip");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| {
        eprintln!(
            "{}: {e} (the recordings live beside the repository)",
            path.display()
        );
        std::process::exit(1)
    });
    let mut dec = Decoder::new();
    let mut rest = &bytes[..];
    let (mut request, mut stamp, mut steps) = (None, 0, Vec::new());
    let mut in_frame = false;
    while !rest.is_empty() {
        let (used, event) = dec.feed(rest);
        rest = &rest[used..];
        match event {
            Some(Event::Start { echo, request: r }) => {
                in_frame = echo == b"ME0000108001100";
                if in_frame {
                    request = r;
                    steps.clear();
                }
            }
            Some(Event::Timestamp(t)) if in_frame => stamp = t,
            Some(Event::Data(line)) if in_frame => steps.extend(
                line.indexed()
                    .filter(|r| r.echo == 0)
                    .map(|r| (r.distance, r.aux)),
            ),
            Some(Event::End(_)) if in_frame && steps.len() == 1081 => break,
            _ => {}
        }
    }
    match request {
        Some(r) if matches!(r.command, Command::Scan(_)) && steps.len() == 1081 => {
            (r, stamp, steps)
        }
        _ => {
            eprintln!("{}: no intact ME0000108001100 frame", path.display());
            std::process::exit(1)
        }
    }
}

/// `frames` scan frames, 25 ms apart.
fn stream(frames: u32) -> (Vec<u8>, usize) {
    let (request, stamp, steps) = recorded_frame();
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    for k in 0..frames {
        w.echo(&request);
        w.status(*b"99");
        w.timestamp((stamp + 25 * k) & 0xFF_FFFF);
        for &(d, i) in &steps {
            w.step(d, i);
        }
        w.end();
    }
    let len = out.len();
    (out, len / frames.max(1) as usize)
}

fn config(typical: bool, distance: DistanceEncoding) -> BridgeConfig {
    let mut pipeline = PipelineConfig::default();
    if typical {
        pipeline.range_window = Some(RangeWindow {
            min_mm: 100,
            max_mm: 30_000,
        });
        pipeline.speckle = Some(SpeckleFilter { max_jump_mm: 200 });
        pipeline.median = Some(MedianWidth::Three);
    }
    BridgeConfig {
        pipeline,
        encoding: Encoding {
            distance,
            intensity: IntensityEncoding::I16,
            unit_exp: 0,
        },
        uart_bit_rate: 12_000_000,
        ..BridgeConfig::new(
            IdWindow::DEFAULT.node(0).expect("node 0 exists"),
            FrameFormat::FD64,
        )
    }
}

/// One run: (frames out, payload bytes out, scans sent).
fn run(stream: &[u8], frame_len: usize, chunk: usize, config: BridgeConfig) -> (u64, u64, u32) {
    let mut bridge: Bridge<128> = Bridge::new(config).expect("valid configuration");
    let (mut frames, mut bytes) = (0u64, 0u64);
    let mut pos = 0usize;
    for piece in stream.chunks(chunk) {
        pos += piece.len();
        let now_ms = (pos * 25 / frame_len.max(1)) as u64;
        bridge.on_uart(piece, now_ms);
        while bridge.poll(now_ms).is_some() {}
        while let Some(f) = bridge.pop_frame() {
            frames += 1;
            bytes += f.data().len() as u64;
        }
    }
    (frames, bytes, bridge.stats().scans_sent)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: bridge_stream <N> [frames=1000] [off|typical] [chunk=64] [d16|dl]";
    let parse = |i: usize, default: usize| match args.get(i) {
        None => Some(default),
        Some(s) => s.parse().ok(),
    };
    let (Some(Some(n)), Some(frames), Some(chunk)) = (
        args.first().map(|s| s.parse::<usize>().ok()),
        parse(1, 1000),
        parse(3, 64),
    ) else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let typical = match args.get(2).map(String::as_str) {
        None | Some("off") => false,
        Some("typical") => true,
        Some(_) => {
            eprintln!("{usage}");
            std::process::exit(2);
        }
    };
    let distance = match args.get(4).map(String::as_str) {
        None | Some("d16") => DistanceEncoding::D16,
        Some("dl") => DistanceEncoding::Lossless,
        Some(_) => {
            eprintln!("{usage}");
            std::process::exit(2);
        }
    };
    let (stream, frame_len) = stream(u32::try_from(frames).unwrap_or(u32::MAX));
    let mut last = (0, 0, 0);
    for _ in 0..n {
        last = run(
            black_box(&stream),
            frame_len,
            chunk.max(1),
            black_box(config(typical, distance)),
        );
    }
    println!(
        "{frames} scan frames ({} bytes, {frame_len} per frame), pipeline {}, chunk {chunk}: \
         {n} runs, last: {} CAN frames, {} payload bytes, {} scans sent",
        stream.len(),
        if typical { "typical" } else { "off" },
        last.0,
        last.1,
        last.2
    );
}
