//! The pipeline's line path on the real recordings: every stage and combination, through
//! the bridge engine, the CAN frames and the reassembling decoder, against a whole-scan
//! reference written here from the stage definitions (README / pipeline docs) and the
//! points the tests' independent SCIP reader reads off the capture.

use bridge::pipeline::{
    Decimation, DecimationMode, MedianWidth, PipelineConfig, RangeWindow, SpeckleFilter, StepWindow,
};
use can_wire::reassembly::Completeness;
use can_wire::{Distance, DistanceEncoding, Encoding, FrameFormat, IntensityEncoding};
use scip2can_tests::{oracle, recordings_or_skip};

use crate::bridge_replay::{config, reassemble, replay};

/// One point of the reference: step, range, raw intensity.
type P = (u16, Option<u32>, Option<u32>);

/// The scan after every stage of `cfg`, computed for the whole scan at once.
fn reference(cfg: &PipelineConfig, points: &[(u16, u32, bool, Option<u32>)]) -> Vec<P> {
    let mut v: Vec<P> = points
        .iter()
        .filter(|p| cfg.roi.is_none_or(|r| r.first <= p.0 && p.0 <= r.last))
        .map(|&(step, d, valid, i)| {
            let ok = valid
                && cfg
                    .range_window
                    .is_none_or(|w| w.min_mm <= d && d <= w.max_mm)
                && !matches!((cfg.min_intensity, i), (Some(m), Some(i)) if i < m);
            (step, ok.then_some(d), i)
        })
        .collect();
    if let Some(f) = cfg.speckle {
        let before = v.clone();
        for (k, p) in v.iter_mut().enumerate() {
            let Some(r) = p.1 else { continue };
            let near = |j: Option<usize>| {
                j.and_then(|j| before.get(j))
                    .and_then(|q| q.1)
                    .is_some_and(|q| q.abs_diff(r) <= f.max_jump_mm)
            };
            if !near(k.checked_sub(1)) && !near(Some(k + 1)) {
                p.1 = None;
            }
        }
    }
    if let Some(m) = cfg.median {
        let h = if m == MedianWidth::Five { 2 } else { 1 };
        let before = v.clone();
        for (k, p) in v.iter_mut().enumerate() {
            let Some(own) = p.1 else { continue };
            let hi = (k + h).min(before.len() - 1);
            let mut vals: Vec<u32> = before[k.saturating_sub(h)..=hi]
                .iter()
                .filter_map(|q| q.1)
                .collect();
            vals.sort();
            let n = vals.len();
            p.1 = Some(own.clamp(vals[(n - 1) / 2], vals[n / 2]));
        }
    }
    if let Some(d) = cfg.decimation.filter(|d| d.factor > 1) {
        v = v
            .chunks(usize::from(d.factor))
            .map(|g| match d.mode {
                DecimationMode::First => g[0],
                DecimationMode::Min => {
                    let best =
                        g.iter()
                            .filter(|q| q.1.is_some())
                            .fold(None::<&P>, |b, q| match b {
                                Some(b) if b.1 <= q.1 => Some(b),
                                _ => Some(q),
                            });
                    (g[0].0, best.and_then(|b| b.1), best.and_then(|b| b.2))
                }
                DecimationMode::Mean => {
                    let mean = |xs: Vec<u64>| {
                        let n = xs.len() as u64;
                        (n > 0).then(|| ((xs.iter().sum::<u64>() + n / 2) / n) as u32)
                    };
                    let valid: Vec<&P> = g.iter().filter(|q| q.1.is_some()).collect();
                    let r = mean(valid.iter().map(|q| u64::from(q.1.unwrap())).collect());
                    let i = mean(valid.iter().filter_map(|q| q.2.map(u64::from)).collect());
                    (g[0].0, r, r.and(i))
                }
            })
            .collect();
    }
    v
}

fn configs() -> Vec<(&'static str, PipelineConfig)> {
    let base = PipelineConfig::default();
    let window = Some(RangeWindow {
        min_mm: 300,
        max_mm: 3000,
    });
    let dec = |factor, mode| Some(Decimation { factor, mode });
    vec![
        (
            "window",
            PipelineConfig {
                range_window: window,
                ..base
            },
        ),
        (
            "intensity",
            PipelineConfig {
                min_intensity: Some(1900),
                ..base
            },
        ),
        (
            "speckle",
            PipelineConfig {
                speckle: Some(SpeckleFilter { max_jump_mm: 8 }),
                ..base
            },
        ),
        (
            "median3",
            PipelineConfig {
                median: Some(MedianWidth::Three),
                ..base
            },
        ),
        (
            "median5",
            PipelineConfig {
                median: Some(MedianWidth::Five),
                ..base
            },
        ),
        (
            "first3",
            PipelineConfig {
                decimation: dec(3, DecimationMode::First),
                ..base
            },
        ),
        (
            "min2",
            PipelineConfig {
                decimation: dec(2, DecimationMode::Min),
                ..base
            },
        ),
        (
            "mean4",
            PipelineConfig {
                decimation: dec(4, DecimationMode::Mean),
                ..base
            },
        ),
        (
            "roi",
            PipelineConfig {
                roi: Some(StepWindow {
                    first: 100,
                    last: 600,
                }),
                ..base
            },
        ),
        (
            "typical",
            PipelineConfig {
                range_window: window,
                speckle: Some(SpeckleFilter { max_jump_mm: 30 }),
                median: Some(MedianWidth::Three),
                ..base
            },
        ),
        (
            "all",
            PipelineConfig {
                roi: Some(StepWindow {
                    first: 61,
                    last: 700,
                }),
                range_window: window,
                min_intensity: Some(1500),
                speckle: Some(SpeckleFilter { max_jump_mm: 20 }),
                median: Some(MedianWidth::Five),
                decimation: dec(3, DecimationMode::Mean),
                ..base
            },
        ),
    ]
}

