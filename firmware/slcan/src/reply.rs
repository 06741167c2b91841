//! Adapter → host lines: answers to commands, and the frames the adapter received.
//!
//! | bytes | meaning |
//! |---|---|
//! | CR | OK (the command was done) |
//! | BEL | error (no CR follows) |
//! | `z` CR / `Z` CR | a `t`/`r` / `T`/`R` frame was queued for transmission |
//! | `V` hhss CR | hardware version hh, software version ss (4 characters) |
//! | `N` xxxx CR | serial number (4 characters) |
//! | `F` xx CR | status flags, 2 hex digits (see [`crate::StatusFlags`]) |
//! | `t`... CR etc. | a received frame, optionally with a 4-digit ms timestamp |
//!
//! CAN FD transmit requests (`d`/`D`/`b`/`B`) are answered with a plain CR, as the CAN FD
//! SLCAN adapters do; Lawicel defines `z`/`Z` only for classic frames.

use crate::frame::Frame;
use crate::hex::{self, Out};
use crate::Error;

/// One line from the adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply {
    /// CR: OK.
    Ok,
    /// BEL: error.
    Error,
    /// `z` (standard ID) or `Z` (extended ID): the frame was queued.
    Transmitted {
        /// The frame had a 29-bit identifier.
        extended: bool,
    },
    /// `V` and four characters: hardware and software version.
    Version([u8; 4]),
    /// `N` and four characters: serial number.
    SerialNumber([u8; 4]),
    /// `F` and two hex digits: status flags.
    Flags(u8),
    /// A frame received from the bus, and its timestamp (ms modulo 60000) if on.
    Frame(Frame, Option<u16>),
}

fn four(rest: &[u8]) -> Result<[u8; 4], Error> {
    let chars: [u8; 4] = rest.try_into().map_err(|_| Error::BadLength)?;
    if chars.iter().all(|c| c.is_ascii_graphic()) {
        Ok(chars)
    } else {
        Err(Error::BadDigit)
    }
}

impl Reply {
    /// Parses one line: the bytes before a CR (`b""` is [`Reply::Ok`]). A BEL is its own
    /// reply: [`crate::LineBuffer`] reports it apart from lines.
    pub fn parse(line: &[u8]) -> Result<Reply, Error> {
        let Some((&c, rest)) = line.split_first() else {
            return Ok(Reply::Ok);
        };
        match (c, rest) {
            (b'z', []) => Ok(Reply::Transmitted { extended: false }),
            (b'Z', []) => Ok(Reply::Transmitted { extended: true }),
            (b'V', _) => Ok(Reply::Version(four(rest)?)),
            (b'N', _) => Ok(Reply::SerialNumber(four(rest)?)),
            (b'F', [_, _]) => Ok(Reply::Flags(
                u8::try_from(hex::number(rest)?).map_err(|_| Error::BadDigit)?,
            )),
            (b'F', _) => Err(Error::BadLength),
            _ => {
                let (frame, ts) = Frame::parse(line, true)?;
                Ok(Reply::Frame(frame, ts))
            }
        }
    }

    /// Writes the reply's bytes (CR included, except after BEL); returns their length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, Error> {
        let mut out = Out::new(buf);
        match *self {
            Reply::Frame(frame, ts) => return frame.emit(ts, buf),
            Reply::Error => {
                out.byte(crate::BEL)?;
                return Ok(out.len);
            }
            Reply::Ok => {}
            Reply::Transmitted { extended } => out.byte(if extended { b'Z' } else { b'z' })?,
            Reply::Version(v) => {
                out.byte(b'V')?;
                out.bytes(&v)?;
            }
            Reply::SerialNumber(n) => {
                out.byte(b'N')?;
                out.bytes(&n)?;
            }
            Reply::Flags(f) => {
                out.byte(b'F')?;
                out.hex(u32::from(f), 2)?;
            }
        }
        out.byte(crate::CR)?;
        Ok(out.len)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FrameKind;
    use embedded_can::{Id, StandardId};

    fn emit(r: &Reply) -> Vec<u8> {
        let mut buf = [0u8; crate::LINE_MAX];
        let n = r.emit(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    #[test]
    fn golden_replies() {
        let f = Frame::new(
            Id::Standard(StandardId::new(0x1B3).unwrap()),
            FrameKind::Data,
            &[1, 2],
        )
        .unwrap();
        let cases: [(&[u8], Reply); 8] = [
            (b"\r", Reply::Ok),
            (b"z\r", Reply::Transmitted { extended: false }),
            (b"Z\r", Reply::Transmitted { extended: true }),
            (b"V1013\r", Reply::Version(*b"1013")),
            (b"NQ001\r", Reply::SerialNumber(*b"Q001")),
            (b"F0A\r", Reply::Flags(0x0A)),
            (b"t1B320102\r", Reply::Frame(f, None)),
            (b"t1B32010201F4\r", Reply::Frame(f, Some(500))),
        ];
        for (bytes, reply) in cases {
            assert_eq!(emit(&reply), bytes, "{reply:?}");
            assert_eq!(Reply::parse(&bytes[..bytes.len() - 1]), Ok(reply));
        }
        assert_eq!(emit(&Reply::Error), [crate::BEL]);
    }

    #[test]
    fn bad_replies() {
        assert_eq!(Reply::parse(b"V10"), Err(Error::BadLength));
        assert_eq!(Reply::parse(b"N12345"), Err(Error::BadLength));
        assert_eq!(Reply::parse(b"N1 23"), Err(Error::BadDigit));
        assert_eq!(Reply::parse(b"F1"), Err(Error::BadLength));
        assert_eq!(Reply::parse(b"FXY"), Err(Error::BadDigit));
        assert_eq!(Reply::parse(b"zz"), Err(Error::UnknownCommand(b'z')));
        assert_eq!(Reply::parse(b"q"), Err(Error::UnknownCommand(b'q')));
    }
}
