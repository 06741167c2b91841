//! Cost of the scan pipeline per scan of a UTM-30LX (1081 points), fed one SCIP data
//! line (21 points) at a time: every stage off, the worst case (every stage on, median of
//! 5, mean of 3), and a typical robot setting.
//!
//! `cargo bench -p bridge --bench pipeline`

use std::hint::black_box;

use bridge::pipeline::{
    Decimation, DecimationMode, MedianWidth, Pipeline, PipelineConfig, Point, RangeWindow,
    RawPoint, ScanInfo, SpeckleFilter, StepWindow, TemporalDecimation,
};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};

const STEPS: u16 = 1081;

/// A deterministic scan: walls with noise, spikes and error codes (no RNG crate needed).
fn scan() -> Vec<RawPoint> {
    let mut x: u32 = 0x2545_F491;
    (0..STEPS)
        .map(|step| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let valid = x % 10 != 0;
            let wall = 1500 + u32::from(step % 200) * 10;
            RawPoint {
                step,
                distance: if valid { wall + x % 40 } else { x % 20 },
                intensity: Some(1000 + x % 3000),
                valid,
            }
        })
        .collect()
}

fn info() -> ScanInfo {
    ScanInfo {
        seq: 0,
        timestamp_ms: 0,
        first_step: 0,
        last_step: STEPS - 1,
        cluster: 1,
    }
}

fn run(p: &mut Pipeline, points: &[RawPoint]) -> u32 {
    let mut sum = 0u32;
    let mut sink = |x: Point| sum = sum.wrapping_add(x.range_mm.unwrap_or(1));
    p.begin_scan(info());
    for line in points.chunks(21) {
        p.push_batch(black_box(line), &mut sink);
    }
    p.end_scan(true, &mut sink);
    sum
}

fn bench(c: &mut Criterion) {
    let points = scan();
    let all_on = PipelineConfig {
        roi: Some(StepWindow {
            first: 0,
            last: STEPS - 1,
        }),
        range_window: Some(RangeWindow {
            min_mm: 23,
            max_mm: 30_000,
        }),
        min_intensity: Some(1100),
        speckle: Some(SpeckleFilter { max_jump_mm: 50 }),
        median: Some(MedianWidth::Five),
        decimation: Some(Decimation {
            factor: 3,
            mode: DecimationMode::Mean,
        }),
        temporal: TemporalDecimation::All,
    };
    let typical = PipelineConfig {
        roi: Some(StepWindow {
            first: 180,
            last: 900,
        }),
        median: Some(MedianWidth::Three),
        decimation: Some(Decimation {
            factor: 2,
            mode: DecimationMode::Min,
        }),
        ..all_on
    };
    let mut group = c.benchmark_group("pipeline_1081_points");
    group.throughput(Throughput::Elements(u64::from(STEPS)));
    for (name, config) in [
        ("all_off", PipelineConfig::default()),
        ("all_on_median5_mean3", all_on),
        ("typical_roi_median3_min2", typical),
    ] {
        let mut p = Pipeline::new(config).expect("valid config");
        group.bench_function(name, |b| b.iter(|| run(&mut p, &points)));
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
