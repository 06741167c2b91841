//! Puts this board's `memory.x` on the linker search path, where cortex-m-rt's
//! `link.x` includes it: the UART binaries get `memory.x`, the benchmarks the same with
//! 64 KiB of RAM (a bridge built on the stack), the Ethernet binary `memory-eth.x`
//! (each binary its own search folder).

use std::{env, fs, path::PathBuf};

/// The UART binaries' RAM line in `memory.x`.
const UART_RAM: &str = "RAM   : ORIGIN = 0x20000000, LENGTH = 24K";

/// The benchmarks' RAM: the bench builds the bridge on its stack (no static, unlike the
/// boards' `shared_bridge`), which with the time sync, the link seam and the clock
/// model's state no longer fits 24 KiB. It counts instructions; the RAM budget is
/// checked on the STM32 boards (`stm32-sizes.sh`) and by the QEMU bridge binary, which
/// keeps 24 KiB.
const BENCH_RAM: &str = "RAM   : ORIGIN = 0x20000000, LENGTH = 64K";

fn main() {
    let uart = include_str!("memory.x");
    assert!(uart.contains(UART_RAM), "memory.x: no `{UART_RAM}` line");
    let bench = uart.replace(UART_RAM, BENCH_RAM);
    let eth = include_str!("memory-eth.x");
    // The binaries and their memory layouts.
    let layouts = [
        ("scip2can-qemu", uart),
        ("scip2can-qemu-decode", uart),
        ("scip2can-qemu-bench", bench.as_str()),
        ("scip2can-qemu-bench-d16", bench.as_str()),
        ("scip2can-qemu-cosim", bench.as_str()),
        ("scip2can-qemu-eth", eth),
    ];
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    for (bin, layout) in layouts {
        let dir = out.join(bin);
        fs::create_dir_all(&dir).expect("create the layout folder");
        fs::write(dir.join("memory.x"), layout).expect("write memory.x");
        println!("cargo:rustc-link-arg-bin={bin}=-L{}", dir.display());
    }
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-eth.x");
    println!("cargo:rerun-if-changed=build.rs");
}
