//! Fuzzes the streaming SCIP response decoder on short inputs (at most 256 bytes: a few
//! lines of a response, where the framing, sum and field checks live), the same checks as
//! `decoder` (`common/scip_check.rs`), many times faster per input than the whole
//! recorded streams, so that the decoder gets its hundreds of millions of executions.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "common/scip_check.rs"]
mod scip_check;

/// Longest input taken (the selector byte included); longer inputs are cut there.
const MAX_INPUT: usize = 256;

fuzz_target!(|data: &[u8]| scip_check::check(&data[..data.len().min(MAX_INPUT)]));
