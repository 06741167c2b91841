//! Point encodings (SPEC section 4) and the LSB-first bit packing of data frames.

use crate::Error;

/// How distances are coded. Code 0 is "invalid / no return", the largest code is
/// "out of range"; codes in between are ranges in units of the scan's range unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DistanceEncoding {
    /// 16 bits per distance.
    D16 = 1,
    /// 14 bits per distance.
    D14 = 2,
    /// 12 bits per distance.
    D12 = 3,
    /// The lossless predictive coding (SPEC 4.2): variable bits per distance, every
    /// sensor value exact (protocol version 2).
    Lossless = 4,
}

impl DistanceEncoding {
    /// The fixed-width distance encodings.
    pub const ALL: [DistanceEncoding; 3] = [
        DistanceEncoding::D16,
        DistanceEncoding::D14,
        DistanceEncoding::D12,
    ];

    /// Parse a wire code.
    pub const fn from_code(code: u8) -> Result<Self, Error> {
        match code {
            1 => Ok(DistanceEncoding::D16),
            2 => Ok(DistanceEncoding::D14),
            3 => Ok(DistanceEncoding::D12),
            4 => Ok(DistanceEncoding::Lossless),
            other => Err(Error::UnknownEncoding(other)),
        }
    }

    /// The wire code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// Bits per distance; for [`DistanceEncoding::Lossless`] the width of a value field
    /// (the most a verbatim value takes).
    pub const fn bits(self) -> u32 {
        match self {
            DistanceEncoding::D16 => 16,
            DistanceEncoding::D14 => 14,
            DistanceEncoding::D12 => 12,
            DistanceEncoding::Lossless => crate::lossless::VALUE_BITS,
        }
    }

    /// Whether this is the lossless predictive coding (variable bits per point).
    pub const fn is_lossless(self) -> bool {
        matches!(self, DistanceEncoding::Lossless)
    }

    /// The "out of range" code (all ones).
    pub const fn max_code(self) -> u16 {
        // At most 16 bits: 2^bits >= 1.
        (1u32 << self.bits()).wrapping_sub(1) as u16
    }
}

/// How intensities are coded: the top bits of a 16-bit intensity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum IntensityEncoding {
    /// No intensity channel.
    None = 0,
    /// All 16 bits.
    I16 = 1,
    /// Top 12 bits.
    I12 = 2,
    /// Top 8 bits.
    I8 = 3,
}

impl IntensityEncoding {
    /// All intensity encodings, `None` first.
    pub const ALL: [IntensityEncoding; 4] = [
        IntensityEncoding::None,
        IntensityEncoding::I16,
        IntensityEncoding::I12,
        IntensityEncoding::I8,
    ];

    /// Parse a wire code.
    pub const fn from_code(code: u8) -> Result<Self, Error> {
        match code {
            0 => Ok(IntensityEncoding::None),
            1 => Ok(IntensityEncoding::I16),
            2 => Ok(IntensityEncoding::I12),
            3 => Ok(IntensityEncoding::I8),
            other => Err(Error::UnknownEncoding(other)),
        }
    }

    /// The wire code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// Bits per intensity (0 without the channel).
    pub const fn bits(self) -> u32 {
        match self {
            IntensityEncoding::None => 0,
            IntensityEncoding::I16 => 16,
            IntensityEncoding::I12 => 12,
            IntensityEncoding::I8 => 8,
        }
    }

    /// Whether the intensity channel is present.
    pub const fn is_present(self) -> bool {
        !matches!(self, IntensityEncoding::None)
    }

    /// The 16-bit intensity of a sensor's raw intensity value (SPEC 4):
    /// `min(4 × raw, 65535)`. Hokuyo sensors report intensities below 2^14, so every
    /// such value keeps all its bits (`raw = intensity / 4`) and I8 and I12 get their
    /// full range; larger values saturate.
    pub const fn from_sensor(raw: u32) -> u16 {
        if raw >= 1 << 14 {
            u16::MAX
        } else {
            (raw << 2) as u16
        }
    }

