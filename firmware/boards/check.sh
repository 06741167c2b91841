#!/usr/bin/env bash
# Checks of the board workspace, for people and CI alike:
#   format, clippy (-D warnings), release build of every board, board-common's host
#   tests, STM32 sizes against their budget (stm32-sizes.sh), and, with qemu-system-arm,
#   the QEMU board: it must boot and print its banner, and every sensor recording fed
#   into its UART0 must give exactly the golden output in qemu-mps2/expected/.
# BLESS=1 rewrites the golden files. Under CI=true a missing qemu-system-arm or a
# missing recordings folder fails; otherwise those steps are skipped with a note.
set -euo pipefail
cd "$(dirname "$0")"

ci=${CI:-false}
skip_or_fail() {
    if [ "$ci" = true ]; then
        echo "FAIL: $1" >&2
        exit 1
    fi
    echo "skipped: $1"
}

cargo fmt -p scip2can-qemu -p board-common -p stm32g474 -p stm32f446 -p stm32h723 -- --check
# One cargo invocation per board binary: features are unified across the packages of
# one build, and the STM32 chips are features of the same embassy-stm32 (which
# also turns on cortex-m-rt's `device` feature, wrong for the QEMU board).
for board in scip2can-qemu stm32g474 stm32f446 stm32h723; do
    cargo clippy --release -p "$board" --all-targets -- -D warnings
    cargo build --release -p "$board"
done
# The lockstep co-simulation binary (needs the clock model: tests/it/qemu_time_estimate.rs).
cargo clippy --release -p scip2can-qemu --features time-estimate --bin scip2can-qemu-cosim \
    -- -D warnings
# board-common's tests (unit tests, and the main loop on a simulated board) run on the host.
host=$(rustc -vV | sed -n 's/^host: //p')
cargo clippy -p board-common --all-targets --target "$host" -- -D warnings
cargo test -p board-common --target "$host"
# STM32 flash, RAM and stack bound against the budget and sizes.txt.
./stm32-sizes.sh

target_dir=${CARGO_TARGET_DIR:-target}
elf=$target_dir/thumbv7em-none-eabihf/release/scip2can-qemu-decode
bridge_elf=$target_dir/thumbv7em-none-eabihf/release/scip2can-qemu

size_tool=$(command -v llvm-size || command -v rust-size || command -v arm-none-eabi-size || true)
if [ -n "$size_tool" ]; then
    "$size_tool" "$bridge_elf" "$elf"
else
    echo "no llvm-size / rust-size / arm-none-eabi-size: size not shown"
fi

if ! command -v qemu-system-arm > /dev/null; then
    skip_or_fail "qemu-system-arm not installed (apt-get install qemu-system-arm)"
    exit 0
fi

# Boot: the banner must appear on UART0 (stdio); the EOT behind it ends the run.
boot=$(printf '\004' | timeout 30 qemu-system-arm -machine mps2-an386 -display none \
    -no-reboot -serial stdio -serial null -kernel "$elf" | tr -d '\r')
case "$boot" in
    scip2can-qemu*) echo "boot ok: $boot" ;;
    *) echo "FAIL: no banner on UART0 (got: $boot)" >&2; exit 1 ;;
esac

# The bridge boots and its CAN port answers SLCAN: V and N on UART1 (stdio), sensor
# port unconnected. It runs until killed, so `timeout` ends it.
slcan=$( (printf 'V\rN\r'; sleep 2) | timeout 5 qemu-system-arm -machine mps2-an386 \
    -display none -no-reboot -serial null -serial stdio -kernel "$bridge_elf" | tr '\r' ' ' || true)
case "$slcan" in
    "V0100 NQEMU "*) echo "bridge boot ok: SLCAN answers $slcan" ;;
    *) echo "FAIL: the bridge's SLCAN port did not answer V and N (got: $slcan)" >&2; exit 1 ;;
esac

recordings=../../../shared/recordings
if [ ! -d "$recordings" ]; then
    skip_or_fail "recordings folder ../shared/recordings (from the repo root) is missing"
    exit 0
fi

mkdir -p qemu-mps2/expected
passed=0
failed=0
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for rec in "$recordings"/*.scip; do
    name=$(basename "$rec" .scip)
    case "$name" in *.tx) continue ;; esac # host-to-sensor commands, not a reply stream
    # UART0 <- the recording + EOT; UART1 -> file. uptime_ms varies from run to run.
    (cat "$rec"; printf '\004') | timeout 60 qemu-system-arm -machine mps2-an386 \
        -display none -no-reboot -serial stdio -serial "file:$tmp/uart1" \
        -kernel "$elf" > /dev/null
    tr -d '\r' < "$tmp/uart1" | sed 's/ uptime_ms=[0-9]*$//' > "$tmp/$name.out"
    golden=qemu-mps2/expected/$name.out
    if [ "${BLESS:-0}" = 1 ]; then
        cp "$tmp/$name.out" "$golden"
        echo "blessed $golden"
    elif diff -u "$golden" "$tmp/$name.out"; then
        passed=$((passed + 1))
    else
        echo "FAIL: $name differs from $golden" >&2
        failed=$((failed + 1))
    fi
done
echo "qemu-mps2: $passed passed, $failed failed"
[ "$failed" = 0 ]
