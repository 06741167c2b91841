//! Link setup: this board's `memory.x` (NUCLEO-F446RE); `budget.x` (from `board-common`)
//! caps flash and RAM at the bridge's budget; `defmt.x` places the defmt log strings.

use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("write memory.x");
    fs::write(
        out.join("budget.x"),
        include_bytes!("../board-common/budget.x"),
    )
    .expect("write budget.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=-Tbudget.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=../board-common/budget.x");
    println!("cargo:rerun-if-changed=build.rs");
}
