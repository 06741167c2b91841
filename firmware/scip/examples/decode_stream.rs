//! Decodes a long SCIP stream N times, for instruction counts under callgrind.
//!
//! `decode_stream <gd|me> <repeats> <N> [chunk]` builds one real response repeated
//! `repeats` times (see `benches/support/streams.rs`), then decodes it N times with a
//! fresh decoder, `chunk` bytes per `feed` (default 64; 0 = the whole stream as one
//! slice). Run it under `valgrind --tool=callgrind` with N and 2N: the difference over
//! N × stream length is the decoder's instructions per input byte, start-up excluded.
//! See BENCHMARKS.md at the repository root.

#[path = "../benches/support/streams.rs"]
mod streams;

use std::hint::black_box;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: decode_stream <gd|me> <repeats> <N> [chunk, 0 = one slice]";
    let (Some(which), Some(repeats), Some(n)) = (
        args.first().and_then(|s| streams::Which::from_name(s)),
        args.get(1).and_then(|s| s.parse::<usize>().ok()),
        args.get(2).and_then(|s| s.parse::<usize>().ok()),
    ) else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let chunk = match args.get(3).map(|s| s.parse::<usize>()) {
        None => 64,
        Some(Ok(0)) => usize::MAX,
        Some(Ok(c)) => c,
        Some(Err(_)) => {
            eprintln!("{usage}");
            std::process::exit(2);
        }
    };
    let (stream, one, real) = streams::stream(which, repeats);
    let mut last = streams::Tally::default();
    for _ in 0..n {
        last = streams::decode(black_box(&stream), black_box(chunk));
    }
    println!(
        "{} x{} ({} bytes, response {} bytes, {}): {} decodes, last: {:?}",
        which.name(),
        repeats,
        stream.len(),
        one,
        if real { "recorded" } else { "written" },
        n,
        last
    );
    // A stream the decoder finds damaged measures its error paths, not decoding.
    if last.errors != 0 || last.responses != repeats as u64 {
        eprintln!("decode_stream: the stream did not decode intact: {last:?}");
        std::process::exit(1);
    }
}
