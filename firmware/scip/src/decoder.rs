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
use crate::info::{Param, ParamError, Range, RangeLimits, SensorParams};
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
/// The largest timestamp step from one intact stream frame to the next that passes the
/// sequence check ([`ErrorKind::OutOfSequence`]), ms: ten skipped scans of the slowest
/// model at its lowest speed, with room for frames lost in between. A longer gap costs
/// one good frame (the next one is checked against nothing).
pub const STREAM_GAP_MAX_MS: u32 = 10_000;

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

/// Counters of what the decoder saw. Every counter wraps at its width (like the CAN
/// status frames' counters): take differences of two readings with `wrapping_sub`.
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
    /// The echo did not parse: its status is reported (a `99` tells a stream frame from
    /// an info answer's `00`), then a payload line fails the response with
    /// [`ErrorKind::UnknownEcho`], and so does its end when the echo is damaged; an
    /// answer without payload to a command of two capital letters (e.g. SCIP 2.2's `RB`
    /// `00`) ends intact.
    Unknown,
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
    /// Of the line's bytes so far, taken while they are copied: their sum (mod 64 is
    /// what counts) and, in bits 6 and 7, a flag for a byte that is not a value char
    /// (see [`Self::take_line_bytes`]).
    sum: u32,
    bad: u32,
    offset: u64,
    line_start: u64,
    current_line: u64,
    state: State,
    skip_checks_sums: bool,
    // The response being decoded.
    request: Option<Request>,
    echo_error: EchoError,
    /// The echo that did not parse names a command all the same (capital letters): an
    /// answer without payload to it ends intact.
    echo_plain: bool,
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
    /// Every reading slot has echo 0 and aux 0 (see [`Self::decode_steps`]).
    readings_plain: bool,
    n_readings: usize,
    /// The last intact frame of a continuous stream (its echo's request, the count =
    /// scans remaining, and its timestamp): the next frame must follow it.
    last_frame: Option<(ScanRequest, u32)>,
    /// The stream frame being decoded, once its timestamp passed the sequence check.
    this_frame: Option<(ScanRequest, u32)>,
    // What the decoder learned of the sensor.
    params: SensorParams,
    pp: SensorParams,
    limits: RangeLimits,
    stats: DecoderStats,
    /// Tests and fuzzing only: never take the whole-step fast path.
    #[cfg(any(test, fuzzing))]
    char_by_char: bool,
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
        const EMPTY: SensorParams = SensorParams::EMPTY;
        Self {
            buf: [0; LINE_CAP],
            len: 0,
            overflow: false,
            sum: 0,
            bad: 0,
            offset: 0,
            line_start: 0,
            current_line: 0,
            state: State::Idle,
            skip_checks_sums: false,
            request: None,
            echo_error: EchoError::UnknownCommand,
            echo_plain: false,
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
            readings_plain: true,
            n_readings: 0,
            last_frame: None,
            this_frame: None,
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
            #[cfg(any(test, fuzzing))]
            char_by_char: false,
        }
    }

    /// A decoder that decodes every value char by char, never a whole step at a time:
    /// the reference the fast path is checked against. Only in tests and under
    /// `cfg(fuzzing)` (set by `cargo fuzz`).
    #[cfg(any(test, fuzzing))]
    #[doc(hidden)]
    pub fn char_by_char() -> Self {
        let mut d = Self::new();
        d.char_by_char = true;
        d
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

    /// The PP parameters of the last intact PP response whose fields are whole and
    /// plausible ([`SensorParams::check`]; a unit differing from its model's table is
    /// accepted here).
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

    /// Forgets the stream frames seen so far: the next frame is not checked against them
    /// (a new session, whose sensor may have restarted its clock).
    pub fn forget_stream(&mut self) {
        self.last_frame = None;
        self.this_frame = None;
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
    #[inline]
    pub fn feed(&mut self, input: &[u8]) -> (usize, Option<Event<'_>>) {
        let mut consumed: usize = 0;
        let mut rest = input;
        loop {
            // The stream offset and the byte counter wrap (after 2^64 bytes).
            let Some(lf) = self.take_line_bytes(rest) else {
                self.offset = self.offset.wrapping_add(rest.len() as u64);
                self.stats.bytes = self.stats.bytes.wrapping_add(rest.len() as u64);
                return (input.len(), None);
            };
            // `lf` indexes `rest`, a tail of `input`: `consumed + lf + 1 <= input.len()`.
            let line = lf.wrapping_add(1);
            consumed = consumed.wrapping_add(line);
            self.offset = self.offset.wrapping_add(line as u64);
            self.stats.bytes = self.stats.bytes.wrapping_add(line as u64);
            rest = rest.get(line..).unwrap_or(&[]);
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

    /// Copies `bytes` up to the first LF into the line buffer and returns the LF's
    /// index, or copies them all and returns `None`. One pass that also takes what
    /// [`Self::data_line`] needs: the byte sum (mod 64) and whether every byte is a
    /// value char. Words of value chars go through [`copy_value_words`]; a word with
    /// anything else in it (the LF, the sum char of some lines, a damaged byte) goes byte
    /// by byte. Past the buffer's capacity the line is
    /// marked overflowed and its bytes are not kept.
    #[inline]
    fn take_line_bytes(&mut self, bytes: &[u8]) -> Option<usize> {
        #[cfg(target_pointer_width = "32")]
        {
            self.take_line_bytes_fused(bytes)
        }
        #[cfg(not(target_pointer_width = "32"))]
        {
            self.take_line_bytes_plain(bytes)
        }
    }

    /// [`Self::take_line_bytes`] as 64-bit hosts do it best: the LF found eight bytes at
    /// a time, the bytes copied, and the sum and char check left to [`sum_and_check`]
    /// (vectorised there) by flagging the accumulators as unusable.
    #[cfg_attr(target_pointer_width = "32", allow(dead_code))]
    #[inline]
    fn take_line_bytes_plain(&mut self, bytes: &[u8]) -> Option<usize> {
        self.bad = 0xC0;
        let lf = find_lf(bytes);
        let line = bytes.get(..lf.unwrap_or(bytes.len())).unwrap_or(&[]);
        if !self.overflow {
            // `self.len <= LINE_CAP` and a slice's length is at most `isize::MAX`: no wrap.
            let end = self.len.wrapping_add(line.len());
            match self.buf.get_mut(self.len..end) {
                Some(dst) => {
                    dst.copy_from_slice(line);
                    self.len = end;
                }
                None => self.overflow = true,
            }
        }
        lf
    }

    /// [`Self::take_line_bytes`] as 32-bit MCUs do it best: one pass of
    /// [`copy_value_words`] and a byte loop for the rest, the sum and char check taken
    /// on the way.
    #[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
    #[inline]
    fn take_line_bytes_fused(&mut self, bytes: &[u8]) -> Option<usize> {
        if self.overflow {
            return find_lf(bytes);
        }
        if self.len == 0 {
            (self.sum, self.bad) = (0, 0);
        }
        let (mut len, mut sum, mut bad) = (self.len, self.sum, self.bad);
        let mut at = 0;
        let found = loop {
            // Whole words of value chars, as many as the input and the buffer have.
            let input = bytes.get(at..).unwrap_or(&[]);
            let room = self.buf.get_mut(len..).unwrap_or(&mut []);
            let (taken, add) = copy_value_words(input, room);
            sum = sum.wrapping_add(add);
            // `len` stays within the line buffer and `at` within `bytes` (`taken` fits
            // both), so neither index wraps; nor does any `at + i` below.
            len = len.wrapping_add(taken);
            at = at.wrapping_add(taken);
            // Then up to four bytes one at a time.
            let Some(next) = bytes.get(at..).filter(|r| !r.is_empty()) else {
                break None;
            };
            let mut lf = None;
            for (i, &b) in next.iter().take(4).enumerate() {
                if b == b'\n' {
                    lf = Some(at.wrapping_add(i));
                    break;
                }
                match self.buf.get_mut(len) {
                    Some(slot) => *slot = b,
                    None => {
                        self.overflow = true;
                        let from = at.wrapping_add(i);
                        lf = Some(
                            find_lf(bytes.get(from..).unwrap_or(&[]))
                                .map_or(usize::MAX, |j| from.wrapping_add(j)),
                        );
                        break;
                    }
                }
                len = len.wrapping_add(1);
                sum = sum.wrapping_add(u32::from(b));
                bad |= u32::from(b.wrapping_sub(CHAR_MIN));
            }
            match lf {
                Some(usize::MAX) => break None,
                Some(i) => break Some(i),
                None => at = at.wrapping_add(next.len().min(4)),
            }
        };
        (self.len, self.sum, self.bad) = (len, sum, bad);
        found
    }

    /// The sum char of the buffered line's first `len - 1` bytes and whether all of them
    /// are value chars, as [`sum_and_check`] gives them: from what
    /// [`Self::take_line_bytes`] took when every byte of the line (sum char included) is
    /// a value char, else computed again.
    #[inline]
    fn line_sum_and_check(&self, len: usize) -> Option<(u8, u8, bool)> {
        let [data @ .., s] = self.buf.get(..len)? else {
            return None;
        };
        // The accumulators cover exactly the line just completed (it did not overflow, or
        // it would not be decoded).
        if self.bad & 0xC0 == 0 {
            // 0x30..=0x6F: no wrap.
            let sum = ((self.sum.wrapping_sub(u32::from(*s)) & 0x3F) as u8).wrapping_add(0x30);
            return Some((sum, *s, true));
        }
        let (sum, valid) = sum_and_check(data);
        Some((sum, *s, valid))
    }

    /// Handles a complete line quickly when it produces no event (empty lines between
    /// responses, lines skipped after an error); true when [`Self::line_event`] must run.
    #[inline]
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
        self.stats.resyncs = self.stats.resyncs.wrapping_add(1);
        Some(self.error(kind, line))
    }

    /// Processes the complete line in the buffer. Kept out of line so that [`Self::feed`]
    /// stays small for the calls that only buffer bytes.
    #[inline(never)]
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
                // `len >= 1`: the line matched `[body @ .., s]` above.
                let body = self.buf.get(..len.wrapping_sub(1)).unwrap_or(&[]);
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
            || (plain.wrapping_sub(0x30).wrapping_add(b';') & 0x3F).wrapping_add(0x30) == s
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
        // The colon is in `body`, itself in the line buffer: no wrap.
        let value_start = colon.wrapping_add(1);
        let body_len = body.len();
        let is_pp = matches!(self.request.map(|r| r.command), Some(Command::Parameters));
        let (name, value) = (
            self.buf.get(..name_end).unwrap_or(&[]),
            self.buf.get(value_start..body_len).unwrap_or(&[]),
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
            self.buf.get(value_start..body_len).unwrap_or(&[]),
        );
        Some(Event::Field(Field { name, value, param }))
    }

    fn data_line(&mut self, len: usize) -> Option<Event<'_>> {
        if len < 2 {
            return self.fail(ErrorKind::BadDataLineLength);
        }
        // Data chars, sum char excluded (`len >= 2`).
        let n = len.wrapping_sub(1);
        // One pass for the sum and the value-char check of the fast path.
        let Some((expected, found, all_valid)) = self.line_sum_and_check(len) else {
            return self.fail(ErrorKind::BadDataLineLength);
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
        if let Err(kind) = self.decode_values(n, all_valid) {
            return self.fail(kind);
        }
        Some(Event::Data(DataLine {
            readings: self.readings.get(..self.n_readings).unwrap_or(&[]),
            data: self.shape.data,
            limits: self.limits,
            line: self.line_no,
        }))
    }

    /// Decodes the first `n` bytes of the buffer as value chars, carrying partial values;
    /// `all_valid` tells that all of them are value chars (see [`sum_and_check`]).
    fn decode_values(&mut self, n: usize, all_valid: bool) -> Result<(), ErrorKind> {
        // Fast path: a line of valid value chars only (no `&`, nothing to report by
        // column) is decoded a whole step at a time. Anything else goes char by char.
        #[cfg(any(test, fuzzing))]
        let all_valid = all_valid && !self.char_by_char;
        if !self.shape.multi_echo && all_valid {
            match (self.shape.dist_width, self.shape.aux_width) {
                (3, 0) => return self.decode_steps::<3, 0>(n),
                (2, 0) => return self.decode_steps::<2, 0>(n),
                (3, 3) => return self.decode_steps::<3, 3>(n),
                (3, 2) => return self.decode_steps::<3, 2>(n),
                (3, 4) => return self.decode_steps::<3, 4>(n),
                _ => {}
            }
        }
        self.decode_chars_copied(n)
    }

    /// Decodes the first `n` bytes of the buffer (all valid value chars, see
    /// [`sum_and_check`]) of a data set
    /// with `D`-char distances and `A`-char second values, a whole step at a time: the
    /// step begun on the previous line is completed from the carried value, the whole
    /// steps go straight into readings, the partial step at the end is carried. Same
    /// readings, state and errors as [`Self::decode_chars`] on the same chars.
    fn decode_steps<const D: usize, const A: usize>(&mut self, n: usize) -> Result<(), ErrorKind> {
        // 2..=7 chars: the `D + A` of the data sets dispatched in `decode_values`.
        let width = D.wrapping_add(A);
        let chars = self.buf.get(..n).unwrap_or(&[]);
        let carried = usize::from(self.carry_n);
        // The step begun on the previous line, completed.
        let mut head = None;
        let mut rest = chars;
        if carried != 0 || self.in_aux {
            let (distance, aux, used) = if self.in_aux {
                let need = A.saturating_sub(carried);
                let Some(a) = chars.get(..need) else {
                    return self.decode_chars_copied(n);
                };
                (self.pending_distance, continue_valid(self.carry, a), need)
            } else {
                let need = D.saturating_sub(carried);
                // At most `D + A`: no wrap.
                let used = need.wrapping_add(A);
                let (Some(d), Some(a)) = (chars.get(..need), chars.get(need..used)) else {
                    return self.decode_chars_copied(n);
                };
                (continue_valid(self.carry, d), continue_valid(0, a), used)
            };
            head = Some((distance, aux));
            rest = chars.get(used..).unwrap_or(&[]);
        }
        // `width` is a nonzero constant here: the division folds, the `0` is never taken.
        let whole = rest.len().checked_div(width).unwrap_or(0);
        // Lengths and counts within one line (at most LINE_CAP): none of these wraps.
        let (mid, tail) = rest.split_at(whole.wrapping_mul(width));
        let total = whole.wrapping_add(usize::from(head.is_some()));
        let too_many = ErrorKind::TooManyValues {
            expected: self.shape.expected,
        };
        if usize::from(self.values).wrapping_add(total) > usize::from(self.shape.expected) {
            return Err(too_many);
        }
        if A == 0 && !self.readings_plain {
            // Once per change of data set: clear what readings with echoes or second
            // values left, so that distance-only lines write less.
            self.readings = [Reading::default(); MAX_READINGS];
            self.readings_plain = true;
        } else if A > 0 {
            self.readings_plain = false;
        }
        let first = self.n_readings;
        let end = first.wrapping_add(total);
        let slots = self.readings.get_mut(first..end).ok_or(too_many)?;
        let mut index = self.values;
        let mut slots = slots.iter_mut();
        if let Some((distance, aux)) = head {
            if let Some(slot) = slots.next() {
                *slot = Reading {
                    index,
                    echo: 0,
                    distance,
                    aux,
                };
                index = index.wrapping_add(1);
            }
        }
        if A == 0 && self.readings_plain {
            // Every slot already has echo 0 and aux 0: the distance and index will do.
            for (slot, step) in slots.zip(mid.chunks_exact(width)) {
                if let Some(d) = step.first_chunk::<D>() {
                    slot.distance = decode_valid(d);
                    slot.index = index;
                }
                index = index.wrapping_add(1);
            }
        } else {
            for (slot, step) in slots.zip(mid.chunks_exact(width)) {
                let Some((d, a)) = step.split_first_chunk::<D>() else {
                    continue;
                };
                let Some(a) = a.first_chunk::<A>() else {
                    continue;
                };
                *slot = Reading {
                    index,
                    echo: 0,
                    distance: decode_valid(d),
                    aux: decode_valid(a),
                };
                index = index.wrapping_add(1);
            }
        }
        if total > 0 {
            self.echo_no = 0;
        }
        self.values = index;
        self.n_readings = end;
        // The partial step at the end: a distance and part of its second value, or part
        // of a distance.
        match tail.split_at_checked(D) {
            Some((d, a)) if A > 0 => {
                self.pending_distance = continue_valid(0, d);
                self.in_aux = true;
                self.carry = continue_valid(0, a);
                self.carry_n = a.len() as u8;
                self.want = A as u8;
            }
            _ => {
                self.in_aux = false;
                self.carry = continue_valid(0, tail);
                self.carry_n = tail.len() as u8;
                self.want = D as u8;
            }
        }
        Ok(())
    }

    /// [`Self::decode_chars`] on the first `n` bytes of the buffer.
    fn decode_chars_copied(&mut self, n: usize) -> Result<(), ErrorKind> {
        let buf = self.buf;
        self.decode_chars(buf.get(..n).unwrap_or(&[]), 0)
    }

    /// Decodes `chars` one by one, carrying partial values; `col0` is the column of the
    /// first of them in its line.
    fn decode_chars(&mut self, chars: &[u8], col0: usize) -> Result<(), ErrorKind> {
        let mut carry = self.carry;
        let mut carry_n = self.carry_n;
        let mut want = self.want;
        for (i, &c) in chars.iter().enumerate() {
            // A column within one line: no wrap.
            let col = col0.wrapping_add(i);
            let v = c.wrapping_sub(CHAR_MIN);
            if v >= 0x40 {
                if c == b'&' {
                    self.ampersand(carry_n, col)?;
                    continue;
                }
                return Err(ErrorKind::BadChar { column: col as u8 });
            }
            carry = (carry << 6) | u32::from(v);
            // Below `want` (at most 4) before this char: no wrap.
            carry_n = carry_n.wrapping_add(1);
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
        // Below MAX_ECHOES before: the check below fails the response at MAX_ECHOES.
        self.echo_no = self.echo_no.wrapping_add(1);
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
            // Below `expected` (checked above), so `+ 1` fits.
            let index = self.values;
            self.values = index.wrapping_add(1);
            (index, 0)
        };
        let slot = self
            .readings
            .get_mut(self.n_readings)
            .ok_or(ErrorKind::TooManyValues {
                expected: self.shape.expected,
            })?;
        self.readings_plain &= echo == 0 && aux == 0;
        *slot = Reading {
            index,
            echo,
            distance,
            aux,
        };
        // The slot at `n_readings` exists (above): below MAX_READINGS, no wrap.
        self.n_readings = self.n_readings.wrapping_add(1);
        Ok(self.shape.dist_width)
    }

    /// The sequence check of a stream frame with timestamp `ts` against the last intact
    /// frame of the same stream: a later timestamp (24-bit wrap allowed, at most
    /// [`STREAM_GAP_MAX_MS`] on) and a remaining-scans count that went down (or stays
    /// `00` for an endless stream). A frame that fails clears the reference, so that
    /// one bad frame cannot hold up the ones after it.
    fn frame_in_sequence(&mut self, ts: u32) -> bool {
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

    /// A measurement that ended wrong: reported, and the response is over (the empty
    /// line that ended it has been read, so nothing is left to skip).
    fn fail_at_end(&mut self, kind: ErrorKind) -> Option<Event<'static>> {
        let ev = self.fail(kind);
        self.state = State::Idle;
        ev
    }

    fn end_response(&mut self) -> Option<Event<'_>> {
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

/// Copies the longest run of whole 4-byte words of value chars (`0x30..=0x6F`) at the
/// start of `input` into `dst` (as far as `dst` has room); returns the bytes copied and
/// their sum less `0x30` each (so the same mod 64). A word is tested at once: no byte of
/// `w - 0x30303030` has bit 6 or 7 set exactly when every byte is a value char (a byte
/// below 0x30 flags itself, whatever it borrows); its four values below 0x40 are summed
/// by one multiplication (no partial sum carries).
#[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
#[inline(always)]
fn copy_value_words(input: &[u8], dst: &mut [u8]) -> (usize, u32) {
    const FLAGS: u32 = 0xC0C0_C0C0;
    const CHARS: u32 = 0x3030_3030;
    let (mut words, mut sum) = (0usize, 0u32);
    for (src, out) in input.chunks_exact(4).zip(dst.chunks_exact_mut(4)) {
        let Ok(four) = <[u8; 4]>::try_from(src) else {
            break;
        };
        let v = u32::from_le_bytes(four).wrapping_sub(CHARS);
        if v & FLAGS != 0 {
            break;
        }
        out.copy_from_slice(&four);
        // Words of `input`: neither this count nor `4 * words` below wraps.
        words = words.wrapping_add(1);
        // The top byte of v·0x01010101 is the sum of v's four bytes.
        sum = sum.wrapping_add(v.wrapping_mul(0x0101_0101) >> 24);
    }
    (words.wrapping_mul(4), sum)
}

/// The sum char of `bytes` (as [`checksum`]) and whether every byte is a value char
/// (`0x30..=0x6F`), in one branch-free pass: bytewise where that vectorises, a 32-bit
/// word at a time on 32-bit targets (a Cortex-M4 has no vectors for it).
#[inline]
fn sum_and_check(bytes: &[u8]) -> (u8, bool) {
    #[cfg(target_pointer_width = "32")]
    {
        sum_and_check_words(bytes)
    }
    #[cfg(not(target_pointer_width = "32"))]
    {
        sum_and_check_bytes(bytes)
    }
}

/// [`sum_and_check`] a byte at a time.
#[cfg_attr(target_pointer_width = "32", allow(dead_code))]
#[inline]
fn sum_and_check_bytes(bytes: &[u8]) -> (u8, bool) {
    let (sum, chars) = fold_chars(bytes);
    // 0x30..=0x6F: no wrap.
    ((sum & 0x3F).wrapping_add(0x30), chars < 0x40)
}

/// The byte sum and the OR of every `c - 0x30` (below `0x40` iff all are value chars).
#[inline(always)]
fn fold_chars(bytes: &[u8]) -> (u8, u8) {
    bytes.iter().fold((0u8, 0u8), |(sum, chars), &c| {
        (sum.wrapping_add(c), chars | c.wrapping_sub(CHAR_MIN))
    })
}

/// [`sum_and_check`] four bytes at a time. The sum goes into two 16-bit lanes (bytes 0
/// and 2, bytes 1 and 3), kept below `2^12` so no lane carries into the next (only the
/// sum mod 64 counts). The check tests every byte's top bit after arithmetic that never
/// carries or borrows across bytes: a value char has its top bit clear, `c + 0x10`
/// below `0x80` (`c <= 0x6F`) and `(c | 0x80) - 0x30` at least `0x80` (`c >= 0x30`).
#[cfg_attr(not(target_pointer_width = "32"), allow(dead_code))]
#[inline]
fn sum_and_check_words(bytes: &[u8]) -> (u8, bool) {
    const HIGHS: u32 = 0x8080_8080;
    const LOWS: u32 = 0x7F7F_7F7F;
    const EVEN: u32 = 0x00FF_00FF;
    let mut words = bytes.chunks_exact(4);
    let (mut lanes, mut bad) = (0u32, 0u32);
    for word in &mut words {
        let w = u32::from_le_bytes(word.try_into().unwrap_or([0; 4]));
        lanes = (lanes & 0x0FFF_0FFF)
            .wrapping_add(w & EVEN)
            .wrapping_add((w >> 8) & EVEN);
        let low = w & LOWS;
        bad |= w | low.wrapping_add(0x1010_1010) | !(low | HIGHS).wrapping_sub(0x3030_3030);
    }
    let (rest_sum, rest_chars) = fold_chars(words.remainder());
    let sum = (lanes & 0xFFFF)
        .wrapping_add(lanes >> 16)
        .wrapping_add(u32::from(rest_sum));
    (
        // 0x30..=0x6F: no wrap.
        ((sum & 0x3F) as u8).wrapping_add(0x30),
        bad & HIGHS == 0 && rest_chars < 0x40,
    )
}

/// The value of `N` valid value chars (see [`sum_and_check`]), most significant first.
///
/// Sums the raw bytes in base 64, then takes the `0x30` of every char off at once:
/// `Σ (c - 0x30)·64^k = Σ c·64^k - 0x30·Σ 64^k`, exact in `u32` for up to 4 chars.
#[inline(always)]
fn decode_valid<const N: usize>(chars: &[u8; N]) -> u32 {
    let raw = chars
        .iter()
        .fold(0u32, |acc, &c| (acc << 6).wrapping_add(u32::from(c)));
    let offset = chars
        .iter()
        .fold(0u32, |acc, _| (acc << 6).wrapping_add(u32::from(CHAR_MIN)));
    raw.wrapping_sub(offset)
}

/// `carry` continued by valid value chars (see [`sum_and_check`]).
#[inline]
fn continue_valid(carry: u32, chars: &[u8]) -> u32 {
    chars.iter().fold(carry, |acc, &c| {
        (acc << 6) | u32::from(c.wrapping_sub(CHAR_MIN) & 0x3F)
    })
}

/// Index of the first LF in `bytes`, eight bytes at a time: a zero-byte test on the
/// bytes XOR LF, whose lowest flagged byte is exact (borrows only run upwards).
#[inline]
fn find_lf(bytes: &[u8]) -> Option<usize> {
    const ONES: u64 = u64::from_le_bytes([0x01; 8]);
    const HIGHS: u64 = u64::from_le_bytes([0x80; 8]);
    const LFS: u64 = u64::from_le_bytes([b'\n'; 8]);
    let lf_in = |word: [u8; 8]| {
        let x = u64::from_le_bytes(word) ^ LFS;
        let hit = x.wrapping_sub(ONES) & !x & HIGHS;
        (hit != 0).then_some((hit.trailing_zeros() / 8) as usize)
    };
    let mut words = bytes.chunks_exact(8);
    let mut at: usize = 0;
    for word in &mut words {
        // Indices within `bytes`: no wrap.
        if let Some(i) = lf_in(word.try_into().unwrap_or([0; 8])) {
            return Some(at.wrapping_add(i));
        }
        at = at.wrapping_add(8);
    }
    if words.remainder().is_empty() {
        return None;
    }
    // The last eight bytes, overlapping bytes already found free of LF.
    match bytes.last_chunk::<8>() {
        // `bytes` has at least the eight bytes of `last`: no wrap.
        Some(last) => lf_in(*last).map(|i| bytes.len().wrapping_sub(8).wrapping_add(i)),
        None => bytes.iter().position(|&b| b == b'\n'),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::ScanMode;
    use crate::response::ResponseWriter;

    /// The kinds of events a whole input gives, one char each: S start, T status,
    /// F field, E error, N end, other x.
    fn kinds(input: &[u8]) -> String {
        let mut d = Decoder::new();
        let mut out = String::new();
        let mut rest = input;
        while !rest.is_empty() {
            let (n, ev) = d.feed(rest);
            rest = &rest[n..];
            out.push(match ev {
                None => continue,
                Some(Event::Start { .. }) => 'S',
                Some(Event::Status(_)) => 'T',
                Some(Event::Field(_)) => 'F',
                Some(Event::Error(e)) => {
                    assert!(matches!(e.kind, ErrorKind::UnknownEcho(_)), "{e:?}");
                    'E'
                }
                Some(Event::End(_)) => 'N',
                Some(_) => 'x',
            });
        }
        out
    }

    #[test]
    fn an_unknown_echo_reports_its_status_before_failing() {
        // A stream frame whose echo lost a bit: status 99 reported, then the failure.
        assert_eq!(kinds(b"mD0000000101000\n99b\n0000\n000\n\n"), "STE");
        // An info answer: 00, then the failure at its first field.
        assert_eq!(kinds(b"Pp\n00P\nDMIN:20;4\n\n"), "STE");
        // Or at its end, when it has no payload line.
        assert_eq!(kinds(b"Pp\n00P\n\n"), "STE");
        // A status without payload: an answer like any other.
        assert_eq!(kinds(b"Pp\n0Ee\n\n"), "STN");
    }

    #[test]
    fn counters_wrap_at_their_width() {
        let mut d = Decoder::new();
        d.stats = DecoderStats {
            bytes: u64::MAX,
            responses: u32::MAX,
            errors: u32::MAX,
            by_kind: [u32::MAX; ErrorKind::COUNT],
            resyncs: u32::MAX,
        };
        let feed_all = |d: &mut Decoder, mut rest: &[u8]| {
            while !rest.is_empty() {
                let (n, _) = d.feed(rest);
                rest = &rest[n..];
            }
        };
        // An intact QT answer (8 bytes), then an answer to a damaged echo (an error and
        // a resync, 8 bytes).
        feed_all(&mut d, b"QT\n00P\n\n");
        assert_eq!((d.stats.responses, d.stats.bytes), (0, 7));
        assert_eq!((d.stats.errors, d.stats.resyncs), (u32::MAX, u32::MAX));
        feed_all(&mut d, b"Pp\n00P\n\n");
        assert_eq!((d.stats.responses, d.stats.bytes), (0, 15));
        assert_eq!((d.stats.errors, d.stats.resyncs), (0, 0));
        let kind = ErrorKind::UnknownEcho(EchoError::UnknownCommand).index();
        for (i, &c) in d.stats.by_kind.iter().enumerate() {
            assert_eq!(c, if i == kind { 0 } else { u32::MAX }, "kind {i}");
        }
    }

    #[test]
    fn distance_lines_after_intensity_lines_carry_no_old_intensity() {
        // Readings of a distance-only scan are written without their echo and aux when
        // the slots are known clear: after a scan with intensities they must be cleared.
        let (ge, _) = scan(DataSet::DistanceIntensity, 100);
        let (gd, values) = scan(DataSet::Distance, 100);
        let mut both = ge.clone();
        both.extend_from_slice(&gd);
        for chunk in [1, 7, 64, 4096] {
            let (_, after) = decode(Decoder::new(), &both, chunk);
            let (_, alone) = decode(Decoder::new(), &gd, chunk);
            assert_eq!(&after[100..], &alone[..], "chunk {chunk}");
            assert!(alone
                .iter()
                .zip(&values)
                .all(|(r, &(d, _))| r.distance == d && r.aux == 0));
        }
    }

    #[test]
    fn value_words_copied_agree_with_bytes() {
        let mut x = 0x0BAD_CAFEu32;
        let mut next = || {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            x >> 8
        };
        for _ in 0..20_000 {
            let len = next() as usize % 100;
            let mut input: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
            if len > 0 && next() % 2 == 0 {
                let at = next() as usize % len;
                input[at] = next() as u8;
            }
            let room = next() as usize % 110;
            let mut d = vec![0u8; room];
            let (taken, sum) = copy_value_words(&input, &mut d);
            assert_eq!(&d[..taken], &input[..taken]);
            // The longest whole-word prefix of value chars that fits.
            let valid = input
                .iter()
                .take_while(|&&b| (0x30..=0x6F).contains(&b))
                .count();
            assert_eq!(taken, valid.min(room) / 4 * 4, "{input:?} room {room}");
            let bytes_sum: u32 = input[..taken].iter().map(|&b| u32::from(b) - 0x30).sum();
            assert_eq!(sum, bytes_sum, "{input:?}");
        }
    }

    #[test]
    fn sum_and_check_taken_while_copying_equals_the_bytewise_one() {
        // Lines of value chars (some with one arbitrary byte, never LF), their LF, in
        // pseudo-random pieces: what `take_line_bytes` takes must be what
        // `sum_and_check_bytes` computes over the line's data.
        let mut x = 0x9E37_79B9u32;
        let mut next = || {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            x >> 8
        };
        for _ in 0..20_000 {
            let len = 1 + next() as usize % 90;
            let mut line: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
            if next() % 2 == 0 {
                let at = next() as usize % len;
                line[at] = match next() as u8 {
                    b'\n' => 0,
                    b => b,
                };
            }
            let mut stream = line.clone();
            stream.push(b'\n');
            let fused = next() % 2 == 0;
            let mut d = Decoder::new();
            let mut rest = &stream[..];
            let mut lf = None;
            let mut base = 0;
            while lf.is_none() && !rest.is_empty() {
                let piece = (1 + next() as usize % 70).min(rest.len());
                let found = if fused {
                    d.take_line_bytes_fused(&rest[..piece])
                } else {
                    d.take_line_bytes_plain(&rest[..piece])
                };
                lf = found.map(|i| base + i);
                base += piece;
                rest = &rest[piece..];
            }
            assert_eq!(lf, Some(len), "{line:?}");
            let expect = sum_and_check_bytes(&line[..len - 1]);
            let overflow = len > LINE_CAP;
            if !overflow {
                let (sum, found, valid) = d.line_sum_and_check(len).unwrap();
                assert_eq!(found, line[len - 1]);
                assert_eq!((sum, valid), expect, "{line:?}");
            }
        }
    }

    #[test]
    fn word_sum_and_check_equals_the_bytewise_one() {
        let chars: Vec<u8> = (0x30..=0x6F).collect();
        let check = |line: &[u8]| {
            let words = sum_and_check_words(line);
            assert_eq!(words, sum_and_check_bytes(line), "{line:?}");
            words
        };
        // Every byte value at every position of short lines of value chars.
        for len in 1..=9 {
            for pos in 0..len {
                for b in 0..=255u8 {
                    let mut line = chars[..len].to_vec();
                    line[pos] = b;
                    let (_, valid) = check(&line);
                    assert_eq!(valid, (0x30..=0x6F).contains(&b));
                }
            }
        }
        // Pseudo-random lines of value chars, some with one arbitrary byte.
        let mut x = 0x1234_5678u32;
        let mut next = || {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            x >> 8
        };
        for _ in 0..20_000 {
            let len = next() as usize % 200;
            let mut line: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
            if len > 0 && next() % 2 == 0 {
                let at = next() as usize % len;
                line[at] = next() as u8;
            }
            check(&line);
        }
        // Long lines of the largest chars: no lane carries into the next.
        assert_eq!(check(&[0x6F; 1001]), (checksum(&[0x6F; 1001]), true));
        assert_eq!(check(&[]), (0x30, true));
    }

    const SETS: [DataSet; 5] = [
        DataSet::Distance,
        DataSet::ShortDistance,
        DataSet::DistanceIntensity,
        DataSet::DistanceReflectance,
        DataSet::DistanceAux,
    ];

    /// A single-scan response over steps `0..n` of `data`, with the values written.
    fn scan(data: DataSet, n: u16) -> (Vec<u8>, Vec<(u32, u32)>) {
        let request = Request::new(Command::Scan(ScanRequest {
            data,
            ..ScanRequest::distance(ScanMode::Single, 0, n - 1)
        }));
        let dmax = (1u32 << (6 * u32::from(data.distance_width()))) - 1;
        let amax = (1u64 << (6 * u32::from(data.aux_width()))) as u32 - 1;
        let values: Vec<(u32, u32)> = (0..u32::from(n))
            .map(|i| {
                let x = i.wrapping_mul(2_654_435_761);
                (x % (dmax + 1), (x >> 7) % amax.saturating_add(1))
            })
            .collect();
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        w.echo(&request);
        w.status(*b"00");
        w.timestamp(0x00AB_CDEF);
        for &(d, a) in &values {
            w.step(d, a);
        }
        w.end();
        (out, values)
    }

    /// Every event of `stream` fed in `chunk`-byte pieces, as text, and every reading.
    fn decode(mut dec: Decoder, stream: &[u8], chunk: usize) -> (Vec<String>, Vec<Reading>) {
        let mut log = Vec::new();
        let mut readings = Vec::new();
        for piece in stream.chunks(chunk) {
            let mut rest = piece;
            while !rest.is_empty() {
                let (used, ev) = dec.feed(rest);
                rest = &rest[used..];
                if let Some(ev) = ev {
                    if let Event::Data(line) = &ev {
                        readings.extend_from_slice(line.readings);
                    }
                    log.push(format!("{ev:?}"));
                }
            }
        }
        if let Some(ev) = dec.finish() {
            log.push(format!("{ev:?}"));
        }
        log.push(format!("{:?}", dec.stats()));
        (log, readings)
    }

    /// The fast path and the char-by-char reference agree on `stream`, whole and in
    /// pieces of sizes around a line's.
    fn assert_same(stream: &[u8]) -> Vec<String> {
        let whole = stream.len().max(1);
        let (reference, _) = decode(Decoder::char_by_char(), stream, whole);
        for chunk in [1, 2, 3, 5, 7, 11, 31, 63, 64, 65, 66, 67, 100, whole] {
            let (fast, _) = decode(Decoder::new(), stream, chunk);
            assert_eq!(
                fast,
                reference,
                "chunk {chunk}, stream {:?}",
                stream.escape_ascii().to_string()
            );
        }
        reference
    }

    /// GE over steps 0..=10: distance 1000 + i, intensity 100 i + 7. 66 value chars: the
    /// first line ends with the distance and one intensity char of step 10, whose other
    /// two intensity chars open the second line (sums computed by hand).
    const GE_SPLIT: &[u8] = b"GE0000001001\n00P\nZlg_<\n\
        0?X0070?Y01[0?Z03?0?[04c0?\\06G0?]07k0?^09O0?_0;30?`0<W0?a0>;0?b0a\n\
        ?_N\n\n";

    #[test]
    fn golden_ge_intensity_split_across_lines() {
        let mut dec = Decoder::new();
        let mut rest = GE_SPLIT;
        let mut lines = Vec::new();
        let mut end = None;
        while !rest.is_empty() {
            let (used, ev) = dec.feed(rest);
            rest = &rest[used..];
            match ev {
                Some(Event::Timestamp(t)) => assert_eq!(t, 0xAB_CDEF),
                Some(Event::Data(line)) => lines.push((line.line, line.readings.to_vec())),
                Some(Event::End(summary)) => end = Some(summary),
                Some(Event::Error(e)) => panic!("{e}"),
                _ => {}
            }
        }
        let expected = |i: u16| Reading {
            index: i,
            echo: 0,
            distance: 1000 + u32::from(i),
            aux: 100 * u32::from(i) + 7,
        };
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0], (3, (0..10).map(expected).collect::<Vec<_>>()));
        assert_eq!(lines[1], (4, vec![expected(10)]));
        let end = end.unwrap();
        assert_eq!(
            (end.values, end.lines, end.timestamp),
            (11, 5, Some(0xAB_CDEF))
        );
        assert_same(GE_SPLIT);
    }

    #[test]
    fn golden_ge_bad_char_column_in_fast_and_reference() {
        // `p` (0x70) is one past the value chars; the sum is fixed so the decode sees it.
        let damaged = damage(GE_SPLIT, 17 + 6 + 13, Some(b'p'));
        let log = assert_same(&damaged);
        assert!(
            log.iter().any(|l| l.contains("BadChar { column: 13 }")),
            "{log:?}"
        );
    }

    #[test]
    fn fast_path_reads_what_the_writer_wrote() {
        for data in SETS {
            for n in [1, 2, 10, 11, 21, 22, 23, 32, 33, 100, 682, 1081] {
                let (stream, values) = scan(data, n);
                let (log, readings) = decode(Decoder::new(), &stream, 64);
                assert!(
                    log.iter().any(|l| l.starts_with("End(")),
                    "{data:?} {n}: {log:?}"
                );
                let got: Vec<(u32, u32)> = readings.iter().map(|r| (r.distance, r.aux)).collect();
                assert_eq!(got, values, "{data:?} {n}");
                let indices: Vec<u16> = readings.iter().map(|r| r.index).collect();
                assert_eq!(indices, (0..n).collect::<Vec<_>>(), "{data:?} {n}");
                assert_same(&stream);
            }
        }
    }

    /// Changes byte `at` of `stream` to `c` and fixes the sum char of its line, so that
    /// the damage reaches the value decoding.
    fn damage(stream: &[u8], at: usize, c: Option<u8>) -> Vec<u8> {
        let mut s = stream.to_vec();
        match c {
            Some(c) => s[at] = c,
            None => {
                s.remove(at);
            }
        }
        let start = s[..at]
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |i| i + 1);
        if let Some(end) = s[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|i| start + i)
        {
            if end >= start + 2 {
                s[end - 1] = checksum(&s[start..end - 1]);
            }
        }
        s
    }

    #[test]
    fn fast_path_matches_char_by_char_on_damaged_values() {
        for data in SETS {
            let (stream, _) = scan(data, 40);
            // The data lines start after echo, status and timestamp lines.
            let first = stream
                .iter()
                .enumerate()
                .filter(|&(_, &b)| b == b'\n')
                .nth(2)
                .map(|(i, _)| i + 1)
                .unwrap();
            for at in first..stream.len() - 2 {
                if stream[at] == b'\n' || stream.get(at + 1) == Some(&b'\n') {
                    continue;
                }
                for c in [
                    Some(b'/'),
                    Some(b'p'),
                    Some(b'&'),
                    Some(b'o'),
                    Some(0),
                    None,
                ] {
                    assert_same(&damage(&stream, at, c));
                }
            }
        }
    }

    #[test]
    fn fast_path_counts_too_many_values_like_the_reference() {
        // The echo asks for 5 steps; the line carries 22.
        let (stream, _) = scan(DataSet::Distance, 22);
        let text = String::from_utf8(stream).unwrap();
        let damaged = text.replacen("GD0000002101", "GD0000000401", 1);
        let log = assert_same(damaged.as_bytes());
        assert!(
            log.iter()
                .any(|l| l.contains("TooManyValues { expected: 5 }")),
            "{log:?}"
        );
    }

    /// A frame of the stream `MD0000000101cc` (two steps, 1000 and 1001 mm), with
    /// `count` scans remaining, status `status`, timestamp `ts`.
    fn md_frame(count: u8, status: [u8; 2], ts: u32, values: &[u32]) -> Vec<u8> {
        let request = Request::new(Command::Scan(ScanRequest {
            count,
            ..ScanRequest::distance(ScanMode::Continuous, 0, 1)
        }));
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        w.echo(&request);
        w.status(status);
        if status != *b"00" {
            w.timestamp(ts);
            for &d in values {
                w.step(d, 0);
            }
        }
        w.end();
        out
    }

    /// What each response of `stream` came to: `end` or the error's name.
    fn outcomes(stream: &[u8]) -> Vec<&'static str> {
        let mut dec = Decoder::new();
        let mut out = Vec::new();
        let mut rest = stream;
        while !rest.is_empty() {
            let (used, ev) = dec.feed(rest);
            rest = &rest[used..];
            match ev {
                Some(Event::End(_)) => out.push("end"),
                Some(Event::Error(e)) => out.push(e.kind.name()),
                _ => {}
            }
        }
        out
    }

    #[test]
    fn stream_frames_must_count_down_and_move_on_in_time() {
        let v = [1000, 1001];
        let frames: Vec<(Vec<u8>, &str)> = vec![
            (md_frame(5, *b"00", 0, &v), "end"),
            (md_frame(4, *b"99", 100, &v), "end"),
            (md_frame(3, *b"99", 200, &v), "end"),
            // The count did not go down.
            (md_frame(3, *b"99", 300, &v), "out_of_sequence"),
            // Checked against nothing after a failure.
            (md_frame(2, *b"99", 400, &v), "end"),
            // Back in time.
            (md_frame(1, *b"99", 350, &v), "out_of_sequence"),
            (md_frame(0, *b"99", 500, &v), "end"),
            // A new endless stream: its ack starts over.
            (md_frame(0, *b"00", 0, &v), "end"),
            (md_frame(0, *b"99", 0xFF_FFF0, &v), "end"),
            // The 24-bit clock wraps.
            (md_frame(0, *b"99", 0x10, &v), "end"),
            // Same time twice.
            (md_frame(0, *b"99", 0x10, &v), "out_of_sequence"),
            (md_frame(0, *b"99", 0x20, &v), "end"),
            // More than STREAM_GAP_MAX_MS on.
            (md_frame(0, *b"99", 0x20 + 10_001, &v), "out_of_sequence"),
            (md_frame(0, *b"99", 0x30 + 10_001, &v), "end"),
            // An endless stream does not count.
            (md_frame(7, *b"99", 0x40 + 10_001, &v), "out_of_sequence"),
            // A damaged frame (one value short) is no reference, and the frame after it
            // is decoded (the failure at the response's end skips nothing more).
            (
                md_frame(0, *b"99", 0x50 + 10_001, &v[..1]),
                "count_mismatch",
            ),
            (md_frame(0, *b"99", 0x60 + 10_001, &v), "end"),
        ];
        let stream: Vec<u8> = frames.iter().flat_map(|f| f.0.clone()).collect();
        let want: Vec<&str> = frames.iter().map(|f| f.1).collect();
        assert_eq!(outcomes(&stream), want);
    }

    #[test]
    fn single_scans_and_other_streams_are_not_sequenced() {
        // A G* answer between frames, and frames of another request, are not checked
        // against the stream; a QT answer ends it.
        let v = [1000, 1001];
        let mut stream = md_frame(0, *b"99", 500, &v);
        stream.extend(b"GD0000000101\n00P\n00000\n0?X0?Y?\n\n");
        stream.extend(md_frame(0, *b"99", 600, &v));
        stream.extend(b"QT\n00P\n\n");
        stream.extend(md_frame(0, *b"99", 100, &v));
        assert_eq!(outcomes(&stream), ["end"; 5]);
    }

    #[test]
    fn an_unknown_command_answered_without_payload_ends_intact() {
        // SCIP 2.2 RB (not a command of this crate) is answered 01, then 00.
        assert_eq!(
            outcomes(b"RB\n01Q\n\nRB\n00P\n\nXX\n00P\nabcV\n\nVV\n00P\n\n"),
            ["end", "end", "unknown_echo", "end"]
        );
    }
}
