//! Integration tests of the scan pipeline: the real recorded scans, a whole-scan reference
//! model written independently of the streaming code, and property tests over random
//! settings, scans and batch splittings.

use std::path::PathBuf;

use bridge::pipeline::{
    output_len, Decimation, DecimationMode, MedianWidth, Pipeline, PipelineConfig, Point,
    RangeWindow, RawPoint, ScanEnd, ScanInfo, ScanStart, SpeckleFilter, StepWindow,
    TemporalDecimation,
};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// Reference model: whole scan in memory, one stage after the other, plain index math.
// ---------------------------------------------------------------------------------------

fn reference(config: &PipelineConfig, raw: &[RawPoint]) -> Vec<Point> {
    // ROI, error codes, range window, intensity threshold.
    let pts: Vec<Point> = raw
        .iter()
        .filter(|p| {
            config
                .roi
                .is_none_or(|w| w.first <= p.step && p.step <= w.last)
        })
        .map(|p| {
            let in_window = config
                .range_window
                .is_none_or(|w| w.min_mm <= p.distance && p.distance <= w.max_mm);
            let bright = match (config.min_intensity, p.intensity) {
                (Some(min), Some(i)) => i >= min,
                _ => true,
            };
            Point {
                step: p.step,
                range_mm: (p.valid && in_window && bright).then_some(p.distance),
                intensity: p.intensity,
            }
        })
        .collect();
    let n = pts.len() as isize;
    let at = |v: &Vec<Point>, i: isize| -> Option<Point> {
        if i < 0 || i >= n {
            None
        } else {
            Some(v[i as usize])
        }
    };
    // Speckle.
    let pts: Vec<Point> = match config.speckle {
        None => pts,
        Some(f) => (0..n)
            .map(|i| {
                let mut p = at(&pts, i).unwrap();
                if let Some(r) = p.range_mm {
                    let ok = |j| {
                        at(&pts, j)
                            .and_then(|q| q.range_mm)
                            .is_some_and(|q| q.abs_diff(r) <= f.max_jump_mm)
                    };
                    if !ok(i - 1) && !ok(i + 1) {
                        p.range_mm = None;
                    }
                }
                p
            })
            .collect(),
    };
    // Median.
    let pts: Vec<Point> = match config.median {
        None => pts,
        Some(w) => {
            let h = match w {
                MedianWidth::Three => 1,
                MedianWidth::Five => 2,
            };
            (0..n)
                .map(|i| {
                    let mut p = at(&pts, i).unwrap();
                    if let Some(own) = p.range_mm {
                        let mut v: Vec<u32> = (i - h..=i + h)
                            .filter_map(|j| at(&pts, j).and_then(|q| q.range_mm))
                            .collect();
                        v.sort();
                        let lo = v[(v.len() - 1) / 2];
                        let hi = v[v.len() / 2];
                        p.range_mm = Some(own.max(lo).min(hi));
                    }
                    p
                })
                .collect()
        }
    };
    // Angular decimation.
    // Factor 1 keeps every point as it is, whatever the mode.
    let Some(d) = config.decimation.filter(|d| d.factor > 1) else {
        return pts;
    };
    pts.chunks(usize::from(d.factor))
        .map(|g| {
            let step = g[0].step;
            let valid: Vec<&Point> = g.iter().filter(|p| p.range_mm.is_some()).collect();
            match d.mode {
                DecimationMode::First => g[0],
                DecimationMode::Min => {
                    let mut best: Option<&Point> = None;
                    for p in &valid {
                        if best.is_none_or(|b| p.range_mm < b.range_mm) {
                            best = Some(p);
                        }
                    }
                    Point {
                        step,
                        range_mm: best.and_then(|b| b.range_mm),
                        intensity: best.and_then(|b| b.intensity),
                    }
                }
                DecimationMode::Mean => {
                    if valid.is_empty() {
                        return Point {
                            step,
                            range_mm: None,
                            intensity: None,
                        };
                    }
                    let round = |s: u64, c: u64| ((s + c / 2) / c) as u32;
                    let sum: u64 = valid.iter().map(|p| u64::from(p.range_mm.unwrap())).sum();
                    let ints: Vec<u64> = valid
                        .iter()
                        .filter_map(|p| p.intensity.map(u64::from))
                        .collect();
                    Point {
                        step,
                        range_mm: Some(round(sum, valid.len() as u64)),
                        intensity: (!ints.is_empty())
                            .then(|| round(ints.iter().sum(), ints.len() as u64)),
                    }
                }
            }
        })
        .collect()
}

