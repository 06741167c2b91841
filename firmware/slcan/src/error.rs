//! The crate's one error type.

use core::fmt;

/// Everything that can go wrong parsing, emitting or executing an SLCAN line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// The line starts with a letter that is not a command (or not one this crate knows).
    UnknownCommand(u8),
    /// The line is longer or shorter than its command (and its DLC) require.
    BadLength,
    /// A character that must be a hex digit (or a decimal digit) is not one.
    BadDigit,
    /// An identifier above 0x7FF (11-bit) or 0x1FFF_FFFF (29-bit).
    IdOutOfRange,
    /// A data length code above 8 in a classic frame (a CAN FD code is 0..=F).
    BadDlc,
    /// A frame of a length no CAN frame of its kind can have (above 8 for classic, not an
    /// FD length for CAN FD), or a remote frame in CAN FD.
    BadFrameLength,
    /// `S` or `Y` with a rate index this crate does not define.
    BadBitRate,
    /// A line longer than [`LINE_MAX`](crate::LINE_MAX); it was discarded up to its CR.
    LineTooLong,
    /// The output buffer is too small for the line.
    BufferTooSmall,
    /// The command needs the channel open (transmit, `F`).
    NotOpen,
    /// The command needs the channel closed (`O`, `L`, `S`, `Y`, `Z`).
    AlreadyOpen,
    /// A transmit request while the channel is open in listen-only mode.
    ListenOnly,
    /// A CAN FD frame, or `Y`, on an adapter that only does classic CAN.
    FdNotSupported,
    /// A frame's timestamp above `EA5F` (timestamps count ms modulo 60000).
    BadTimestamp,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::UnknownCommand(c) => write!(f, "unknown command {:?}", char::from(*c)),
            Error::BadLength => f.write_str("line length does not match the command"),
            Error::BadDigit => f.write_str("not a hex digit"),
            Error::IdOutOfRange => f.write_str("identifier out of range"),
            Error::BadDlc => f.write_str("bad data length code"),
            Error::BadFrameLength => f.write_str("no frame of this kind has that length"),
            Error::BadBitRate => f.write_str("unknown bit rate index"),
            Error::LineTooLong => f.write_str("line too long"),
            Error::BufferTooSmall => f.write_str("output buffer too small"),
            Error::NotOpen => f.write_str("channel not open"),
            Error::AlreadyOpen => f.write_str("channel already open"),
            Error::ListenOnly => f.write_str("channel is listen-only"),
            Error::FdNotSupported => f.write_str("CAN FD not supported"),
            Error::BadTimestamp => f.write_str("timestamp above EA5F (59999 ms)"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for Error {}
