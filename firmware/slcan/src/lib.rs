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
#![doc = include_str!("../README.md")]

pub mod adapter;
pub mod command;
mod error;
pub mod frame;
mod hex;
pub mod line;
pub mod reply;

pub use adapter::{Adapter, Mode, Outcome, StatusFlags};
pub use command::Command;
pub use error::Error;
pub use frame::{dlc_to_len, len_to_dlc, Frame, FrameKind};
pub use line::LineBuffer;
pub use reply::Reply;

/// Longest line either side sends, terminator included: an extended CAN FD frame with
/// 64 data bytes and a timestamp (`B` + 8 + 1 + 128 + 4 + CR).
pub const LINE_MAX: usize = 1 + 8 + 1 + 128 + 4 + 1;

/// The line terminator (CR), also the "OK" answer.
pub const CR: u8 = b'\r';

/// The error answer (BEL).
pub const BEL: u8 = 0x07;
