//! A simulated Hokuyo sensor that SCIP drivers cannot tell from a real one: the engine of
//! `scip2can sim`, of the host tests and of the benchmarks' streams.
//!
//! - [`model`]: URG-04LX, UTM-30LX, UST-10LX, UXM-30LX-E with their real VV/PP/II text.
//! - [`scene`]: a deterministic 2-D world (walls, boxes, glass, a moving object).
//! - [`measure`]: echoes → ranges, intensities and error codes, with range noise.
//! - [`replay`]: the scans of a recorded stream instead of a scene.
//! - [`session`]: the protocol state machine, sans-IO (bytes and time in, bytes out).
//! - [`faults`]: bit flips, dropped/inserted bytes, stalls, hardware statuses, reboots.
//! - [`transport`]: TCP, pseudo-terminal and stdio drivers on the real clock.
//!
//! The command line's flags and `sim:` specs that build a [`Sensor`] are in the
//! `scip2can` command (`scip2can_host::sim::options`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod faults;
pub mod measure;
pub mod model;
pub mod replay;
pub mod scene;
pub mod session;
pub mod transport;

pub use session::Sensor;