    /// The code of a 16-bit intensity.
    pub const fn encode(self, intensity: u16) -> u16 {
        match self {
            IntensityEncoding::None => 0,
            // 8..=16 bits on this arm.
            _ => intensity >> 16u32.wrapping_sub(self.bits()),
        }
    }

    /// The 16-bit intensity a code stands for.
    pub const fn decode(self, code: u16) -> u16 {
        match self {
            IntensityEncoding::None => 0,
            // 8..=16 bits on this arm.
            _ => code << 16u32.wrapping_sub(self.bits()),
        }
    }
}

/// A distance reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Distance {
    /// No valid measurement (no return, filtered out, or a sensor error code the
    /// encoding does not keep).
    Invalid,
    /// The sensor's error code (a SCIP distance below DMIN, or 65533..=65535 of the
    /// Ethernet models), kept by the lossless encoding; the fixed-width encodings send
    /// it as invalid.
    SensorError(u32),
    /// A range in millimetres.
    Mm(u32),
    /// Beyond what the encoding and unit can express.
    OutOfRange,
}

/// The per-scan encoding: distance and intensity codes and the range unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Encoding {
    /// Distance code width.
    pub distance: DistanceEncoding,
    /// Intensity code width (or none).
    pub intensity: IntensityEncoding,
    /// One distance count is `2^unit_exp` mm (0..=15).
    pub unit_exp: u8,
}

impl Encoding {
    /// Plain 16-bit millimetres, no intensity.
    pub const PLAIN_MM: Encoding = Encoding {
        distance: DistanceEncoding::D16,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };

    /// Check `unit_exp <= 15`.
    pub const fn validate(&self) -> Result<(), Error> {
        if self.unit_exp > 15 {
            Err(Error::OutOfRange { offset: 0 })
        } else {
            Ok(())
        }
    }

    /// Bits per point (distance + intensity).
    pub const fn bits_per_point(&self) -> u32 {
        // At most 16 + 16.
        self.distance.bits().wrapping_add(self.intensity.bits())
    }

    /// Points a data frame of length `len` (≥ 2) holds when full.
    pub const fn capacity(&self, len: usize) -> usize {
        if len < 2 {
            return 0;
        }
        // A distance code has at least 12 bits: the division never fails.
        match len
            .wrapping_sub(2)
            .saturating_mul(8)
            .checked_div(self.bits_per_point() as usize)
        {
            Some(points) => points,
            None => 0,
        }
    }

    /// The unit in millimetres.
    pub const fn unit_mm(&self) -> u32 {
        1u32 << (self.unit_exp & 0xF)
    }

    /// The code of a distance (SPEC section 4: round half up, ranges never become 0,
    /// too long ranges become the out-of-range code).
    pub const fn encode_distance(&self, d: Distance) -> u16 {
        self.distance_coder().code(d)
    }

    /// The distance coding with its constants worked out once (for a whole scan).
    pub(crate) const fn distance_coder(&self) -> DistanceCoder {
        let e = (self.unit_exp & 0xF) as u32;
        DistanceCoder {
            max: self.distance.max_code() as u32,
            half: (1u32 << e) >> 1,
            exp: e,
        }
    }

    /// The distance a code stands for.
    pub const fn decode_distance(&self, code: u16) -> Distance {
        if code == 0 {
            Distance::Invalid
        } else if code >= self.distance.max_code() {
            Distance::OutOfRange
        } else {
            Distance::Mm((code as u32) << (self.unit_exp & 0xF))
        }
    }

    /// Whether a distance code is a range (neither invalid nor out of range).
    pub const fn is_valid_code(&self, code: u16) -> bool {
        code != 0 && code < self.distance.max_code()
    }
}

/// [`Encoding::encode_distance`] with its per-encoding constants computed once.
#[derive(Debug, Clone, Copy)]
pub(crate) struct DistanceCoder {
    /// The out-of-range code.
    max: u32,
    /// Half a unit in mm, rounded down (rounds half up).
    half: u32,
    /// log2 of the unit in mm.
    exp: u32,
}

