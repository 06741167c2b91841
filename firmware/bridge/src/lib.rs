#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
// No panic on any input: no unwrap/expect/panic, no unchecked indexing, and every
// operation that could overflow says what it does then (checked, wrapping, saturating).
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects
    )
)]
//! The sans-IO bridge core of scip2can: what sits between the SCIP decoder and the CAN
//! encoder, with no hardware, clock or allocation of its own.
//!
//! - [`pipeline`]: the streaming scan pipeline (region of interest, range window,
//!   intensity threshold, speckle removal, median, angular and temporal decimation).
//! - [`clock`]: the sensor clock model (scan start times in the bridge's clock).
//! - [`engine`]: the bridge itself: UART bytes in, CAN frames out.
//! - [`control`]: control frames validated, applied and answered.
//! - [`status`]: health counters and the status (heartbeat) frames.
//! - [`governor`]: the bandwidth governor (decimation plan, whole-scan admission).
//! - [`link`]: the sensor link (UART or TCP stream), its bit rate and its state.
//! - [`session`]: the sensor session state machine (SCIP 1.1 detection, identification,
//!   bit rate, streaming, silence/fault/reboot detection, recovery with back-off, time
//!   sync).
//! - [`timesync`]: following a time master over CAN (the robot's clock).

pub mod clock;
pub mod control;
pub mod engine;
pub mod governor;
pub mod link;
pub mod pipeline;
pub mod queue;
pub mod session;
pub mod status;
pub mod timesync;
