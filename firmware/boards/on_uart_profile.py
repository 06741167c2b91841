#!/usr/bin/env python3
"""Where `Bridge::on_uart` spends its instructions on the emulated Cortex-M4, by function.

    target/release/scip2can icount --model urg04lx --scans 3 --save-input /tmp/in.bin
    python3 firmware/boards/on_uart_profile.py \
        firmware/boards/target/thumbv7em-none-eabihf/release/scip2can-qemu-bench /tmp/in.bin

Runs the bench firmware (the ELF that `scip2can icount` measured, so the same encoding)
under `qemu-system-arm -singlestep -d exec,nochain` on the bytes `icount --save-input`
wrote (control frames, then the stream), and counts every instruction executed inside
`Bridge::on_uart` (inlined into the bench's `measure`) and the calls it makes, the
SysTick handler excluded. Each address is resolved with its inlined frames
(`llvm-symbolizer --inlining`): "inclusive" counts an instruction for every function on
its inline stack, "exclusive" for the innermost one only. Functions that are called, not
inlined, appear as themselves (their callers' inclusive counts do not hold them).

With `ANNOTATE=NAME` in the environment it also prints the disassembly of every
function whose symbol contains NAME, each instruction with the times it ran (the exact
counts to judge a loop's shape by: code layout moves `icount` by a few tenths per byte).

The total is the one `scip2can icount` reports (instructions per UART byte times the
stream's bytes) to within the SysTick handler's share. Traces are about 80 bytes per
instruction: keep streams to a few scans. Needs qemu-system-arm and llvm-symbolizer.
"""
import collections
import os
import re
import subprocess
import sys
import tempfile


def short(name):
    name = re.sub(r"::h[0-9a-f]{16}$", "", name)
    for _ in range(3):
        name = re.sub(r"<[^<>]*>", "", name)
    return name


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    elf, stream = sys.argv[1], sys.argv[2]
    top = int(sys.argv[3]) if len(sys.argv) > 3 else 45
    data = open(stream, "rb").read() + b"\x04"
    nm = subprocess.run(["llvm-nm", "-S", elf], capture_output=True, text=True, check=True)
    lo = hi = None
    for line in nm.stdout.splitlines():
        parts = line.split()
        if len(parts) == 4 and "bench7measure" in parts[3]:
            lo = int(parts[0], 16)
            hi = lo + int(parts[1], 16)
    if lo is None:
        sys.exit(f"{elf}: no bench::measure symbol (not the bench firmware?)")
    fd, trace = tempfile.mkstemp(suffix=".trace")
    os.close(fd)
    try:
        subprocess.run(
            ["qemu-system-arm", "-machine", "mps2-an386", "-icount", "shift=0",
             "-display", "none", "-no-reboot", "-serial", "stdio", "-serial", "file:/dev/null",
             "-kernel", elf, "-singlestep", "-d", "exec,nochain", "-D", trace],
            input=data, capture_output=True, timeout=3000, check=False)
        rx = re.compile(rb"Trace \d+: \w+ \[\w+/([0-9a-f]+)/")
        seq = []
        with open(trace, "rb") as f:
            for line in f:
                m = rx.match(line)
                if m:
                    seq.append(int(m.group(1), 16))
    finally:
        os.unlink(trace)
    pcs = sorted(set(seq))
    sym = subprocess.run(
        ["llvm-symbolizer", "--inlining", "--functions=linkage", "--demangle", "-e", elf],
        input="\n".join(hex(a) for a in pcs) + "\n", capture_output=True, text=True,
        check=True).stdout
    frames_of = {}
    for a, block in zip(pcs, sym.strip("\n").split("\n\n")):
        lines = block.split("\n")
        frames_of[a] = [short(lines[i]) for i in range(0, len(lines), 2)]
    # Inside on_uart: the last instruction executed in `measure` was on_uart's (inlined)
    # code; everything it calls until control comes back to `measure` counts too.
    inside = False
    counts = collections.Counter()
    for a in seq:
        frames = frames_of[a]
        if lo <= a < hi:
            inside = any("on_uart" in f for f in frames)
            if inside:
                counts[a] += 1
        elif inside and not any("DefaultHandler" in f or "SysTick" in f for f in frames):
            counts[a] += 1
    inclusive, exclusive, total = collections.Counter(), collections.Counter(), 0
    for a, c in counts.items():
        frames = frames_of[a]
        total += c
        exclusive[frames[0]] += c
        for f in set(frames):
            inclusive[f] += c
    n = len(data) - 1
    print(f"on_uart: {total} instructions, {n} input bytes ({total / max(n, 1):.2f} per byte)")
    for title, table in (("inclusive", inclusive), ("exclusive", exclusive)):
        print(f"--- {title}")
        for f, c in table.most_common(top):
            print(f"{c:>10} {100 * c / max(total, 1):5.1f}%  {f}")
    if os.environ.get("ANNOTATE"):
        annotate(elf, os.environ["ANNOTATE"], counts)


def annotate(elf, name, counts):
    """The disassembly of the functions whose symbol holds `name`, with each
    instruction's count."""
    dis = subprocess.run(["llvm-objdump", "-d", "--no-show-raw-insn", "-C", elf],
                         capture_output=True, text=True, check=True).stdout
    on = False
    for line in dis.splitlines():
        if line.endswith(">:"):
            # ARM mapping symbols (`<$t>`, `<$d.1>`: code and literal pools inside a
            # function) do not end it.
            if "<$" in line:
                continue
            on = name in line
            if on:
                print(f"--- {line}")
            continue
        if on and ":" in line:
            try:
                a = int(line.split(":")[0].strip(), 16)
            except ValueError:
                continue
            print(f"{counts.get(a, 0):>8} {line.strip()}")


if __name__ == "__main__":
    main()