/// Runs one scan through a fresh pipeline, fed in the given batches.
fn stream(
    config: PipelineConfig,
    info: ScanInfo,
    batches: &[&[RawPoint]],
    intact: bool,
) -> (ScanStart, Vec<Point>, ScanEnd, Pipeline) {
    let mut p = Pipeline::new(config).expect("valid config");
    let start = p.begin_scan(info);
    let mut out = Vec::new();
    for b in batches {
        p.push_batch(b, &mut |x| out.push(x));
    }
    let end = p.end_scan(intact, &mut |x| out.push(x));
    (start, out, end, p)
}

/// Splits `points` into consecutive batches whose sizes cycle through `sizes`.
fn split<'a>(points: &'a [RawPoint], sizes: &[usize]) -> Vec<&'a [RawPoint]> {
    let mut out = Vec::new();
    let mut rest = points;
    let mut i = 0;
    while !rest.is_empty() {
        let n = sizes[i % sizes.len()].clamp(1, rest.len());
        let (a, b) = rest.split_at(n);
        out.push(a);
        rest = b;
        i += 1;
    }
    out
}

// ---------------------------------------------------------------------------------------
// The real recordings, decoded by a minimal test-only SCIP reader (sum checked).
// ---------------------------------------------------------------------------------------

fn recordings() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/recordings");
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("recordings folder missing: {}", dir.display());
    }
    eprintln!(
        "skipping: recordings folder {} not found (it sits beside the repository)",
        dir.display()
    );
    None
}

/// A recorded scan: its geometry and its points, batched as the data lines delivered them.
struct Recorded {
    info: ScanInfo,
    lines: Vec<Vec<RawPoint>>,
}

impl Recorded {
    fn points(&self) -> Vec<RawPoint> {
        self.lines.concat()
    }
}

/// Reads the response to `echo` (a 3-char-per-value GD/MD or ME command) from `file`.
fn recorded_scan(file: &str, echo: &str, dmin: u32) -> Option<Recorded> {
    let bytes = std::fs::read(recordings()?.join(file)).expect("readable recording");
    let text = std::str::from_utf8(&bytes).expect("ASCII recording");
    let start = text.find(&format!("{echo}\n")).expect("echo in recording");
    let body = &text[start..];
    let body = &body[..body.find("\n\n").expect("response end")];
    let lines: Vec<&str> = body.split('\n').collect();
    for l in &lines[1..] {
        let (data, sum) = l.split_at(l.len() - 1);
        let s = data.bytes().map(u32::from).sum::<u32>();
        assert_eq!(
            (s & 0x3F) + 0x30,
            u32::from(sum.as_bytes()[0]),
            "sum of {l:?}"
        );
    }
    let first_step: u16 = echo[2..6].parse().unwrap();
    let last_step: u16 = echo[6..10].parse().unwrap();
    let cluster: u16 = echo[10..12].parse().unwrap();
    let with_intensity = echo.starts_with("ME");
    let per_point = if with_intensity { 6 } else { 3 };
    let decode = |c: &[u8]| {
        c.iter()
            .fold(0u32, |acc, b| (acc << 6) | u32::from(b - 0x30))
    };
    let mut pending: Vec<u8> = Vec::new();
    let mut step = first_step;
    let mut out = Vec::new();
    for l in &lines[3..] {
        pending.extend_from_slice(&l.as_bytes()[..l.len() - 1]);
        let whole = pending.len() / per_point * per_point;
        let batch: Vec<RawPoint> = pending[..whole]
            .chunks(per_point)
            .map(|c| {
                let distance = decode(&c[..3]);
                let p = RawPoint {
                    step,
                    distance,
                    intensity: with_intensity.then(|| decode(&c[3..6])),
                    valid: distance >= dmin,
                };
                step += cluster.max(1);
                p
            })
            .collect();
        pending.drain(..whole);
        out.push(batch);
    }
    assert!(pending.is_empty(), "dangling value chars");
    Some(Recorded {
        info: ScanInfo {
            seq: 0,
            timestamp_ms: decode(&lines[2].as_bytes()[..4]),
            first_step,
            last_step,
            cluster,
        },
        lines: out,
    })
}