impl DistanceCoder {
    /// The code of a distance.
    #[inline(always)]
    pub(crate) const fn code(&self, d: Distance) -> u16 {
        let code = match d {
            Distance::Invalid | Distance::SensorError(_) => 0,
            Distance::OutOfRange => self.max,
            Distance::Mm(mm) => {
                // Saturating: a range near u32::MAX is out of range in any unit.
                let q = mm.saturating_add(self.half) >> self.exp;
                if q >= self.max {
                    self.max
                } else if q == 0 {
                    1
                } else {
                    q
                }
            }
        };
        code as u16
    }

    /// The code of a distance and whether it is a range: `(code(d), is_valid(code(d)))`
    /// with the validity known from the branch taken rather than tested again.
    #[inline(always)]
    pub(crate) const fn code_valid(&self, d: Distance) -> (u16, bool) {
        match d {
            Distance::Invalid | Distance::SensorError(_) => (0, false),
            Distance::OutOfRange => (self.max as u16, false),
            Distance::Mm(mm) => {
                let q = mm.saturating_add(self.half) >> self.exp;
                if q >= self.max {
                    (self.max as u16, false)
                } else if q == 0 {
                    (1, true)
                } else {
                    (q as u16, true)
                }
            }
        }
    }

    /// The out-of-range code (every range at or above it is coded so).
    #[inline(always)]
    pub(crate) const fn max_code(&self) -> u32 {
        self.max
    }

    /// Whether codes are millimetres as they are (unit 1 mm: no rounding, no shift).
    #[inline(always)]
    pub(crate) const fn is_mm(&self) -> bool {
        self.exp == 0
    }

    /// Whether a code is a range (neither invalid nor out of range).
    #[inline(always)]
    pub(crate) const fn is_valid(&self, code: u16) -> bool {
        code != 0 && (code as u32) < self.max
    }
}

/// Packs fields LSB-first into a data frame, a 32-bit word at a time.
///
/// The bits that do not yet fill a byte wait in `acc`; every `put` stores `acc` whole at
/// the current byte (4 bytes, the ones past the field being zero), so the buffer always
/// holds every bit put so far, then moves on by the bytes the field completed. Constant
/// work per field, no loop and one bounds check.
#[derive(Debug, Clone)]
pub(crate) struct Packer {
    buf: [u8; PACKER_LEN],
    /// Byte the next store begins at.
    pos: usize,
    /// Bits put but not yet in a whole byte (`nbits` of them, fewer than 8).
    acc: u32,
    nbits: u32,
}

/// A whole CAN FD payload and the 3 bytes a word store may reach past it.
const PACKER_LEN: usize = crate::frame::MAX_LEN + 3;

impl Packer {
    /// An empty packer whose first field goes at byte `start`.
    pub(crate) const fn new(start: usize) -> Self {
        Packer {
            buf: [0; PACKER_LEN],
            pos: start,
            acc: 0,
            nbits: 0,
        }
    }

    /// Bits put so far, counted from byte 0.
    #[cfg(test)]
    pub(crate) fn position(&self) -> usize {
        self.pos * 8 + self.nbits as usize
    }

    /// Put a field of `bits` bits (at most 24: with the at most 7 bits waiting, they fit
    /// the 32-bit word); `value` must be below `2^bits` (the callers' codes are). Bits
    /// beyond the buffer are dropped (the callers size frames so that this does not
    /// happen).
    #[inline(always)]
    pub(crate) fn put(&mut self, value: u32, bits: u32) {
        self.acc |= value << self.nbits;
        self.nbits = self.nbits.wrapping_add(bits);
        self.store(self.acc);
        let whole = self.nbits / 8;
        self.pos = self.pos.wrapping_add(whole as usize);
        // At most 31 bits were waiting: the shift is at most 24.
        self.acc = self.acc.wrapping_shr(whole.wrapping_mul(8));
        self.nbits %= 8;
    }

