//! Decoding errors: what was wrong, and where.

use core::fmt;

use crate::command::EchoError;

/// What was wrong with a line of a response.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorKind {
    /// A line longer than [`crate::LINE_CAP`] bytes (no LF in time).
    LineTooLong,
    /// A line's sum char does not match its bytes.
    BadSum {
        /// The sum char the bytes call for.
        expected: u8,
        /// The sum char received.
        found: u8,
    },
    /// A char outside `0x30..=0x6F` (or a misplaced `&`) in a value, at this column.
    BadChar {
        /// Column of the char in its line (0-based).
        column: u8,
    },
    /// The echo is not a known command, yet payload lines follow its status.
    UnknownEcho(EchoError),
    /// The status line is neither 2 chars + sum nor a lone SCIP 1.1 char.
    BadStatusLine,
    /// The response ended (empty line) where its status was expected.
    MissingStatus,
    /// A VV/PP/II line that is not `NAME:VALUE;S`.
    BadField,
    /// The timestamp line is not 4 chars + sum.
    BadTimestamp,
    /// A data line over 64 chars, or a short data line that was not the last one.
    BadDataLineLength,
    /// A `&` (extra echo) where no value can follow it, or in a single-echo response.
    MisplacedEcho,
    /// More than 3 echoes for one step.
    TooManyEchoes,
    /// The response ended in the middle of a value.
    TruncatedValue,
    /// More values than start/end/cluster allow.
    TooManyValues {
        /// What the echo allows.
        expected: u16,
    },
    /// Fewer values than start/end/cluster call for.
    CountMismatch {
        /// What the echo calls for.
        expected: u16,
        /// What arrived.
        found: u16,
    },
    /// A payload line where the command or its status has none.
    UnexpectedPayload,
    /// The stream ended inside a response.
    Truncated,
    /// A stream frame that cannot follow the one before it: its timestamp is not later
    /// (by at most [`crate::decoder::STREAM_GAP_MAX_MS`]) or its remaining-scans count
    /// did not count down. Echoes carry no sum, and a timestamp passes its 6-bit sum
    /// by chance once in 64 corruptions: this catches what slips through.
    OutOfSequence,
}

impl ErrorKind {
    /// Number of kinds, for counter arrays.
    pub const COUNT: usize = 17;

    /// A dense index `0..COUNT`, for counters.
    pub const fn index(&self) -> usize {
        match self {
            Self::LineTooLong => 0,
            Self::BadSum { .. } => 1,
            Self::BadChar { .. } => 2,
            Self::UnknownEcho(_) => 3,
            Self::BadStatusLine => 4,
            Self::MissingStatus => 5,
            Self::BadField => 6,
            Self::BadTimestamp => 7,
            Self::BadDataLineLength => 8,
            Self::MisplacedEcho => 9,
            Self::TooManyEchoes => 10,
            Self::TruncatedValue => 11,
            Self::TooManyValues { .. } => 12,
            Self::CountMismatch { .. } => 13,
            Self::UnexpectedPayload => 14,
            Self::Truncated => 15,
            Self::OutOfSequence => 16,
        }
    }

    /// A short snake_case name, as used in JSON output.
    pub const fn name(&self) -> &'static str {
        match self {
            Self::LineTooLong => "line_too_long",
            Self::BadSum { .. } => "bad_sum",
            Self::BadChar { .. } => "bad_char",
            Self::UnknownEcho(_) => "unknown_echo",
            Self::BadStatusLine => "bad_status_line",
            Self::MissingStatus => "missing_status",
            Self::BadField => "bad_field",
            Self::BadTimestamp => "bad_timestamp",
            Self::BadDataLineLength => "bad_data_line_length",
            Self::MisplacedEcho => "misplaced_echo",
            Self::TooManyEchoes => "too_many_echoes",
            Self::TruncatedValue => "truncated_value",
            Self::TooManyValues { .. } => "too_many_values",
            Self::CountMismatch { .. } => "count_mismatch",
            Self::UnexpectedPayload => "unexpected_payload",
            Self::Truncated => "truncated",
            Self::OutOfSequence => "out_of_sequence",
        }
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadSum { expected, found } => write!(
                f,
                "bad sum: expected {:?}, found {:?}",
                char::from(*expected),
                char::from(*found)
            ),
            Self::BadChar { column } => write!(f, "bad value char at column {column}"),
            Self::UnknownEcho(e) => write!(f, "unknown echo: {e}"),
            Self::TooManyValues { expected } => write!(f, "more than {expected} values"),
            Self::CountMismatch { expected, found } => {
                write!(f, "expected {expected} values, found {found}")
            }
            other => f.write_str(other.name()),
        }
    }
}

/// A decoding error with its position.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Error {
    /// What was wrong.
    pub kind: ErrorKind,
    /// Byte offset in the stream of the first byte of the offending line.
    pub offset: u64,
    /// Line number within the response (0 = echo, 1 = status, ...).
    pub line: u16,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} (response line {}, stream offset {})",
            self.kind, self.line, self.offset
        )
    }
}

#[cfg(feature = "std")]
impl std::error::Error for Error {}
