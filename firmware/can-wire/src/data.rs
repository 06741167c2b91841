//! Scan data frames (SPEC section 3.3): a 2-byte header and an LSB-first point stream.

use crate::encoding::{BitReader, Encoding};
use crate::frame::padded_len;
use crate::header::{le16, ScanHeader};
use crate::Error;

mod field {
    use core::ops::Range;
    pub const INDEX_SEQ: Range<usize> = 0..2;
    pub const POINTS: usize = 2;
}

/// Bytes before the point stream.
pub const DATA_HEADER_LEN: usize = field::POINTS;

/// The 2-byte header of a data frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DataHeader {
    /// Index of the frame's first point (0..=4095).
    pub first_index: u16,
    /// Low 4 bits of the scan sequence number.
    pub seq_low: u8,
}

impl DataHeader {
    /// Parse the first two bytes of a data frame (needs at least 3 bytes: one point).
    pub fn parse(data: &[u8]) -> Result<DataHeader, Error> {
        if data.len() <= DATA_HEADER_LEN {
            return Err(Error::BadLength {
                expected: 3,
                actual: data.len() as u8,
            });
        }
        let w = le16(data, field::INDEX_SEQ);
        Ok(DataHeader {
            first_index: w & 0x0FFF,
            seq_low: (w >> 12) as u8,
        })
    }

    /// The two header bytes.
    pub fn emit(&self) -> [u8; DATA_HEADER_LEN] {
        ((self.first_index & 0x0FFF) | (u16::from(self.seq_low & 0xF) << 12)).to_le_bytes()
    }
}

/// Length of a data frame holding `n` points in `encoding`.
pub fn data_frame_len(encoding: &Encoding, n: usize) -> Option<usize> {
    let bits = n.checked_mul(encoding.bits_per_point() as usize)?;
    padded_len(bits.div_ceil(8).checked_add(DATA_HEADER_LEN)?)
}

/// A validated data frame of a known scan.
#[derive(Debug, Clone, Copy)]
pub struct DataFrame<'a> {
    header: DataHeader,
    count: u16,
    encoding: Encoding,
    points: &'a [u8],
}

