//! What the engine writes into scan headers and trailers, against values worked out by
//! hand from the SCIP bytes and SPEC.md: extended timestamps (3.1), unknown and assumed
//! geometry (3.2), error codes never published as ranges (4), intensity scaling (4),
//! the trailer's `filtered` flag (3.4).

use bridge::engine::{Bridge, BridgeConfig};
use bridge::pipeline::{MedianWidth, PipelineConfig, RangeWindow};
use can_wire::reassembly::{Decoder as CanDecoder, Event as CanEvent};
use can_wire::{
    Distance, DistanceEncoding, Encoding, FrameFormat, IdWindow, IntensityEncoding, ScanHeader,
};
use scip::{Command, DataSet, Request, ResponseWriter, ScanMode, ScanRequest};

const Q: usize = 256;

fn config() -> BridgeConfig {
    BridgeConfig {
        encoding: Encoding::PLAIN_MM,
        status_period_ms: 0,
        ..BridgeConfig::new(IdWindow::DEFAULT.node(0).unwrap(), FrameFormat::FD64)
    }
}

fn bridge(config: BridgeConfig) -> Box<Bridge<Q>> {
    let mut b = Box::new(Bridge::new(config).unwrap());
    b.set_auto_decimation(false);
    b
}

/// One MD stream frame over steps `first..` with these (distance, intensity) values
/// (an ME frame when any intensity is given).
fn scan_frame(first: u16, ts: u32, values: &[(u32, Option<u32>)]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    let last = first + values.len() as u16 - 1;
    let mut s = ScanRequest::distance(ScanMode::Continuous, first, last);
    if values.iter().any(|v| v.1.is_some()) {
        s.data = DataSet::DistanceIntensity;
    }
    s.count = 0;
    w.echo(&Request::new(Command::Scan(s)));
    w.status(*b"99");
    w.timestamp(ts);
    for &(d, i) in values {
        w.step(d, i.unwrap_or(0));
    }
    w.end();
    let _ = w.into_inner();
    out
}

/// A scan as a receiver decodes it.
struct Decoded {
    header: ScanHeader,
    points: Vec<(Distance, Option<u16>)>,
    points_valid: u16,
    filtered: bool,
}

fn decoded(b: &mut Bridge<Q>) -> Vec<Decoded> {
    let mut dec: Box<CanDecoder<1440, 1>> = Box::new(CanDecoder::new(IdWindow::DEFAULT));
    let mut out = Vec::new();
    while let Some(f) = b.pop_frame() {
        if let Ok(Some(CanEvent::Scan { scan, .. })) = dec.push_frame(&f) {
            assert!(scan.is_intact());
            let t = scan.trailer().unwrap();
            out.push(Decoded {
                header: *scan.header(),
                points: scan
                    .points()
                    .map(|p| p.map(|p| (p.distance, p.intensity)).unwrap())
                    .collect(),
                points_valid: t.points_valid,
                filtered: t.flags.filtered,
            });
        }
    }
    out
}

fn ranges(d: &Decoded) -> Vec<Option<u32>> {
    d.points
        .iter()
        .map(|p| match p.0 {
            Distance::Mm(mm) => Some(mm),
            _ => None,
        })
        .collect()
}

#[test]
fn timestamps_are_extended_past_the_24_bit_wrap() {
    let mut b = bridge(config());
    let pts = [(1000, None); 3];
    // 0xFFFFF0, then 0x10 (the counter wrapped: 2^24 + 0x10), then 0x20.
    for (now, ts) in [(0, 0xFF_FFF0), (100, 0x10), (200, 0x20)] {
        b.on_uart(&scan_frame(0, ts, &pts), now);
    }
    let ts: Vec<u32> = decoded(&mut b)
        .iter()
        .map(|d| d.header.timestamp_ms)
        .collect();
    assert_eq!(ts, [0xFF_FFF0, 0x100_0010, 0x100_0020]);
    // A new session (the sensor may have been power-cycled meanwhile) starts over.
    b.start(300);
    b.on_uart(&scan_frame(0, 5, &pts), 400);
    let d = decoded(&mut b);
    assert_eq!(d.last().unwrap().header.timestamp_ms, 5);
    assert!(d.iter().all(|d| !d.header.time_synced));
}

