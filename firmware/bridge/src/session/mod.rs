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
//! Link down (a TCP link, [`crate::link`]): any state ▶ LinkDown (held: nothing sent,
//! nothing times out) ▶ link up ▶ Probe.
//!
//! The PP answer is judged whole ([`scip::SensorParams::check`]: every field once and all
//! digits, DMIN < DMAX, AMIN ≤ AFRT ≤ AMAX < ARES, SCAN plausible, the known model's
//! values, the model VV named): a damaged or doubted answer is asked again up to
//! `max_retries` times, then the sensor is recovered; the stream only starts on an
//! established [`Geometry`], and while it is in doubt the bridge publishes no scan.
//!
//! Silence: a stream is lost after [`STALL_FRAMES`] frame periods plus
//! [`STALL_MARGIN_MS`] without a line (700 ms at 40 Hz, 1.3 s at 10 Hz), so a sensor
//! that stalls for 300 ms keeps its stream and its late scans. A response cut off in the
//! middle (a reboot) is dropped by the bridge once its input has been silent for
//! [`Session::stale_input_ms`], so that the sensor's next answer is read cleanly.

mod config;
mod machine;

pub use config::{SessionConfig, SessionError};
pub use machine::{
    Action, Geometry, Notice, RecoverReason, Session, SessionStats, State, STALL_FRAMES,
    STALL_MARGIN_MS,
};
