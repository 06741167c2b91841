//! The crate's one error type.

use core::fmt;

/// Everything that can go wrong when parsing, emitting, encoding or reassembling frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// The frame's length is not one this frame type allows.
    BadLength {
        /// Length the layout requires (for data frames: the length the point count implies).
        expected: u8,
        /// Length the frame had.
        actual: u8,
    },
    /// A control frame's opcode is not defined.
    UnknownOpcode(u8),
    /// A status frame's page (byte 0) is not defined.
    UnknownPage(u8),
    /// A distance or intensity encoding code is not defined.
    UnknownEncoding(u8),
    /// A field holds a value outside its allowed range; `offset` is its byte offset.
    OutOfRange {
        /// Byte offset of the offending field in the frame.
        offset: u8,
    },
    /// Reserved bits or padding bits are not zero.
    ReservedBits,
    /// A data frame's points do not lie inside the scan (`first_index + n > point_count`)
    /// or it carries no point at all.
    PointIndex,
    /// The identifier is outside the configured window or of the other format.
    ForeignId,
    /// An identifier window or base that does not leave room for all eight kinds.
    BadIdWindow,
    /// A frame longer than 64 bytes, or longer than 8 without CAN FD.
    FrameTooLong,
    /// The encoder was asked to emit scan frames without a scan in progress.
    NoScan,
    /// The encoder was asked to begin a scan while one is in progress.
    ScanInProgress,
    /// More points were pushed than the header announced.
    TooManyPoints,
    /// The decoder already tracks as many bridges as it has room for.
    TooManyBridges,
    /// The operation is not available for the scan's encoding: the points of a lossless
    /// scan can make several data frames due at once, so they need a frame sink
    /// ([`crate::ScanEncoder::push_point_to`], [`crate::ScanEncoder::push_run`]).
    NeedsSink,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::BadLength { expected, actual } => {
                write!(f, "bad frame length {actual} (expected {expected})")
            }
            Error::UnknownOpcode(op) => write!(f, "unknown control opcode {op:#04x}"),
            Error::UnknownPage(p) => write!(f, "unknown status page {p}"),
            Error::UnknownEncoding(e) => write!(f, "unknown encoding {e}"),
            Error::OutOfRange { offset } => write!(f, "value out of range at byte {offset}"),
            Error::ReservedBits => f.write_str("reserved or padding bits are not zero"),
            Error::PointIndex => f.write_str("data frame points outside the scan"),
            Error::ForeignId => f.write_str("identifier outside the configured window"),
            Error::BadIdWindow => f.write_str("identifier window does not fit the ID format"),
            Error::FrameTooLong => f.write_str("frame data too long"),
            Error::NoScan => f.write_str("no scan in progress"),
            Error::ScanInProgress => f.write_str("a scan is already in progress"),
            Error::TooManyPoints => f.write_str("more points than the header announced"),
            Error::TooManyBridges => f.write_str("too many bridges to track"),
            Error::NeedsSink => f.write_str("a lossless scan's points need a frame sink"),
        }
    }
}

#[cfg(any(test, feature = "std"))]
impl std::error::Error for Error {}

/// Check that `data` is exactly `len` bytes long.
pub(crate) fn check_len(data: &[u8], len: usize) -> Result<(), Error> {
    if data.len() == len {
        Ok(())
    } else {
        Err(Error::BadLength {
            expected: len as u8,
            actual: u8::try_from(data.len()).unwrap_or(u8::MAX),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display() {
        let e = Error::BadLength {
            expected: 8,
            actual: 3,
        };
        assert_eq!(e.to_string(), "bad frame length 3 (expected 8)");
        assert_eq!(
            Error::UnknownOpcode(0x7f).to_string(),
            "unknown control opcode 0x7f"
        );
    }

    #[test]
    fn check_len_saturates() {
        let big = [0u8; 300];
        assert_eq!(
            check_len(&big, 8),
            Err(Error::BadLength {
                expected: 8,
                actual: 255
            })
        );
        assert_eq!(check_len(&big[..8], 8), Ok(()));
    }
}
