#!/usr/bin/env bash
# Flash, static RAM and worst-case stack of the STM32 board binaries, measured from
# their release ELFs (build them first: check.sh does) and compared with sizes.txt:
#   flash = .vector_table + .text + .rodata + .data   (the image written to flash)
#   ram   = .data + .bss + .uninit + the stack reservation
#   stack = stack-usage.py's worst case (boot included), and once the tasks run
# Fails when a binary is over its budget (the CAN-only boards: flash 96 KiB, RAM 24 KiB,
# 14 KiB of it the stack, board-common/budget.x; the Ethernet board NUCLEO-H723ZG: flash
# 256 KiB, RAM 128 KiB, 32 KiB of it the stack, stm32h723/budget.x; the linker enforces
# the same), when the worst-case stack exceeds the reservation, or when flash or RAM grew
# by more than 10 % over sizes.txt.
# BLESS=1 rewrites sizes.txt. Under CI=true a missing llvm-size or llvm-objdump fails.
set -euo pipefail
cd "$(dirname "$0")"

binaries="scip2can-stm32g474 scip2can-stm32f446 scip2can-stm32h723"
# "flash ram stack-reservation" of a binary, bytes: its budget.x.
budget() {
    case "$1" in
        scip2can-stm32h723) echo $((256 * 1024)) $((128 * 1024)) $((32 * 1024)) ;;
        *) echo $((96 * 1024)) $((24 * 1024)) $((14 * 1024)) ;;
    esac
}
target_dir=${CARGO_TARGET_DIR:-target}
release=$target_dir/thumbv7em-none-eabihf/release

size_tool=$(command -v llvm-size || command -v rust-size || true)
objdump_tool=$(command -v llvm-objdump || command -v rust-objdump || true)
if [ -z "$size_tool" ]; then
    # The llvm-tools rustup component ships one.
    rustup component add llvm-tools > /dev/null 2>&1 || true
    candidate=$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-size
    [ -x "$candidate" ] && size_tool=$candidate
fi
if [ -n "$size_tool" ] && [ -z "$objdump_tool" ]; then
    # stack-usage.py finds the component's llvm-objdump itself when it is not on PATH.
    rustup component add llvm-tools > /dev/null 2>&1 || true
fi
if [ -z "$size_tool" ]; then
    if [ "${CI:-false}" = true ]; then
        echo "FAIL: no llvm-size (rustup component add llvm-tools)" >&2
        exit 1
    fi
    echo "skipped: STM32 sizes (no llvm-size; rustup component add llvm-tools)"
    exit 0
fi

# "name flash ram text data bss stack stack_run" for one ELF (llvm-size -A: section,
# size, address; stack-usage.py's last line is "STACK <bytes>").
measure() {
    local stack run reserve
    read -r _ _ reserve <<< "$(budget "$1")"
    if ! python3 stack-usage.py "$release/$1" --boot '(^|[^a-z])(setup|shared_bridge)' > "$tmp/$1.stack"; then
        echo "FAIL: stack-usage.py on $1" >&2
        exit 1
    fi
    stack=$(sed -n 's/^STACK //p' "$tmp/$1.stack")
    run=$(sed -n 's/^after start-up.* = \([0-9]*\) bytes$/\1/p' "$tmp/$1.stack")
    "$size_tool" -A "$release/$1" | awk -v name="$1" -v reserve="$reserve" \
        -v stack="$stack" -v run="$run" '
        $1 == ".vector_table" || $1 == ".text" || $1 == ".rodata" { text += $2 }
        $1 == ".data" { data += $2 }
        $1 == ".bss" || $1 == ".uninit" { bss += $2 }
        END { printf "%-20s %7d %7d %7d %7d %7d %7d %7d\n", name, text + data,
              data + bss + reserve, text, data, bss, stack, run }'
}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

header="# Flash, static RAM and worst-case stack of the STM32 board binaries (release), bytes,
# from the ELF: flash = .vector_table + .text + .rodata + .data;
# ram = .data + .bss + .uninit + the stack reservation of the board's budget.x;
# stack = stack-usage.py's bound at boot (must fit the reservation), run = once the tasks run.
# Budget (flash, ram, stack reservation): G474 and F446 $(budget g474 | tr ' ' '/'),
# H723 (Ethernet) $(budget scip2can-stm32h723 | tr ' ' '/'). Reproduce: ./check.sh (or build,
# then ./stm32-sizes.sh); BLESS=1 rewrites this file.
# binary               flash     ram    text    data     bss   stack     run"

measured=$(for b in $binaries; do measure "$b"; done)
echo "$header"
echo "$measured"

failed=0
while read -r name flash ram _ _ _ stack _; do
    read -r flash_budget ram_budget stack_reserve <<< "$(budget "$name")"
    if [ "$flash" -gt "$flash_budget" ] || [ "$ram" -gt "$ram_budget" ]; then
        echo "FAIL: $name is over budget (flash $flash > $flash_budget or ram $ram > $ram_budget)" >&2
        failed=1
    fi
    if [ -z "$stack" ] || [ "$stack" -gt "$stack_reserve" ]; then
        echo "FAIL: $name worst-case stack '$stack' exceeds the $stack_reserve-byte reservation" >&2
        sed 's/^/    /' "$tmp/$name.stack" >&2
        failed=1
    fi
    recorded=$(awk -v n="$name" '$1 == n { print $2, $3 }' sizes.txt 2> /dev/null || true)
    if [ -z "$recorded" ]; then
        echo "note: $name not in sizes.txt"
        continue
    fi
    read -r old_flash old_ram <<< "$recorded"
    if [ "$flash" != "$old_flash" ] || [ "$ram" != "$old_ram" ]; then
        echo "note: $name was flash $old_flash ram $old_ram in sizes.txt"
    fi
    if [ "${BLESS:-0}" != 1 ] &&
        { [ $((flash * 10)) -gt $((old_flash * 11)) ] || [ $((ram * 10)) -gt $((old_ram * 11)) ]; }; then
        echo "FAIL: $name grew by more than 10 % over sizes.txt (BLESS=1 to accept)" >&2
        failed=1
    fi
done <<< "$measured"

if [ "${BLESS:-0}" = 1 ]; then
    printf '%s\n%s\n' "$header" "$measured" > sizes.txt
    echo "blessed sizes.txt"
fi
exit "$failed"
