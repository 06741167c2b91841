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

mod fields;
mod line;
mod machine;
#[cfg(test)]
mod tests;
mod values;

/// Longest line the decoder accepts, LF excluded. Data lines are at most 65 bytes
/// (64 data chars + sum); info lines of real sensors stay well below this.
pub const LINE_CAP: usize = 96;
/// Data chars of a full measurement line.
pub const DATA_CHARS: usize = 64;
/// Most readings one data line can complete: 64 chars of 2-char values, plus one value
/// begun on the previous line.
pub const MAX_READINGS: usize = DATA_CHARS / 2 + 1;
/// Most readings one [`Event::Data`] of [`Decoder::feed_runs`] carries: the readings of
/// a run of consecutive data lines, two full lines of 3-char distances (21 or 22 steps
/// each) at most. (A UART chunk of 128 bytes holds the ends of two lines at most.)
pub const MAX_RUN_READINGS: usize = 2 * (DATA_CHARS / 3 + 1);
/// Most echoes per step in a multi-echo response.
pub const MAX_ECHOES: u8 = 3;
/// The largest timestamp step from one intact stream frame to the next that passes the
/// sequence check ([`ErrorKind::OutOfSequence`]), ms: ten skipped scans of the slowest
/// model at its lowest speed, with room for frames lost in between. A longer gap costs
/// one good frame (the next one is checked against nothing).
pub const STREAM_GAP_MAX_MS: u32 = 10_000;

/// One decoded value of a step (or one extra echo of a step): its distance and its
/// second value. Which step and echo it is follows from its place in its
/// [`DataLine`] ([`DataLine::indexed`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reading {
    /// Distance as sent: mm, or an error code below DMIN (see [`DataLine::range`]).
    pub distance: u32,
    /// Intensity, reflectance or aux value; 0 when the command has none.
    pub aux: u32,
}

/// A reading with its place in the scan, as [`DataLine::indexed`] gives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IndexedReading {
    /// Index of the step in the scan (0 = `start` step; with clustering, one index
    /// covers `cluster` steps).
    pub index: u16,
    /// 0 for the first echo, 1 and 2 for extra echoes of multi-echo commands.
    pub echo: u8,
    /// Distance as sent: mm, or an error code below DMIN (see [`DataLine::range`]).
    pub distance: u32,
    /// Intensity, reflectance or aux value; 0 when the command has none.
    pub aux: u32,
}

impl IndexedReading {
    /// The reading without its place in the scan (e.g. for [`DataLine::range`]).
    pub fn reading(&self) -> Reading {
        Reading {
            distance: self.distance,
            aux: self.aux,
        }
    }
}

/// The readings completed by one data line, or by a run of consecutive data lines
/// ([`Decoder::feed_runs`]).
///
/// In a single-echo line (`echoes` empty) reading `i` is the first (only) echo of step
/// `first + i`. In a multi-echo line `echoes` has one entry per reading: a reading of
/// echo 0 begins the next step, an extra echo (1 or 2) belongs to the step of the reading
/// before it, and the first reading, whatever its echo, is of step `first` (a line may
/// begin with an extra echo of the step the previous line ended with).
/// [`DataLine::indexed`] gives every reading with its step and echo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataLine<'a> {
    /// The readings, in order.
    pub readings: &'a [Reading],
    /// Index in the scan of the step of the first reading; for a line without
    /// readings, the index of the next step.
    pub first: u16,
    /// Multi-echo lines: the echo number of each reading (0 for a step's first echo, 1
    /// and 2 for its extra echoes), as many as `readings`. Empty for single-echo lines,
    /// whose readings are all first echoes.
    pub echoes: &'a [u8],
    /// What each step carries.
    pub data: DataSet,
    /// DMIN and model family in force, to tell ranges from error codes.
    pub limits: RangeLimits,
    /// Line number within the response (of a run's last line, [`Decoder::feed_runs`]).
    pub line: u16,
}

