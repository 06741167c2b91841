//! Scan headers A and B (SPEC sections 3.1, 3.2).

use crate::encoding::{DistanceEncoding, Encoding, IntensityEncoding};
use crate::error::check_len;
use crate::Error;

/// Most points a scan can have (12-bit point indices).
pub const MAX_POINTS: u16 = 4095;

mod field {
    use core::ops::Range;
    // Header A
    pub const SEQ: Range<usize> = 0..2;
    pub const TIMESTAMP: Range<usize> = 2..6;
    pub const COUNT_UNIT: Range<usize> = 6..8;
    // Header B
    pub const SEQ_LOW: usize = 0;
    pub const ENCODING: usize = 1;
    pub const FLAGS: usize = 2;
    pub const STEP_INCREMENT: usize = 3;
    pub const FIRST_STEP: Range<usize> = 4..6;
    pub const ARES: Range<usize> = 6..8;
}

/// Length of either header frame.
pub const HEADER_LEN: usize = 8;

/// How a point summarises the `step_increment` sensor steps it stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Grouping {
    /// One step (every n-th step, or cluster of one).
    Single = 0,
    /// The minimum distance of the group (SCIP clustering).
    Min = 1,
    /// The mean distance of the group.
    Mean = 2,
}

impl Grouping {
    fn from_bits(b: u8) -> Option<Grouping> {
        match b {
            0 => Some(Grouping::Single),
            1 => Some(Grouping::Min),
            2 => Some(Grouping::Mean),
            _ => None,
        }
    }
}

pub(crate) fn le16(data: &[u8], r: core::ops::Range<usize>) -> u16 {
    match data.get(r) {
        Some([a, b]) => u16::from_le_bytes([*a, *b]),
        _ => 0,
    }
}

pub(crate) fn le32(data: &[u8], r: core::ops::Range<usize>) -> u32 {
    match data.get(r) {
        Some([a, b, c, d]) => u32::from_le_bytes([*a, *b, *c, *d]),
        _ => 0,
    }
}

pub(crate) fn byte(data: &[u8], i: usize) -> u8 {
    data.get(i).copied().unwrap_or(0)
}

pub(crate) fn put(buf: &mut [u8], r: core::ops::Range<usize>, bytes: &[u8]) {
    if let Some(dst) = buf.get_mut(r) {
        if dst.len() == bytes.len() {
            dst.copy_from_slice(bytes);
        }
    }
}

/// Everything a scan header says (both frames together).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanHeader {
    /// Scan sequence number (wrapping).
    pub seq: u16,
    /// Time of the scan, modulo 2^32: sensor ms (or bridge ms when `time_synced`);
    /// with `time_estimated`, µs of the bridge's clock at the first point (SPEC 3.1).
    pub timestamp_ms: u32,
    /// Number of points, 0..=4095.
    pub point_count: u16,
    /// Point encoding and range unit.
    pub encoding: Encoding,
    /// Timestamp mapped to the bridge clock.
    pub time_synced: bool,
    /// Timestamp is the bridge's estimate of the first point's time, µs (protocol
    /// version 3; SPEC 3.2).
    pub time_estimated: bool,
    /// With `time_estimated`: the time is in µs of the time master's clock (SPEC 9),
    /// modulo 2^32, not the bridge's (protocol version 3; SPEC 3.1).
    pub time_master: bool,
    /// How each point summarises its steps.
    pub grouping: Grouping,
    /// Sensor steps between consecutive points, ≥ 1.
    pub step_increment: u8,
    /// Step of point 0 relative to the sensor's front step; with the geometry unknown
    /// (`ares` 0), the sensor step of point 0.
    pub first_step: i16,
    /// Steps per revolution; 0: geometry unknown, no angles (SPEC 3.2).
    pub ares: u16,
}

