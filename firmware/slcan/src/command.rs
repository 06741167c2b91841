//! Host → adapter commands.
//!
//! | line | command |
//! |---|---|
//! | `O` | open the channel (normal mode) |
//! | `L` | open the channel listen-only |
//! | `C` | close the channel |
//! | `S0`..`S8` | nominal bit rate: 10k, 20k, 50k, 100k, 125k, 250k, 500k, 800k, 1M |
//! | `Y0`..`Y8` | CAN FD data bit rate: 500k, 1M, 2M, 3M, 4M, 5M, 6M, 7M, 8M |
//! | `V` | hardware and software version |
//! | `N` | serial number |
//! | `F` | status flags |
//! | `Z0` / `Z1` | timestamps off / on for received frames |
//! | `t` `T` `r` `R` `d` `D` `b` `B` | transmit a frame (see [`crate::frame`]) |
//! | (empty) | nothing; answered OK (some clients send a bare CR) |

use crate::frame::Frame;
use crate::hex::{self, Out};
use crate::Error;

/// Nominal bit rates of `S0`..`S8`, bit/s (Lawicel's table: `S7` is 800 kbit/s).
pub const BIT_RATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// CAN FD data bit rates of `Y0`..`Y8`, bit/s.
pub const DATA_BIT_RATES: [u32; 9] = [
    500_000, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 5_000_000, 6_000_000, 7_000_000, 8_000_000,
];

/// One command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `O`: open the channel.
    Open,
    /// `L`: open the channel, listen only.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: nominal bit rate index `n` (0..=8, see [`BIT_RATES`]).
    BitRate(u8),
    /// `Yn`: CAN FD data bit rate index `n` (0..=8, see [`DATA_BIT_RATES`]).
    DataBitRate(u8),
    /// `V`: versions.
    Version,
    /// `N`: serial number.
    SerialNumber,
    /// `F`: status flags.
    StatusFlags,
    /// `Zn`: timestamps on received frames.
    Timestamps(bool),
    /// A frame to transmit.
    Transmit(Frame),
    /// An empty line.
    Empty,
}

impl Command {
    /// Parses one line (without its CR).
    pub fn parse(line: &[u8]) -> Result<Command, Error> {
        let Some((&c, rest)) = line.split_first() else {
            return Ok(Command::Empty);
        };
        let single = |cmd: Command| {
            if rest.is_empty() {
                Ok(cmd)
            } else {
                Err(Error::BadLength)
            }
        };
        let index = || -> Result<u8, Error> {
            match rest {
                // Cannot wrap: `d` is a digit.
                [d @ b'0'..=b'8'] => Ok(d.wrapping_sub(b'0')),
                [b'0'..=b'9'] => Err(Error::BadBitRate),
                [_] => Err(Error::BadDigit),
                _ => Err(Error::BadLength),
            }
        };
        match c {
            b'O' => single(Command::Open),
            b'L' => single(Command::ListenOnly),
            b'C' => single(Command::Close),
            b'V' => single(Command::Version),
            b'N' => single(Command::SerialNumber),
            b'F' => single(Command::StatusFlags),
            b'S' => Ok(Command::BitRate(index()?)),
            b'Y' => Ok(Command::DataBitRate(index()?)),
            b'Z' => match rest {
                [b'0'] => Ok(Command::Timestamps(false)),
                [b'1'] => Ok(Command::Timestamps(true)),
                [_] => Err(Error::BadDigit),
                _ => Err(Error::BadLength),
            },
            b't' | b'T' | b'r' | b'R' | b'd' | b'D' | b'b' | b'B' => {
                Ok(Command::Transmit(Frame::parse(line, false)?.0))
            }
            other => Err(Error::UnknownCommand(other)),
        }
    }

