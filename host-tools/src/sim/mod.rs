//! `scip2can sim`: a simulated Hokuyo sensor that SCIP drivers cannot tell from a real
//! one.
//!
//! - [`model`]: URG-04LX, UTM-30LX, UST-10LX, UXM-30LX-E with their real VV/PP/II text.
//! - [`scene`]: a deterministic 2-D world (walls, boxes, glass, a moving object).
//! - [`measure`]: echoes → ranges, intensities and error codes, with range noise.
//! - [`replay`]: the scans of a recorded stream instead of a scene.
//! - [`session`]: the protocol state machine, sans-IO (bytes and time in, bytes out).
//! - [`faults`]: bit flips, dropped/inserted bytes, stalls, hardware statuses, reboots.
//! - [`transport`]: TCP, pseudo-terminal and stdio drivers on the real clock.
//! - [`options`]: the flags and the `sim:` spec that build a [`Sensor`].

pub mod cli;
pub mod faults;
pub mod measure;
pub mod model;
pub mod options;
pub mod replay;
pub mod scene;
pub mod session;
pub mod transport;

pub use options::SimOptions;
pub use session::Sensor;
