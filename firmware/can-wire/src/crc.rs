//! The scan CRC (SPEC section 3.4): CRC-16/IBM-3740 over headers, point codes and the
//! trailer's first six bytes.

use crc::{Crc, Digest, CRC_16_IBM_3740};

static SCAN_CRC: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// An incremental scan CRC.
#[derive(Clone)]
pub struct ScanCrc {
    digest: Digest<'static, u16>,
}

impl core::fmt::Debug for ScanCrc {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ScanCrc").finish_non_exhaustive()
    }
}

impl ScanCrc {
    /// Start a scan's CRC with its two header frames.
    pub fn new(header_a: &[u8], header_b: &[u8]) -> ScanCrc {
        let mut digest = SCAN_CRC.digest();
        digest.update(header_a);
        digest.update(header_b);
        ScanCrc { digest }
    }

    /// Add one point's codes (`intensity` only if the channel is present).
    pub fn point(&mut self, distance: u16, intensity: Option<u16>) {
        self.digest.update(&distance.to_le_bytes());
        if let Some(i) = intensity {
            self.digest.update(&i.to_le_bytes());
        }
    }

    /// Add the codes of several points laid out as the CRC takes them: per point its
    /// distance code as u16 little-endian, then its intensity code the same way if the
    /// channel is present. The same as calling [`ScanCrc::point`] for each point, at a
    /// fraction of the cost (one table pass, no call per point).
    pub fn codes(&mut self, le_codes: &[u8]) {
        self.digest.update(le_codes);
    }

    /// Finish with the trailer's bytes 0..6.
    pub fn finish(self, trailer_head: &[u8]) -> u16 {
        let mut d = self.digest;
        d.update(trailer_head);
        d.finalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        // "123456789" split over the pieces gives the catalogue check value 0x29B1.
        let mut c = ScanCrc::new(b"1", b"2");
        c.point(u16::from_le_bytes(*b"34"), Some(u16::from_le_bytes(*b"56")));
        assert_eq!(c.finish(b"789"), 0x29B1);
    }

    #[test]
    fn codes_are_points() {
        let mut one = ScanCrc::new(&[1, 2], &[3]);
        let mut all = one.clone();
        for (d, i) in [(0xABC, 0x12), (0, 0xFFFF), (0xFFF, 0)] {
            one.point(d, Some(i));
        }
        all.codes(&[0xBC, 0x0A, 0x12, 0x00, 0, 0, 0xFF, 0xFF, 0xFF, 0x0F, 0, 0]);
        assert_eq!(one.finish(&[9]), all.finish(&[9]));
    }
}
