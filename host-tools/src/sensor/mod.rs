//! Clients for real (and simulated) sensors: `scip2can info`, `scan`, `record`.
//!
//! - [`spec`]: the `<sensor>` argument (`tcp://host:port`, a serial device, `sim:...`).
//! - [`link`]: byte links with timeouts over TCP, a serial port, an in-process simulator.
//! - [`client`]: requests and whole responses over a link, with the `scip` decoder.
//! - [`info`], [`scan`], [`record`]: the three commands.
//! - [`record_file`]: the documented record format of `scip2can record`.
//! - [`cli`]: their command-line flags.

pub mod cli;
pub mod client;
pub mod info;
pub mod link;
pub mod record;
pub mod record_file;
pub mod scan;
pub mod spec;