impl<'a> DataLine<'a> {
    /// The distance of `reading` as a range or an error code.
    pub fn range(&self, reading: &Reading) -> Range {
        self.limits
            .classify(reading.distance, self.data.distance_width())
    }

    /// Every reading with its step index and echo number, in order.
    pub fn indexed(&self) -> Indexed<'a> {
        Indexed {
            readings: self.readings.iter(),
            echoes: self.echoes.iter(),
            index: self.first,
            started: false,
        }
    }
}

/// The readings of a [`DataLine`] with their step index and echo number
/// ([`DataLine::indexed`]).
#[derive(Debug, Clone)]
pub struct Indexed<'a> {
    readings: core::slice::Iter<'a, Reading>,
    echoes: core::slice::Iter<'a, u8>,
    /// The step of the reading given last (of the first reading, before it).
    index: u16,
    started: bool,
}

impl Iterator for Indexed<'_> {
    type Item = IndexedReading;

    #[inline]
    fn next(&mut self) -> Option<IndexedReading> {
        let r = self.readings.next()?;
        let echo = self.echoes.next().copied().unwrap_or(0);
        // A first echo after the line's first reading begins the next step; the indices
        // of one scan fit in u16 (the decoder checks the count), so this does not wrap.
        if self.started && echo == 0 {
            self.index = self.index.wrapping_add(1);
        }
        self.started = true;
        Some(IndexedReading {
            index: self.index,
            echo,
            distance: r.distance,
            aux: r.aux,
        })
    }

    #[inline]
    fn size_hint(&self) -> (usize, Option<usize>) {
        self.readings.size_hint()
    }
}

impl ExactSizeIterator for Indexed<'_> {}

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

