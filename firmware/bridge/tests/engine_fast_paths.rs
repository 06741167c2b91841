//! The engine's direct paths (a line's points straight into one encoder run when every
//! pipeline stage is off, or when angular decimation is the only one) publish exactly
//! what the pipeline gives point by point: scans with error codes, ranges past the
//! encoding's out-of-range code, lines split anywhere, classic and CAN FD frames.

use bridge::engine::{Bridge, BridgeConfig};
use bridge::pipeline::{
    Decimation, DecimationMode, MedianWidth, Pipeline, PipelineConfig, Point, RangeWindow,
    RawPoint, ScanInfo, SpeckleFilter, StepWindow,
};
use can_wire::bandwidth::BitRates;
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{Distance, DistanceEncoding, Encoding, Frame, FrameFormat, IdWindow};
use scip::{
    Command, ModelFamily, Range, RangeLimits, Request, ResponseWriter, ScanMode, ScanRequest,
};

const Q: usize = 512;

/// Steps per scan: 17 whole data lines and a short one.
const STEPS: u16 = 1081;

fn config(pipeline: PipelineConfig, format: FrameFormat) -> BridgeConfig {
    let mut config = BridgeConfig {
        pipeline,
        encoding: Encoding::PLAIN_MM,
        status_period_ms: 0,
        fd_capable: true,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(5).unwrap(), format)
    };
    // The CAN FD bit rates whatever the format.
    config.budget.rates = BitRates::FD_1M_5M;
    config
}

/// Distances of scan `k`: ranges, error codes below DMIN (20), and ranges past 65534
/// (the out-of-range code of 16-bit millimetres).
fn distances(k: u32) -> Vec<u32> {
    (0..u32::from(STEPS))
        .map(|i| {
            let x = (i + 1).wrapping_mul(2_654_435_761) ^ k.wrapping_mul(0x9E37_79B9);
            match x % 11 {
                0 => x % 20,
                1 => 65_000 + x % 4_000,
                _ => 20 + x % 30_000,
            }
        })
        .collect()
}

/// A continuous-scan stream of `scans` frames over steps 0..STEPS-1.
fn stream(scans: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    let mut s = ScanRequest::distance(ScanMode::Continuous, 0, STEPS - 1);
    s.count = 0;
    for k in 0..scans {
        w.echo(&Request::new(Command::Scan(s)));
        w.status(*b"99");
        w.timestamp(1000 + 25 * k);
        for d in distances(k) {
            w.step(d, 0);
        }
        w.end();
    }
    let _ = w.into_inner();
    out
}

/// The bridge's scans, decoded from its frames ([`bridge_frames`]): per scan its
/// distances.
fn bridge_scans(cfg: BridgeConfig, bytes: &[u8], chunk: usize) -> Vec<Vec<Distance>> {
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Vec::new();
    for f in bridge_frames(cfg, bytes, chunk) {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(&f) {
            assert!(scan.is_intact());
            out.push(
                scan.points()
                    .map(|p| p.map_or(Distance::Invalid, |p| p.distance))
                    .collect(),
            );
        }
    }
    out
}

/// What the pipeline gives for the same scans pushed point by point, as the wire
/// encoding carries it.
fn expected(pipeline: PipelineConfig, scans: u32) -> Vec<Vec<Distance>> {
    let limits = RangeLimits {
        dmin: 20,
        family: ModelFamily::Unknown,
    };
    let enc = Encoding::PLAIN_MM;
    (0..scans)
        .map(|k| {
            let mut p = Pipeline::new(pipeline).unwrap();
            p.begin_scan(ScanInfo {
                seq: k,
                timestamp_ms: 0,
                first_step: 0,
                last_step: STEPS - 1,
                cluster: 1,
            });
            let mut out: Vec<Point> = Vec::new();
            for (i, d) in distances(k).into_iter().enumerate() {
                let raw = RawPoint {
                    step: i as u16,
                    distance: d,
                    intensity: None,
                    valid: matches!(limits.classify(d, 3), Range::Mm(_)),
                };
                p.push(raw, &mut |x| out.push(x));
            }
            p.end_scan(true, &mut |x| out.push(x));
            out.iter()
                .map(|x| {
                    let d = x.range_mm.map_or(Distance::Invalid, Distance::Mm);
                    enc.decode_distance(enc.encode_distance(d))
                })
                .collect()
        })
        .collect()
}

#[test]
fn direct_paths_publish_what_the_pipeline_gives_point_by_point() {
    let bytes = stream(3);
    let mut pipelines = vec![PipelineConfig::default()];
    for mode in [
        DecimationMode::First,
        DecimationMode::Min,
        DecimationMode::Mean,
    ] {
        for factor in [2, 3, 7] {
            pipelines.push(PipelineConfig {
                decimation: Some(Decimation { factor, mode }),
                ..PipelineConfig::default()
            });
        }
    }
    for pipeline in pipelines {
        let want = expected(pipeline, 3);
        for format in [FrameFormat::Classic, FrameFormat::FD64] {
            for chunk in [64, 1000] {
                let got = bridge_scans(config(pipeline, format), &bytes, chunk);
                let what = format!("{pipeline:?} {format:?} chunks of {chunk}");
                assert_eq!(got.len(), want.len(), "{what}");
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(g.len(), w.len(), "{what}: scan {k}");
                    let first = g.iter().zip(w).position(|(a, b)| a != b);
                    assert_eq!(first, None, "{what}: scan {k}, first difference");
                }
            }
        }
    }
}

