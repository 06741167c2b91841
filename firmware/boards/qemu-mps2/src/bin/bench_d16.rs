//! The work benchmark (see `bench.rs`) with the board's configuration in plain 16-bit millimetres (D16).

#![no_std]
#![no_main]
#![deny(unsafe_code)]

#[path = "../bench.rs"]
mod bench;
#[path = "../config.rs"]
#[allow(dead_code)] // the SLCAN and watchdog settings are the bridge binary's
mod config;
#[path = "../frame_hash.rs"]
mod frame_hash;
#[path = "../hw.rs"]
#[allow(dead_code)] // shared with the bridge binary
mod hw;

use cortex_m_rt::entry;

#[entry]
fn main() -> ! {
    bench::run(can_wire::Encoding::PLAIN_MM)
}
