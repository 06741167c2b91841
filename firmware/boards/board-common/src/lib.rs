//! What the scip2can STM32 board binaries share, so that each board crate only binds its
//! peripherals.
//!
//! - [`config`]: the bridge settings of the boards (queue capacity, sensor bit rates,
//!   node, status period, bus share) and the timing of the main loop.
//! - [`shared`]: the bridge shared by the tasks of the one thread-mode executor, and the
//!   "frames queued" signal that wakes the CAN transmit task.
//! - [`sensor`]: the main loop: sensor UART (or TCP) in and out, the session's commands and bit
//!   rate changes, and once per tick the watchdog, the CAN bus state with rate-limited
//!   bus-off recovery, and the CPU load. A board implements [`sensor::Board`].
//! - [`recovery`]: the bus-off recovery policy (sans-IO, tested on the host).
//! - [`link`]: the reconnect policy of a sensor link that can go down (TCP).
//! - [`load`]: CPU load from the executor's busy time.
//! - [`tdc`]: the CAN FD transmitter delay compensation offset of a data bit timing.
//! - `panic` (feature `panic-handler`, on the MCU): the boards' panic handler, which logs
//!   the location and a plain message through defmt without `core::fmt`, then faults.
//!
//! The CAN transmit and receive tasks stay in the board crates: their frame types are the
//! controller's (FDCAN or bxCAN).
//!
//! Host tests (unit tests, and `tests/main_loop.rs`: the main loop on a simulated board
//! with embassy-time's std driver): `cargo test -p board-common --target
//! x86_64-unknown-linux-gnu` from `firmware/boards` (whose default target is the MCU's).
#![cfg_attr(not(test), no_std)]
#![deny(unsafe_code)]
#![deny(missing_docs)]

#[macro_use]
mod fmt;

pub mod config;
pub mod link;
pub mod load;
#[cfg(all(feature = "panic-handler", target_os = "none"))]
mod panic;
pub mod recovery;
pub mod sensor;
pub mod shared;
pub mod tdc;

pub use config::Bridge;
pub use shared::Shared;

/// The value of a start-up step that the board's fixed settings never make fail
/// (the bridge's settings, the UART's, the CAN bit timings, spawning a task), or a panic
/// naming the step.
///
/// Unlike `defmt::unwrap!`, the error itself is not logged: that linked the error
/// type's `defmt::Format` code (the derived formatting of nested error enums, several
/// hundred bytes of flash per board) for an error these settings never give.
#[cfg(target_os = "none")]
pub fn started<T, E>(step: Result<T, E>, what: &str) -> T {
    match step {
        Ok(value) => value,
        Err(_) => defmt::panic!("start-up failed: {=str}", what),
    }
}
