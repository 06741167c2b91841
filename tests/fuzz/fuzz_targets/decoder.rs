//! Fuzzes the streaming SCIP response decoder on inputs of any length (the recordings'
//! whole streams seed it): see `common/scip_check.rs` for what is checked.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "common/scip_check.rs"]
mod scip_check;

fuzz_target!(|data: &[u8]| scip_check::check(data));
