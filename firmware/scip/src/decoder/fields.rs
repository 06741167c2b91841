//! The non-value lines of a response: the echo, the status, the timestamp's sequence
//! check, and the `NAME:VALUE;S` fields of VV / PP / II.

use super::*;

impl Decoder {
    pub(super) fn start_response(&mut self, len: usize) {
        let echo = self.buf.get(..len).unwrap_or(&[]);
        match Request::parse(echo) {
            Ok(r) => self.request = Some(r),
            Err(e) => {
                self.request = None;
                self.echo_error = e;
                // A command of another SCIP version (two capital letters, e.g. `RB`),
                // not a damaged echo.
                self.echo_plain =
                    matches!(echo, [a, b, ..] if a.is_ascii_uppercase() && b.is_ascii_uppercase());
            }
        }
        self.line_no = 0;
        self.state = State::Status;
        self.timestamp = None;
        self.values = 0;
        self.extra_echoes = 0;
        self.carry = 0;
        self.carry_n = 0;
        self.in_aux = false;
        self.next_is_echo = false;
        self.echo_no = 0;
        self.short_line_seen = false;
        self.this_frame = None;
        self.pp = SensorParams::default();
    }

    pub(super) fn status_line(&mut self, len: usize) -> Option<Event<'_>> {
        let status = match self.buf.get(..len).unwrap_or(&[]) {
            [] => return self.fail(ErrorKind::MissingStatus),
            [c] => Status::Scip11(*c),
            [a, b, s] => {
                let expected = checksum(&[*a, *b]);
                if expected != *s {
                    return self.fail(ErrorKind::BadSum {
                        expected,
                        found: *s,
                    });
                }
                Status::Scip2([*a, *b])
            }
            _ => return self.fail(ErrorKind::BadStatusLine),
        };
        self.status = status;
        let payload = match (status, self.request.map(|r| r.command)) {
            (Status::Scip11(_), _) => Payload::Ignore,
            (s, _) if !s.carries_data() => Payload::None,
            (_, None) => Payload::Unknown,
            (s, Some(cmd)) => match cmd {
                Command::Version | Command::Parameters | Command::Info => Payload::Fields,
                Command::Time(TimeMode::Read) => Payload::Time,
                Command::State => Payload::Lines,
                Command::Scan(scan) => self.begin_scan(scan, s),
                _ => Payload::None,
            },
        };
        self.state = State::Payload(payload);
        Some(Event::Status(status))
    }

    pub(super) fn begin_scan(&mut self, scan: ScanRequest, status: Status) -> Payload {
        // The ack of a continuous request (status 00) carries no data; its frames (99,
        // or 0M on SCIP 2.2) and single-scan answers (00) do.
        if scan.mode == ScanMode::Continuous && status == Status::OK {
            return Payload::None;
        }
        self.shape = Shape {
            data: scan.data,
            dist_width: scan.data.distance_width(),
            aux_width: scan.data.aux_width(),
            multi_echo: scan.multi_echo,
            expected: scan.value_count(),
        };
        self.want = self.shape.dist_width;
        Payload::ScanTimestamp
    }

    pub(super) fn field_line(&mut self, len: usize) -> Option<Event<'_>> {
        let line = self.buf.get(..len).unwrap_or(&[]);
        // NAME:VALUE;S — the `;` is the second-last byte (values may contain `;`).
        let [body @ .., b';', s] = line else {
            return self.fail(ErrorKind::BadField);
        };
        let s = *s;
        let Some(colon) = body.iter().position(|&c| c == b':') else {
            return self.fail(ErrorKind::BadField);
        };
        // Accepted sums: over NAME:VALUE (SCIP 2.0 as sensors send it), over NAME:VALUE;
        // (the form some documents give), and without a trailing `<-comment`.
        // A word at a time on 32-bit targets (the value-char check unused here).
        let (plain, _) = super::line::sum_and_check(body);
        let ok = plain == s
            || (plain.wrapping_sub(0x30).wrapping_add(b';') & 0x3F).wrapping_add(0x30) == s
            || body
                .windows(2)
                .position(|w| matches!(w, [b'<', b'-']))
                .and_then(|i| body.get(..i))
                .is_some_and(|head| checksum(head) == s);
        if !ok {
            return self.fail(ErrorKind::BadSum {
                expected: plain,
                found: s,
            });
        }
        let name_end = colon;
        // The colon is in `body`, itself in the line buffer: no wrap.
        let value_start = colon.wrapping_add(1);
        let body_len = body.len();
        let is_pp = matches!(self.request.map(|r| r.command), Some(Command::Parameters));
        let (name, value) = (
            self.buf.get(..name_end).unwrap_or(&[]),
            self.buf.get(value_start..body_len).unwrap_or(&[]),
        );
        let param = if is_pp {
            self.pp.apply_parsed(name, value)
        } else {
            None
        };
        let (name, value) = (
            self.buf.get(..name_end).unwrap_or(&[]),
            self.buf.get(value_start..body_len).unwrap_or(&[]),
        );
        Some(Event::Field(Field { name, value, param }))
    }

    /// The sequence check of a stream frame with timestamp `ts` against the last intact
    /// frame of the same stream: a later timestamp (24-bit wrap allowed, at most
    /// [`STREAM_GAP_MAX_MS`] on) and a remaining-scans count that went down (or stays
    /// `00` for an endless stream). A frame that fails clears the reference, so that
    /// one bad frame cannot hold up the ones after it.
    pub(super) fn frame_in_sequence(&mut self, ts: u32) -> bool {
        let Some(Command::Scan(scan)) = self.request.map(|r| r.command) else {
            return true;
        };
        if scan.mode != ScanMode::Continuous {
            return true;
        }
        let ok = match self.last_frame {
            Some((prev, prev_ts))
                if ScanRequest { count: 0, ..prev } == ScanRequest { count: 0, ..scan } =>
            {
                let gap = ts.wrapping_sub(prev_ts) & 0x00FF_FFFF;
                let counted = if prev.count == 0 {
                    scan.count == 0
                } else {
                    scan.count < prev.count
                };
                counted && gap != 0 && gap <= STREAM_GAP_MAX_MS
            }
            _ => true,
        };
        if ok {
            self.this_frame = Some((scan, ts));
        } else {
            self.last_frame = None;
        }
        ok
    }
}