/// Every frame the bridge sends for `bytes` fed in pieces of `chunk` bytes (each at the
/// time its last byte arrives at 115 200 bit/s), in order; none lost, no scan dropped.
fn bridge_frames(cfg: BridgeConfig, bytes: &[u8], chunk: usize) -> Vec<Frame> {
    let mut b: Box<Bridge<Q>> = Box::new(Bridge::new(cfg).unwrap());
    b.set_auto_decimation(false);
    let mut out = Vec::new();
    let mut at = 0u64;
    for piece in bytes.chunks(chunk) {
        at += piece.len() as u64;
        b.on_uart(piece, at * 10 * 1000 / 115_200);
        while let Some(f) = b.pop_frame() {
            out.push(f);
        }
    }
    assert_eq!(b.stats().queue_overflows, 0);
    assert_eq!(b.stats().scans_dropped, 0, "chunks of {chunk}");
    out
}

/// The filtered lines that end in one `on_uart` chunk go into the encoder as one run:
/// the frames, byte for byte and in order, are those of a chunk a byte long (a line at a
/// time: no two lines end in one chunk), for any chunking, every encoding and frame
/// kind; and the scans are what the pipeline gives point by point.
#[test]
fn filtered_lines_batched_per_chunk_send_the_frames_of_a_line_at_a_time() {
    let bytes = stream(3);
    let typical = PipelineConfig {
        range_window: Some(RangeWindow {
            min_mm: 100,
            max_mm: 30_000,
        }),
        speckle: Some(SpeckleFilter { max_jump_mm: 200 }),
        median: Some(MedianWidth::Three),
        ..PipelineConfig::default()
    };
    let every = PipelineConfig {
        roi: Some(StepWindow {
            first: 100,
            last: 900,
        }),
        median: Some(MedianWidth::Five),
        decimation: Some(Decimation {
            factor: 3,
            mode: DecimationMode::Mean,
        }),
        ..typical
    };
    let median5 = PipelineConfig {
        median: Some(MedianWidth::Five),
        ..PipelineConfig::default()
    };
    let lossless = Encoding {
        distance: DistanceEncoding::Lossless,
        ..Encoding::PLAIN_MM
    };
    for pipeline in [typical, every, median5] {
        let want = expected(pipeline, 3);
        for format in [FrameFormat::Classic, FrameFormat::FD64] {
            for encoding in [Encoding::PLAIN_MM, lossless] {
                let cfg = BridgeConfig {
                    encoding,
                    ..config(pipeline, format)
                };
                let one = bridge_frames(cfg, &bytes, 1);
                // A scan is at least its two headers, a data frame and its trailer.
                assert!(one.len() >= 3 * 4, "{pipeline:?} {format:?} {encoding:?}");
                for chunk in [7, 64, 128, 1000] {
                    let got = bridge_frames(cfg, &bytes, chunk);
                    let what = format!("{pipeline:?} {format:?} {encoding:?} chunks of {chunk}");
                    assert_eq!(got.len(), one.len(), "{what}");
                    let first = got.iter().zip(&one).position(|(a, b)| a != b);
                    assert_eq!(first, None, "{what}: first differing frame");
                }
                // Three intact scans (`bridge_scans` checks); in 16-bit millimetres
                // (the lossless coding keeps ranges past 65534), the pipeline's.
                let got = bridge_scans(cfg, &bytes, 1000);
                assert_eq!(got.len(), 3, "{pipeline:?} {format:?} {encoding:?}");
                if encoding == Encoding::PLAIN_MM {
                    assert_eq!(got, want, "{pipeline:?} {format:?}");
                }
            }
        }
    }
}

/// A continuous multi-echo stream of `scans` frames over steps 0..STEPS-1: each step's
/// first echo is its distance of [`distances`], and one or two extra echoes (other
/// distances) follow on some steps, so that some data lines begin with an extra echo.
fn multi_echo_stream(scans: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    let mut s = ScanRequest::distance(ScanMode::Continuous, 0, STEPS - 1);
    s.count = 0;
    s.multi_echo = true;
    for k in 0..scans {
        w.echo(&Request::new(Command::Scan(s)));
        w.status(*b"99");
        w.timestamp(1000 + 25 * k);
        for (i, d) in distances(k).into_iter().enumerate() {
            w.step(d, 0);
            for e in 0..(i as u32 * 7 + k) % 5 / 2 {
                w.extra_echo(d / 2 + 100 * e + 21, 0);
            }
        }
        w.end();
    }
    let _ = w.into_inner();
    out
}

/// Multi-echo lines go point by point: the bridge publishes each step's first echo, at
/// its step, as the pipeline gives the single-echo scan of those first echoes.
#[test]
fn multi_echo_lines_publish_their_first_echoes_at_their_steps() {
    let bytes = multi_echo_stream(3);
    // Some data line begins with an extra echo: a line's first char is `&`.
    let lines_with_echo_first = bytes
        .split(|&b| b == b'\n')
        .filter(|l| l.first() == Some(&b'&'))
        .count();
    assert!(lines_with_echo_first > 0);
    let decimated = PipelineConfig {
        decimation: Some(Decimation {
            factor: 3,
            mode: DecimationMode::Min,
        }),
        ..PipelineConfig::default()
    };
    for pipeline in [PipelineConfig::default(), decimated] {
        let want = expected(pipeline, 3);
        for chunk in [64, 1000] {
            let got = bridge_scans(config(pipeline, FrameFormat::Classic), &bytes, chunk);
            let what = format!("{pipeline:?} chunks of {chunk}");
            assert_eq!(got, want, "{what}");
        }
    }
}
