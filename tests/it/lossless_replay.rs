//! The lossless coding (SPEC 4.2) on the real recordings: every point of every scan
//! arrives exactly as the sensor sent it, error codes by their identity, at the bits per
//! point the coding promises. The expected values come from a small SCIP reader written
//! here (character decoding and line layout of the protocol), not from the codec under
//! test.

use bridge::engine::BridgeConfig;
use can_wire::reassembly::Completeness;
use can_wire::{Distance, DistanceEncoding, Encoding, FrameFormat, IntensityEncoding};
use scip2can_tests::recordings_or_skip;

/// The bridge replay tests' configuration in the lossless coding.
fn config(format: FrameFormat, intensity: IntensityEncoding) -> BridgeConfig {
    crate::bridge_replay::config(
        format,
        Encoding {
            distance: DistanceEncoding::Lossless,
            intensity,
            unit_exp: 0,
        },
    )
}

/// One scan as the sensor sent it: raw distance values and intensities.
struct Truth {
    distances: Vec<u32>,
    intensities: Vec<u32>,
}

/// SCIP's character decoding: 6 bits per char, offset 0x30, most significant first.
fn chars(c: &[u8]) -> u32 {
    c.iter().fold(0, |v, &b| (v << 6) | u32::from(b - 0x30))
}

/// The measurement scans of a stream: responses whose echo is GD/MD/ME and whose status
/// says data follows; data lines are 64 chars and a sum char (the last shorter).
fn truth(bytes: &[u8]) -> Vec<Truth> {
    let text = String::from_utf8_lossy(bytes);
    let mut out = vec![];
    for response in text.split("\n\n") {
        let lines: Vec<&str> = response.trim_start_matches('\n').split('\n').collect();
        let [echo, status, _time, data @ ..] = lines.as_slice() else {
            continue;
        };
        let cmd = &echo[..2.min(echo.len())];
        let ok = match cmd {
            "GD" => status.starts_with("00"),
            "MD" | "ME" => status.starts_with("99"),
            _ => false,
        };
        if !ok || data.is_empty() {
            continue;
        }
        let payload: Vec<u8> = data
            .iter()
            .flat_map(|l| l.as_bytes()[..l.len() - 1].to_vec())
            .collect();
        let step = if cmd == "ME" { 6 } else { 3 };
        let mut t = Truth {
            distances: vec![],
            intensities: vec![],
        };
        for v in payload.chunks_exact(step) {
            t.distances.push(chars(&v[..3]));
            if step == 6 {
                t.intensities.push(chars(&v[3..]));
            }
        }
        out.push(t);
    }
    out
}

use crate::bridge_replay::{reassemble, replay};

/// (recording, DMIN from its PP answer)
const CAPTURES: [(&str, u32); 2] = [
    ("hokuyoaist_example_urg_04lx.rx.scip", 20),
    ("hokuyoaist_example_utm_30lx.rx.scip", 23),
];

#[test]
fn every_value_of_the_real_captures_arrives_exactly() {
    let Some(dir) = recordings_or_skip("lossless replay") else {
        return;
    };
    for (name, dmin) in CAPTURES {
        let bytes = std::fs::read(dir.join(name)).expect("read");
        let want = truth(&bytes);
        assert_eq!(want.len(), 1, "{name}: one scan");
        for format in [
            FrameFormat::Classic,
            FrameFormat::FD64,
            FrameFormat::Fd { max_len: 16 },
        ] {
            let got = reassemble(&replay(&bytes, config(format, IntensityEncoding::I16)));
            assert_eq!(got.len(), 1, "{name} {format:?}");
            let (c, points) = &got[0];
            assert_eq!(*c, Completeness::Intact, "{name} {format:?}");
            let w = &want[0];
            assert_eq!(points.len(), w.distances.len());
            let mut errors = 0;
            for (k, p) in points.iter().enumerate() {
                let p = p.expect("present");
                let v = w.distances[k];
                let d = if v < dmin {
                    errors += 1;
                    Distance::SensorError(v)
                } else {
                    Distance::Mm(v)
                };
                assert_eq!(p.distance, d, "{name} {format:?} point {k}");
                // SPEC 4: the 16-bit intensity is min(4 × raw, 65535).
                let want = w
                    .intensities
                    .get(k)
                    .map(|&i| i.saturating_mul(4).min(65535) as u16);
                assert_eq!(p.intensity, want);
            }
            if name.contains("urg") {
                // The URG capture has error codes 0, 7 and 10 (101 points): kept by identity.
                assert_eq!(errors, 101);
            }
        }
    }
}

/// All-in bits per point on classic CAN (headers, framing, segment headers, padding,
/// CRCs and trailer included): the target is at most 8.
#[test]
fn the_real_captures_cost_at_most_8_bits_per_point() {
    let Some(dir) = recordings_or_skip("lossless replay") else {
        return;
    };
    for (name, _) in CAPTURES {
        let bytes = std::fs::read(dir.join(name)).expect("read");
        let points = truth(&bytes)[0].distances.len();
        let frames = replay(
            &bytes,
            config(FrameFormat::Classic, IntensityEncoding::None),
        );
        let bits: usize = frames.iter().map(|f| f.len() * 8).sum();
        let per_point = bits as f64 / points as f64;
        assert!(per_point <= 8.0, "{name}: {per_point:.2} bits per point");
    }
}
