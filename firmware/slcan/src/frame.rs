//! CAN and CAN FD frames as SLCAN writes them, and the data length codes.
//!
//! ```text
//! t iii L dd..        classic data, 11-bit ID, L = 0..8
//! T iiiiiiii L dd..   classic data, 29-bit ID
//! r iii L             remote (RTR), 11-bit ID, no data
//! R iiiiiiii L        remote, 29-bit ID
//! d iii L dd..        CAN FD data without bit-rate switch, L = 0..F (9..F = 12..64 bytes)
//! D iiiiiiii L dd..   the same, 29-bit ID
//! b iii L dd..        CAN FD data with bit-rate switch
//! B iiiiiiii L dd..   the same, 29-bit ID
//! ```
//! Hex digits are written upper case and read in either case. A line the adapter sends
//! may end with a 4-digit timestamp (ms, `0000..EA5F`) when timestamps are on (`Z1`).

use embedded_can::{ExtendedId, Id, StandardId};

use crate::hex::{self, Out};
use crate::Error;

/// Largest payload (CAN FD).
pub const MAX_DATA: usize = 64;

/// Timestamps count milliseconds modulo this (`0000`..=`EA5F`).
const TIMESTAMP_MODULUS: u32 = 60_000;

/// Payload length of each CAN FD data length code.
const FD_LENGTHS: [u8; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// Payload bytes of a CAN FD data length code (`0..=15`), `None` above.
pub fn dlc_to_len(dlc: u8) -> Option<usize> {
    FD_LENGTHS.get(usize::from(dlc)).map(|&l| usize::from(l))
}

/// The data length code of a payload length, `None` for a length no frame has
/// (9..=11, 13..=15, ..., above 64).
pub fn len_to_dlc(len: usize) -> Option<u8> {
    FD_LENGTHS
        .iter()
        .position(|&l| usize::from(l) == len)
        .and_then(|i| u8::try_from(i).ok())
}

/// What kind of frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameKind {
    /// Classic CAN data frame (`t`/`T`), up to 8 bytes.
    Data,
    /// Classic remote frame (`r`/`R`): a DLC, no data.
    Remote,
    /// CAN FD data frame without bit-rate switch (`d`/`D`).
    Fd,
    /// CAN FD data frame with bit-rate switch (`b`/`B`).
    FdBrs,
}

impl FrameKind {
    /// The command letter of this kind with a standard (11-bit) identifier; the
    /// extended-ID letter is its upper case.
    pub const fn letter(self) -> u8 {
        match self {
            FrameKind::Data => b't',
            FrameKind::Remote => b'r',
            FrameKind::Fd => b'd',
            FrameKind::FdBrs => b'b',
        }
    }

    /// The kind and whether the ID is extended, from a line's first letter.
    pub const fn from_letter(c: u8) -> Option<(FrameKind, bool)> {
        Some(match c {
            b't' => (FrameKind::Data, false),
            b'T' => (FrameKind::Data, true),
            b'r' => (FrameKind::Remote, false),
            b'R' => (FrameKind::Remote, true),
            b'd' => (FrameKind::Fd, false),
            b'D' => (FrameKind::Fd, true),
            b'b' => (FrameKind::FdBrs, false),
            b'B' => (FrameKind::FdBrs, true),
            _ => return None,
        })
    }

    /// Whether this is a CAN FD kind.
    pub const fn is_fd(self) -> bool {
        matches!(self, FrameKind::Fd | FrameKind::FdBrs)
    }
}

/// One frame: identifier, kind, payload (for a remote frame: its DLC as length, data 0).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    id: Id,
    kind: FrameKind,
    len: u8,
    data: [u8; MAX_DATA],
}

impl core::fmt::Debug for Frame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Frame")
            .field("id", &self.id)
            .field("kind", &self.kind)
            .field("len", &self.len)
            .field("data", &self.data())
            .finish()
    }
}

