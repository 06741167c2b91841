//! Puts this board's `memory.x` on the linker search path, where cortex-m-rt's
//! `link.x` includes it: the UART binaries get `memory.x`, the benchmarks
//! `memory-bench.x` (more RAM for a bridge built on the stack), the Ethernet binary
//! `memory-eth.x` (each binary its own search folder).

use std::{env, fs, path::PathBuf};

/// The binaries and their memory layouts.
const LAYOUTS: [(&str, &[u8]); 5] = [
    ("scip2can-qemu", include_bytes!("memory.x")),
    ("scip2can-qemu-decode", include_bytes!("memory.x")),
    ("scip2can-qemu-bench", include_bytes!("memory-bench.x")),
    ("scip2can-qemu-bench-d16", include_bytes!("memory-bench.x")),
    ("scip2can-qemu-eth", include_bytes!("memory-eth.x")),
];

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    for (bin, layout) in LAYOUTS {
        let dir = out.join(bin);
        fs::create_dir_all(&dir).expect("create the layout folder");
        fs::write(dir.join("memory.x"), layout).expect("write memory.x");
        println!("cargo:rustc-link-arg-bin={bin}=-L{}", dir.display());
    }
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-eth.x");
    println!("cargo:rerun-if-changed=memory-bench.x");
    println!("cargo:rerun-if-changed=build.rs");
}
