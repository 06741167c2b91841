//! The streaming response decoder.
//!
//! Bytes go in, in chunks of any size, through [`Decoder::feed`]; it consumes bytes up to
//! the end of the next line that completes an event and hands that event out, borrowing
//! the decoder's one-line buffer (no copy of scans, no allocation). Any chunking of the
//! same bytes gives the same events.
//!
//! Every response that starts ([`Event::Start`]) ends with exactly one of
//! [`Event::End`] (intact: every line checked) or [`Event::Error`] (damaged: the decoder
//! then skips to the next response boundary, an empty line). While it skips the rest of a
//! damaged measurement it still checks each line's sum and reports every further bad line
//! as another [`Event::Error`] of the same response; [`Decoder::between_responses`] tells
//! when the damaged response is over. Errors can also arrive outside a response, for
//! garbage between responses.

use crate::command::{Command, DataSet, EchoError, Request, ScanMode, ScanRequest, TimeMode};
use crate::error::{Error, ErrorKind};
use crate::info::{Param, Range, RangeLimits, SensorParams};
use crate::status::Status;
use crate::sum::checksum;
use crate::value::CHAR_MIN;

/// Longest line the decoder accepts, LF excluded. Data lines are at most 65 bytes
/// (64 data chars + sum); info lines of real sensors stay well below this.
pub const LINE_CAP: usize = 96;
/// Data chars of a full measurement line.
pub const DATA_CHARS: usize = 64;
/// Most readings one data line can complete: 64 chars of 2-char values, plus one value
/// begun on the previous line.
pub const MAX_READINGS: usize = DATA_CHARS / 2 + 1;
/// Most echoes per step in a multi-echo response.
pub const MAX_ECHOES: u8 = 3;

/// One decoded step value (or one extra echo of a step).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reading {
    /// Index of the value in the scan (0 = `start` step; with clustering, one index
    /// covers `cluster` steps).
    pub index: u16,
    /// 0 for the first echo, 1 and 2 for extra echoes of multi-echo commands.
    pub echo: u8,
    /// Distance as sent: mm, or an error code below DMIN (see [`DataLine::range`]).
    pub distance: u32,
    /// Intensity, reflectance or aux value; 0 when the command has none.
    pub aux: u32,
}

/// The readings completed by one data line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataLine<'a> {
    /// The readings, in order.
    pub readings: &'a [Reading],
    /// What each step carries.
    pub data: DataSet,
    /// DMIN and model family in force, to tell ranges from error codes.
    pub limits: RangeLimits,
    /// Line number within the response.
    pub line: u16,
}

impl DataLine<'_> {
    /// The distance of `reading` as a range or an error code.
    pub fn range(&self, reading: &Reading) -> Range {
        self.limits
            .classify(reading.distance, self.data.distance_width())
    }
}

/// A `NAME:VALUE` line of VV / PP / II.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field<'a> {
    /// The name before the first `:`.
    pub name: &'a [u8],
    /// The raw value, up to the last `;`.
    pub value: &'a [u8],
    /// The typed value, for the PP fields DMIN..SCAN.
    pub param: Option<Param>,
}

/// What an intact response contained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Summary {
    /// The echoed request; `None` when the echo was not a known command (the sensor's
    /// answer to an unknown or malformed command, with an error status and no data).
    pub request: Option<Request>,
    /// The status.
    pub status: Status,
    /// Lines in the response, echo and status included, the final empty line not.
    pub lines: u16,
    /// Values (steps) decoded.
    pub values: u16,
    /// Extra echoes decoded (multi-echo commands).
    pub extra_echoes: u16,
    /// The scan timestamp (or the TM1 time), 24-bit ms.
    pub timestamp: Option<u32>,
}

