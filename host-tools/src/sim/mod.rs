//! `scip2can sim`: the simulated sensor of the `scip2can-sim` crate on the command line.
//!
//! - [`options`]: the flags and the `sim:` spec that build a [`Sensor`].
//! - [`cli`]: the `sim` subcommand (TCP, pseudo-terminal or stdio).
//!
//! The simulator's modules are re-exported here under their names (`sim::model`,
//! `sim::session`, ...).

pub mod cli;
pub mod options;

pub use options::SimOptions;
pub use scip2can_sim::{faults, measure, model, replay, scene, session, transport, Sensor};