/// The reproducer: an Ethernet sensor's MD frame with no PP before it.
const NO_ECHO: &[u8] =
    b"MD0100011000000;MD00000222\n99b\nCl2J[\n?om?om?om?om?om?om?om?om?om0JI0JCc\n\n";

#[test]
fn ethernet_no_echo_is_no_range_and_geometry_is_unknown_without_pp() {
    // By hand: `?om` = 15·4096 + 63·64 + 61 = 65533 (no echo), `0JI` = 26·64 + 25 =
    // 1689, `0JC` = 1683; `Cl2J` = 19·2^18 + 60·2^12 + 2·64 + 26 = 5226650. Steps
    // 100..=110, no PP: the geometry is unknown, so ares 0 and first_step the sensor
    // step, 100.
    let mut b = bridge(config());
    b.on_uart(NO_ECHO, 0);
    let d = decoded(&mut b);
    assert_eq!(d.len(), 1);
    let mut want = vec![None; 9];
    want.extend([Some(1689), Some(1683)]);
    assert_eq!(ranges(&d[0]), want);
    assert_eq!(d[0].points_valid, 2);
    let h = d[0].header;
    assert_eq!(h.timestamp_ms, 5_226_650);
    assert_eq!((h.ares, h.first_step, h.step_increment), (0, 100, 1));
    assert!(!h.geometry_known());
    assert_eq!(h.angle(0), None);
}

/// The same frame in the lossless coding: each no-echo value arrives as the sensor's
/// code 65533 by its identity (SPEC 4.2.1), the ranges exact; on the direct path, and
/// through angular decimation (a group without a range is invalid, not a sensor code).
#[test]
fn ethernet_codes_keep_their_identity_in_the_lossless_coding() {
    let mut c = config();
    c.encoding = Encoding {
        distance: can_wire::DistanceEncoding::Lossless,
        ..Encoding::PLAIN_MM
    };
    let mut b = bridge(c);
    b.on_uart(NO_ECHO, 0);
    let d = decoded(&mut b);
    let mut want = vec![(Distance::SensorError(65533), None); 9];
    want.extend([(Distance::Mm(1689), None), (Distance::Mm(1683), None)]);
    assert_eq!(d[0].points, want);
    assert_eq!(d[0].points_valid, 2);

    c.pipeline.decimation = Some(bridge::pipeline::Decimation {
        factor: 3,
        mode: bridge::pipeline::DecimationMode::First,
    });
    let mut b = bridge(c);
    b.on_uart(NO_ECHO, 0);
    let d = decoded(&mut b);
    // Groups of 3: steps 100-102, 103-105, 106-108 all no echo; 109-110 from 1689.
    let got: Vec<Distance> = d[0].points.iter().map(|p| p.0).collect();
    assert_eq!(
        got,
        [
            Distance::Invalid,
            Distance::Invalid,
            Distance::Invalid,
            Distance::Mm(1689)
        ]
    );
}

#[test]
fn ethernet_codes_are_no_ranges_through_the_pipeline_too() {
    // The same frame through the filter path (a range window that keeps all ranges).
    let mut c = config();
    c.pipeline.range_window = Some(RangeWindow {
        min_mm: 1,
        max_mm: 100_000,
    });
    let mut b = bridge(c);
    b.on_uart(NO_ECHO, 0);
    let d = decoded(&mut b);
    let mut want = vec![None; 9];
    want.extend([Some(1689), Some(1683)]);
    assert_eq!(ranges(&d[0]), want);
    // The window changed nothing: no filtered flag.
    assert!(!d[0].filtered);
}

#[test]
fn an_assumed_model_gives_the_geometry() {
    // URG-04LX: ARES 1024, AFRT 384. Steps 100.. are 100 - 384 = -284 from the front.
    let mut b = bridge(config());
    b.assume_sensor(scip::SensorParams {
        ares: Some(1024),
        afrt: Some(384),
        ..Default::default()
    });
    b.on_uart(&scan_frame(100, 7, &[(1000, None); 4]), 0);
    let d = decoded(&mut b);
    assert_eq!((d[0].header.ares, d[0].header.first_step), (1024, -284));
}