    /// The first 8 bytes as a little-endian word (a classic frame being built).
    #[inline(always)]
    pub(crate) fn word64(&self) -> u64 {
        self.buf
            .first_chunk::<8>()
            .map_or(0, |b| u64::from_le_bytes(*b))
    }

    /// Sets the first 8 bytes to `word` (little endian) with `bits` bits of fields put,
    /// as if they had been put one by one.
    #[inline(always)]
    pub(crate) fn set_word64(&mut self, word: u64, bits: u32) {
        if let Some(b) = self.buf.first_chunk_mut::<8>() {
            *b = word.to_le_bytes();
        }
        self.pos = (bits / 8) as usize;
        self.nbits = bits % 8;
        // `pos` is at most `bits / 8` and `nbits` below 8.
        self.acc = (word >> self.pos.wrapping_mul(8).min(63)) as u32
            & (1u32 << self.nbits).wrapping_sub(1);
    }

    /// Put one point: its `db`-bit distance code and `ib`-bit intensity code (0 bits
    /// without the channel), in one field when they fit one put.
    #[inline(always)]
    pub(crate) fn put_point(&mut self, dc: u32, ic: u32, db: u32, ib: u32) {
        // Code widths are at most 16 bits each.
        let bits = db.wrapping_add(ib);
        if bits <= 24 {
            self.put(dc | ic << db, bits);
        } else {
            self.put(dc, db);
            self.put(ic, ib);
        }
    }

    /// The next `len` bytes, for fields of whole bytes written directly (no bits may be
    /// waiting), and the position moved past them; `None` (nothing moved) if they do not
    /// fit the buffer.
    #[inline(always)]
    pub(crate) fn take_bytes(&mut self, len: usize) -> Option<&mut [u8]> {
        let start = self.pos;
        let end = start.checked_add(len)?;
        let bytes = self.buf.get_mut(start..end)?;
        self.pos = end;
        Some(bytes)
    }

    #[inline(always)]
    fn store(&mut self, word: u32) {
        if let Some(dst) = self.buf.get_mut(self.pos..self.pos.wrapping_add(4)) {
            dst.copy_from_slice(&word.to_le_bytes());
        }
    }

    /// The buffer (a data frame's bytes up to `len`, zero past what was put).
    pub(crate) fn bytes_mut(&mut self) -> &mut [u8] {
        &mut self.buf
    }

    /// The first `len` bytes: what was put, zero past it. A store writes a whole word at
    /// the current byte, so the bytes up to 4 past it are current; bytes further on may
    /// be left from a longer, earlier frame and are zeroed here (only the padding of a
    /// CAN FD frame can reach them).
    pub(crate) fn frame_bytes(&mut self, len: usize) -> Option<&[u8]> {
        let first_free = self.pos.wrapping_add(usize::from(self.nbits > 0));
        if first_free < len {
            if let Some(stale) = self.buf.get_mut(first_free..len) {
                stale.fill(0);
            }
        }
        self.buf.get(..len)
    }

    /// Empties the packer without clearing its bytes (see [`Packer::frame_bytes`]); the
    /// next field goes at byte `start`.
    pub(crate) fn reset(&mut self, start: usize) {
        self.pos = start;
        self.acc = 0;
        self.nbits = 0;
    }
}

/// Reads fields LSB-first from a byte slice; reads beyond the end yield zero bits.
pub(crate) struct BitReader<'a> {
    buf: &'a [u8],
    bit: usize,
}