impl ScanHeader {
    /// Check every field against its allowed range.
    pub fn validate(&self) -> Result<(), Error> {
        if self.point_count > MAX_POINTS || self.encoding.unit_exp > 15 {
            return Err(Error::OutOfRange { offset: 6 });
        }
        if self.step_increment == 0 {
            return Err(Error::OutOfRange {
                offset: field::STEP_INCREMENT as u8,
            });
        }
        if self.time_master && !self.time_estimated {
            return Err(Error::OutOfRange {
                offset: field::FLAGS as u8,
            });
        }
        Ok(())
    }

    /// Whether the header gives the sensor's geometry (`ares` ≠ 0), so points have angles.
    pub fn geometry_known(&self) -> bool {
        self.ares != 0
    }

    /// Angle of point `index` in radians (0 = sensor front, counter-clockwise); `None`
    /// when the geometry is unknown.
    pub fn angle(&self, index: u16) -> Option<f32> {
        if !self.geometry_known() {
            return None;
        }
        // An i16 plus a u16 times a u8: far inside i32.
        let step = i32::from(self.first_step)
            .wrapping_add(i32::from(index).wrapping_mul(i32::from(self.step_increment)));
        Some(step as f32 * core::f32::consts::TAU / f32::from(self.ares))
    }

    /// [`ScanHeader::angle`], NaN when the geometry is unknown.
    pub fn angle_rad(&self, index: u16) -> f32 {
        self.angle(index).unwrap_or(f32::NAN)
    }

    /// The header A frame bytes.
    pub fn emit_a(&self) -> Result<[u8; HEADER_LEN], Error> {
        self.validate()?;
        let mut b = [0u8; HEADER_LEN];
        put(&mut b, field::SEQ, &self.seq.to_le_bytes());
        put(&mut b, field::TIMESTAMP, &self.timestamp_ms.to_le_bytes());
        let cu = self.point_count | (u16::from(self.encoding.unit_exp) << 12);
        put(&mut b, field::COUNT_UNIT, &cu.to_le_bytes());
        Ok(b)
    }

    /// The header B frame bytes.
    pub fn emit_b(&self) -> Result<[u8; HEADER_LEN], Error> {
        self.validate()?;
        let mut b = [0u8; HEADER_LEN];
        b[field::SEQ_LOW] = self.seq as u8;
        b[field::ENCODING] = self.encoding.distance.code() | (self.encoding.intensity.code() << 4);
        b[field::FLAGS] = u8::from(self.time_synced)
            | ((self.grouping as u8) << 1)
            | (u8::from(self.time_estimated) << 3)
            | (u8::from(self.time_master) << 4);
        b[field::STEP_INCREMENT] = self.step_increment;
        put(&mut b, field::FIRST_STEP, &self.first_step.to_le_bytes());
        put(&mut b, field::ARES, &self.ares.to_le_bytes());
        Ok(b)
    }

    /// Combine parsed headers A and B; fails with [`Error::OutOfRange`] (offset 0) if
    /// header B belongs to another scan.
    pub fn join(a: &HeaderA, b: &HeaderB) -> Result<ScanHeader, Error> {
        if a.seq as u8 != b.seq_low {
            return Err(Error::OutOfRange { offset: 0 });
        }
        Ok(ScanHeader {
            seq: a.seq,
            timestamp_ms: a.timestamp_ms,
            point_count: a.point_count,
            encoding: Encoding {
                distance: b.distance,
                intensity: b.intensity,
                unit_exp: a.unit_exp,
            },
            time_synced: b.time_synced,
            time_estimated: b.time_estimated,
            time_master: b.time_master,
            grouping: b.grouping,
            step_increment: b.step_increment,
            first_step: b.first_step,
            ares: b.ares,
        })
    }
}

/// Parsed header A.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HeaderA {
    /// Scan sequence number.
    pub seq: u16,
    /// Sensor time, ms.
    pub timestamp_ms: u32,
    /// Number of points.
    pub point_count: u16,
    /// Range unit exponent.
    pub unit_exp: u8,
}

