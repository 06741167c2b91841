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
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=budget.x");
    println!("cargo:rerun-if-changed=build.rs");
    // The network settings are compiled in (see net.rs).
    println!("cargo:rerun-if-env-changed=SCIP2CAN_IP");
    println!("cargo:rerun-if-env-changed=SCIP2CAN_SENSOR");
}
