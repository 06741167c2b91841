//! Sensor stream → bridge engine → CAN frames → reassembling decoder, on the real
//! recordings: what arrives is exactly what the capture holds (read by the tests'
//! independent SCIP reader and, for a few points, by hand); a lost frame costs only its
//! points and is reported; a damaged UART line never yields an intact scan; small scans
//! go out as exactly the frames written by hand from SPEC.md
//! (tests/golden/spec_frames_d16.txt).

use bridge::engine::{Bridge, BridgeConfig};
use bridge::pipeline::StepWindow;
use can_wire::reassembly::{Completeness, Decoder as CanDecoder, Event as CanEvent};
use can_wire::{
    Distance, DistanceEncoding, Encoding, Frame, FrameFormat, IdWindow, IntensityEncoding,
};
use embedded_can::{Id, StandardId};
use scip2can_tests::{oracle, recordings_or_skip};

const Q: usize = 512;

pub(crate) fn config(format: FrameFormat, encoding: Encoding) -> BridgeConfig {
    BridgeConfig {
        encoding,
        status_period_ms: 0,
        fd_capable: true,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).expect("node 0"), format)
    }
}

/// Runs a stream through a bridge (session not started: a replay), 100 bytes at a time,
/// 1 ms apart; returns every frame in transmit order.
pub(crate) fn replay(bytes: &[u8], config: BridgeConfig) -> Vec<Frame> {
    let mut bridge: Bridge<Q> = Bridge::new(config).expect("valid config");
    let mut frames = Vec::new();
    for (t, chunk) in bytes.chunks(100).enumerate() {
        bridge.on_uart(chunk, t as u64);
        while let Some(f) = bridge.pop_frame() {
            frames.push(f);
        }
    }
    frames
}

/// A reassembled scan: completeness and points (None = point not received).
pub(crate) type Got = (Completeness, Vec<Option<can_wire::reassembly::Point>>);

pub(crate) fn reassemble(frames: &[Frame]) -> Vec<Got> {
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Vec::new();
    for f in frames {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
            out.push((scan.completeness(), scan.points().collect()));
        }
    }
    if let Some(scan) = dec.flush(0) {
        out.push((scan.completeness(), scan.points().collect()));
    }
    out
}

/// The expected points of each intact measurement response, read by the independent
/// SCIP reader of the tests (not the decoder under test): error codes (below the
/// stream's PP `DMIN`) become invalid points; intensities when the encoding carries
/// them, saturated to 16 bits.
fn expected(bytes: &[u8], with_intensity: bool) -> Vec<Vec<(Distance, Option<u16>)>> {
    let dmin = oracle::dmin(bytes);
    oracle::scans(bytes)
        .into_iter()
        .filter(|s| !s.damaged)
        .map(|s| {
            s.distances
                .iter()
                .enumerate()
                .map(|(i, &d)| {
                    let dist = if oracle::is_range(d, s.width, dmin) {
                        Distance::Mm(d)
                    } else {
                        Distance::Invalid
                    };
                    let inten = s
                        .intensities
                        .get(i)
                        .filter(|_| with_intensity)
                        // SPEC 4: the 16-bit intensity is min(4 × raw, 65535).
                        .map(|&v| u16::try_from(v.saturating_mul(4)).unwrap_or(u16::MAX));
                    (dist, inten)
                })
                .collect()
        })
        .collect()
}

fn points(got: &Got) -> Vec<(Distance, Option<u16>)> {
    got.1
        .iter()
        .map(|p| p.map_or((Distance::Invalid, None), |p| (p.distance, p.intensity)))
        .collect()
}

const D16_I16: Encoding = Encoding {
    distance: DistanceEncoding::D16,
    intensity: IntensityEncoding::I16,
    unit_exp: 0,
};

/// Points read off the captures by hand (`sum((c - 0x30) << 6k)` over each value's
/// chars): recording, point count, and (index, mm, intensity) of a few points. They
/// anchor the test reader [`expected`] relies on.
type HandRead = (&'static str, usize, &'static [(usize, u32, Option<u16>)]);
const HAND_READ: [HandRead; 3] = [
    // GD0044072501: first line `068068067061 05m…`, last value `06e`.
    (
        "hokuyoaist_example_urg_04lx.rx.scip",
        682,
        &[
            (0, 392, None),
            (2, 391, None),
            (3, 385, None),
            (4, 381, None),
            (681, 437, None),
        ],
    ),
    // ME0000108001100: `00]0LA` = 45 mm, 28*64+17; `00`0Kd`; last `00a0Ld`.
    (
        "hokuyoaist_example_utm_30lx.rx.scip",
        1081,
        &[
            (0, 45, Some(1809)),
            (1, 48, Some(1780)),
            (1080, 49, Some(1844)),
        ],
    ),
    // `06306J06_…`: 6*64+3, 6*64+26, 6*64+47, … the last `070`.
    (
        "snark_gd_0000_0010_tag.scip",
        11,
        &[
            (0, 387, None),
            (1, 410, None),
            (2, 431, None),
            (10, 448, None),
        ],
    ),
];

