#!/usr/bin/env python3
"""Worst-case stack use of a Cortex-M ELF, by static analysis of its disassembly.

    stack-usage.py ELF [--top N] [--boot REGEX]

Builds the call graph from `llvm-objdump -d` and each function's frame from its stack
instructions, then reports the deepest path from the reset handler and from each
interrupt handler, and the worst case: thread mode plus the deepest handler plus one
exception frame with floating-point context (104 bytes; the boards' handlers share one
priority, so they do not nest).

Conservative on purpose, so that the result is an upper bound:
- a function's frame is the sum of every stack decrement in it (`push`, `vpush`,
  `sub sp`, pre-indexed stores to sp), whatever path executes it;
- a direct call (`bl`) or tail call (`b.w` to a function's start) adds the callee;
- an indirect call (`blx rN`, `bx rN` other than `lr`) adds the deepest function whose
  address appears as a word in the image or is built by a `movw`/`movt` pair (vtables,
  task and waker pointers), vector table entries aside; embassy task polls count only
  as targets of the executor's own indirect calls (it alone calls them);
- recursion is reported and each cycle counted once.
A function that moves sp by a register amount is reported as unbounded.

`--boot REGEX` names functions that run once at start-up (the boards' `setup`); a second
figure leaves them out: the worst case once the tasks run.
"""

import argparse
import re
import shutil
import subprocess
import sys

TASK_POLL = re.compile(r"embassy_executor.*TaskStorage.*4poll")
EXECUTOR = re.compile(r"embassy_executor.*(Executor|SyncExecutor|run_queue)")
EXCEPTION_FRAME = 104  # 8 core registers + 18 FP registers (lazy stacking), aligned


def tool(name):
    path = shutil.which(name)
    if path:
        return path
    sysroot = subprocess.run(["rustc", "--print", "sysroot"], capture_output=True,
                             text=True, check=True).stdout.strip()
    host = re.search(r"host: (\S+)", subprocess.run(["rustc", "-vV"], capture_output=True,
                                                     text=True, check=True).stdout).group(1)
    candidate = f"{sysroot}/lib/rustlib/{host}/bin/{name}"
    if shutil.which(candidate):
        return candidate
    sys.exit(f"{name} not found (rustup component add llvm-tools)")


def reg_count(reglist):
    n = 0
    for part in reglist.split(","):
        part = part.strip()
        m = re.match(r"([a-z]+)(\d+)-[a-z]+(\d+)$", part)
        n += int(m.group(3)) - int(m.group(2)) + 1 if m else 1
    return n


def parse(elf):
    objdump = tool("llvm-objdump")
    dis = subprocess.run([objdump, "-d", "--no-show-raw-insn", elf], capture_output=True,
                         text=True, check=True).stdout
    funcs = {}  # start address -> dict
    cur = None
    for line in dis.splitlines():
        m = re.match(r"^([0-9a-f]+) <(.+)>:$", line)
        if m and not m.group(2).startswith("$"):  # $t/$d: mapping symbols, not functions
            cur = {"name": m.group(2), "frame": 0, "calls": set(), "indirect": False,
                   "unbounded": False, "branches": set(), "movw": {}, "consts": set()}
            funcs[int(m.group(1), 16)] = cur
            continue
        m = re.match(r"^\s*([0-9a-f]+):\s+(\S+)\s*(.*)$", line)
        if not m or cur is None:
            continue
        op, args = m.group(2), m.group(3)
        base = op.split(".")[0]
        if base == "push":
            cur["frame"] += 4 * reg_count(args.strip("{} "))
        elif base == "vpush":
            regs = args.strip("{} ")
            cur["frame"] += (8 if regs.startswith("d") else 4) * reg_count(regs)
        elif base in ("sub", "subw") and re.match(r"sp,\s*(sp,\s*)?#", args):
            cur["frame"] += int(re.search(r"#(0x[0-9a-f]+|\d+)", args).group(1), 0)
        elif base in ("sub", "subw") and re.match(r"sp,\s*(sp,\s*)?r", args):
            cur["unbounded"] = True
        elif base == "mov" and re.match(r"sp,\s*r", args):
            pass  # restoring sp from a frame pointer
        elif base in ("str", "strd", "vstr") and re.search(r"\[sp, #-(\d+)\]!", args):
            cur["frame"] += int(re.search(r"\[sp, #-(\d+)\]!", args).group(1))
        elif base == "bl":
            t = re.match(r"(0x)?([0-9a-f]+)", args)
            if t:
                cur["calls"].add(int(t.group(2), 16))
        elif base == "b" or op in ("b.w",):
            t = re.match(r"(0x)?([0-9a-f]+)", args)
            if t:
                cur["branches"].add(int(t.group(2), 16))
        elif base == "movw":
            t = re.match(r"(r\d+|lr|ip),\s*#(0x[0-9a-f]+|\d+)", args)
            if t:
                cur["movw"][t.group(1)] = int(t.group(2), 0)
        elif base == "movt":
            t = re.match(r"(r\d+|lr|ip),\s*#(0x[0-9a-f]+|\d+)", args)
            if t and t.group(1) in cur["movw"]:
                cur["consts"].add((int(t.group(2), 0) << 16) | cur["movw"].pop(t.group(1)))
        elif base == "blx" and args.startswith("r"):
            cur["indirect"] = True
        elif base == "bx" and args.strip() != "lr":
            cur["indirect"] = True
    for f in funcs.values():
        # A branch to another function's start is a tail call.
        f["calls"] |= {t for t in f["branches"] if t in funcs}
    return funcs


