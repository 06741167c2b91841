#!/usr/bin/env bash
# Instructions per input byte of the SCIP decoder, counted by callgrind.
#
# Decodes a long stream (one recorded response repeated REPEATS times) N and 2N times
# with the `decode_stream` example and reports (Ir(2N) - Ir(N)) / (N x stream bytes):
# the instructions per input byte of decoding, start-up excluded, the example's small
# consumer loop (feed calls, event match, sum of distances) included. `Decoder::feed`
# is inlined into that loop, so the two cannot be told apart by function.
# Usage: firmware/scip/benches/callgrind.sh [REPEATS] [N]   (defaults 100, 1)
set -euo pipefail
cd "$(dirname "$0")/.."
repeats="${1:-100}"
n="${2:-1}"
target="${CARGO_TARGET_DIR:-$(cargo metadata --format-version 1 --no-deps | sed -n 's/.*"target_directory":"\([^"]*\)".*/\1/p')}"
cargo build --quiet --release --example decode_stream
bin="$target/release/examples/decode_stream"
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
printf '%-4s %-8s %10s %12s\n' stream feeding bytes Ir/byte
for which in gd me; do
    for chunk in 64 0; do
        label=$([ "$chunk" = 0 ] && echo slice || echo "chunk$chunk")
        for k in "$n" "$((2 * n))"; do
            valgrind --tool=callgrind --callgrind-out-file="$out/$which.$chunk.$k" \
                "$bin" "$which" "$repeats" "$k" "$chunk" > "$out/$which.$chunk.$k.txt" 2> "$out/err" \
                || { cat "$out/err" >&2; exit 1; }
        done
        bytes=$(sed -n 's/.*(\([0-9]*\) bytes,.*/\1/p' "$out/$which.$chunk.$n.txt")
        total() { callgrind_annotate "$1" | sed -n 's/^ *\([0-9,]*\) .*PROGRAM TOTALS.*/\1/p' | tr -d ,; }
        t1=$(total "$out/$which.$chunk.$n")
        t2=$(total "$out/$which.$chunk.$((2 * n))")
        printf '%-4s %-8s %10s %12.2f\n' "$which" "$label" "$bytes" \
            "$(echo "($t2 - $t1) / ($n * $bytes)" | bc -l)"
    done
done