    /// Writes the command's line, CR included; returns its length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, Error> {
        if let Command::Transmit(frame) = self {
            return frame.emit(None, buf);
        }
        let mut out = Out::new(buf);
        match *self {
            Command::Open => out.byte(b'O')?,
            Command::ListenOnly => out.byte(b'L')?,
            Command::Close => out.byte(b'C')?,
            Command::Version => out.byte(b'V')?,
            Command::SerialNumber => out.byte(b'N')?,
            Command::StatusFlags => out.byte(b'F')?,
            Command::BitRate(n) | Command::DataBitRate(n) if n > 8 => {
                return Err(Error::BadBitRate)
            }
            // `n <= 8` here: its hex digit is its decimal digit.
            Command::BitRate(n) => out.bytes(&[b'S', hex::upper(u32::from(n))])?,
            Command::DataBitRate(n) => out.bytes(&[b'Y', hex::upper(u32::from(n))])?,
            Command::Timestamps(on) => out.bytes(&[b'Z', if on { b'1' } else { b'0' }])?,
            Command::Empty | Command::Transmit(_) => {}
        }
        out.byte(crate::CR)?;
        Ok(out.len)
    }

    /// The `S` index of a nominal bit rate, if the table has it.
    pub fn bit_rate_index(bit_rate: u32) -> Option<u8> {
        BIT_RATES
            .iter()
            .position(|&r| r == bit_rate)
            .and_then(|i| u8::try_from(i).ok())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FrameKind;
    use embedded_can::{Id, StandardId};

    fn emit(c: &Command) -> Vec<u8> {
        let mut buf = [0u8; crate::LINE_MAX];
        let n = c.emit(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    #[test]
    fn golden_commands() {
        let cases: [(&[u8], Command); 12] = [
            (b"O\r", Command::Open),
            (b"L\r", Command::ListenOnly),
            (b"C\r", Command::Close),
            (b"S0\r", Command::BitRate(0)),
            (b"S8\r", Command::BitRate(8)),
            (b"Y5\r", Command::DataBitRate(5)),
            (b"V\r", Command::Version),
            (b"N\r", Command::SerialNumber),
            (b"F\r", Command::StatusFlags),
            (b"Z1\r", Command::Timestamps(true)),
            (b"Z0\r", Command::Timestamps(false)),
            (b"\r", Command::Empty),
        ];
        for (line, cmd) in cases {
            assert_eq!(emit(&cmd), line, "{cmd:?}");
            assert_eq!(Command::parse(&line[..line.len() - 1]), Ok(cmd));
        }
        let f = Frame::new(
            Id::Standard(StandardId::new(0x100).unwrap()),
            FrameKind::Data,
            &[0x14, 0x07, 0x04, 0x01],
        )
        .unwrap();
        assert_eq!(emit(&Command::Transmit(f)), b"t100414070401\r");
        assert_eq!(Command::parse(b"t100414070401"), Ok(Command::Transmit(f)));
    }

    #[test]
    fn bad_commands() {
        assert_eq!(Command::parse(b"O1"), Err(Error::BadLength));
        assert_eq!(Command::parse(b"S9"), Err(Error::BadBitRate));
        assert_eq!(Command::parse(b"SX"), Err(Error::BadDigit));
        assert_eq!(Command::parse(b"S"), Err(Error::BadLength));
        assert_eq!(Command::parse(b"S10"), Err(Error::BadLength));
        assert_eq!(Command::parse(b"Y9"), Err(Error::BadBitRate));
        assert_eq!(Command::parse(b"Z2"), Err(Error::BadDigit));
        assert_eq!(Command::parse(b"Z"), Err(Error::BadLength));
        assert_eq!(Command::parse(b"s0031"), Err(Error::UnknownCommand(b's')));
        assert_eq!(Command::parse(b"t12"), Err(Error::BadLength));
        assert_eq!(
            Command::BitRate(9).emit(&mut [0u8; 4]),
            Err(Error::BadBitRate)
        );
    }

    #[test]
    fn bit_rate_table() {
        assert_eq!(Command::bit_rate_index(1_000_000), Some(8));
        assert_eq!(Command::bit_rate_index(800_000), Some(7));
        assert_eq!(Command::bit_rate_index(750_000), None);
    }
}