/// The streaming SCIP 2.x response decoder. 840 bytes of RAM on a Cortex-M4 (the readings
/// of two lines, [`MAX_RUN_READINGS`], are 352 of them); no allocation.
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
    /// Where the line being read starts in the stream: the bytes fed before it
    /// (`stats.bytes` is the stream offset too).
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
    /// The readings of the line (or, for [`Decoder::feed_runs`], the run of lines) just
    /// decoded.
    readings: [Reading; MAX_RUN_READINGS],
    /// The echo number of each reading of a multi-echo line (unused otherwise).
    echoes: [u8; MAX_READINGS],
    /// Every reading slot has aux 0 (see [`Self::decode_steps`]).
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
    /// Tests and fuzzing only: take the paths of 32-bit targets.
    #[cfg(any(test, fuzzing))]
    m4: bool,
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
                distance: 0,
                aux: 0,
            }; MAX_RUN_READINGS],
            echoes: [0; MAX_READINGS],
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
            #[cfg(any(test, fuzzing))]
            m4: false,
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

    /// A decoder that takes the paths of 32-bit targets (the line copy that checks and
    /// sums, then the line decoded from the line buffer) on any target: how the
    /// Cortex-M boards decode, for tests on the host. Only in tests and under
    /// `cfg(fuzzing)`.
    #[cfg(any(test, fuzzing))]
    #[doc(hidden)]
    pub fn m4_paths() -> Self {
        let mut d = Self::new();
        d.m4 = true;
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
    ///
    /// On 64-bit hosts a full data line (64 value chars, its sum char, the LF) is taken
    /// without an LF search and, when all of it is in `input`, decoded from there
    /// without a copy into the line buffer. On 32-bit targets the bytes of a data line
    /// up to a full line's LF are copied, checked and summed a word at a time, without
    /// an LF search either. The events are the same.
    #[inline]
    pub fn feed(&mut self, input: &[u8]) -> (usize, Option<Event<'_>>) {
        self.feed_as::<false>(input)
    }

    /// [`Decoder::feed`] for a caller that takes a scan's readings as a stream: an
    /// [`Event::Data`] may carry the readings of several consecutive data lines (at
    /// most [`MAX_RUN_READINGS`]), the line that ends first in `input` and the full data
    /// lines of 3-char distances that follow it whole in `input`, each checked as
    /// [`Decoder::feed`] checks it. `line` is then the last one's number, `readings` and
    /// `first` cover them all. A line that fails a check is not joined to the run: the
    /// next call takes it alone and reports it, so every other event, and every error
    /// with its line and offset, is the one [`Decoder::feed`] gives, and the readings in
    /// order are the same for any chunking. Lines that do not lie whole in one call's
    /// `input` are not joined, so an event never waits for more input.
    ///
    /// For a caller with a per-line cost (a filter pipeline, an encoder's set-up), the
    /// run pays it once for the lines of a UART chunk.
    #[inline]
    pub fn feed_runs(&mut self, input: &[u8]) -> (usize, Option<Event<'_>>) {
        self.feed_as::<true>(input)
    }

    /// [`Decoder::feed`] (`RUNS` false) or [`Decoder::feed_runs`].
    #[inline(always)]
    fn feed_as<const RUNS: bool>(&mut self, input: &[u8]) -> (usize, Option<Event<'_>>) {
        // 64-bit hosts, in a data line: with the state, the overflow flag and the line's
        // length so far tested once, either a full data line ends in `input` or all of
        // `input` continues the line without reaching a full line's LF.
        #[cfg(not(target_pointer_width = "32"))]
        if self.state == State::Payload(Payload::Data) && !self.overflow && !self.on_m4_paths() {
            let buffered = self.len;
            // Bytes of `input` up to a full line's LF, excluded: the line buffer has at
            // most that much of the line (more go the general path).
            if let Some(rest) = (DATA_CHARS + 1).checked_sub(buffered) {
                match input.get(rest) {
                    Some(&b'\n') => {
                        if let Some((used, decoded)) = self.full_data_line(input, buffered, rest) {
                            return match decoded {
                                Ok(()) => {
                                    let more = input.get(used..).unwrap_or_default();
                                    let joined = if RUNS {
                                        self.join_plain_lines(more, false).0
                                    } else {
                                        0
                                    };
                                    // Both at most `input`'s length: no wrap.
                                    (used.wrapping_add(joined), Some(self.data_event()))
                                }
                                Err(kind) => (used, self.fail(kind)),
                            };
                        }
                    }
                    // All of `input` fits before the LF: `buffered + input.len()` is at
                    // most a full line.
                    None if self.take_data_chars(input, buffered) => return (input.len(), None),
                    _ => {}
                }
            }
        }
        // 32-bit targets, in a data line: the bytes up to a full data line's LF, or all
        // of `input` when it ends before, copied and checked a word at a time.
        if self.state == State::Payload(Payload::Data) && !self.overflow && self.on_m4_paths() {
            if let Some((used, ends)) = self.take_data_words(input) {
                if !ends {
                    return (used, None);
                }
                let more = if RUNS {
                    input.get(used..).unwrap_or_default()
                } else {
                    &[]
                };
                let (joined, ev) = self.full_line_event(more);
                // Both at most `input`'s length: no wrap.
                return (used.wrapping_add(joined), ev);
            }
        }
        let mut consumed: usize = 0;
        let mut rest = input;
        loop {
            // The byte counter, also the stream offset, wraps (after 2^64 bytes).
            let Some(lf) = self.take_line_bytes(rest) else {
                self.stats.bytes = self.stats.bytes.wrapping_add(rest.len() as u64);
                return (input.len(), None);
            };
            // `lf` indexes `rest`, a tail of `input`: `consumed + lf + 1 <= input.len()`.
            let line = lf.wrapping_add(1);
            consumed = consumed.wrapping_add(line);
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
        self.line_start = self.stats.bytes;
        if in_response {
            Some(self.error(ErrorKind::Truncated, line))
        } else {
            None
        }
    }
}
