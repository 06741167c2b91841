//! Hex digits, both ways, and a small bounded writer.

use crate::Error;

const DIGITS: &[u8; 16] = b"0123456789ABCDEF";

/// The value of one hex digit (either case).
pub(crate) fn digit(c: u8) -> Result<u8, Error> {
    match c {
        // None of these wraps: `c` lies in the matched range.
        b'0'..=b'9' => Ok(c.wrapping_sub(b'0')),
        b'A'..=b'F' => Ok(c.wrapping_sub(b'A').wrapping_add(10)),
        b'a'..=b'f' => Ok(c.wrapping_sub(b'a').wrapping_add(10)),
        _ => Err(Error::BadDigit),
    }
}

/// The value of a run of hex digits (at most 8).
pub(crate) fn number(chars: &[u8]) -> Result<u32, Error> {
    chars
        .iter()
        .try_fold(0u32, |acc, &c| Ok((acc << 4) | u32::from(digit(c)?)))
}

/// The upper-case hex digit of the low nibble of `v`.
pub(crate) fn upper(v: u32) -> u8 {
    DIGITS.get((v & 0xF) as usize).copied().unwrap_or(b'0')
}

/// Writes into a byte slice, failing with `BufferTooSmall` instead of panicking.
pub(crate) struct Out<'a> {
    buf: &'a mut [u8],
    pub(crate) len: usize,
}

impl<'a> Out<'a> {
    pub(crate) fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, len: 0 }
    }

    pub(crate) fn byte(&mut self, b: u8) -> Result<(), Error> {
        let slot = self.buf.get_mut(self.len).ok_or(Error::BufferTooSmall)?;
        *slot = b;
        // `len` indexed a slot of the buffer, so `len + 1 <= buf.len()`: never saturates.
        self.len = self.len.saturating_add(1);
        Ok(())
    }

    /// `digits` upper-case hex digits of `v`, most significant first (digits above the
    /// 8 of a `u32` are `0`).
    pub(crate) fn hex(&mut self, v: u32, digits: u32) -> Result<(), Error> {
        for i in (0..digits).rev() {
            let nibble = v.checked_shr(i.saturating_mul(4)).unwrap_or(0);
            self.byte(upper(nibble))?;
        }
        Ok(())
    }

    pub(crate) fn bytes(&mut self, data: &[u8]) -> Result<(), Error> {
        data.iter().try_for_each(|&b| self.byte(b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_and_numbers() {
        assert_eq!(digit(b'0'), Ok(0));
        assert_eq!(digit(b'f'), Ok(15));
        assert_eq!(digit(b'F'), Ok(15));
        assert_eq!(digit(b'G'), Err(Error::BadDigit));
        assert_eq!(digit(b'/'), Err(Error::BadDigit));
        assert_eq!(number(b"1FFFFFFF"), Ok(0x1FFF_FFFF));
        assert_eq!(number(b"7e5"), Ok(0x7E5));
        assert_eq!(number(b""), Ok(0));
        assert_eq!(number(b"12 4"), Err(Error::BadDigit));
    }

    #[test]
    fn out_is_bounded() {
        let mut buf = [0u8; 3];
        let mut o = Out::new(&mut buf);
        assert_eq!(o.hex(0xABC, 3), Ok(()));
        assert_eq!(o.byte(b'x'), Err(Error::BufferTooSmall));
        assert_eq!(&buf, b"ABC");
    }
}
