//! Decoder throughput on long streams: a real response repeated 1000 times, fed in
//! 64-byte chunks and as one slice. See BENCHMARKS.md at the repository root.

#[path = "support/streams.rs"]
mod streams;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use streams::Which;

/// Responses per stream.
const REPEATS: usize = 1000;

fn throughput(c: &mut Criterion) {
    let mut group = c.benchmark_group("decoder");
    for which in Which::ALL {
        let (stream, _, _) = streams::stream(which, REPEATS);
        // Sanity: every response decodes intact, so the numbers measure the happy path.
        let tally = streams::decode(&stream, 64);
        assert_eq!(tally.responses, REPEATS as u64, "{}", which.name());
        assert_eq!(tally.errors, 0, "{}", which.name());
        group.throughput(Throughput::Bytes(stream.len() as u64));
        for (label, chunk) in [("chunk64", 64), ("slice", usize::MAX)] {
            group.bench_with_input(
                BenchmarkId::new(which.name(), label),
                &chunk,
                |b, &chunk| b.iter(|| streams::decode(black_box(&stream), chunk)),
            );
        }
    }
    group.finish();
}

criterion_group!(benches, throughput);
criterion_main!(benches);