fn urg_gd() -> Option<Recorded> {
    recorded_scan("hokuyoaist_example_urg_04lx.rx.scip", "GD0044072501", 20)
}

fn utm_me() -> Option<Recorded> {
    recorded_scan("hokuyoaist_example_utm_30lx.rx.scip", "ME0000108001100", 23)
}

#[test]
fn recorded_urg_scan_passes_unchanged_and_error_codes_become_invalid() {
    let Some(scan) = urg_gd() else { return };
    let points = scan.points();
    // 682 values; 101 of them are error codes below DMIN = 20 (checked independently).
    assert_eq!(points.len(), 682);
    assert_eq!(points.iter().filter(|p| !p.valid).count(), 101);
    let lines: Vec<&[RawPoint]> = scan.lines.iter().map(Vec::as_slice).collect();
    let (start, out, end, p) = stream(PipelineConfig::default(), scan.info, &lines, true);
    assert_eq!(start, ScanStart::Publish { points: 682 });
    assert_eq!(end, ScanEnd::Complete { points: 682 });
    for (o, i) in out.iter().zip(&points) {
        assert_eq!(o.step, i.step);
        assert_eq!(o.range_mm, i.valid.then_some(i.distance));
    }
    assert_eq!(p.stats().invalid_error_code, 101);
    assert_eq!(p.stats().points_out_invalid, 101);
}

#[test]
fn recorded_urg_scan_min_of_three_by_hand() {
    let Some(scan) = urg_gd() else { return };
    // The first six values of the scan are 392 392 391 385 381 381 (steps 44..=49).
    let first: Vec<u32> = scan.points()[..6].iter().map(|p| p.distance).collect();
    assert_eq!(first, [392, 392, 391, 385, 381, 381]);
    let config = PipelineConfig {
        decimation: Some(Decimation {
            factor: 3,
            mode: DecimationMode::Min,
        }),
        ..PipelineConfig::default()
    };
    let lines: Vec<&[RawPoint]> = scan.lines.iter().map(Vec::as_slice).collect();
    let (start, out, _, _) = stream(config, scan.info, &lines, true);
    // ceil(682 / 3) = 228 points; the first two groups give 391 at 44 and 381 at 47.
    assert_eq!(start, ScanStart::Publish { points: 228 });
    assert_eq!(out.len(), 228);
    assert_eq!((out[0].step, out[0].range_mm), (44, Some(391)));
    assert_eq!((out[1].step, out[1].range_mm), (47, Some(381)));
}

/// A configuration a robot would run: front 180°, sane ranges, speckle, median, min of 2.
fn realistic(first: u16, last: u16, min_intensity: Option<u32>) -> PipelineConfig {
    PipelineConfig {
        roi: Some(StepWindow { first, last }),
        range_window: Some(RangeWindow {
            min_mm: 100,
            max_mm: 4000,
        }),
        min_intensity,
        speckle: Some(SpeckleFilter { max_jump_mm: 60 }),
        median: Some(MedianWidth::Five),
        decimation: Some(Decimation {
            factor: 2,
            mode: DecimationMode::Min,
        }),
        temporal: TemporalDecimation::All,
    }
}