impl Frame {
    /// A data frame of `kind` (not [`FrameKind::Remote`]); fails if `data` is too long for
    /// the kind or, in CAN FD, not an FD length.
    pub fn new(id: Id, kind: FrameKind, data: &[u8]) -> Result<Frame, Error> {
        let ok = match kind {
            FrameKind::Data => data.len() <= 8,
            FrameKind::Remote => false,
            FrameKind::Fd | FrameKind::FdBrs => len_to_dlc(data.len()).is_some(),
        };
        if !ok {
            return Err(Error::BadFrameLength);
        }
        let mut buf = [0u8; MAX_DATA];
        buf.get_mut(..data.len())
            .ok_or(Error::BadFrameLength)?
            .copy_from_slice(data);
        Ok(Frame {
            id,
            kind,
            len: data.len() as u8,
            data: buf,
        })
    }

    /// A remote frame asking for `dlc` (0..=8) bytes.
    pub fn remote(id: Id, dlc: u8) -> Result<Frame, Error> {
        if dlc > 8 {
            return Err(Error::BadDlc);
        }
        Ok(Frame {
            id,
            kind: FrameKind::Remote,
            len: dlc,
            data: [0; MAX_DATA],
        })
    }

    /// The identifier.
    pub fn id(&self) -> Id {
        self.id
    }

    /// The kind.
    pub fn kind(&self) -> FrameKind {
        self.kind
    }

    /// The payload (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        if self.kind == FrameKind::Remote {
            return &[];
        }
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// The data length code (for a remote frame: the requested length).
    pub fn dlc(&self) -> u8 {
        len_to_dlc(usize::from(self.len)).unwrap_or(0)
    }

    /// Writes the frame's line: letter, ID, DLC, data, the optional timestamp (ms; taken
    /// modulo 60000 as Lawicel adapters count), and CR. Returns the length written.
    pub fn emit(&self, timestamp_ms: Option<u16>, buf: &mut [u8]) -> Result<usize, Error> {
        let mut out = Out::new(buf);
        let (extended, raw) = match self.id {
            Id::Standard(s) => (false, u32::from(s.as_raw())),
            Id::Extended(e) => (true, e.as_raw()),
        };
        let letter = self.kind.letter();
        out.byte(if extended {
            letter.to_ascii_uppercase()
        } else {
            letter
        })?;
        out.hex(raw, if extended { 8 } else { 3 })?;
        out.hex(u32::from(self.dlc()), 1)?;
        for &b in self.data() {
            out.hex(u32::from(b), 2)?;
        }
        if let Some(ts) = timestamp_ms {
            out.hex(u32::from(ts) % TIMESTAMP_MODULUS, 4)?;
        }
        out.byte(crate::CR)?;
        Ok(out.len)
    }

    /// Parses a frame line without its CR. With `timestamp` the line may (must, if the
    /// characters are there) end with a 4-digit timestamp, returned too.
    pub fn parse(line: &[u8], timestamp: bool) -> Result<(Frame, Option<u16>), Error> {
        let (&letter, rest) = line.split_first().ok_or(Error::BadLength)?;
        let (kind, extended) =
            FrameKind::from_letter(letter).ok_or(Error::UnknownCommand(letter))?;
        let id_len = if extended { 8 } else { 3 };
        let id_chars = rest.get(..id_len).ok_or(Error::BadLength)?;
        let raw = hex::number(id_chars)?;
        let id = if extended {
            Id::Extended(ExtendedId::new(raw).ok_or(Error::IdOutOfRange)?)
        } else {
            let raw = u16::try_from(raw).map_err(|_| Error::IdOutOfRange)?;
            Id::Standard(StandardId::new(raw).ok_or(Error::IdOutOfRange)?)
        };
        let (&dlc_char, body) = rest
            .get(id_len..)
            .and_then(<[u8]>::split_first)
            .ok_or(Error::BadLength)?;
        let dlc = hex::digit(dlc_char)?;
        let len = match kind {
            FrameKind::Data | FrameKind::Remote if dlc > 8 => return Err(Error::BadDlc),
            FrameKind::Remote => 0,
            _ => dlc_to_len(dlc).ok_or(Error::BadDlc)?,
        };
        let chars = len.checked_mul(2).ok_or(Error::BadLength)?;
        let (data_chars, tail) = body.split_at_checked(chars).ok_or(Error::BadLength)?;
        let ts = match (tail.len(), timestamp) {
            (0, _) => None,
            (4, true) => match hex::number(tail)? {
                ms @ 0..TIMESTAMP_MODULUS => Some(u16::try_from(ms).map_err(|_| Error::BadDigit)?),
                _ => return Err(Error::BadTimestamp),
            },
            _ => return Err(Error::BadLength),
        };
        let mut data = [0u8; MAX_DATA];
        for (slot, pair) in data.iter_mut().zip(data_chars.chunks_exact(2)) {
            let (hi, lo) = match pair {
                [hi, lo] => (hex::digit(*hi)?, hex::digit(*lo)?),
                _ => return Err(Error::BadLength),
            };
            *slot = (hi << 4) | lo;
        }
        let frame = if kind == FrameKind::Remote {
            Frame::remote(id, dlc)?
        } else {
            Frame::new(id, kind, data.get(..len).ok_or(Error::BadLength)?)?
        };
        Ok((frame, ts))
    }
}

