//! Event routing: each decoder event to the session and, for measurement responses, along
//! the scan path (echo, status, timestamp, data lines, end or error) by the response's
//! [`Phase`].

use can_wire::AbortReason;
use scip::{Command, Event, ScanMode, ScanRequest, Status};

use super::{Core, Phase};

impl<const Q: usize> Core<Q> {
    pub(super) fn event(&mut self, event: &Event<'_>, now: u64) {
        if let Event::Data(line) = event {
            // Most events: a data line. The session only notes its time.
            self.session.on_data(now);
            if let Phase::Active(s) = self.phase {
                self.data_line(line, &s);
            }
            return;
        }
        // Every other event after the filtered lines before it.
        self.flush_batch();
        if let Some(n) = self.session.on_event(event, now) {
            self.notice(n);
        }
        if let Event::Field(f) = event {
            if f.name == b"MODL" || f.name == b"PROD" {
                if let Some(model) = crate::status::model_from_text(f.value) {
                    self.model = Some(model);
                }
            }
        }
        match (event, self.phase) {
            (Event::Start { request, .. }, phase) => {
                if matches!(phase, Phase::Active(_)) {
                    // A response began before the scan's end: cannot happen with a sound
                    // decoder, but never leave a scan open.
                    self.abort_scan(AbortReason::BadData);
                }
                self.echo_damaged = request.is_none();
                self.echo_status = None;
                self.phase = match request.map(|r| r.command) {
                    Some(Command::Scan(s)) => Phase::Echo(s),
                    _ => Phase::None,
                };
            }
            (Event::Status(status), Phase::Echo(s)) => {
                self.phase = if carries_scan(&s, *status) {
                    Phase::Framed(s)
                } else {
                    Phase::None
                };
            }
            (Event::Timestamp(t), Phase::Framed(s)) => {
                self.in_stream = s.mode == ScanMode::Continuous;
                self.begin_scan(s, *t, now);
            }
            (Event::End(_), Phase::Active(_)) => {
                self.finish_scan();
                if self.estimating() && self.scan_clock.wants_tm() {
                    // The scans just crossed a tick of the sensor's clock: a TM now pins
                    // the latency. Asked once the scan is complete (the stream stops for
                    // it, a few scans; the one under way is not cut).
                    self.scan_clock.tm_requested();
                    self.session.request_time_sync(now);
                }
            }
            (Event::Error(e), Phase::Active(_)) => {
                let reason = match e.kind {
                    scip::ErrorKind::BadSum { .. } => AbortReason::Checksum,
                    scip::ErrorKind::Truncated => AbortReason::Timeout,
                    _ => AbortReason::BadData,
                };
                self.abort_scan(reason);
            }
            (Event::Error(_), Phase::Echo(_) | Phase::Framed(_)) => {
                // A measurement response damaged before its scan began.
                self.lose_scan();
                self.phase = Phase::None;
            }
            (Event::Status(status), Phase::None) if self.echo_damaged => {
                self.echo_status = Some(*status);
            }
            (Event::Error(_), Phase::None)
                if self.echo_damaged
                    && match self.echo_status {
                        Some(status) => carries_frame(status),
                        None => self.in_stream,
                    } =>
            {
                // A stream frame whose echo was damaged (its status says so or, when
                // that was damaged too, it came in a stream).
                self.lose_scan();
            }
            (Event::End(_) | Event::Error(_), _) => {
                if matches!(event, Event::End(_))
                    && matches!(self.phase, Phase::None)
                    && !self.echo_damaged
                {
                    // An answer to another command: the stream is not what came last.
                    self.in_stream = false;
                }
                self.phase = Phase::None;
            }
            _ => {}
        }
    }

    /// A scan the sensor sent and the bridge never started: counted, and its sequence
    /// number skipped so that a receiver sees the gap.
    pub(super) fn lose_scan(&mut self) {
        self.stats.scans_lost = self.stats.scans_lost.wrapping_add(1);
        self.seq = self.seq.wrapping_add(1);
    }
}

/// A measurement response whose status carries a scan.
fn carries_scan(s: &ScanRequest, status: Status) -> bool {
    match s.mode {
        ScanMode::Single => status == Status::OK,
        ScanMode::Continuous => carries_frame(status),
    }
}

/// The status of a stream frame (`99`, or `0M` on SCIP 2.2).
fn carries_frame(status: Status) -> bool {
    matches!(status, Status::Scip2([b'9', b'9'] | [b'0', b'M']))
}