#[test]
fn recorded_scans_by_line_match_the_reference() {
    let cases = [
        (urg_gd(), realistic(128, 640, None)),
        (utm_me(), realistic(180, 900, Some(1500))),
    ];
    for (scan, config) in cases {
        let Some(scan) = scan else { return };
        let points = scan.points();
        let want = reference(&config, &points);
        assert_eq!(want.len(), output_len(&config, &scan.info));
        // By data line, as the firmware receives them.
        let lines: Vec<&[RawPoint]> = scan.lines.iter().map(Vec::as_slice).collect();
        let (start, by_line, end, p) = stream(config, scan.info, &lines, true);
        assert_eq!(start, ScanStart::Publish { points: want.len() });
        assert_eq!(end, ScanEnd::Complete { points: want.len() });
        assert_eq!(by_line, want);
        // One at a time.
        let singles: Vec<&[RawPoint]> = points.chunks(1).collect();
        let (_, one_by_one, _, _) = stream(config, scan.info, &singles, true);
        assert_eq!(one_by_one, want);
        // Each stage did something on real data.
        let s = p.stats();
        assert!(s.points_outside_roi > 0);
        assert!(s.invalid_speckle + s.invalid_out_of_range > 0);
        assert!(by_line.iter().any(|p| p.range_mm.is_some()));
        assert!(by_line.iter().any(|p| p.range_mm.is_none()));
    }
}

#[test]
fn recorded_utm_scan_keeps_intensity_of_the_minimum() {
    let Some(scan) = utm_me() else { return };
    let points = scan.points();
    assert_eq!(points.len(), 1081);
    // First values (checked independently): ranges 45 48 49 50, intensities 1809 1780 1792
    // 1746. Min of 4: range 45 with its intensity 1809.
    let config = PipelineConfig {
        decimation: Some(Decimation {
            factor: 4,
            mode: DecimationMode::Min,
        }),
        ..PipelineConfig::default()
    };
    let lines: Vec<&[RawPoint]> = scan.lines.iter().map(Vec::as_slice).collect();
    let (start, out, _, _) = stream(config, scan.info, &lines, true);
    assert_eq!(start, ScanStart::Publish { points: 271 });
    assert_eq!(
        out[0],
        Point {
            step: 0,
            range_mm: Some(45),
            intensity: Some(1809)
        }
    );
}

// ---------------------------------------------------------------------------------------
// Property tests.
// ---------------------------------------------------------------------------------------

fn config_strategy() -> impl Strategy<Value = PipelineConfig> {
    let roi = prop::option::of((0u16..90, 0u16..90).prop_map(|(a, b)| StepWindow {
        first: a.min(b),
        last: a.max(b),
    }));
    let window = prop::option::of((0u32..1500, 0u32..7000).prop_map(|(a, b)| RangeWindow {
        min_mm: a.min(b),
        max_mm: a.max(b),
    }));
    let speckle = prop::option::of((0u32..300).prop_map(|t| SpeckleFilter { max_jump_mm: t }));
    let median = prop::option::of(prop_oneof![
        Just(MedianWidth::Three),
        Just(MedianWidth::Five)
    ]);
    let mode = prop_oneof![
        Just(DecimationMode::First),
        Just(DecimationMode::Min),
        Just(DecimationMode::Mean)
    ];
    let decimation =
        prop::option::of((1u16..9, mode).prop_map(|(factor, mode)| Decimation { factor, mode }));
    (
        roi,
        window,
        prop::option::of(0u32..300),
        speckle,
        median,
        decimation,
    )
        .prop_map(
            |(roi, range_window, min_intensity, speckle, median, decimation)| PipelineConfig {
                roi,
                range_window,
                min_intensity,
                speckle,
                median,
                decimation,
                temporal: TemporalDecimation::All,
            },
        )
}

