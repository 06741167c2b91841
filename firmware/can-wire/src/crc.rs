//! The scan CRC (SPEC section 3.4): CRC-16/IBM-3740 over headers, point codes and the
//! trailer's first six bytes.
//!
//! Bytes go through the usual 256-entry table. Point codes, the bulk of the input, go
//! through two tables a 16-bit code at a time (slice-by-2): the CRC register XOR the code
//! (its bytes in the order the CRC takes them, low first) indexes one table with each
//! byte. That is half the table steps of the bytewise update for 1 KiB of tables; the
//! `crc` crate offers 1 and 16 tables (the latter 8 KiB), so the 2-table form is here.
//!
//! The register is kept with its two bytes swapped, and so are the tables' entries: a
//! code (little endian, low byte first) then meets the register as it is, with no byte
//! swap per step, and its higher bits (a packed point's intensity) need no mask, since
//! only the low two bytes index the tables. The two tables are one of 32-bit entries
//! (the second table's entry in the low half, the first's in the high half), so a
//! step needs one table address: an XOR, two byte extractions, two loads and an XOR
//! with a shift. The tests check both forms against the `crc` crate.

/// CRC-16/IBM-3740: polynomial 0x1021, not reflected, initial value 0xFFFF, no final XOR.
const POLY: u16 = 0x1021;
const INIT: u16 = 0xFFFF;

/// For byte `b`, with both halves' bytes swapped as the register is kept: in the high
/// half the register after shifting `b` through it from zero (the bytewise table); in
/// the low half the same followed by a zero byte (for the first byte of a 16-bit step).
static TABLE: [u32; 256] = table();

// Evaluated at compile time (for a `static`): an index out of range would fail the
// build, never a run.
#[allow(clippy::indexing_slicing)]
const fn table() -> [u32; 256] {
    let mut t0 = [0u16; 256];
    let mut b = 0;
    while b < 256 {
        let mut r = (b as u16) << 8;
        let mut k = 0u32;
        while k < 8 {
            r = if r & 0x8000 != 0 {
                (r << 1) ^ POLY
            } else {
                r << 1
            };
            k = k.wrapping_add(1); // at most 8
        }
        t0[b] = r;
        b = b.wrapping_add(1); // at most 256
    }
    let mut t = [0u32; 256];
    let mut b = 0;
    while b < 256 {
        let r = t0[b];
        let r2 = (r << 8) ^ t0[(r >> 8) as usize];
        t[b] = (r2.swap_bytes() as u32) | (r.swap_bytes() as u32) << 16;
        b = b.wrapping_add(1); // at most 256
    }
    t
}

/// The table entry for byte `i` (the index is a byte, so always in the table).
#[inline(always)]
fn entry(i: u32) -> u32 {
    TABLE.get((i & 0xFF) as usize).copied().unwrap_or(0)
}

/// An incremental scan CRC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanCrc {
    /// The CRC register with its two bytes swapped.
    reg: u16,
}

impl ScanCrc {
    /// A CRC over nothing yet (the initial register), for a CRC over other bytes than a
    /// scan's (the lossless coding's segment check).
    pub const fn start() -> ScanCrc {
        ScanCrc {
            reg: INIT.swap_bytes(),
        }
    }

    /// Add one byte.
    #[inline(always)]
    pub fn byte(&mut self, b: u8) {
        // The register's high byte is the swapped one's low byte.
        let r = u32::from(self.reg);
        self.reg = ((r >> 8) ^ (entry(r ^ u32::from(b)) >> 16)) as u16;
    }

    /// The CRC of the bytes added so far.
    pub const fn value(&self) -> u16 {
        self.reg.swap_bytes()
    }

    /// Start a scan's CRC with its two header frames.
    pub fn new(header_a: &[u8], header_b: &[u8]) -> ScanCrc {
        let mut c = ScanCrc::start();
        c.bytes(header_a);
        c.bytes(header_b);
        c
    }