impl HeaderA {
    /// Parse header A bytes (always succeeds on 8 bytes: every bit pattern is valid).
    pub fn parse(data: &[u8]) -> Result<HeaderA, Error> {
        check_len(data, HEADER_LEN)?;
        let cu = le16(data, field::COUNT_UNIT);
        Ok(HeaderA {
            seq: le16(data, field::SEQ),
            timestamp_ms: le32(data, field::TIMESTAMP),
            point_count: cu & 0x0FFF,
            unit_exp: (cu >> 12) as u8,
        })
    }
}

/// Parsed header B.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HeaderB {
    /// Low 8 bits of the scan sequence number.
    pub seq_low: u8,
    /// Distance encoding.
    pub distance: DistanceEncoding,
    /// Intensity encoding.
    pub intensity: IntensityEncoding,
    /// Timestamp mapped to the bridge clock.
    pub time_synced: bool,
    /// Timestamp in µs, the bridge's estimate (version 3).
    pub time_estimated: bool,
    /// The estimate is in the time master's clock (version 3; needs `time_estimated`).
    pub time_master: bool,
    /// Point grouping.
    pub grouping: Grouping,
    /// Steps between points (≥ 1).
    pub step_increment: u8,
    /// Step of point 0 relative to the front.
    pub first_step: i16,
    /// Steps per revolution; 0: geometry unknown.
    pub ares: u16,
}

