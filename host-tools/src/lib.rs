#![forbid(unsafe_code)]
#![deny(missing_docs)]
//! The host side of scip2can: the pieces behind the `scip2can` command, as a library so
//! that the integration tests run exactly what the command runs.

pub mod candump;
pub mod cosim;
pub mod decode;
pub mod emulate;
pub mod icount;
pub mod live;
pub mod noise;
pub mod parse;
pub mod plot;
pub mod replay;
pub mod sensor;
pub mod sim;
pub mod timesync;
pub mod view;