#[test]
fn intensities_scale_by_four_into_16_bits() {
    // SPEC 4: 16-bit intensity = min(4 raw, 65535); I8 = its top 8 bits; a receiver
    // reports code << 8. raw 2439 → 9756 → 38 → 9728; 16219 → 64876 → 253 → 64768;
    // 20000 → 65535 → 255 → 65280; 3 → 12 → 0.
    let mut c = config();
    c.encoding = Encoding {
        distance: DistanceEncoding::D16,
        intensity: IntensityEncoding::I8,
        unit_exp: 0,
    };
    let raws = [2439, 16219, 20000, 3];
    let values: Vec<_> = raws.iter().map(|&i| (1500, Some(i))).collect();
    for pipeline in [
        PipelineConfig::default(),
        PipelineConfig {
            median: Some(MedianWidth::Three),
            ..PipelineConfig::default()
        },
    ] {
        let mut b = bridge(BridgeConfig { pipeline, ..c });
        b.on_uart(&scan_frame(0, 1, &values), 0);
        let d = decoded(&mut b);
        let got: Vec<_> = d[0].points.iter().map(|p| p.1).collect();
        assert_eq!(
            got,
            [Some(9728), Some(64768), Some(65280), Some(0)],
            "{pipeline:?}"
        );
    }
}

#[test]
fn the_filtered_flag_says_a_filter_changed_or_invalidated_points() {
    let pts = |d: &[u32]| d.iter().map(|&d| (d, None)).collect::<Vec<_>>();
    let window = PipelineConfig {
        range_window: Some(RangeWindow {
            min_mm: 500,
            max_mm: 2000,
        }),
        ..PipelineConfig::default()
    };
    let median = PipelineConfig {
        median: Some(MedianWidth::Three),
        ..PipelineConfig::default()
    };
    let cases = [
        // (pipeline, ranges, filtered)
        (PipelineConfig::default(), pts(&[1000, 3000, 1000]), false),
        (window, pts(&[1000, 1500, 1000]), false),
        // 3000 is outside the window: made invalid.
        (window, pts(&[1000, 3000, 1000]), true),
        // Monotonic: the median of 3 keeps every range.
        (median, pts(&[1000, 1100, 1200]), false),
        // 3000 between two 1000s becomes 1000.
        (median, pts(&[1000, 3000, 1000]), true),
    ];
    for (pipeline, values, filtered) in cases {
        let mut b = bridge(BridgeConfig {
            pipeline,
            ..config()
        });
        b.on_uart(&scan_frame(0, 1, &values), 0);
        // The flag is per scan: a clean scan after it has none.
        b.on_uart(&scan_frame(0, 2, &pts(&[1000, 1000, 1000])), 0);
        let d = decoded(&mut b);
        assert_eq!(
            (d[0].filtered, d[1].filtered),
            (filtered, false),
            "{pipeline:?} {values:?}"
        );
    }
}

#[test]
fn a_range_windows_rejections_count_alike_in_every_encoding() {
    // Window 500..=2000 mm; DMIN 20 (no PP: the decoder's default). 3000 and 100 are
    // ranges the window takes away, 0 and 5 error codes, 1000 and 2000 kept. Counted
    // by hand: 2 out of range, 2 error codes, 4 invalid points out of 6.
    let values: Vec<_> = [1000, 3000, 0, 100, 5, 2000]
        .iter()
        .map(|&d| (d, None))
        .collect();
    let pipeline = PipelineConfig {
        range_window: Some(RangeWindow {
            min_mm: 500,
            max_mm: 2000,
        }),
        ..PipelineConfig::default()
    };
    for distance in [DistanceEncoding::D16, DistanceEncoding::Lossless] {
        let encoding = Encoding {
            distance,
            intensity: IntensityEncoding::None,
            unit_exp: 0,
        };
        let mut b = bridge(BridgeConfig {
            pipeline,
            encoding,
            ..config()
        });
        b.on_uart(&scan_frame(0, 1, &values), 0);
        let st = *b.pipeline().stats();
        assert_eq!(
            (
                st.invalid_out_of_range,
                st.invalid_error_code,
                st.points_out_invalid,
                st.points_out
            ),
            (2, 2, 4, 6),
            "{distance:?}"
        );
        let d = decoded(&mut b);
        assert_eq!(
            (d[0].points_valid, d[0].filtered),
            (2, true),
            "{distance:?}"
        );
    }
}
