//! Scans in the formats of visualisation tools.

pub mod foxglove;
