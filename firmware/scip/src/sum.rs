//! The SCIP line check sum (scip-reference §2).

/// The sum char of `bytes`: `((sum of bytes) & 0x3F) + 0x30`.
#[inline]
pub fn checksum(bytes: &[u8]) -> u8 {
    // Wrapping u8 addition keeps the low 6 bits exact and lets the compiler vectorise.
    let s = bytes.iter().fold(0u8, |acc, &b| acc.wrapping_add(b));
    // At most 0x3F + 0x30: never wraps.
    (s & 0x3F).wrapping_add(0x30)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_ok_sum_is_p() {
        assert_eq!(checksum(b"00"), b'P');
        assert_eq!(checksum(b"99"), b'b');
        assert_eq!(checksum(b"02"), b'R');
    }

    #[test]
    fn info_line_sums_from_real_sensors() {
        assert_eq!(checksum(b"DMIN:20"), b'4');
        assert_eq!(checksum(b"DMAX:5600"), b'_');
        assert_eq!(checksum(b"ARES:1024"), b'\\');
        assert_eq!(checksum(b"G]\\VF"[..4].as_ref()), b'F');
    }

    #[test]
    fn empty_sum() {
        assert_eq!(checksum(b""), b'0');
    }
}
