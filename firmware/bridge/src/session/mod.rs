//! The sensor session: the state machine that brings a SCIP sensor up, keeps it streaming,
//! and recovers it when it goes silent, fails or reboots.
//!
//! Sans-IO: the caller feeds it the decoder's events ([`Session::on_event`]) and the time,
//! and asks it what to do next ([`Session::poll`]): send a command, or change the UART bit
//! rate. It never blocks and holds no buffers.
//!
//! ```text
//! start ─▶ Probe (QT) ──1.1 status──▶ Switch (SCIP2.0) ─▶ Probe
//!            │ 2.x status
//!            ▼
//!          Identify: VV ▶ PP ▶ II ─▶ [SS <rate> ▶ set UART rate] ─▶ Start (M*/N*) ─▶ Streaming
//!                                                                                    │
//!   silence, hardware fault (50–97), SCIP 1.1 status (reboot), repeated timeouts ◀───┘
//!            ▼
//!          Recover: QT, RS, back-off (doubling, capped) ─▶ Probe
//! ```
//! Time sync on request: QT ▶ TM0 ▶ TM1 ▶ TM2 ▶ Start again.

mod config;
mod machine;

pub use config::{SessionConfig, SessionError};
pub use machine::{Action, Geometry, Notice, RecoverReason, Session, SessionStats, State};