#[test]
fn every_recorded_scan_arrives_exactly_as_sent() {
    let Some(dir) = recordings_or_skip("bridge replay") else {
        return;
    };
    for (name, count, read) in HAND_READ {
        let bytes = std::fs::read(dir.join(name)).expect("read");
        let want = expected(&bytes, true);
        assert_eq!(want.len(), 1, "{name}: one scan per recording");
        assert_eq!(want[0].len(), count, "{name}");
        for &(i, mm, intensity) in read {
            // The hand-read raw intensity as SPEC 4's 16-bit value: 4 × raw.
            let intensity = intensity.map(|v| v.saturating_mul(4));
            assert_eq!(
                want[0][i],
                (Distance::Mm(mm), intensity),
                "{name} point {i}"
            );
        }
        for format in [
            FrameFormat::Classic,
            FrameFormat::FD64,
            FrameFormat::Fd { max_len: 24 },
        ] {
            let got = reassemble(&replay(&bytes, config(format, D16_I16)));
            assert_eq!(got.len(), want.len(), "{name} {format:?}");
            for (g, w) in got.iter().zip(&want) {
                assert_eq!(g.0, Completeness::Intact, "{name} {format:?}");
                assert_eq!(&points(g), w, "{name} {format:?}");
            }
        }
    }
}

#[test]
fn a_replayed_scan_carries_the_geometry_of_the_recorded_pp() {
    let Some(dir) = recordings_or_skip("replay geometry") else {
        return;
    };
    let bytes = std::fs::read(dir.join("hokuyoaist_example_urg_04lx.rx.scip")).expect("read");
    let frames = replay(&bytes, config(FrameFormat::Classic, D16_I16));
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut headers = Vec::new();
    for f in &frames {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(f) {
            headers.push(*scan.header());
        }
    }
    assert_eq!(headers.len(), 1);
    // PP of the recording: AMIN 44 is the first step, AFRT 384 the front, ARES 1024.
    let h = headers[0];
    assert_eq!(
        (h.first_step, h.step_increment, h.ares),
        (44 - 384, 1, 1024)
    );
    assert_eq!(h.point_count, 682);
}

#[test]
fn losing_any_single_frame_costs_only_its_points_and_is_reported() {
    let Some(dir) = recordings_or_skip("frame loss") else {
        return;
    };
    let bytes = std::fs::read(dir.join("hokuyoaist_example_utm_30lx.rx.scip")).expect("read");
    let want = expected(&bytes, true).remove(0);
    let frames = replay(&bytes, config(FrameFormat::FD64, D16_I16));
    assert!(frames.len() > 10);
    for lost in 0..frames.len() {
        let mut kept = frames.clone();
        kept.remove(lost);
        let got = reassemble(&kept);
        if lost < 2 {
            // A lost header: the scan cannot be placed; nothing is delivered as intact.
            assert!(
                got.iter().all(|g| g.0 != Completeness::Intact),
                "lost header {lost}"
            );
            continue;
        }
        assert_eq!(got.len(), 1, "lost frame {lost}");
        let g = &got[0];
        assert_ne!(g.0, Completeness::Intact, "lost frame {lost} not reported");
        // Every point that arrived is right; the missing ones are exactly one frame's.
        let mut missing = 0;
        for (p, w) in g.1.iter().zip(&want) {
            match p {
                Some(p) => assert_eq!((p.distance, p.intensity), *w, "lost frame {lost}"),
                None => missing += 1,
            }
        }
        let last = lost == frames.len() - 1;
        if last {
            assert_eq!(missing, 0, "lost trailer");
        } else {
            assert!(
                missing > 0 && missing <= 64,
                "lost frame {lost}: {missing} missing"
            );
        }
    }
}

#[test]
fn a_damaged_uart_line_is_never_published_as_intact() {
    let Some(dir) = recordings_or_skip("corrupted") else {
        return;
    };
    let bytes = std::fs::read(dir.join("eeros_md_0046_0600.scip")).expect("read");
    let got = reassemble(&replay(&bytes, config(FrameFormat::Classic, D16_I16)));
    assert_eq!(got.len(), 1);
    assert!(
        matches!(got[0].0, Completeness::Aborted { .. }),
        "{:?}",
        got[0].0
    );

    // Any single flipped byte inside the UTM scan: never an intact scan with other values.
    let clean = std::fs::read(dir.join("hokuyoaist_example_utm_30lx.rx.scip")).expect("read");
    let want = expected(&clean, true).remove(0);
    let start = clean
        .windows(15)
        .position(|w| w == b"ME0000108001100")
        .expect("frame");
    for i in (start..clean.len()).step_by(97) {
        let mut bad = clean.clone();
        bad[i] ^= 0x04;
        for g in reassemble(&replay(&bad, config(FrameFormat::FD64, D16_I16))) {
            if g.0 == Completeness::Intact {
                assert_eq!(points(&g), want, "flip at {i} published wrong values");
            }
        }
    }
}

