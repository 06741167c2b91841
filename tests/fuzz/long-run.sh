#!/usr/bin/env bash
# The long fuzzing runs recorded in BENCHMARKS.md ("Fuzzing at scale"): each target for
# SECONDS (default 3600) on its own corpus (kept between runs, so runs add up), one after
# the other, at the lowest CPU priority, with libFuzzer's final statistics appended to
# runs.log (one line per run: date, target, executions, time, coverage, corpus).
#   ./long-run.sh [SECONDS] [TARGET...]      (default: every decoder target)
# SANITIZER (default none) is cargo fuzz's --sanitizer: the fuzzed crates forbid unsafe code,
# so AddressSanitizer finds nothing their bounds checks do not, and costs 3-4x the executions
# (decoder_small about 8 000 inputs/s with it, 30 000 without). Builds for each sanitizer
# go to their own target directory, so they do not rebuild the CI smoke run's.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
cd "$here"
secs="${1:-3600}"
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(decoder_small can_frames control slcan)
max_len() {
    case "$1" in
        decoder_small) echo 256 ;;
        decoder) echo 8192 ;;
        can_frames) echo 1024 ;;
        *) echo 512 ;;
    esac
}
[ -d corpus/decoder ] || ./seed.sh
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    if [ "$t" = decoder_small ] && [ -z "$(ls -A corpus/decoder_small)" ]; then
        cp corpus/decoder/* corpus/decoder_small/
    fi
    out="$(mktemp)"
    san="${SANITIZER:-none}"
    nice -n 19 cargo +nightly fuzz run -O -s "$san" --target-dir "target/san-$san" "$t" "corpus/$t" -- \
        -max_total_time="$secs" -max_len="$(max_len "$t")" -print_final_stats=1 \
        >"$out" 2>&1 || { tail -30 "$out" >&2; exit 1; }
    runs=$(awk '/stat::number_of_executed_units/ {print $NF}' "$out")
    cov=$(grep -o 'cov: [0-9]*' "$out" | tail -1 | cut -d' ' -f2)
    corp=$(grep -o 'corp: [0-9]*/[0-9]*[a-zA-Z]*' "$out" | tail -1 | cut -d' ' -f2)
    printf '%s %s runs=%s seconds=%s cov=%s corpus=%s crashes=0 sanitizer=%s\n' \
        "$(date -u +%Y-%m-%dT%H:%M)" "$t" "$runs" "$secs" "$cov" "$corp" "$san" | tee -a runs.log
    rm -f "$out"
done