impl<'a> DataFrame<'a> {
    /// Parse and validate `data` as a data frame of the scan `scan` (SPEC 3.3: sequence,
    /// point range, exact length, zero padding). It does *not* check the sequence bits
    /// against the scan: see [`DataFrame::header`].
    pub fn parse(data: &'a [u8], scan: &ScanHeader) -> Result<DataFrame<'a>, Error> {
        let header = DataHeader::parse(data)?;
        let enc = scan.encoding;
        let remaining = scan
            .point_count
            .checked_sub(header.first_index)
            .filter(|r| *r > 0)
            .ok_or(Error::PointIndex)?;
        let cap = enc.capacity(data.len());
        let n = cap.min(usize::from(remaining));
        if n == 0 {
            return Err(Error::PointIndex);
        }
        let expected = data_frame_len(&enc, n).ok_or(Error::FrameTooLong)?;
        if expected != data.len() {
            return Err(Error::BadLength {
                expected: expected as u8,
                actual: data.len() as u8,
            });
        }
        let points = data.get(field::POINTS..).unwrap_or(&[]);
        let mut r = BitReader::new(points);
        // `data_frame_len` above computed this product without overflow.
        r.skip(n.wrapping_mul(enc.bits_per_point() as usize));
        if !r.rest_is_zero() {
            return Err(Error::ReservedBits);
        }
        Ok(DataFrame {
            header,
            count: n as u16,
            encoding: enc,
            points,
        })
    }

    /// The frame's header.
    pub fn header(&self) -> DataHeader {
        self.header
    }

    /// Number of points in the frame.
    pub fn len(&self) -> u16 {
        self.count
    }

    /// Whether the frame holds no point (never true for a parsed frame).
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The points as `(index, distance code, intensity code)`; the intensity code is 0
    /// without an intensity channel.
    pub fn codes(&self) -> impl Iterator<Item = (u16, u16, u16)> + 'a {
        let mut r = BitReader::new(self.points);
        let d = self.encoding.distance.bits();
        let i = self.encoding.intensity.bits();
        let first = self.header.first_index;
        (0..self.count).map(move |k| {
            let dc = r.read(d);
            let ic = r.read(i);
            // A parsed frame ends within the scan: first index + count <= 4096.
            (first.wrapping_add(k), dc, ic)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding::{DistanceEncoding, IntensityEncoding};
    use crate::header::Grouping;

    fn scan(count: u16, distance: DistanceEncoding, intensity: IntensityEncoding) -> ScanHeader {
        ScanHeader {
            seq: 0x0025,
            timestamp_ms: 0,
            point_count: count,
            encoding: Encoding {
                distance,
                intensity,
                unit_exp: 0,
            },
            time_synced: false,
            time_estimated: false,
            time_master: false,
            grouping: Grouping::Single,
            step_increment: 1,
            first_step: 0,
            ares: 1440,
        }
    }

    // seq low 5, first index 0x123; four 12-bit points 0xABC, 0x001, 0xFFF, 0x800
    const D12: [u8; 8] = [0x23, 0x51, 0xBC, 0x1A, 0x00, 0xFF, 0x0F, 0x80];

    #[test]
    fn parse_golden_d12() {
        let s = scan(0x200, DistanceEncoding::D12, IntensityEncoding::None);
        let f = DataFrame::parse(&D12, &s).unwrap();
        assert_eq!(
            f.header(),
            DataHeader {
                first_index: 0x123,
                seq_low: 5
            }
        );
        let pts: Vec<_> = f.codes().collect();
        assert_eq!(
            pts,
            vec![
                (0x123, 0xABC, 0),
                (0x124, 0x001, 0),
                (0x125, 0xFFF, 0),
                (0x126, 0x800, 0)
            ]
        );
        assert_eq!(
            DataHeader {
                first_index: 0x123,
                seq_low: 5
            }
            .emit(),
            [0x23, 0x51]
        );
    }

    #[test]
    fn last_frame_and_padding() {
        // 2 points left of 0x125: 24 bits → 5 bytes.
        let s = scan(0x125, DistanceEncoding::D12, IntensityEncoding::None);
        let short = [0x23, 0x51, 0xBC, 0x1A, 0x00];
        let f = DataFrame::parse(&short, &s).unwrap();
        assert_eq!(f.len(), 2);
        // A full-length frame when only 2 points are left is a bad length.
        assert_eq!(
            DataFrame::parse(&D12, &s).map(|f| f.len()),
            Err(Error::BadLength {
                expected: 5,
                actual: 8
            })
        );
        // Nonzero padding: one D16 point + one I8 (24 bits) in 5 bytes.
        let s = scan(1, DistanceEncoding::D16, IntensityEncoding::I8);
        assert!(DataFrame::parse(&[0, 0, 1, 2, 3], &s).is_ok());
        let s = scan(1, DistanceEncoding::D14, IntensityEncoding::None);
        assert_eq!(
            DataFrame::parse(&[0, 0, 0xFF, 0x7F], &s).map(|f| f.len()),
            Err(Error::ReservedBits)
        );
        assert!(DataFrame::parse(&[0, 0, 0xFF, 0x3F], &s).is_ok());
    }

    #[test]
    fn fd_padding() {
        // 4 D16 points = 8 bytes → 10 → padded to 12 on CAN FD.
        let s = scan(4, DistanceEncoding::D16, IntensityEncoding::None);
        let mut buf = [0u8; 12];
        buf[2] = 7;
        let f = DataFrame::parse(&buf, &s).unwrap();
        assert_eq!(f.len(), 4);
        buf[11] = 1;
        assert_eq!(
            DataFrame::parse(&buf, &s).map(|f| f.len()),
            Err(Error::ReservedBits)
        );
    }

    #[test]
    fn bad_index_and_lengths() {
        let s = scan(0x123, DistanceEncoding::D12, IntensityEncoding::None);
        assert_eq!(
            DataFrame::parse(&D12, &s).map(|f| f.len()),
            Err(Error::PointIndex)
        );
        for len in 0..=2 {
            assert_eq!(
                DataFrame::parse(&D12[..len], &s).map(|f| f.len()),
                Err(Error::BadLength {
                    expected: 3,
                    actual: len as u8
                })
            );
        }
        // Every length from 3 to 64 other than the right one is rejected.
        let s = scan(4000, DistanceEncoding::D16, IntensityEncoding::I16);
        let buf = [0u8; 64];
        for len in 3..=64 {
            let ok = DataFrame::parse(&buf[..len], &s).is_ok();
            let valid = crate::frame::is_valid_len(len) && len >= 6 && {
                let n = (len - 2) * 8 / 32;
                data_frame_len(&s.encoding, n) == Some(len)
            };
            assert_eq!(ok, valid, "len {len}");
        }
    }

    #[test]
    fn frame_len() {
        let e = Encoding {
            distance: DistanceEncoding::D12,
            intensity: IntensityEncoding::None,
            unit_exp: 0,
        };
        assert_eq!(data_frame_len(&e, 4), Some(8));
        assert_eq!(data_frame_len(&e, 41), Some(64));
        assert_eq!(data_frame_len(&e, 42), None);
        assert_eq!(data_frame_len(&e, 5), Some(12));
    }
}