/// One block of tests/golden/spec_frames_d16.txt: a capture, the bridge settings, and
/// the frames written by hand from the SPEC.
struct GoldenScan {
    recording: String,
    roi: (u16, u16),
    frame_len: u8,
    intensity: IntensityEncoding,
    /// (identifier, CAN FD, data).
    frames: Vec<(u16, bool, Vec<u8>)>,
}

fn hex_bytes(text: &str) -> Vec<u8> {
    assert!(text.len() % 2 == 0, "odd hex {text:?}");
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).expect("hex byte"))
        .collect()
}

fn golden_scans(name: &str) -> Vec<GoldenScan> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("golden")
        .join(name);
    let text = std::fs::read_to_string(&path).expect("golden frames");
    let mut out: Vec<GoldenScan> = Vec::new();
    let mut open = false;
    for line in text.lines().map(str::trim) {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(rest) = line.strip_prefix("scan ") {
            assert!(!open, "scan inside a scan: {line}");
            let mut words = rest.split_whitespace();
            let recording = words.next().expect("recording").to_owned();
            let (mut roi, mut frame_len, mut intensity) = (None, None, None);
            for w in words {
                match w.split_once('=').expect("key=value") {
                    ("roi", v) => {
                        let (a, b) = v.split_once(':').expect("FIRST:LAST");
                        roi = Some((a.parse().expect("step"), b.parse().expect("step")));
                    }
                    ("len", v) => frame_len = Some(v.parse().expect("length")),
                    ("intensity", "i16") => intensity = Some(IntensityEncoding::I16),
                    ("intensity", "none") => intensity = Some(IntensityEncoding::None),
                    other => panic!("unknown setting {other:?}"),
                }
            }
            out.push(GoldenScan {
                recording,
                roi: roi.expect("roi="),
                frame_len: frame_len.expect("len="),
                intensity: intensity.expect("intensity="),
                frames: Vec::new(),
            });
            open = true;
        } else if line == "end" {
            assert!(open, "end outside a scan");
            open = false;
        } else {
            assert!(open, "frame outside a scan: {line}");
            let (id, data) = line.split_once('#').expect("ID#DATA");
            let id = u16::from_str_radix(id, 16).expect("hex id");
            let (fd, hex) = match data.strip_prefix('#') {
                // `ID##<flags><data>`: one hex digit of flags.
                Some(fd) => (true, fd.get(1..).expect("flags")),
                None => (false, data),
            };
            let scan = out.last_mut().expect("a scan");
            scan.frames.push((id, fd, hex_bytes(hex)));
        }
    }
    assert!(!open, "{name}: unterminated scan");
    out
}

#[test]
fn the_bridge_sends_the_golden_frames_written_from_the_spec() {
    let Some(dir) = recordings_or_skip("SPEC golden frames") else {
        return;
    };
    let golden = golden_scans("spec_frames_d16.txt");
    assert_eq!(golden.len(), 3);
    for g in &golden {
        let bytes = std::fs::read(dir.join(&g.recording)).expect("read");
        let format = if g.frame_len == 8 {
            FrameFormat::Classic
        } else {
            FrameFormat::Fd {
                max_len: g.frame_len,
            }
        };
        let mut c = config(
            format,
            Encoding {
                distance: DistanceEncoding::D16,
                intensity: g.intensity,
                unit_exp: 0,
            },
        );
        c.pipeline.roi = Some(StepWindow {
            first: g.roi.0,
            last: g.roi.1,
        });
        let frames = replay(&bytes, c);
        let got: Vec<(u16, bool, Vec<u8>)> = frames
            .iter()
            .map(|f| {
                let Id::Standard(id) = f.id() else {
                    panic!("an extended id")
                };
                (id.as_raw(), f.is_fd(), f.data().to_vec())
            })
            .collect();
        let show = |v: &[(u16, bool, Vec<u8>)]| -> Vec<String> {
            v.iter()
                .map(|(id, fd, d)| {
                    let hex: String = d.iter().map(|b| format!("{b:02X}")).collect();
                    format!("{id:03X}#{}{hex}", if *fd { "#1" } else { "" })
                })
                .collect()
        };
        assert_eq!(
            show(&got),
            show(&g.frames),
            "{} roi {:?} len {}",
            g.recording,
            g.roi,
            g.frame_len
        );

        // The other way round: the golden frames reassemble to the points read by hand.
        let golden_frames: Vec<Frame> = g
            .frames
            .iter()
            .map(|(id, fd, d)| {
                let id = StandardId::new(*id).expect("11-bit id");
                Frame::new(Id::Standard(id), d, *fd).expect("valid frame")
            })
            .collect();
        let scans = reassemble(&golden_frames);
        assert_eq!(scans.len(), 1);
        assert_eq!(scans[0].0, Completeness::Intact, "{}", g.recording);
        let want = expected(&bytes, true).remove(0);
        let (first, last) = (usize::from(g.roi.0), usize::from(g.roi.1));
        // Point i of the scan is step `start + i` of the request (cluster 1): the GD
        // starts at step 44, the ME at step 0.
        let start = if g.recording.contains("urg_04lx") {
            44
        } else {
            0
        };
        assert_eq!(points(&scans[0]), want[first - start..=last - start]);
    }
}