impl embedded_can::Frame for Frame {
    /// A classic data frame up to 8 bytes, a CAN FD frame (with bit-rate switch) for the
    /// FD lengths above 8.
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        let kind = if data.len() > 8 {
            FrameKind::FdBrs
        } else {
            FrameKind::Data
        };
        Frame::new(id.into(), kind, data).ok()
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        Frame::remote(id.into(), u8::try_from(dlc).ok()?).ok()
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        self.kind == FrameKind::Remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.len)
    }

    fn data(&self) -> &[u8] {
        Frame::data(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn std_id(raw: u16) -> Id {
        Id::Standard(StandardId::new(raw).unwrap())
    }

    fn ext_id(raw: u32) -> Id {
        Id::Extended(ExtendedId::new(raw).unwrap())
    }

    fn line(f: &Frame, ts: Option<u16>) -> Vec<u8> {
        let mut buf = [0u8; crate::LINE_MAX];
        let n = f.emit(ts, &mut buf).unwrap();
        buf[..n].to_vec()
    }

    #[test]
    fn dlc_table() {
        assert_eq!(dlc_to_len(8), Some(8));
        assert_eq!(dlc_to_len(9), Some(12));
        assert_eq!(dlc_to_len(0xD), Some(32));
        assert_eq!(dlc_to_len(0xF), Some(64));
        assert_eq!(dlc_to_len(16), None);
        assert_eq!(len_to_dlc(48), Some(0xE));
        assert_eq!(len_to_dlc(9), None);
        assert_eq!(len_to_dlc(65), None);
    }

    #[test]
    fn golden_lines() {
        let f = Frame::new(std_id(0x123), FrameKind::Data, &[0x11, 0x22, 0x33]).unwrap();
        assert_eq!(line(&f, None), b"t1233112233\r");
        assert_eq!(line(&f, Some(0x1234)), b"t12331122331234\r");
        // Lawicel timestamps wrap at 60000 ms.
        assert_eq!(line(&f, Some(60_001)), b"t12331122330001\r");
        let f = Frame::new(ext_id(0x1ABC_DEF0), FrameKind::Data, &[]).unwrap();
        assert_eq!(line(&f, None), b"T1ABCDEF00\r");
        let f = Frame::remote(std_id(0x7FF), 8).unwrap();
        assert_eq!(line(&f, None), b"r7FF8\r");
        let f = Frame::remote(ext_id(0x10), 2).unwrap();
        assert_eq!(line(&f, None), b"R000000102\r");
        let data: Vec<u8> = (0..12).collect();
        let f = Frame::new(std_id(0x150), FrameKind::Fd, &data).unwrap();
        assert_eq!(line(&f, None), b"d1509000102030405060708090A0B\r");
        let f = Frame::new(ext_id(0x150), FrameKind::FdBrs, &[0xAB; 64]).unwrap();
        let l = line(&f, None);
        assert_eq!(&l[..10], b"B00000150F");
        assert_eq!(l.len(), 10 + 128 + 1);
        assert!(l[10..138].chunks(2).all(|p| p == b"AB"));
        // The longest line fits LINE_MAX exactly.
        assert_eq!(line(&f, Some(1)).len(), crate::LINE_MAX);
    }

    #[test]
    fn parse_golden_lines() {
        let (f, ts) = Frame::parse(b"t1233112233", false).unwrap();
        assert_eq!(ts, None);
        assert_eq!(f.id(), std_id(0x123));
        assert_eq!(f.kind(), FrameKind::Data);
        assert_eq!(f.data(), &[0x11, 0x22, 0x33]);
        // Lower-case hex is accepted.
        let (f, _) = Frame::parse(b"T1abcdef02beef", false).unwrap();
        assert_eq!(f.id(), ext_id(0x1ABC_DEF0));
        assert_eq!(f.data(), &[0xBE, 0xEF]);
        let (f, ts) = Frame::parse(b"t1233112233EA5F", true).unwrap();
        assert_eq!((f.data().len(), ts), (3, Some(0xEA5F)));
        let (f, _) = Frame::parse(b"r7FF8", false).unwrap();
        assert_eq!(
            (f.kind(), f.dlc(), f.data()),
            (FrameKind::Remote, 8, &[][..])
        );
        let (f, _) = Frame::parse(b"b1509000102030405060708090A0B", false).unwrap();
        assert_eq!((f.kind(), f.data().len()), (FrameKind::FdBrs, 12));
    }

    #[test]
    fn parse_errors() {
        assert_eq!(Frame::parse(b"", false), Err(Error::BadLength));
        assert_eq!(
            Frame::parse(b"x1230", false),
            Err(Error::UnknownCommand(b'x'))
        );
        assert_eq!(Frame::parse(b"t12", false), Err(Error::BadLength));
        assert_eq!(Frame::parse(b"t123", false), Err(Error::BadLength));
        assert_eq!(Frame::parse(b"t8000", false), Err(Error::IdOutOfRange));
        assert_eq!(Frame::parse(b"T200000000", false), Err(Error::IdOutOfRange));
        assert_eq!(Frame::parse(b"t1239", false), Err(Error::BadDlc));
        assert_eq!(Frame::parse(b"r1239", false), Err(Error::BadDlc));
        assert_eq!(Frame::parse(b"t12321", false), Err(Error::BadLength));
        assert_eq!(Frame::parse(b"t1231112", false), Err(Error::BadLength));
        assert_eq!(Frame::parse(b"t12311G", false), Err(Error::BadDigit));
        assert_eq!(Frame::parse(b"t12G0", false), Err(Error::BadDigit));
        // A timestamp only where timestamps are expected, and exactly 4 digits.
        assert_eq!(Frame::parse(b"t12300001", false), Err(Error::BadLength));
        assert_eq!(Frame::parse(b"t1230001", true), Err(Error::BadLength));
        assert_eq!(Frame::parse(b"t1230000X", true), Err(Error::BadDigit));
        // CAN FD: the whole payload of the DLC must be there.
        assert_eq!(Frame::parse(b"d1239", false), Err(Error::BadLength));
    }

    #[test]
    fn constructor_checks() {
        assert_eq!(
            Frame::new(std_id(1), FrameKind::Data, &[0; 9]),
            Err(Error::BadFrameLength)
        );
        assert_eq!(
            Frame::new(std_id(1), FrameKind::Fd, &[0; 13]),
            Err(Error::BadFrameLength)
        );
        assert_eq!(
            Frame::new(std_id(1), FrameKind::Remote, &[]),
            Err(Error::BadFrameLength)
        );
        assert_eq!(Frame::remote(std_id(1), 9), Err(Error::BadDlc));
        let mut small = [0u8; 5];
        let f = Frame::new(std_id(1), FrameKind::Data, &[1]).unwrap();
        assert_eq!(f.emit(None, &mut small), Err(Error::BufferTooSmall));
    }

    /// Found by the `slcan` fuzz target: `d0dd1d1ed1d` is a CAN FD frame with a timestamp
    /// of 0xED1D = 60701 ms, which no adapter sends (they count modulo 60000) and which
    /// would emit back as 701.
    #[test]
    fn timestamp_above_ea5f_is_rejected() {
        assert_eq!(Frame::parse(b"d0dd1d1ed1d", true), Err(Error::BadTimestamp));
        let (_, ts) = Frame::parse(b"d0dd1d1ea5f", true).unwrap();
        assert_eq!(ts, Some(59_999));
    }
}
