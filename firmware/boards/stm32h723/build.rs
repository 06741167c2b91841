//! Link setup: the NUCLEO-H723ZG's memory map (`memory.x`: the AXI SRAM as RAM, which the
//! Ethernet DMA reaches), its budget (`budget.x`: 256 KiB flash, 128 KiB RAM), and
//! `defmt.x` for the defmt log strings.

use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("write memory.x");
    fs::write(out.join("budget.x"), include_bytes!("budget.x")).expect("write budget.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=-Tbudget.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    // Identical code folding: identical functions and read-only data (monomorphised
    // copies, equal vtables) are kept once (about 360 B of flash on the G474 and F446).
    // Rust does not promise distinct addresses for functions, vtables or constants; two
    // equal immutable statics could share one, which matters only to code comparing
    // their addresses (none in the bridge or the boards). defmt's string indices are not
    // folded (their section is not loaded).
    println!("cargo:rustc-link-arg-bins=--icf=all");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=budget.x");
    println!("cargo:rerun-if-changed=build.rs");
    // The network settings are compiled in (see net.rs).
    println!("cargo:rerun-if-env-changed=SCIP2CAN_IP");
    println!("cargo:rerun-if-env-changed=SCIP2CAN_SENSOR");
}