def address_taken(elf, funcs):
    """Functions whose address is a word of the image or built by a movw/movt pair."""
    objdump = tool("llvm-objdump")
    dump = subprocess.run([objdump, "-s", "-j", ".text", "-j", ".rodata", "-j", ".data", elf],
                          capture_output=True, text=True, check=True).stdout
    words = set()
    for line in dump.splitlines():
        m = re.match(r"^\s*([0-9a-f]{4,})\s+((?:[0-9a-f]{1,8}\s){1,4})", line)
        if not m:
            continue
        for w in m.group(2).split():
            if len(w) == 8:
                words.add(int.from_bytes(bytes.fromhex(w), "little"))
    for f in funcs.values():
        words |= f["consts"]
    return {a for a in funcs if (a | 1) in words}


def vector_table(elf, funcs):
    objdump = tool("llvm-objdump")
    dump = subprocess.run([objdump, "-s", "-j", ".vector_table", elf], capture_output=True,
                          text=True, check=True).stdout
    entries = []
    for line in dump.splitlines():
        m = re.match(r"^\s*([0-9a-f]{4,})\s+((?:[0-9a-f]{1,8}\s){1,4})", line)
        if m:
            entries += [int.from_bytes(bytes.fromhex(w), "little")
                        for w in m.group(2).split() if len(w) == 8]
    # Word 0 is the initial stack pointer, word 1 the reset vector, then the exceptions
    # and interrupts.
    handlers = [e & ~1 for e in entries[1:] if (e & ~1) in funcs]
    return handlers[0], sorted(set(handlers[1:]))


def analyse(funcs, taken, vectors, excluded=frozenset()):
    memo, cycles = {}, []
    # Task polls are reached only through the executor's run queue; every other indirect
    # call (vtables: fmt, wakers, defmt) may reach any other address-taken function.
    polls = {a for a in taken if TASK_POLL.search(funcs[a]["name"])}
    general = sorted(taken - polls - set(vectors))

    def depth(a, stack):
        if a in memo:
            return memo[a]
        if a in stack:
            cycles.append([funcs[x]["name"] for x in stack[stack.index(a):]])
            return 0, [funcs[a]["name"] + " (recursion)"]
        f = funcs[a]
        best, path = 0, []
        callees = set(f["calls"])
        if f["indirect"]:
            callees |= set(general)
            if EXECUTOR.search(f["name"]):
                callees |= polls
        for c in callees:
            if c == a or c not in funcs or c in excluded:
                continue
            d, p = depth(c, stack + [a])
            if d > best:
                best, path = d, p
        result = (f["frame"] + best, [f"{f['name']} [{f['frame']}]"] + path)
        memo[a] = result
        return result

    sys.setrecursionlimit(100000)
    return depth, cycles


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("elf")
    ap.add_argument("--top", type=int, default=12, help="frames of the deepest path shown")
    ap.add_argument("--boot", help="regex of functions that run only at start-up")
    args = ap.parse_args()

    funcs = parse(args.elf)
    taken = address_taken(args.elf, funcs)
    reset, handlers = vector_table(args.elf, funcs)
    vectors = [reset] + handlers

    def worst(excluded=frozenset()):
        depth, cycles = analyse(funcs, taken, vectors, excluded)
        thread, thread_path = depth(reset, [])
        isr, isr_path = 0, []
        for h in handlers:
            d, p = depth(h, [])
            if d > isr:
                isr, isr_path = d, p
        return thread, thread_path, isr, isr_path, cycles

    thread, thread_path, worst_isr, isr_path, cycles = worst()
    unbounded = sorted(f["name"] for f in funcs.values() if f["unbounded"])

    total = thread + worst_isr + EXCEPTION_FRAME
    print(f"thread mode (reset handler): {thread} bytes")
    for step in thread_path[:args.top]:
        print(f"    {step}")
    print(f"deepest interrupt handler: {worst_isr} bytes (+ {EXCEPTION_FRAME} exception frame)")
    for step in isr_path[:args.top]:
        print(f"    {step}")
    print(f"worst case: {total} bytes")
    print(f"indirect-call targets assumed: {len(taken - set([reset] + handlers))}; "
          f"recursion cycles: {len(cycles)}; unbounded frames: {len(unbounded)}")
    for name in unbounded:
        print(f"    unbounded: {name}")
    if args.boot:
        boot = re.compile(args.boot)
        excluded = frozenset(a for a, f in funcs.items() if boot.search(f["name"]))
        run_thread, run_path, run_isr, _, _ = worst(excluded)
        print(f"after start-up (without {len(excluded)} functions matching {args.boot!r}): "
              f"thread {run_thread} + handler {run_isr} + {EXCEPTION_FRAME} = "
              f"{run_thread + run_isr + EXCEPTION_FRAME} bytes")
        for step in run_path[:args.top]:
            print(f"    {step}")
    print(f"STACK {total}")


if __name__ == "__main__":
    main()
