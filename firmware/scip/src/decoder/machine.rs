//! The response state machine: what each complete line means in the state the decoder
//! is in (echo, status, payload, the empty line that ends a response, skipping after an
//! error), and the errors and counters.

use super::*;

impl Decoder {
    /// Handles a complete line quickly when it produces no event (empty lines between
    /// responses, lines skipped after an error); true when [`Self::line_event`] must run.
    #[inline]
    pub(super) fn line_has_event(&mut self) -> bool {
        let empty = self.len == 0 && !self.overflow;
        match self.state {
            State::Idle if empty => {
                self.line_start = self.stats.bytes;
                false
            }
            State::Skip => {
                if empty {
                    self.state = State::Idle;
                } else {
                    self.line_no = self.line_no.saturating_add(1);
                    if self.skip_checks_sums && !self.overflow && !self.line_sum_ok() {
                        return true;
                    }
                }
                self.len = 0;
                self.overflow = false;
                self.line_start = self.stats.bytes;
                false
            }
            State::Payload(Payload::Ignore) if !empty => {
                self.len = 0;
                self.overflow = false;
                self.line_no = self.line_no.saturating_add(1);
                self.line_start = self.stats.bytes;
                false
            }
            _ => true,
        }
    }

    pub(super) fn error(&mut self, kind: ErrorKind, line: u16) -> Event<'static> {
        self.stats.errors = self.stats.errors.wrapping_add(1);
        if let Some(c) = self.stats.by_kind.get_mut(kind.index()) {
            *c = c.wrapping_add(1);
        }
        Event::Error(Error {
            kind,
            offset: self.current_line,
            line,
        })
    }

    /// An error inside a response: skip to its end.
    #[cold]
    #[inline(never)]
    pub(super) fn fail(&mut self, kind: ErrorKind) -> Option<Event<'static>> {
        let line = self.line_no;
        // Lines of a damaged measurement are still LF-framed: keep checking their sums
        // so that every bad line is reported, while none of their values is published.
        self.skip_checks_sums = matches!(
            self.state,
            State::Payload(Payload::Data | Payload::ScanTimestamp)
        );
        self.state = State::Skip;
        self.stats.resyncs = self.stats.resyncs.wrapping_add(1);
        Some(self.error(kind, line))
    }

    /// Processes the complete line in the buffer. Kept out of line so that [`Self::feed`]
    /// stays small for the calls that only buffer bytes.
    #[inline(never)]
    pub(super) fn line_event(&mut self) -> Option<Event<'_>> {
        let len = self.len;
        let overflow = self.overflow;
        self.len = 0;
        self.overflow = false;
        self.current_line = self.line_start;
        self.line_start = self.stats.bytes;
        if overflow {
            return self.fail(ErrorKind::LineTooLong);
        }
        // A data line, the common case, first: what [`Self::line`] and
        // [`Self::payload_line`] would do with it, without their dispatch.
        if self.state == State::Payload(Payload::Data) && len != 0 {
            self.line_no = self.line_no.saturating_add(1);
            return self.data_line(len);
        }
        self.line(len)
    }

    pub(super) fn line(&mut self, len: usize) -> Option<Event<'_>> {
        match self.state {
            State::Idle => {
                self.start_response(len);
                let request = self.request;
                let echo = self.buf.get(..len).unwrap_or(&[]);
                Some(Event::Start { echo, request })
            }
            State::Status => {
                self.line_no = 1;
                self.status_line(len)
            }
            State::Payload(p) => {
                if len == 0 {
                    return self.end_response();
                }
                self.line_no = self.line_no.saturating_add(1);
                self.payload_line(p, len)
            }
            State::Skip => {
                // Only reached for a line whose sum failed while skipping.
                let expected = match self.buf.get(..len) {
                    Some([body @ .., _]) => checksum(body),
                    _ => 0,
                };
                let found = self.buf.get(len.wrapping_sub(1)).copied().unwrap_or(0);
                let line = self.line_no;
                Some(self.error(ErrorKind::BadSum { expected, found }, line))
            }
        }
    }

    pub(super) fn payload_line(&mut self, p: Payload, len: usize) -> Option<Event<'_>> {
        match p {
            Payload::None => self.fail(ErrorKind::UnexpectedPayload),
            Payload::Unknown => self.fail(ErrorKind::UnknownEcho(self.echo_error)),
            Payload::Ignore => None,
            Payload::Fields => self.field_line(len),
            Payload::ScanTimestamp | Payload::Time => {
                let line = self.buf.get(..len).unwrap_or(&[]);
                let [t @ .., s] = line else {
                    return self.fail(ErrorKind::BadTimestamp);
                };
                if t.len() != 4 {
                    return self.fail(ErrorKind::BadTimestamp);
                }
                let expected = checksum(t);
                if expected != *s {
                    return self.fail(ErrorKind::BadSum {
                        expected,
                        found: *s,
                    });
                }
                let Some(ts) = crate::value::decode(t) else {
                    return self.fail(ErrorKind::BadChar { column: 0 });
                };
                if p == Payload::ScanTimestamp && !self.frame_in_sequence(ts) {
                    return self.fail(ErrorKind::OutOfSequence);
                }
                self.timestamp = Some(ts);
                self.state = State::Payload(if p == Payload::Time {
                    Payload::None
                } else {
                    Payload::Data
                });
                Some(Event::Timestamp(ts))
            }
            // [`Self::line_event`] takes every data line before it gets here (one call
            // site keeps [`Self::data_line`] inlined there); not reached.
            Payload::Data => self.fail(ErrorKind::BadDataLineLength),
            Payload::Lines => {
                let line = self.buf.get(..len).unwrap_or(&[]);
                let [body @ .., s] = line else {
                    return self.fail(ErrorKind::UnexpectedPayload);
                };
                let expected = checksum(body);
                if expected != *s {
                    return self.fail(ErrorKind::BadSum {
                        expected,
                        found: *s,
                    });
                }
                // `len >= 1`: the line matched `[body @ .., s]` above.
                let body = self.buf.get(..len.wrapping_sub(1)).unwrap_or(&[]);
                Some(Event::Payload(body))
            }
        }
    }

    /// A measurement that ended wrong: reported, and the response is over (the empty
    /// line that ended it has been read, so nothing is left to skip).
    pub(super) fn fail_at_end(&mut self, kind: ErrorKind) -> Option<Event<'static>> {
        let ev = self.fail(kind);
        self.state = State::Idle;
        ev
    }

    pub(super) fn end_response(&mut self) -> Option<Event<'_>> {
        if self.state == State::Payload(Payload::Unknown) && !self.echo_plain {
            // A damaged echo: the answer's kind is unknown, it cannot end intact.
            return self.fail(ErrorKind::UnknownEcho(self.echo_error));
        }
        if let State::Payload(p @ (Payload::ScanTimestamp | Payload::Data)) = self.state {
            if self.carry_n != 0 || self.in_aux || self.next_is_echo {
                return self.fail_at_end(ErrorKind::TruncatedValue);
            }
            if p == Payload::ScanTimestamp || self.values != self.shape.expected {
                return self.fail_at_end(ErrorKind::CountMismatch {
                    expected: self.shape.expected,
                    found: self.values,
                });
            }
        }
        // An intact frame is the next one's reference; any other intact answer (an
        // ack, QT, RS ...) ends the stream it would belong to.
        self.last_frame = self.this_frame.take();
        if matches!(self.state, State::Payload(Payload::Fields))
            && matches!(self.request.map(|r| r.command), Some(Command::Parameters))
        {
            // Parameters and limits only from an answer whose fields are whole and
            // plausible: a flip the line sum cannot see must not change the geometry or
            // how ranges are told from error codes.
            if matches!(self.pp.check(), Ok(()) | Err(ParamError::NotTheModels(_))) {
                self.params = self.pp;
                if let Some(dmin) = self.pp.dmin {
                    self.limits.dmin = dmin;
                }
                if let Some(family) = self.pp.family {
                    self.limits.family = family;
                }
            }
        }
        self.state = State::Idle;
        self.stats.responses = self.stats.responses.wrapping_add(1);
        Some(Event::End(Summary {
            request: self.request,
            status: self.status,
            lines: self.line_no.saturating_add(1),
            values: self.values,
            extra_echoes: self.extra_echoes,
            timestamp: self.timestamp,
        }))
    }
}
