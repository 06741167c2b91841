//! Sensor stream → bridge engine → CAN frames → reassembling decoder, on the real
//! recordings: what arrives is exactly the pipeline's expected scan; a lost frame costs
//! only its points and is reported; a damaged UART line never yields an intact scan.

use bridge::engine::{Bridge, BridgeConfig};
use bridge::governor::Budget;
use bridge::pipeline::PipelineConfig;
use bridge::session::SessionConfig;
use can_wire::bandwidth::BitRates;
use can_wire::reassembly::{Completeness, Decoder as CanDecoder, Event as CanEvent};
use can_wire::{
    Distance, DistanceEncoding, Encoding, Frame, FrameFormat, IdWindow, IntensityEncoding,
};
use scip2can_host::parse::parse_bytes;
use scip2can_tests::recordings_or_skip;

const Q: usize = 512;

fn config(format: FrameFormat, encoding: Encoding) -> BridgeConfig {
    BridgeConfig {
        session: SessionConfig::default(),
        pipeline: PipelineConfig::default(),
        encoding,
        budget: Budget {
            rates: if format.is_fd() {
                BitRates::FD_1M_5M
            } else {
                BitRates::CLASSIC_1M
            },
            format,
            extended: false,
            share_permille: 1000,
        },
        ids: IdWindow::DEFAULT.node(0).expect("node 0"),
        uart_bit_rate: 115_200,
        status_period_ms: 0,
        fd_capable: true,
    }
}

/// Runs a stream through a bridge (session not started: a replay), 100 bytes at a time,
/// 1 ms apart; returns every frame in transmit order.
fn replay(bytes: &[u8], config: BridgeConfig) -> Vec<Frame> {
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
type Got = (Completeness, Vec<Option<can_wire::reassembly::Point>>);

fn reassemble(frames: &[Frame]) -> Vec<Got> {
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

/// The expected points of each intact measurement response, from `scip2can parse`:
/// error codes become invalid points; intensities when the encoding carries them.
fn expected(bytes: &[u8], with_intensity: bool) -> Vec<Vec<(Distance, Option<u16>)>> {
    parse_bytes(bytes)
        .into_iter()
        .filter(|r| !r.damaged && !r.distances.is_empty())
        .map(|r| {
            let codes: Vec<u64> = r
                .errors
                .iter()
                .filter_map(|e| e.get("index")?.as_u64())
                .collect();
            r.distances
                .iter()
                .enumerate()
                .map(|(i, &d)| {
                    let dist = if codes.contains(&(i as u64)) {
                        Distance::Invalid
                    } else {
                        Distance::Mm(d)
                    };
                    let inten = (with_intensity && !r.intensities.is_empty())
                        // SPEC 4: the 16-bit intensity is min(4 × raw, 65535).
                        .then(|| u16::try_from(r.intensities[i] * 4).unwrap_or(u16::MAX));
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

#[test]
fn every_recorded_scan_arrives_exactly_as_sent() {
    let Some(dir) = recordings_or_skip("bridge replay") else {
        return;
    };
    for name in [
        "hokuyoaist_example_urg_04lx.rx.scip",
        "hokuyoaist_example_utm_30lx.rx.scip",
        "snark_gd_0000_0010_tag.scip",
    ] {
        let bytes = std::fs::read(dir.join(name)).expect("read");
        let want = expected(&bytes, true);
        assert_eq!(want.len(), 1, "{name}: one scan per recording");
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