/// One thing the decoder learned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event<'a> {
    /// A response starts: its echo line.
    Start {
        /// The echo line as received.
        echo: &'a [u8],
        /// The echo parsed, or `None` when it is not a known command.
        request: Option<Request>,
    },
    /// The response's status.
    Status(Status),
    /// A VV / PP / II field.
    Field(Field<'a>),
    /// The scan timestamp of a measurement, or the time of a TM1 answer (24-bit ms).
    Timestamp(u32),
    /// The values of one data line.
    Data(DataLine<'a>),
    /// Another checked payload line (e.g. the `%ST` state), sum removed.
    Payload(&'a [u8]),
    /// The response ended intact.
    End(Summary),
    /// The response (or a line between responses) is damaged.
    Error(Error),
}

/// Counters of what the decoder saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecoderStats {
    /// Bytes fed.
    pub bytes: u64,
    /// Responses that ended intact.
    pub responses: u32,
    /// Errors, total.
    pub errors: u32,
    /// Errors by [`ErrorKind::index`].
    pub by_kind: [u32; ErrorKind::COUNT],
    /// Times the decoder skipped to the next response boundary after an error.
    pub resyncs: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Between responses: the next non-empty line is an echo.
    Idle,
    /// After the echo: the status line.
    Status,
    /// After the status: payload lines, then the empty line.
    Payload(Payload),
    /// After an error: discard lines up to the next empty line.
    Skip,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Payload {
    /// No payload may follow.
    None,
    /// SCIP 1.1 answer: whatever follows is not ours; pass over it.
    Ignore,
    /// `NAME:VALUE;S` lines.
    Fields,
    /// The timestamp line of a measurement.
    ScanTimestamp,
    /// Data lines.
    Data,
    /// The single time line of TM1.
    Time,
    /// Generic checked lines (`%ST`).
    Lines,
}

/// Shape of the values of the measurement being decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Shape {
    data: DataSet,
    dist_width: u8,
    aux_width: u8,
    multi_echo: bool,
    expected: u16,
}

/// The streaming SCIP 2.x response decoder. About 560 bytes of RAM; no allocation.
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: [u8; LINE_CAP],
    len: usize,
    overflow: bool,
    offset: u64,
    line_start: u64,
    current_line: u64,
    state: State,
    skip_checks_sums: bool,
    // The response being decoded.
    request: Option<Request>,
    echo_error: EchoError,
    status: Status,
    line_no: u16,
    shape: Shape,
    timestamp: Option<u32>,
    // Value decoding, carried across lines.
    carry: u32,
    carry_n: u8,
    want: u8,
    in_aux: bool,
    pending_distance: u32,
    next_is_echo: bool,
    echo_no: u8,
    values: u16,
    extra_echoes: u16,
    short_line_seen: bool,
    readings: [Reading; MAX_READINGS],
    n_readings: usize,
    // What the decoder learned of the sensor.
    params: SensorParams,
    pp: SensorParams,
    limits: RangeLimits,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// A decoder between responses, with default range limits (DMIN 20, family unknown)
    /// until it decodes a PP response.
    pub const fn new() -> Self {
        const EMPTY: SensorParams = SensorParams {
            dmin: None,
            dmax: None,
            ares: None,
            amin: None,
            amax: None,
            afrt: None,
            scan_rpm: None,
            family: None,
        };
        Self {
            buf: [0; LINE_CAP],
            len: 0,
            overflow: false,
            offset: 0,
            line_start: 0,
            current_line: 0,
            state: State::Idle,
            skip_checks_sums: false,
            request: None,
            echo_error: EchoError::UnknownCommand,
            status: Status::OK,
            line_no: 0,
            shape: Shape {
                data: DataSet::Distance,
                dist_width: 3,
                aux_width: 0,
                multi_echo: false,
                expected: 0,
            },
            timestamp: None,
            carry: 0,
            carry_n: 0,
            want: 3,
            in_aux: false,
            pending_distance: 0,
            next_is_echo: false,
            echo_no: 0,
            values: 0,
            extra_echoes: 0,
            short_line_seen: false,
            readings: [Reading {
                index: 0,
                echo: 0,
                distance: 0,
                aux: 0,
            }; MAX_READINGS],
            n_readings: 0,
            params: EMPTY,
            pp: EMPTY,
            limits: RangeLimits {
                dmin: 20,
                family: crate::info::ModelFamily::Unknown,
            },
            stats: DecoderStats {
                bytes: 0,
                responses: 0,
                errors: 0,
                by_kind: [0; ErrorKind::COUNT],
                resyncs: 0,
            },
        }
    }

    /// A decoder that already knows the sensor's range limits (e.g. from an earlier PP).
    pub fn with_limits(limits: RangeLimits) -> Self {
        let mut d = Self::new();
        d.limits = limits;
        d
    }

    /// The range limits in force.
    pub fn limits(&self) -> RangeLimits {
        self.limits
    }

    /// The PP parameters of the last intact PP response.
    pub fn params(&self) -> &SensorParams {
        &self.params
    }

    /// Counters.
    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// True between responses (no partial line or response pending).
    pub fn is_idle(&self) -> bool {
        self.state == State::Idle && self.len == 0 && !self.overflow
    }

    /// True when no response is open: the last one ended (intact or damaged, its
    /// remaining lines skipped). A partial next line may be buffered.
    pub fn between_responses(&self) -> bool {
        self.state == State::Idle
    }

    /// Drops any partial line and response: the next byte starts a new line between
    /// responses. Learned limits and counters stay.
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflow = false;
        self.state = State::Idle;
    }

    /// Consumes bytes from `input` up to and including the first LF that completes an
    /// event, or all of `input` when none does. Returns the bytes consumed and the event.
    ///
    /// Call again with the rest of the input until it is empty. Work is linear in the
    /// bytes consumed.
    pub fn feed(&mut self, input: &[u8]) -> (usize, Option<Event<'_>>) {
        let mut consumed = 0;
        let mut rest = input;
        loop {
            let Some(lf) = rest.iter().position(|&b| b == b'\n') else {
                self.append(rest);
                self.offset += rest.len() as u64;
                self.stats.bytes += rest.len() as u64;
                return (input.len(), None);
            };
            self.append(rest.get(..lf).unwrap_or(&[]));
            consumed += lf + 1;
            self.offset += lf as u64 + 1;
            self.stats.bytes += lf as u64 + 1;
            rest = rest.get(lf + 1..).unwrap_or(&[]);
            if self.line_has_event() {
                break;
            }
        }
        let ev = self.line_event();
        (consumed, ev)
    }

    /// Tells the decoder the stream has ended: a response in progress is reported as
    /// [`ErrorKind::Truncated`]. The decoder is then idle again.
    pub fn finish(&mut self) -> Option<Event<'_>> {
        let partial = self.len > 0 || self.overflow;
        let in_response = self.state != State::Idle || partial;
        self.len = 0;
        self.overflow = false;
        // The line cut short is the one after the last complete line.
        let line = match self.state {
            State::Idle => 0,
            _ if partial => self.line_no.saturating_add(1),
            _ => self.line_no,
        };
        self.state = State::Idle;
        self.current_line = self.line_start;
        self.line_start = self.offset;
        if in_response {
            Some(self.error(ErrorKind::Truncated, line))
        } else {
            None
        }
    }

    fn append(&mut self, bytes: &[u8]) {
        if self.overflow {
            return;
        }
        match self.buf.get_mut(self.len..self.len + bytes.len()) {
            Some(dst) => {
                dst.copy_from_slice(bytes);
                self.len += bytes.len();
            }
            None => self.overflow = true,
        }
    }

    /// Handles a complete line quickly when it produces no event (empty lines between
    /// responses, lines skipped after an error); true when [`Self::line_event`] must run.
    fn line_has_event(&mut self) -> bool {
        let empty = self.len == 0 && !self.overflow;
        match self.state {
            State::Idle if empty => {
                self.line_start = self.offset;
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
                self.line_start = self.offset;
                false
            }
            State::Payload(Payload::Ignore) if !empty => {
                self.len = 0;
                self.overflow = false;
                self.line_no = self.line_no.saturating_add(1);
                self.line_start = self.offset;
                false
            }
            _ => true,
        }
    }

    fn error(&mut self, kind: ErrorKind, line: u16) -> Event<'static> {
        self.stats.errors += 1;
        if let Some(c) = self.stats.by_kind.get_mut(kind.index()) {
            *c += 1;
        }
        Event::Error(Error {
            kind,
            offset: self.current_line,
            line,
        })
    }

    /// True when the buffered line ends with the right sum char.
    fn line_sum_ok(&self) -> bool {
        match self.buf.get(..self.len) {
            Some([body @ .., s]) => checksum(body) == *s,
            _ => false,
        }
    }

    /// An error inside a response: skip to its end.
    fn fail(&mut self, kind: ErrorKind) -> Option<Event<'static>> {
        let line = self.line_no;
        // Lines of a damaged measurement are still LF-framed: keep checking their sums
        // so that every bad line is reported, while none of their values is published.
        self.skip_checks_sums = matches!(
            self.state,
            State::Payload(Payload::Data | Payload::ScanTimestamp)
        );
        self.state = State::Skip;
        self.stats.resyncs += 1;
        Some(self.error(kind, line))
    }

    /// Processes the complete line in the buffer.
    fn line_event(&mut self) -> Option<Event<'_>> {
        let len = self.len;
        let overflow = self.overflow;
        self.len = 0;
        self.overflow = false;
        self.current_line = self.line_start;
        self.line_start = self.offset;
        if overflow {
            self.fail(ErrorKind::LineTooLong)
        } else {
            self.line(len)
        }
    }

    fn line(&mut self, len: usize) -> Option<Event<'_>> {
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

    fn start_response(&mut self, len: usize) {
        let echo = self.buf.get(..len).unwrap_or(&[]);
        match Request::parse(echo) {
            Ok(r) => self.request = Some(r),
            Err(e) => {
                self.request = None;
                self.echo_error = e;
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
        self.pp = SensorParams::default();
    }

    fn status_line(&mut self, len: usize) -> Option<Event<'_>> {
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
            (_, None) => return self.fail(ErrorKind::UnknownEcho(self.echo_error)),
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

    fn begin_scan(&mut self, scan: ScanRequest, status: Status) -> Payload {
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

    fn payload_line(&mut self, p: Payload, len: usize) -> Option<Event<'_>> {
        match p {
            Payload::None => self.fail(ErrorKind::UnexpectedPayload),
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
                self.timestamp = Some(ts);
                self.state = State::Payload(if p == Payload::Time {
                    Payload::None
                } else {
                    Payload::Data
                });
                Some(Event::Timestamp(ts))
            }
            Payload::Data => self.data_line(len),
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
                let body = self.buf.get(..len - 1).unwrap_or(&[]);
                Some(Event::Payload(body))
            }
        }
    }

    fn field_line(&mut self, len: usize) -> Option<Event<'_>> {
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
        let plain = checksum(body);
        let ok = plain == s
            || (plain.wrapping_sub(0x30).wrapping_add(b';') & 0x3F) + 0x30 == s
            || body
                .windows(2)
                .position(|w| w == b"<-")
                .and_then(|i| body.get(..i))
                .is_some_and(|head| checksum(head) == s);
        if !ok {
            return self.fail(ErrorKind::BadSum {
                expected: plain,
                found: s,
            });
        }
        let name_end = colon;
        let body_len = body.len();
        let is_pp = matches!(self.request.map(|r| r.command), Some(Command::Parameters));
        let (name, value) = (
            self.buf.get(..name_end).unwrap_or(&[]),
            self.buf.get(name_end + 1..body_len).unwrap_or(&[]),
        );
        let param = if is_pp {
            Param::parse(name, value)
        } else {
            None
        };
        if is_pp {
            self.pp.apply(name, value);
        }
        let (name, value) = (
            self.buf.get(..name_end).unwrap_or(&[]),
            self.buf.get(name_end + 1..body_len).unwrap_or(&[]),
        );
        Some(Event::Field(Field { name, value, param }))
    }

    fn data_line(&mut self, len: usize) -> Option<Event<'_>> {
        if len < 2 {
            return self.fail(ErrorKind::BadDataLineLength);
        }
        let n = len - 1;
        let (expected, found) = match self.buf.get(..len) {
            Some([data @ .., s]) => (checksum(data), *s),
            _ => return self.fail(ErrorKind::BadDataLineLength),
        };
        if expected != found {
            return self.fail(ErrorKind::BadSum { expected, found });
        }
        if n > DATA_CHARS || self.short_line_seen {
            return self.fail(ErrorKind::BadDataLineLength);
        }
        if n < DATA_CHARS {
            self.short_line_seen = true;
        }
        self.n_readings = 0;
        if let Err(kind) = self.decode_values(n) {
            return self.fail(kind);
        }
        Some(Event::Data(DataLine {
            readings: self.readings.get(..self.n_readings).unwrap_or(&[]),
            data: self.shape.data,
            limits: self.limits,
            line: self.line_no,
        }))
    }

    /// Decodes the first `n` bytes of the buffer as value chars, carrying partial values.
    fn decode_values(&mut self, n: usize) -> Result<(), ErrorKind> {
        let mut carry = self.carry;
        let mut carry_n = self.carry_n;
        let mut want = self.want;
        let buf = self.buf;
        let chars = buf.get(..n).unwrap_or(&[]);
        for (col, &c) in chars.iter().enumerate() {
            let v = c.wrapping_sub(CHAR_MIN);
            if v >= 0x40 {
                if c == b'&' {
                    self.ampersand(carry_n, col)?;
                    continue;
                }
                return Err(ErrorKind::BadChar { column: col as u8 });
            }
            carry = (carry << 6) | u32::from(v);
            carry_n += 1;
            if carry_n == want {
                want = self.value_done(carry)?;
                carry = 0;
                carry_n = 0;
            }
        }
        self.carry = carry;
        self.carry_n = carry_n;
        self.want = want;
        Ok(())
    }

    fn ampersand(&mut self, carry_n: u8, col: usize) -> Result<(), ErrorKind> {
        if !self.shape.multi_echo {
            return Err(ErrorKind::BadChar { column: col as u8 });
        }
        if carry_n != 0 || self.in_aux || self.values == 0 || self.next_is_echo {
            return Err(ErrorKind::MisplacedEcho);
        }
        self.echo_no += 1;
        if self.echo_no >= MAX_ECHOES {
            return Err(ErrorKind::TooManyEchoes);
        }
        self.next_is_echo = true;
        Ok(())
    }

    /// A value of `want` chars is complete; returns the width of the next one.
    #[inline]
    fn value_done(&mut self, value: u32) -> Result<u8, ErrorKind> {
        if !self.in_aux && self.shape.aux_width != 0 {
            self.pending_distance = value;
            self.in_aux = true;
            return Ok(self.shape.aux_width);
        }
        let (distance, aux) = if self.in_aux {
            (self.pending_distance, value)
        } else {
            (value, 0)
        };
        self.in_aux = false;
        let (index, echo) = if self.next_is_echo {
            self.next_is_echo = false;
            self.extra_echoes = self.extra_echoes.saturating_add(1);
            (self.values.saturating_sub(1), self.echo_no)
        } else {
            if self.values >= self.shape.expected {
                return Err(ErrorKind::TooManyValues {
                    expected: self.shape.expected,
                });
            }
            self.echo_no = 0;
            self.values += 1;
            (self.values - 1, 0)
        };
        let slot = self
            .readings
            .get_mut(self.n_readings)
            .ok_or(ErrorKind::TooManyValues {
                expected: self.shape.expected,
            })?;
        *slot = Reading {
            index,
            echo,
            distance,
            aux,
        };
        self.n_readings += 1;
        Ok(self.shape.dist_width)
    }

    fn end_response(&mut self) -> Option<Event<'_>> {
        if let State::Payload(p @ (Payload::ScanTimestamp | Payload::Data)) = self.state {
            if self.carry_n != 0 || self.in_aux || self.next_is_echo {
                return self.fail(ErrorKind::TruncatedValue);
            }
            if p == Payload::ScanTimestamp || self.values != self.shape.expected {
                return self.fail(ErrorKind::CountMismatch {
                    expected: self.shape.expected,
                    found: self.values,
                });
            }
        }
        if matches!(self.state, State::Payload(Payload::Fields))
            && matches!(self.request.map(|r| r.command), Some(Command::Parameters))
        {
            self.params = self.pp;
            if let Some(dmin) = self.pp.dmin {
                self.limits.dmin = dmin;
            }
            if let Some(family) = self.pp.family {
                self.limits.family = family;
            }
        }
        self.state = State::Idle;
        self.stats.responses += 1;
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
