//! The scan trailer (SPEC section 3.4).

use crate::error::check_len;
use crate::header::{le16, put};
use crate::Error;

mod field {
    use core::ops::Range;
    pub const SEQ: Range<usize> = 0..2;
    pub const SENT_FLAGS: Range<usize> = 2..4;
    pub const VALID: Range<usize> = 4..6;
    pub const CRC: Range<usize> = 6..8;
}

/// Length of a trailer frame.
pub const TRAILER_LEN: usize = 8;
/// Bytes of the trailer that enter the scan CRC.
pub const TRAILER_CRC_PREFIX: usize = field::CRC.start;

/// What the bridge says about a scan it finished.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrailerFlags {
    /// The scan ended early (`points_sent < point_count`).
    pub truncated: bool,
    /// The sensor reported an error status during this scan.
    pub sensor_error: bool,
    /// Filters changed or invalidated some points.
    pub filtered: bool,
}

impl TrailerFlags {
    fn bits(&self) -> u16 {
        (u16::from(self.truncated) << 12)
            | (u16::from(self.sensor_error) << 13)
            | (u16::from(self.filtered) << 14)
    }
}

/// A parsed trailer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Trailer {
    /// Scan sequence number.
    pub seq: u16,
    /// Points sent, 0..=4095.
    pub points_sent: u16,
    /// Points whose distance is a range.
    pub points_valid: u16,
    /// Flags.
    pub flags: TrailerFlags,
    /// The scan CRC.
    pub crc: u16,
}

impl Trailer {
    /// Parse and validate trailer bytes. The truncated flag must agree with the counts,
    /// which needs the header's point count: see [`Trailer::check_count`].
    pub fn parse(data: &[u8]) -> Result<Trailer, Error> {
        check_len(data, TRAILER_LEN)?;
        let sf = le16(data, field::SENT_FLAGS);
        let valid = le16(data, field::VALID);
        if sf & 0x8000 != 0 || valid & 0xF000 != 0 {
            return Err(Error::ReservedBits);
        }
        let points_sent = sf & 0x0FFF;
        if valid > points_sent {
            return Err(Error::OutOfRange {
                offset: field::VALID.start as u8,
            });
        }
        Ok(Trailer {
            seq: le16(data, field::SEQ),
            points_sent,
            points_valid: valid,
            flags: TrailerFlags {
                truncated: sf & (1 << 12) != 0,
                sensor_error: sf & (1 << 13) != 0,
                filtered: sf & (1 << 14) != 0,
            },
            crc: le16(data, field::CRC),
        })
    }

    /// Check the counts against the scan's `point_count`: `points_sent <= point_count`
    /// and `truncated` iff fewer were sent.
    pub fn check_count(&self, point_count: u16) -> Result<(), Error> {
        if self.points_sent > point_count
            || self.flags.truncated != (self.points_sent < point_count)
        {
            return Err(Error::OutOfRange {
                offset: field::SENT_FLAGS.start as u8,
            });
        }
        Ok(())
    }

    /// The first six bytes (everything but the CRC), which enter the CRC.
    pub fn emit_head(&self) -> Result<[u8; TRAILER_CRC_PREFIX], Error> {
        if self.points_sent > 0x0FFF {
            return Err(Error::OutOfRange { offset: 2 });
        }
        if self.points_valid > self.points_sent {
            return Err(Error::OutOfRange { offset: 4 });
        }
        let mut b = [0u8; TRAILER_CRC_PREFIX];
        put(&mut b, field::SEQ, &self.seq.to_le_bytes());
        put(
            &mut b,
            field::SENT_FLAGS,
            &(self.points_sent | self.flags.bits()).to_le_bytes(),
        );
        put(&mut b, field::VALID, &self.points_valid.to_le_bytes());
        Ok(b)
    }

    /// The trailer bytes.
    pub fn emit(&self) -> Result<[u8; TRAILER_LEN], Error> {
        let head = self.emit_head()?;
        let mut b = [0u8; TRAILER_LEN];
        put(&mut b, 0..TRAILER_CRC_PREFIX, &head);
        put(&mut b, field::CRC, &self.crc.to_le_bytes());
        Ok(b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOLDEN: [u8; 8] = [0x02, 0x01, 0x00, 0x54, 0x20, 0x03, 0xCD, 0xAB];

    fn trailer() -> Trailer {
        Trailer {
            seq: 0x0102,
            points_sent: 0x400,
            points_valid: 0x320,
            flags: TrailerFlags {
                truncated: true,
                sensor_error: false,
                filtered: true,
            },
            crc: 0xABCD,
        }
    }

    #[test]
    fn golden() {
        assert_eq!(trailer().emit(), Ok(GOLDEN));
        assert_eq!(Trailer::parse(&GOLDEN), Ok(trailer()));
    }

    #[test]
    fn rejects() {
        for len in (0..=64).filter(|l| *l != 8) {
            let e = Error::BadLength {
                expected: 8,
                actual: len as u8,
            };
            assert_eq!(Trailer::parse(&[0u8; 64][..len]), Err(e));
        }
        let mut b = GOLDEN;
        b[3] |= 0x80;
        assert_eq!(Trailer::parse(&b), Err(Error::ReservedBits));
        let mut b = GOLDEN;
        b[5] |= 0x10;
        assert_eq!(Trailer::parse(&b), Err(Error::ReservedBits));
        let mut b = GOLDEN;
        b[4] = 0x01;
        b[5] = 0x04; // valid 0x401 > sent 0x400
        assert_eq!(Trailer::parse(&b), Err(Error::OutOfRange { offset: 4 }));
    }

    #[test]
    fn count_check() {
        let t = trailer();
        assert_eq!(t.check_count(0x401), Ok(()));
        assert_eq!(t.check_count(0x400), Err(Error::OutOfRange { offset: 2 }));
        let full = Trailer {
            flags: TrailerFlags::default(),
            ..t
        };
        assert_eq!(full.check_count(0x400), Ok(()));
        assert_eq!(
            full.check_count(0x3FF),
            Err(Error::OutOfRange { offset: 2 })
        );
        assert_eq!(
            full.check_count(0x401),
            Err(Error::OutOfRange { offset: 2 })
        );
    }
}