#[test]
fn every_stage_on_the_recordings_matches_the_reference() {
    let Some(dir) = recordings_or_skip("pipeline blocks") else {
        return;
    };
    let encoding = Encoding {
        distance: DistanceEncoding::D16,
        intensity: IntensityEncoding::I16,
        unit_exp: 0,
    };
    let mut checked = 0;
    for name in [
        "hokuyoaist_example_urg_04lx.rx.scip",
        "hokuyoaist_example_utm_30lx.rx.scip",
        "snark_gd_0000_0010_tag.scip",
    ] {
        let bytes = std::fs::read(dir.join(name)).expect("read");
        let dmin = oracle::dmin(&bytes);
        let scans: Vec<_> = oracle::scans(&bytes)
            .into_iter()
            .filter(|s| !s.damaged)
            .collect();
        assert!(!scans.is_empty(), "{name}");
        for (what, cfg) in configs() {
            let mut c = config(FrameFormat::Classic, encoding);
            c.pipeline = cfg;
            let got = reassemble(&replay(&bytes, c));
            assert_eq!(got.len(), scans.len(), "{name} {what}");
            for (g, s) in got.iter().zip(&scans) {
                // Echo `GD`/`MD`/`ME` + start (4) + end (4) + cluster (2).
                let start: u16 = s.echo[2..6].parse().expect("start");
                let cluster: u16 = s.echo[10..12].parse::<u16>().expect("cluster").max(1);
                let points: Vec<(u16, u32, bool, Option<u32>)> = s
                    .distances
                    .iter()
                    .enumerate()
                    .map(|(i, &d)| {
                        let step = start + i as u16 * cluster;
                        (
                            step,
                            d,
                            oracle::is_range(d, s.width, dmin),
                            s.intensities.get(i).copied(),
                        )
                    })
                    .collect();
                let want: Vec<(Distance, Option<u16>)> = reference(&cfg, &points)
                    .iter()
                    .map(|&(_, r, i)| match r {
                        // SPEC 4: a range of 0 is coded 1; the 16-bit intensity is
                        // min(4 × raw, 65535).
                        Some(mm) => (
                            Distance::Mm(mm.max(1)),
                            i.map(|v| u16::try_from(v.saturating_mul(4)).unwrap_or(u16::MAX)),
                        ),
                        None => (Distance::Invalid, None),
                    })
                    .collect();
                assert_eq!(g.0, Completeness::Intact, "{name} {what}");
                let got: Vec<(Distance, Option<u16>)> =
                    g.1.iter()
                        .map(|p| {
                            let p = p.expect("every point received");
                            match p.distance {
                                Distance::Mm(_) => (p.distance, p.intensity),
                                _ => (Distance::Invalid, None),
                            }
                        })
                        .collect();
                assert_eq!(got.len(), want.len(), "{name} {what}");
                for (k, (a, b)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(a, b, "{name} {what} point {k}");
                }
                checked += 1;
            }
        }
    }
    assert!(checked >= 33, "{checked} scans checked");
}

/// Control frames (SPEC 6) received one after the other before a scan all apply: the
/// second one keeps what the first one set (each used to start from the settings of the
/// scan in progress, so only the last one took effect).
#[test]
fn successive_control_frames_all_apply() {
    let Some(dir) = recordings_or_skip("pipeline control frames") else {
        return;
    };
    let bytes = std::fs::read(dir.join("hokuyoaist_example_urg_04lx.rx.scip")).expect("read");
    let encoding = Encoding {
        distance: DistanceEncoding::D16,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };
    let c = config(FrameFormat::Classic, encoding);
    let ids = c.ids;
    let mut bridge: bridge::engine::Bridge<512> = bridge::engine::Bridge::new(c).expect("config");
    // Range window 300..=3000 mm (opcode 0x10, token, two 24-bit limits), then median
    // of 3 (opcode 0x12, token, 3), as SPEC 6 lays them out.
    let controls: [&[u8]; 2] = [&[0x10, 1, 0x2C, 0x01, 0, 0xB8, 0x0B, 0], &[0x12, 2, 3]];
    for data in controls {
        let f = can_wire::Frame::new(ids.id(can_wire::Kind::Control), data, false).expect("frame");
        assert!(bridge.on_can_frame(&f, 0));
    }
    while bridge.pop_frame().is_some() {}
    let mut frames = Vec::new();
    for (t, chunk) in bytes.chunks(100).enumerate() {
        bridge.on_uart(chunk, t as u64);
        while let Some(f) = bridge.pop_frame() {
            frames.push(f);
        }
    }
    let got = reassemble(&frames);
    let cfg = PipelineConfig {
        range_window: Some(RangeWindow {
            min_mm: 300,
            max_mm: 3000,
        }),
        median: Some(MedianWidth::Three),
        ..PipelineConfig::default()
    };
    assert_eq!(bridge.pipeline().config(), &cfg);
    let dmin = oracle::dmin(&bytes);
    let s = &oracle::scans(&bytes)[0];
    let points: Vec<(u16, u32, bool, Option<u32>)> = s
        .distances
        .iter()
        .enumerate()
        .map(|(i, &d)| (44 + i as u16, d, oracle::is_range(d, s.width, dmin), None))
        .collect();
    let want: Vec<Distance> = reference(&cfg, &points)
        .iter()
        .map(|p| p.1.map_or(Distance::Invalid, Distance::Mm))
        .collect();
    let got: Vec<Distance> = got[0]
        .1
        .iter()
        .map(|p| p.expect("received").distance)
        .collect();
    assert_eq!(got, want);
}