    /// Add bytes, one table step each.
    #[inline]
    pub fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.byte(b);
        }
    }

    /// Add one code as the CRC takes it (u16, little endian): one 2-table step.
    #[inline(always)]
    pub fn code(&mut self, code: u16) {
        self.step(u32::from(code));
    }

    /// One 2-table step over the low 16 bits of `code` (little endian); the bits above
    /// are not looked at.
    #[inline(always)]
    fn step(&mut self, code: u32) {
        // The low byte goes first: it meets the register's high byte, the swapped
        // register's low byte.
        let x = u32::from(self.reg) ^ code;
        self.reg = (entry(x) ^ (entry(x >> 8) >> 16)) as u16;
    }

    /// Add one point's codes packed in a word: the distance code in the low 16 bits,
    /// then the intensity code above if the channel is present (`intensity`).
    #[inline(always)]
    pub fn point_code(&mut self, code: u32, intensity: bool) {
        self.step(code);
        if intensity {
            self.step(code >> 16);
        }
    }

    /// Add the codes of several points packed in words, as [`ScanCrc::point_code`] for
    /// each, with the register in a 32-bit local and the channel's test out of the loop.
    #[inline(always)]
    pub fn point_codes(&mut self, codes: &[u32], intensity: bool) {
        // The bits of `r` above 16 are left over from the table entries: only the low
        // two bytes index the tables, and the result is the low 16 bits.
        let mut r = u32::from(self.reg);
        let step = |r: u32, code: u32| {
            let x = r ^ code;
            entry(x) ^ (entry(x >> 8) >> 16)
        };
        if intensity {
            for &code in codes {
                r = step(step(r, code), code >> 16);
            }
        } else {
            for &code in codes {
                r = step(r, code);
            }
        }
        self.reg = r as u16;
    }

    /// [`ScanCrc::point_codes`] of points with a 16-bit distance code alone (each of
    /// `codes` below 2^16), each code also written into `out` as two bytes, little
    /// endian, in the same pass (a frame's point fields; as many as both hold).
    #[inline(always)]
    pub fn codes16_into(&mut self, codes: &[u32], out: &mut [u8]) {
        let mut r = u32::from(self.reg);
        for (&code, field) in codes.iter().zip(out.chunks_exact_mut(2)) {
            let x = r ^ code;
            r = entry(x) ^ (entry(x >> 8) >> 16);
            if let Some(field) = field.first_chunk_mut::<2>() {
                *field = (code as u16).to_le_bytes();
            }
        }
        self.reg = r as u16;
    }

    /// Add one point's codes (`intensity` only if the channel is present).
    #[inline]
    pub fn point(&mut self, distance: u16, intensity: Option<u16>) {
        self.code(distance);
        if let Some(i) = intensity {
            self.code(i);
        }
    }

    /// Add the codes of several points laid out as the CRC takes them: per point its
    /// distance code as u16 little-endian, then its intensity code the same way if the
    /// channel is present. The same as calling [`ScanCrc::point`] for each point.
    pub fn codes(&mut self, le_codes: &[u8]) {
        let mut pairs = le_codes.chunks_exact(2);
        for pair in &mut pairs {
            if let [lo, hi] = *pair {
                self.code(u16::from_le_bytes([lo, hi]));
            }
        }
        self.bytes(pairs.remainder());
    }

    /// Finish with the trailer's bytes 0..6.
    pub fn finish(self, trailer_head: &[u8]) -> u16 {
        let mut c = self;
        c.bytes(trailer_head);
        c.value()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The `crc` crate's CRC-16/IBM-3740, the reference.
    fn reference(bytes: &[u8]) -> u16 {
        crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740).checksum(bytes)
    }

    #[test]
    fn check_value() {
        // "123456789" split over the pieces gives the catalogue check value 0x29B1.
        let mut c = ScanCrc::new(b"1", b"2");
        c.point(u16::from_le_bytes(*b"34"), Some(u16::from_le_bytes(*b"56")));
        assert_eq!(c.finish(b"789"), 0x29B1);
        assert_eq!(reference(b"123456789"), 0x29B1);
    }

    #[test]
    fn codes_are_points() {
        let mut one = ScanCrc::new(&[1, 2], &[3]);
        let mut all = one;
        for (d, i) in [(0xABC, 0x12), (0, 0xFFFF), (0xFFF, 0)] {
            one.point(d, Some(i));
        }
        all.codes(&[0xBC, 0x0A, 0x12, 0x00, 0, 0, 0xFF, 0xFF, 0xFF, 0x0F, 0, 0]);
        assert_eq!(one.finish(&[9]), all.finish(&[9]));
    }

    proptest! {
        /// Packed point codes (distance in the low 16 bits, intensity above), a slice
        /// at a time: the CRC of their bytes as SPEC 3.4 lists them.
        #[test]
        fn packed_point_codes_equal_the_crc_crate(
            codes in proptest::collection::vec(any::<u32>(), 0..40),
            intensity in any::<bool>(),
        ) {
            let mut c = ScanCrc::start();
            c.point_codes(&codes, intensity);
            let mut bytes = Vec::new();
            for &code in &codes {
                bytes.extend((code as u16).to_le_bytes());
                if intensity {
                    bytes.extend(((code >> 16) as u16).to_le_bytes());
                }
            }
            prop_assert_eq!(c.value(), reference(&bytes));
        }

        /// 16-bit distance codes alone, CRC and fields in one pass: the CRC of their
        /// bytes by the `crc` crate, and the bytes themselves, each code little endian;
        /// a field area shorter than the codes takes as many as it holds.
        #[test]
        fn codes_into_fields_equal_the_crc_crate(
            head in proptest::collection::vec(any::<u8>(), 0..6),
            codes in proptest::collection::vec(any::<u16>(), 0..40),
            short in 0usize..3,
        ) {
            let words: Vec<u32> = codes.iter().map(|&c| u32::from(c)).collect();
            let mut c = ScanCrc::new(&head, &[]);
            let mut out = vec![0xEE; 2 * codes.len().saturating_sub(short)];
            c.codes16_into(&words, &mut out);
            let fields: Vec<u8> = codes.iter().take(out.len() / 2).flat_map(|c| c.to_le_bytes()).collect();
            prop_assert_eq!(&out, &fields);
            let mut all = head.clone();
            all.extend(&fields);
            prop_assert_eq!(c.value(), reference(&all));
        }

        #[test]
        fn both_forms_equal_the_crc_crate(
            a in proptest::collection::vec(any::<u8>(), 0..12),
            b in proptest::collection::vec(any::<u8>(), 0..12),
            codes in proptest::collection::vec(any::<u16>(), 0..40),
            tail in proptest::collection::vec(any::<u8>(), 0..8),
        ) {
            let mut c = ScanCrc::new(&a, &b);
            for &code in &codes {
                c.code(code);
            }
            let mut all = a.clone();
            all.extend(&b);
            all.extend(codes.iter().flat_map(|c| c.to_le_bytes()));
            all.extend(&tail);
            prop_assert_eq!(c.finish(&tail), reference(&all));
        }
    }
}
