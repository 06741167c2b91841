#!/usr/bin/env bash
# Seeds the fuzz corpora from the real captures in ../shared/recordings (relative to
# the repository root; pass another folder as $1). The corpora are not committed.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
rec="${1:-$here/../../../shared/recordings}"
if [ ! -d "$rec" ]; then
    echo "seed.sh: no recordings folder at $rec" >&2
    exit 1
fi
mkdir -p "$here/corpus/decoder" "$here/corpus/echo"
# The decoder target reads its first byte as the chunking selector: one seed with
# fixed 64-byte chunks (0x3f) and one with varying chunks (0xa5) per capture.
n=0
for f in "$rec"/*.scip; do
    b="$(basename "$f" .scip)"
    { printf '\x3f'; cat "$f"; } > "$here/corpus/decoder/$b.fixed64"
    { printf '\xa5'; cat "$f"; } > "$here/corpus/decoder/$b.varying"
    n=$((n + 2))
done
# Echo seeds: every line the host sent, and every echo line of the responses
# (the first line after an empty line), one file per line.
for f in "$rec"/*.scip; do
    awk 'BEGIN { first = 1 } { if (first && length($0) > 0) print $0; first = (length($0) == 0) }' "$f"
done | sort -u | while IFS= read -r line; do
    printf '%s' "$line" > "$here/corpus/echo/$(printf '%s' "$line" | cksum | cut -d' ' -f1)"
done
m=$(ls "$here/corpus/echo" | wc -l)
echo "seeded $n decoder inputs and $m echo lines"