/// A scan: geometry plus its points in step order (ranges cluster around a few surfaces,
/// with error codes and outliers mixed in).
fn scan_strategy() -> impl Strategy<Value = (ScanInfo, Vec<RawPoint>)> {
    let value = (
        prop::bool::weighted(0.8),
        prop_oneof![3 => 1000u32..1150, 1 => 0u32..7000],
        0u32..400,
    );
    (
        0u16..60,
        1u16..4,
        0u16..3,
        any::<bool>(),
        prop::collection::vec(value, 1..80),
    )
        .prop_map(|(first, cluster, extra, with_intensity, values)| {
            let n = values.len() as u16;
            let points: Vec<RawPoint> = values
                .iter()
                .enumerate()
                .map(|(i, &(valid, distance, intensity))| RawPoint {
                    step: first + i as u16 * cluster,
                    distance: if valid { distance } else { distance % 20 },
                    intensity: with_intensity.then_some(intensity),
                    valid,
                })
                .collect();
            let info = ScanInfo {
                seq: 7,
                timestamp_ms: 0,
                first_step: first,
                last_step: first + (n - 1) * cluster + extra % cluster,
                cluster,
            };
            (info, points)
        })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 512,
        // Integration tests have no lib.rs beside them to persist seeds next to.
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// Any splitting into batches gives the reference output, exactly as many points as
    /// announced, and a complete end.
    #[test]
    fn any_batching_matches_the_reference(
        config in config_strategy(),
        (info, points) in scan_strategy(),
        sizes in prop::collection::vec(1usize..30, 1..8),
    ) {
        let want = reference(&config, &points);
        prop_assert_eq!(output_len(&config, &info), want.len());
        let batches = split(&points, &sizes);
        let (start, got, end, p) = stream(config, info, &batches, true);
        prop_assert_eq!(start, ScanStart::Publish { points: want.len() });
        prop_assert_eq!(end, ScanEnd::Complete { points: want.len() });
        prop_assert_eq!(&got, &want);
        // Whole scan in one batch and one point at a time agree too.
        let (_, whole, _, _) = stream(config, info, &[&points], true);
        let singles: Vec<&[RawPoint]> = points.chunks(1).collect();
        let (_, single, _, _) = stream(config, info, &singles, true);
        prop_assert_eq!(&whole, &got);
        prop_assert_eq!(&single, &got);
        // Stats add up.
        let s = p.stats();
        prop_assert_eq!(s.points_in as usize, points.len());
        prop_assert_eq!(s.points_out as usize, got.len());
        prop_assert_eq!(
            s.points_out_invalid as usize,
            got.iter().filter(|p| p.range_mm.is_none()).count()
        );
        prop_assert_eq!(
            s.invalid_error_code as usize,
            points
                .iter()
                .filter(|p| !p.valid && config.roi.is_none_or(|w| w.contains(p.step)))
                .count()
        );
        prop_assert_eq!(s.points_ignored + s.sequence_errors + s.points_discarded, 0);
    }

    /// `output_len` is the number of points emitted, for any geometry and settings.
    #[test]
    fn output_len_counts_the_emitted_points(
        config in config_strategy(),
        (info, points) in scan_strategy(),
    ) {
        let (_, got, _, _) = stream(config, info, &[&points], true);
        prop_assert_eq!(output_len(&config, &info), got.len());
    }

    /// No range is ever made from an invalid input point: every output range is a measured
    /// distance of a valid input (the median and `Min` pick one, `Mean` stays between the
    /// smallest and largest) within the output point's group, widened by the median's
    /// reach; and without `Min`/`Mean` decimation, the output point's own input must be
    /// valid.
    #[test]
    fn no_range_from_invalid_inputs(
        config in config_strategy(),
        (info, points) in scan_strategy(),
    ) {
        let (_, got, _, _) = stream(config, info, &[&points], true);
        let roi: Vec<RawPoint> = points
            .iter()
            .copied()
            .filter(|p| config.roi.is_none_or(|w| w.contains(p.step)))
            .collect();
        let k = usize::from(config.decimation_factor());
        let reach = config.median.map_or(0, MedianWidth::half);
        for (g, out) in got.iter().enumerate() {
            let own = &roi[g * k];
            prop_assert_eq!(out.step, own.step);
            let Some(r) = out.range_mm else { continue };
            let lo = (g * k).saturating_sub(reach);
            let hi = ((g + 1) * k + reach).min(roi.len());
            let valid: Vec<u32> =
                roi[lo..hi].iter().filter(|p| p.valid).map(|p| p.distance).collect();
            prop_assert!(!valid.is_empty(), "range {} from no valid input", r);
            match config.decimation.map(|d| d.mode) {
                Some(DecimationMode::Mean) if k > 1 => {
                    prop_assert!(valid.iter().min().unwrap() <= &r);
                    prop_assert!(&r <= valid.iter().max().unwrap());
                }
                Some(DecimationMode::Min) if k > 1 => prop_assert!(valid.contains(&r)),
                _ => {
                    prop_assert!(own.valid, "range for an invalid point at {}", own.step);
                    prop_assert!(valid.contains(&r));
                }
            }
        }
    }

    /// A scan cut short or declared broken emits a prefix of what the intact scan emits
    /// (never a point the intact scan would not have), and never more than announced.
    #[test]
    fn incomplete_scans_emit_a_prefix(
        config in config_strategy(),
        (info, points) in scan_strategy(),
        cut in 0usize..80,
        intact in any::<bool>(),
    ) {
        let cut = cut.min(points.len());
        let (_, full, _, _) = stream(config, info, &[&points], true);
        let (_, part, end, p) = stream(config, info, &[&points[..cut]], intact);
        prop_assert!(part.len() <= full.len());
        prop_assert_eq!(&full[..part.len()], &part[..]);
        if cut == points.len() && intact {
            prop_assert_eq!(end, ScanEnd::Complete { points: full.len() });
        } else {
            let ScanEnd::Incomplete { points: n, .. } = end else {
                return Err(TestCaseError::fail("expected an incomplete end"));
            };
            prop_assert_eq!(n, part.len());
            prop_assert_eq!(p.stats().scans_incomplete, 1);
        }
    }

    /// Every n-th scan: exactly ceil(m / n) of m scans are published, the first included.
    #[test]
    fn every_nth_scan_publishes_ceil_m_over_n(n in 1u16..10, m in 0usize..50) {
        let config = PipelineConfig {
            temporal: TemporalDecimation::EveryNth(n),
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        let info = ScanInfo { seq: 0, timestamp_ms: 0, first_step: 0, last_step: 0, cluster: 1 };
        let published: Vec<usize> = (0..m)
            .filter(|_| matches!(p.begin_scan(info), ScanStart::Publish { .. }))
            .collect();
        prop_assert_eq!(published.len(), m.div_ceil(usize::from(n)));
        prop_assert!(published.iter().all(|i| i % usize::from(n) == 0));
    }

    /// Rate limit: consecutive published scans are at least 1000 / f ms apart, and a scan
    /// is skipped only when publishing it would break that (on a 24-bit wrapping clock).
    #[test]
    fn rate_limit_is_never_exceeded(
        millihertz in 1u32..100_000,
        start in 0u32..(1 << 24),
        gaps in prop::collection::vec(0u32..200, 1..60),
    ) {
        let config = PipelineConfig {
            temporal: TemporalDecimation::MaxRate { millihertz, timestamp_bits: 24 },
            ..PipelineConfig::default()
        };
        let mut p = Pipeline::new(config).unwrap();
        let mut now = u64::from(start);
        let mut last: Option<u64> = None;
        for gap in gaps {
            now += u64::from(gap);
            let info = ScanInfo {
                seq: 0,
                timestamp_ms: (now & 0xFF_FFFF) as u32,
                first_step: 0,
                last_step: 0,
                cluster: 1,
            };
            let published = matches!(p.begin_scan(info), ScanStart::Publish { .. });
            let due = last.is_none_or(|l| (now - l) * u64::from(millihertz) >= 1_000_000);
            prop_assert_eq!(published, due);
            if published {
                last = Some(now);
            }
        }
    }
}