impl<'a> BitReader<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        BitReader { buf, bit: 0 }
    }

    /// At most 16 bits per call, gathered from the (at most 3) bytes the field spans.
    pub(crate) fn read(&mut self, bits: u32) -> u16 {
        let bits = bits.min(16);
        let first = self.bit / 8;
        let shift = self.bit % 8;
        // `first` is at most `usize::MAX / 8`: adding 0..=2 cannot wrap.
        let byte = |k: usize| u32::from(self.buf.get(first.wrapping_add(k)).copied().unwrap_or(0));
        let word = byte(0) | (byte(1) << 8) | (byte(2) << 16);
        self.bit = self.bit.saturating_add(bits as usize);
        // At most 16 bits: 2^bits >= 1.
        ((word >> shift) & (1u32 << bits).wrapping_sub(1)) as u16
    }

    /// Skip `bits` bits.
    pub(crate) fn skip(&mut self, bits: usize) {
        self.bit = self.bit.saturating_add(bits);
    }

    /// Whether every bit from the current position to the end is zero.
    pub(crate) fn rest_is_zero(&self) -> bool {
        let byte = self.bit / 8;
        let first_ok = match self.buf.get(byte) {
            Some(b) => (b >> (self.bit % 8)) == 0,
            None => true,
        };
        first_ok
            && self
                .buf
                // `byte` is at most `usize::MAX / 8`.
                .get(byte.wrapping_add(1)..)
                .is_none_or(|rest| rest.iter().all(|b| *b == 0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip() {
        for d in DistanceEncoding::ALL {
            assert_eq!(DistanceEncoding::from_code(d.code()), Ok(d));
        }
        for i in IntensityEncoding::ALL {
            assert_eq!(IntensityEncoding::from_code(i.code()), Ok(i));
        }
        assert_eq!(
            DistanceEncoding::from_code(0),
            Err(Error::UnknownEncoding(0))
        );
        assert_eq!(
            IntensityEncoding::from_code(4),
            Err(Error::UnknownEncoding(4))
        );
    }

    #[test]
    fn distance_codes() {
        let e = Encoding {
            distance: DistanceEncoding::D12,
            intensity: IntensityEncoding::None,
            unit_exp: 1,
        };
        assert_eq!(e.encode_distance(Distance::Invalid), 0);
        assert_eq!(e.encode_distance(Distance::OutOfRange), 4095);
        assert_eq!(e.encode_distance(Distance::Mm(0)), 1); // a range never becomes invalid
        assert_eq!(e.encode_distance(Distance::Mm(1)), 1); // (1 + 1) >> 1
        assert_eq!(e.encode_distance(Distance::Mm(2)), 1);
        assert_eq!(e.encode_distance(Distance::Mm(3)), 2); // round half up
        assert_eq!(e.encode_distance(Distance::Mm(5600)), 2800);
        assert_eq!(e.encode_distance(Distance::Mm(8187)), 4094);
        assert_eq!(e.encode_distance(Distance::Mm(8189)), 4095); // saturates
        assert_eq!(e.encode_distance(Distance::Mm(u32::MAX)), 4095);
        assert_eq!(e.decode_distance(0), Distance::Invalid);
        assert_eq!(e.decode_distance(2800), Distance::Mm(5600));
        assert_eq!(e.decode_distance(4095), Distance::OutOfRange);
        assert!(e.is_valid_code(4094));
        assert!(!e.is_valid_code(4095));
        let big = Encoding {
            unit_exp: 15,
            ..Encoding::PLAIN_MM
        };
        assert_eq!(big.decode_distance(65534), Distance::Mm(65534 << 15));
    }

    #[test]
    fn intensity_codes() {
        assert_eq!(IntensityEncoding::I8.encode(0xABCD), 0xAB);
        assert_eq!(IntensityEncoding::I8.decode(0xAB), 0xAB00);
        assert_eq!(IntensityEncoding::I12.encode(0xABCD), 0xABC);
        assert_eq!(IntensityEncoding::I16.encode(0xABCD), 0xABCD);
        assert_eq!(IntensityEncoding::None.encode(0xABCD), 0);
    }

    #[test]
    fn sensor_intensities_scale_by_four_saturating() {
        // SPEC 4 worked by hand: raw 2439 (the median of the UTM-30LX capture) is
        // 9756 = 0x261C: I16 9756, I12 0x261 = 609, I8 0x26 = 38; raw 16219 (its
        // largest) is 64876 = 0xFD6C: I8 0xFD = 253; 16383 the largest exact value.
        let cases = [
            (0, 0, 0, 0),
            (1, 4, 0, 0),
            (2439, 9756, 609, 38),
            (16219, 64876, 4054, 253),
            (16383, 65532, 4095, 255),
            (16384, 65535, 4095, 255),
            ((1 << 18) - 1, 65535, 4095, 255),
            (u32::MAX, 65535, 4095, 255),
        ];
        for (raw, i16, i12, i8) in cases {
            let v = IntensityEncoding::from_sensor(raw);
            assert_eq!(v, i16, "raw {raw}");
            assert_eq!(IntensityEncoding::I16.encode(v), i16, "raw {raw}");
            assert_eq!(IntensityEncoding::I12.encode(v), i12, "raw {raw}");
            assert_eq!(IntensityEncoding::I8.encode(v), i8, "raw {raw}");
        }
    }

    #[test]
    fn capacity() {
        let d12 = Encoding {
            distance: DistanceEncoding::D12,
            ..Encoding::PLAIN_MM
        };
        assert_eq!(d12.capacity(8), 4);
        assert_eq!(d12.capacity(64), 41);
        assert_eq!(Encoding::PLAIN_MM.capacity(8), 3);
        assert_eq!(Encoding::PLAIN_MM.capacity(1), 0);
    }

    #[test]
    fn bit_packing() {
        let mut w = Packer::new(0);
        w.put(0xABC, 12);
        w.put(0x123, 12);
        assert_eq!(w.position(), 24);
        let buf = [0xBC, 0x3A, 0x12];
        assert_eq!(&w.bytes_mut()[..4], &[0xBC, 0x3A, 0x12, 0]);
        let mut r = BitReader::new(&buf);
        assert_eq!(r.read(12), 0xABC);
        assert!(!r.rest_is_zero());
        assert_eq!(r.read(12), 0x123);
        assert!(r.rest_is_zero());
        let pad = [0x0F, 0x10];
        let mut r = BitReader::new(&pad);
        r.read(4);
        assert!(!r.rest_is_zero());
        let pad = [0x0F, 0x00];
        let mut r = BitReader::new(&pad);
        r.read(4);
        assert!(r.rest_is_zero());
    }

    proptest::proptest! {
        /// Whatever the field widths, the packer's bytes read back as the fields put
        /// (the reader gathers bit by bit from at most 3 bytes), with zeros after them.
        #[test]
        fn packer_round_trip(fields in proptest::collection::vec((proptest::num::u32::ANY, 1u32..=24), 0..20)) {
            let mut w = Packer::new(2);
            let mut total = 16;
            for &(v, bits) in &fields {
                if total + bits as usize > crate::frame::MAX_LEN * 8 {
                    break;
                }
                w.put(v & ((1u32 << bits) - 1), bits);
                total += bits as usize;
            }
            proptest::prop_assert_eq!(w.position(), total);
            let bytes = w.bytes_mut().to_vec();
            let mut r = BitReader::new(&bytes);
            r.skip(16);
            let mut read = 16;
            for &(v, bits) in &fields {
                if read + bits as usize > total {
                    break;
                }
                let lo = r.read(bits.min(16)) as u32;
                let hi = if bits > 16 { r.read(bits - 16) as u32 } else { 0 };
                proptest::prop_assert_eq!(lo | hi << 16, v & ((1u32 << bits) - 1));
                read += bits as usize;
            }
            proptest::prop_assert!(r.rest_is_zero());
            proptest::prop_assert_eq!(&bytes[..2], &[0, 0]);
            // After a reset, a shorter frame's bytes are its own fields and zeros only.
            let len = (total / 8 + 1).min(PACKER_LEN);
            w.reset(2);
            w.put(1, 1);
            let short = w.frame_bytes(len).unwrap().to_vec();
            let mut expect = vec![0u8; len];
            expect[2] = 1;
            proptest::prop_assert_eq!(short, expect);
        }
    }
}