impl HeaderB {
    /// Parse and validate header B bytes.
    pub fn parse(data: &[u8]) -> Result<HeaderB, Error> {
        check_len(data, HEADER_LEN)?;
        let enc = byte(data, field::ENCODING);
        let distance = DistanceEncoding::from_code(enc & 0xF)?;
        let intensity = IntensityEncoding::from_code(enc >> 4)?;
        let flags = byte(data, field::FLAGS);
        if flags & !0x1F != 0 {
            return Err(Error::ReservedBits);
        }
        // The master's clock is only ever given for an estimated time.
        if flags & 0x18 == 0x10 {
            return Err(Error::OutOfRange {
                offset: field::FLAGS as u8,
            });
        }
        let grouping = Grouping::from_bits((flags >> 1) & 3).ok_or(Error::OutOfRange {
            offset: field::FLAGS as u8,
        })?;
        let step_increment = byte(data, field::STEP_INCREMENT);
        if step_increment == 0 {
            return Err(Error::OutOfRange {
                offset: field::STEP_INCREMENT as u8,
            });
        }
        let ares = le16(data, field::ARES);
        Ok(HeaderB {
            seq_low: byte(data, field::SEQ_LOW),
            distance,
            intensity,
            time_synced: flags & 1 == 1,
            time_estimated: flags & 0x08 != 0,
            time_master: flags & 0x10 != 0,
            grouping,
            step_increment,
            first_step: le16(data, field::FIRST_STEP) as i16,
            ares,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> ScanHeader {
        ScanHeader {
            seq: 0x1234,
            timestamp_ms: 0x0A0B0C0D,
            point_count: 682,
            encoding: Encoding {
                distance: DistanceEncoding::D12,
                intensity: IntensityEncoding::I8,
                unit_exp: 1,
            },
            time_synced: true,
            time_estimated: false,
            time_master: false,
            grouping: Grouping::Min,
            step_increment: 1,
            first_step: -340,
            ares: 1024,
        }
    }

    // 682 = 0x2AA, unit_exp 1 → 0x12AA; -340 = 0xFEAC; 1024 = 0x0400
    const A: [u8; 8] = [0x34, 0x12, 0x0D, 0x0C, 0x0B, 0x0A, 0xAA, 0x12];
    const B: [u8; 8] = [0x34, 0x33, 0x03, 0x01, 0xAC, 0xFE, 0x00, 0x04];

    #[test]
    fn emit_golden() {
        assert_eq!(header().emit_a(), Ok(A));
        assert_eq!(header().emit_b(), Ok(B));
    }

    #[test]
    fn parse_golden_and_join() {
        let a = HeaderA::parse(&A).unwrap();
        assert_eq!(a.point_count, 682);
        assert_eq!(a.unit_exp, 1);
        let b = HeaderB::parse(&B).unwrap();
        assert_eq!(b.first_step, -340);
        assert_eq!(ScanHeader::join(&a, &b), Ok(header()));
        let mut b2 = b;
        b2.seq_low = 0x35;
        assert_eq!(
            ScanHeader::join(&a, &b2),
            Err(Error::OutOfRange { offset: 0 })
        );
    }

    #[test]
    fn every_bad_length() {
        for len in (0..=64).filter(|l| *l != 8) {
            let buf = [0u8; 64];
            let e = Error::BadLength {
                expected: 8,
                actual: len as u8,
            };
            assert_eq!(HeaderA::parse(&buf[..len]), Err(e));
            assert_eq!(HeaderB::parse(&buf[..len]), Err(e));
        }
    }

    #[test]
    fn header_b_rejects() {
        let mut b = B;
        b[1] = 0x30; // distance encoding 0
        assert_eq!(HeaderB::parse(&b), Err(Error::UnknownEncoding(0)));
        let mut b = B;
        b[1] = 0x43; // intensity encoding 4
        assert_eq!(HeaderB::parse(&b), Err(Error::UnknownEncoding(4)));
        let mut b = B;
        b[2] = 0x20;
        assert_eq!(HeaderB::parse(&b), Err(Error::ReservedBits));
        // Bit 4 (the master's clock) without bit 3 (an estimated time) says nothing.
        b[2] = 0x11;
        assert_eq!(HeaderB::parse(&b), Err(Error::OutOfRange { offset: 2 }));
        // Bit 3: the timestamp is the bridge's estimate in µs (version 3).
        b[2] = 0x09;
        let h = HeaderB::parse(&b).unwrap();
        assert!(h.time_estimated && h.time_synced && !h.time_master);
        // Bits 3 and 4: that estimate in µs of the time master's clock.
        b[2] = 0x19;
        let h = HeaderB::parse(&b).unwrap();
        assert!(h.time_estimated && h.time_master);
        let mut b = B;
        b[2] = 0x06; // grouping 3
        assert_eq!(HeaderB::parse(&b), Err(Error::OutOfRange { offset: 2 }));
        let mut b = B;
        b[3] = 0;
        assert_eq!(HeaderB::parse(&b), Err(Error::OutOfRange { offset: 3 }));
    }

    #[test]
    fn geometry_unknown() {
        // SPEC 3.2: ares 0 is a valid header whose points have no angles; first_step is
        // then the sensor step of point 0 (here 44 = 0x002C).
        let b = [0x34, 0x33, 0x03, 0x01, 0x2C, 0x00, 0x00, 0x00];
        let h =
            ScanHeader::join(&HeaderA::parse(&A).unwrap(), &HeaderB::parse(&b).unwrap()).unwrap();
        assert_eq!((h.ares, h.first_step), (0, 44));
        assert!(!h.geometry_known());
        assert_eq!(h.angle(0), None);
        assert!(h.angle_rad(0).is_nan());
        assert_eq!(h.emit_b(), Ok(b));
    }

    #[test]
    fn emit_validates() {
        let mut h = header();
        h.point_count = 4096;
        assert_eq!(h.emit_a(), Err(Error::OutOfRange { offset: 6 }));
        let mut h = header();
        h.step_increment = 0;
        assert_eq!(h.emit_b(), Err(Error::OutOfRange { offset: 3 }));
    }

    #[test]
    fn angles() {
        let h = header();
        let a0 = h.angle_rad(0);
        let want = -340.0 * core::f32::consts::TAU / 1024.0;
        assert!((a0 - want).abs() < 1e-6);
        assert!((h.angle_rad(340)).abs() < 1e-6);
    }
}
