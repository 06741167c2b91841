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

pub mod abort;
pub mod bandwidth;
pub mod control;
pub mod crc;
pub mod data;
pub mod encoder;
pub mod encoding;
mod error;
pub mod frame;
pub mod header;
pub mod id;
pub mod lossless;
pub mod reassembly;
pub mod status;
pub mod timesync;
pub mod trailer;

pub use abort::{Abort, AbortReason};
pub use control::{Answer, Command, Control, DecimationMode, MedianWindow, Outcome};
pub use encoder::{Emitted, FrameFormat, FrameSink, RangeRule, Run, RunStop, ScanEncoder};
pub use encoding::{Distance, DistanceEncoding, Encoding, IntensityEncoding};
pub use error::Error;
pub use frame::Frame;
pub use header::{Grouping, ScanHeader, MAX_POINTS};
pub use id::{IdWindow, Kind, NodeIds};
pub use reassembly::{Completeness, Decoder, Event, LossStats, Point, Scan};
pub use status::{BridgeState, BusState, SensorModel, Status};
pub use timesync::TimeFrame;
pub use trailer::{Trailer, TrailerFlags};
