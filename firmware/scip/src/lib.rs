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

pub mod command;
pub mod decoder;
pub mod error;
pub mod info;
pub mod response;
pub mod status;
pub mod sum;
pub mod timestamp;
pub mod value;

pub use command::{
    Command, DataSet, EchoError, EncodeError, RawRequest, Request, ScanMode, ScanRequest, Tag,
    TimeMode, BIT_RATES, REQUEST_MAX, TAG_MAX,
};
pub use decoder::{
    DataLine, Decoder, DecoderStats, Event, Field, Indexed, IndexedReading, Reading, Summary,
    LINE_CAP, MAX_READINGS, MAX_RUN_READINGS,
};
pub use error::{Error, ErrorKind};
pub use info::{
    KnownModel, ModelFamily, Param, ParamError, ParamName, Range, RangeError, RangeLimits,
    RangeTest, SensorParams, SCAN_RPM_RANGE,
};
pub use response::ResponseWriter;
pub use status::{Status, StatusKind};
pub use sum::checksum;
pub use timestamp::TimestampUnwrapper;
