//! The 6-bit character encoding of SCIP values (scip-reference §3).

/// Lowest valid value char (`'0'`, value 0).
pub const CHAR_MIN: u8 = 0x30;
/// Highest valid value char (`'o'`, value 63).
pub const CHAR_MAX: u8 = 0x6F;

/// The 6-bit value of one char, or `None` when it is outside `0x30..=0x6F`.
#[inline]
pub fn char_value(c: u8) -> Option<u32> {
    let v = c.wrapping_sub(CHAR_MIN);
    if v < 0x40 {
        Some(u32::from(v))
    } else {
        None
    }
}

/// Decodes 1 to 4 value chars, most significant first.
///
/// Returns `None` for an empty or over-long input or for a char outside `0x30..=0x6F`.
pub fn decode(chars: &[u8]) -> Option<u32> {
    if chars.is_empty() || chars.len() > 4 {
        return None;
    }
    chars
        .iter()
        .try_fold(0u32, |acc, &c| Some((acc << 6) | char_value(c)?))
}

/// Encodes `value` into `out.len()` chars (1 to 4), most significant first.
///
/// Returns `None` when `value` does not fit in `6 * out.len()` bits or `out` is empty
/// or longer than 4.
pub fn encode(value: u32, out: &mut [u8]) -> Option<()> {
    // 2^(6n): the first value that does not fit in n chars (0 for n = 0 or n > 4).
    let limit = [0u32, 1 << 6, 1 << 12, 1 << 18, 1 << 24]
        .get(out.len())
        .copied()
        .unwrap_or(0);
    if value >= limit {
        return None;
    }
    let mut rest = value;
    for slot in out.iter_mut().rev() {
        // Masked to 6 bits, so the char stays within 0x30..=0x6F: never wraps.
        *slot = ((rest & 0x3F) as u8).wrapping_add(CHAR_MIN);
        rest >>= 6;
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_examples() {
        assert_eq!(decode(b"CB"), Some(1234));
        assert_eq!(decode(b"1Dh"), Some(5432));
        assert_eq!(decode(b"m2@0"), Some(16_000_000));
        assert_eq!(decode(b"oo"), Some(4095));
        assert_eq!(decode(b"?om"), Some(65533));
    }

    #[test]
    fn bad_inputs() {
        assert_eq!(decode(b""), None);
        assert_eq!(decode(b"00000"), None);
        assert_eq!(decode(b"0p"), None);
        assert_eq!(decode(b"/0"), None);
        assert_eq!(decode(b"&0"), None);
    }

    #[test]
    fn encode_round_trip_and_limits() {
        let mut out = [0u8; 3];
        encode(5432, &mut out).unwrap();
        assert_eq!(&out, b"1Dh");
        let mut two = [0u8; 2];
        assert_eq!(encode(4096, &mut two), None);
        encode(4095, &mut two).unwrap();
        assert_eq!(&two, b"oo");
        assert_eq!(encode(1, &mut []), None);
        let mut four = [0u8; 4];
        encode(16_000_000, &mut four).unwrap();
        assert_eq!(&four, b"m2@0");
    }
}
