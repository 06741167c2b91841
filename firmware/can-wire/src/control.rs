//! Control frames and their answers (SPEC section 6).

use crate::encoding::{DistanceEncoding, Encoding, IntensityEncoding};
use crate::error::check_len;
use crate::frame::is_valid_len;
use crate::header::{byte, le16, put};
use crate::Error;

mod field {
    use core::ops::Range;
    pub const OPCODE: usize = 0;
    pub const TOKEN: usize = 1;
    pub const P0: usize = 2;
    pub const P1: usize = 3;
    pub const P2: usize = 4;
    pub const W0: Range<usize> = 2..4;
    pub const W1: Range<usize> = 4..6;
    pub const RATE: Range<usize> = 3..5;
    pub const MIN24: Range<usize> = 2..5;
    pub const MAX24: Range<usize> = 5..8;
    // answer
    pub const RESULT: usize = 2;
    pub const DETAIL: usize = 3;
}

/// Length of a control answer.
pub const ANSWER_LEN: usize = 4;
/// Longest control frame.
pub const MAX_CONTROL_LEN: usize = 8;
/// Largest region-of-interest step.
pub const MAX_STEP: u16 = 4095;

/// Control opcodes.
pub mod opcode {
    /// Start streaming.
    pub const START: u8 = 0x01;
    /// Stop streaming.
    pub const STOP: u8 = 0x02;
    /// Send sensor info (status pages 3-6).
    pub const REQUEST_SENSOR_INFO: u8 = 0x03;
    /// Reset the status counters.
    pub const RESET_COUNTERS: u8 = 0x04;
    /// Range window.
    pub const RANGE_WINDOW: u8 = 0x10;
    /// Speckle filter on/off.
    pub const SPECKLE: u8 = 0x11;
    /// Median filter window.
    pub const MEDIAN: u8 = 0x12;
    /// Intensity threshold.
    pub const INTENSITY_THRESHOLD: u8 = 0x13;
    /// Angular decimation.
    pub const ANGULAR_DECIMATION: u8 = 0x14;
    /// Region of interest.
    pub const REGION_OF_INTEREST: u8 = 0x15;
    /// Temporal decimation.
    pub const TEMPORAL_DECIMATION: u8 = 0x16;
    /// Point encoding.
    pub const ENCODING: u8 = 0x20;
    /// Frame size.
    pub const FRAME_SIZE: u8 = 0x21;
}

/// Median filter window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MedianWindow {
    /// No median filter.
    Off = 0,
    /// 3 points.
    Three = 3,
    /// 5 points.
    Five = 5,
}

/// How angular decimation merges `k` points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecimationMode {
    /// Keep every k-th point.
    Every = 0,
    /// Minimum distance of the group.
    Min = 1,
    /// Mean distance of the group.
    Mean = 2,
}

/// A control request (without its token).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Start streaming scans.
    Start,
    /// Stop streaming scans.
    Stop,
    /// Send sensor information (status pages 3-6).
    RequestSensorInfo,
    /// Reset the status counters.
    ResetCounters,
    /// Publish only ranges in `min_mm..=max_mm` (others become invalid); `min < max`,
    /// both ≤ 0xFF_FFFF.
    RangeWindow {
        /// Lower limit, mm.
        min_mm: u32,
        /// Upper limit, mm.
        max_mm: u32,
    },
    /// Speckle (isolated point) filter.
    Speckle {
        /// On or off.
        enabled: bool,
    },
    /// Median filter.
    Median {
        /// Window.
        window: MedianWindow,
    },
    /// Invalidate points with a weaker intensity (0 = off).
    IntensityThreshold {
        /// Threshold, 16-bit intensity scale.
        threshold: u16,
    },
    /// Merge `k` neighbouring points (k ≥ 1).
    AngularDecimation {
        /// Group size.
        k: u8,
        /// Merge mode.
        mode: DecimationMode,
    },
    /// Publish only steps `start_step..=end_step` (≤ 4095).
    RegionOfInterest {
        /// First step.
        start_step: u16,
        /// Last step.
        end_step: u16,
    },
    /// Publish every n-th scan, and at most `max_rate_centihz` / 100 scans per second
    /// (0 = no limit).
    TemporalDecimation {
        /// n ≥ 1.
        every_nth: u8,
        /// Rate limit in 0.01 Hz, 0 = none.
        max_rate_centihz: u16,
    },
    /// Point encoding of the following scans.
    Encoding(Encoding),
    /// Largest frame: 8 = classic CAN, 12..=64 (an FD length) = CAN FD.
    FrameSize {
        /// Maximum frame length.
        max_len: u8,
    },
}

/// A control frame: a command and the token echoed in its answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Control {
    /// Any value; echoed in the answer.
    pub token: u8,
    /// What to do.
    pub command: Command,
}

fn out(offset: usize) -> Error {
    Error::OutOfRange {
        offset: offset as u8,
    }
}

fn le24(data: &[u8], r: core::ops::Range<usize>) -> u32 {
    match data.get(r) {
        Some([a, b, c]) => u32::from_le_bytes([*a, *b, *c, 0]),
        _ => 0,
    }
}

impl Command {
    /// The opcode.
    pub fn opcode(&self) -> u8 {
        use opcode::*;
        match self {
            Command::Start => START,
            Command::Stop => STOP,
            Command::RequestSensorInfo => REQUEST_SENSOR_INFO,
            Command::ResetCounters => RESET_COUNTERS,
            Command::RangeWindow { .. } => RANGE_WINDOW,
            Command::Speckle { .. } => SPECKLE,
            Command::Median { .. } => MEDIAN,
            Command::IntensityThreshold { .. } => INTENSITY_THRESHOLD,
            Command::AngularDecimation { .. } => ANGULAR_DECIMATION,
            Command::RegionOfInterest { .. } => REGION_OF_INTEREST,
            Command::TemporalDecimation { .. } => TEMPORAL_DECIMATION,
            Command::Encoding(_) => ENCODING,
            Command::FrameSize { .. } => FRAME_SIZE,
        }
    }

    /// The frame length of an opcode, or `None` for an unknown one.
    pub fn len_of(op: u8) -> Option<usize> {
        use opcode::*;
        Some(match op {
            START | STOP | REQUEST_SENSOR_INFO | RESET_COUNTERS => 2,
            RANGE_WINDOW => 8,
            SPECKLE | MEDIAN | FRAME_SIZE => 3,
            INTENSITY_THRESHOLD | ANGULAR_DECIMATION => 4,
            REGION_OF_INTEREST => 6,
            TEMPORAL_DECIMATION | ENCODING => 5,
            _ => return None,
        })
    }

    /// Check every value against its allowed range (the error names the field's offset).
    pub fn validate(&self) -> Result<(), Error> {
        match *self {
            Command::RangeWindow { min_mm, max_mm } => {
                if max_mm > 0xFF_FFFF {
                    return Err(out(field::MAX24.start));
                }
                if min_mm >= max_mm {
                    return Err(out(field::MIN24.start));
                }
            }
            Command::AngularDecimation { k: 0, .. } => return Err(out(field::P0)),
            Command::RegionOfInterest {
                start_step,
                end_step,
            } => {
                if end_step > MAX_STEP {
                    return Err(out(field::W1.start));
                }
                if start_step > end_step {
                    return Err(out(field::W0.start));
                }
            }
            Command::TemporalDecimation { every_nth: 0, .. } => return Err(out(field::P0)),
            Command::Encoding(e) if e.unit_exp > 15 => return Err(out(field::P2)),
            Command::FrameSize { max_len } if !valid_frame_size(max_len) => {
                return Err(out(field::P0))
            }
            _ => {}
        }
        Ok(())
    }
}

fn valid_frame_size(len: u8) -> bool {
    len == 8 || (len > 8 && is_valid_len(usize::from(len)))
}

impl Control {
    /// Parse and validate a control frame: unknown opcode, wrong length and every
    /// out-of-range value are errors, so a parsed frame can be applied as it is.
    pub fn parse(data: &[u8]) -> Result<Control, Error> {
        let op = *data.first().ok_or(Error::BadLength {
            expected: 2,
            actual: 0,
        })?;
        let len = Command::len_of(op).ok_or(Error::UnknownOpcode(op))?;
        check_len(data, len)?;
        let p0 = byte(data, field::P0);
        let p1 = byte(data, field::P1);
        let command = match op {
            opcode::START => Command::Start,
            opcode::STOP => Command::Stop,
            opcode::REQUEST_SENSOR_INFO => Command::RequestSensorInfo,
            opcode::RESET_COUNTERS => Command::ResetCounters,
            opcode::RANGE_WINDOW => Command::RangeWindow {
                min_mm: le24(data, field::MIN24),
                max_mm: le24(data, field::MAX24),
            },
            opcode::SPECKLE => Command::Speckle {
                enabled: match p0 {
                    0 => false,
                    1 => true,
                    _ => return Err(out(field::P0)),
                },
            },
            opcode::MEDIAN => Command::Median {
                window: match p0 {
                    0 => MedianWindow::Off,
                    3 => MedianWindow::Three,
                    5 => MedianWindow::Five,
                    _ => return Err(out(field::P0)),
                },
            },
            opcode::INTENSITY_THRESHOLD => Command::IntensityThreshold {
                threshold: le16(data, field::W0),
            },
            opcode::ANGULAR_DECIMATION => Command::AngularDecimation {
                k: p0,
                mode: match p1 {
                    0 => DecimationMode::Every,
                    1 => DecimationMode::Min,
                    2 => DecimationMode::Mean,
                    _ => return Err(out(field::P1)),
                },
            },
            opcode::REGION_OF_INTEREST => Command::RegionOfInterest {
                start_step: le16(data, field::W0),
                end_step: le16(data, field::W1),
            },
            opcode::TEMPORAL_DECIMATION => Command::TemporalDecimation {
                every_nth: p0,
                max_rate_centihz: le16(data, field::RATE),
            },
            opcode::ENCODING => Command::Encoding(Encoding {
                distance: DistanceEncoding::from_code(p0).map_err(|_| out(field::P0))?,
                intensity: IntensityEncoding::from_code(p1).map_err(|_| out(field::P1))?,
                unit_exp: byte(data, field::P2),
            }),
            opcode::FRAME_SIZE => Command::FrameSize { max_len: p0 },
            _ => return Err(Error::UnknownOpcode(op)),
        };
        command.validate()?;
        Ok(Control {
            token: byte(data, field::TOKEN),
            command,
        })
    }

    /// Write the frame into `buf` and return its length (validates first).
    pub fn emit(&self, buf: &mut [u8; MAX_CONTROL_LEN]) -> Result<usize, Error> {
        self.command.validate()?;
        let op = self.command.opcode();
        let len = Command::len_of(op).ok_or(Error::UnknownOpcode(op))?;
        *buf = [0; MAX_CONTROL_LEN];
        buf[field::OPCODE] = op;
        buf[field::TOKEN] = self.token;
        match self.command {
            Command::Start
            | Command::Stop
            | Command::RequestSensorInfo
            | Command::ResetCounters => {}
            Command::RangeWindow { min_mm, max_mm } => {
                put(buf, field::MIN24, &min_mm.to_le_bytes()[..3]);
                put(buf, field::MAX24, &max_mm.to_le_bytes()[..3]);
            }
            Command::Speckle { enabled } => buf[field::P0] = u8::from(enabled),
            Command::Median { window } => buf[field::P0] = window as u8,
            Command::IntensityThreshold { threshold } => {
                put(buf, field::W0, &threshold.to_le_bytes())
            }
            Command::AngularDecimation { k, mode } => {
                buf[field::P0] = k;
                buf[field::P1] = mode as u8;
            }
            Command::RegionOfInterest {
                start_step,
                end_step,
            } => {
                put(buf, field::W0, &start_step.to_le_bytes());
                put(buf, field::W1, &end_step.to_le_bytes());
            }
            Command::TemporalDecimation {
                every_nth,
                max_rate_centihz,
            } => {
                buf[field::P0] = every_nth;
                put(buf, field::RATE, &max_rate_centihz.to_le_bytes());
            }
            Command::Encoding(e) => {
                buf[field::P0] = e.distance.code();
                buf[field::P1] = e.intensity.code();
                buf[field::P2] = e.unit_exp;
            }
            Command::FrameSize { max_len } => buf[field::P0] = max_len,
        }
        Ok(len)
    }
}

/// The result of a control request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Outcome {
    /// Accepted (applies from the next scan on).
    Accepted,
    /// The opcode is not defined.
    UnknownOpcode,
    /// Wrong length for the opcode.
    BadLength,
    /// A value is out of range; the answer's detail is the field's byte offset.
    OutOfRange,
    /// Not supported by this bridge or sensor.
    Unsupported,
    /// Not possible in the current state.
    WrongState,
    /// A code this version does not know.
    Unknown(u8),
}

impl From<u8> for Outcome {
    fn from(v: u8) -> Self {
        match v {
            0 => Outcome::Accepted,
            1 => Outcome::UnknownOpcode,
            2 => Outcome::BadLength,
            3 => Outcome::OutOfRange,
            4 => Outcome::Unsupported,
            5 => Outcome::WrongState,
            other => Outcome::Unknown(other),
        }
    }
}

impl From<Outcome> for u8 {
    fn from(o: Outcome) -> u8 {
        match o {
            Outcome::Accepted => 0,
            Outcome::UnknownOpcode => 1,
            Outcome::BadLength => 2,
            Outcome::OutOfRange => 3,
            Outcome::Unsupported => 4,
            Outcome::WrongState => 5,
            Outcome::Unknown(v) => v,
        }
    }
}

/// The answer to one control frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Answer {
    /// Opcode of the request (0 if it was empty).
    pub opcode: u8,
    /// Token of the request (0 if it had none).
    pub token: u8,
    /// Result.
    pub outcome: Outcome,
    /// For [`Outcome::OutOfRange`], the byte offset of the field; else 0.
    pub detail: u8,
}

impl Answer {
    /// "Accepted" for a parsed request.
    pub fn accept(req: &Control) -> Answer {
        Answer {
            opcode: req.command.opcode(),
            token: req.token,
            outcome: Outcome::Accepted,
            detail: 0,
        }
    }

    /// The answer to raw control bytes that [`Control::parse`] rejected with `err`.
    pub fn reject(request: &[u8], err: &Error) -> Answer {
        let (outcome, detail) = match *err {
            Error::UnknownOpcode(_) => (Outcome::UnknownOpcode, 0),
            Error::BadLength { .. } => (Outcome::BadLength, 0),
            Error::OutOfRange { offset } => (Outcome::OutOfRange, offset),
            _ => (Outcome::Unsupported, 0),
        };
        Answer {
            opcode: request.first().copied().unwrap_or(0),
            token: request.get(field::TOKEN).copied().unwrap_or(0),
            outcome,
            detail,
        }
    }

    /// Parse answer bytes.
    pub fn parse(data: &[u8]) -> Result<Answer, Error> {
        check_len(data, ANSWER_LEN)?;
        Ok(Answer {
            opcode: byte(data, field::OPCODE),
            token: byte(data, field::TOKEN),
            outcome: byte(data, field::RESULT).into(),
            detail: byte(data, field::DETAIL),
        })
    }

    /// The frame bytes.
    pub fn emit(&self) -> [u8; ANSWER_LEN] {
        [self.opcode, self.token, self.outcome.into(), self.detail]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn golden() -> Vec<(Command, &'static [u8])> {
        vec![
            (Command::Start, &[0x01, 0x42]),
            (Command::Stop, &[0x02, 0x42]),
            (Command::RequestSensorInfo, &[0x03, 0x42]),
            (Command::ResetCounters, &[0x04, 0x42]),
            (
                Command::RangeWindow {
                    min_mm: 20,
                    max_mm: 60000,
                },
                &[0x10, 0x42, 20, 0, 0, 0x60, 0xEA, 0x00],
            ),
            (Command::Speckle { enabled: true }, &[0x11, 0x42, 1]),
            (
                Command::Median {
                    window: MedianWindow::Five,
                },
                &[0x12, 0x42, 5],
            ),
            (
                Command::IntensityThreshold { threshold: 0x1234 },
                &[0x13, 0x42, 0x34, 0x12],
            ),
            (
                Command::AngularDecimation {
                    k: 3,
                    mode: DecimationMode::Mean,
                },
                &[0x14, 0x42, 3, 2],
            ),
            (
                Command::RegionOfInterest {
                    start_step: 44,
                    end_step: 725,
                },
                &[0x15, 0x42, 44, 0, 0xD5, 0x02],
            ),
            (
                Command::TemporalDecimation {
                    every_nth: 2,
                    max_rate_centihz: 1000,
                },
                &[0x16, 0x42, 2, 0xE8, 0x03],
            ),
            (
                Command::Encoding(Encoding {
                    distance: DistanceEncoding::D12,
                    intensity: IntensityEncoding::I8,
                    unit_exp: 2,
                }),
                &[0x20, 0x42, 3, 3, 2],
            ),
            (Command::FrameSize { max_len: 64 }, &[0x21, 0x42, 64]),
        ]
    }

    #[test]
    fn golden_round_trip() {
        for (command, bytes) in golden() {
            let c = Control {
                token: 0x42,
                command,
            };
            let mut buf = [0u8; 8];
            let len = c.emit(&mut buf).unwrap();
            assert_eq!(&buf[..len], bytes, "{command:?}");
            assert_eq!(Control::parse(bytes), Ok(c));
        }
    }

    #[test]
    fn every_bad_length() {
        for (_, bytes) in golden() {
            let mut long = [0u8; 65];
            long[..bytes.len()].copy_from_slice(bytes);
            for len in (1..=64).filter(|l| *l != bytes.len()) {
                assert_eq!(
                    Control::parse(&long[..len]),
                    Err(Error::BadLength {
                        expected: bytes.len() as u8,
                        actual: len as u8
                    })
                );
            }
        }
        assert_eq!(
            Control::parse(&[]),
            Err(Error::BadLength {
                expected: 2,
                actual: 0
            })
        );
    }

    #[test]
    fn unknown_opcodes() {
        let known: Vec<u8> = golden().iter().map(|(_, b)| b[0]).collect();
        for op in 0..=255u8 {
            if !known.contains(&op) {
                assert_eq!(Control::parse(&[op, 0]), Err(Error::UnknownOpcode(op)));
            }
        }
    }

    #[test]
    fn out_of_range_values() {
        let cases: &[(&[u8], u8)] = &[
            (&[0x10, 0, 5, 0, 0, 5, 0, 0], 2), // min == max
            (&[0x10, 0, 6, 0, 0, 5, 0, 0], 2), // min > max
            (&[0x11, 0, 2], 2),                // speckle not 0/1
            (&[0x12, 0, 4], 2),                // median 4
            (&[0x14, 0, 0, 0], 2),             // k = 0
            (&[0x14, 0, 1, 3], 3),             // mode 3
            (&[0x15, 0, 10, 0, 9, 0], 2),      // start > end
            (&[0x15, 0, 0, 0, 0x00, 0x10], 4), // end 4096
            (&[0x16, 0, 0, 0, 0], 2),          // every 0
            (&[0x20, 0, 0, 0, 0], 2),          // distance encoding 0
            (&[0x20, 0, 1, 4, 0], 3),          // intensity encoding 4
            (&[0x20, 0, 1, 0, 16], 4),         // unit 2^16
            (&[0x21, 0, 9], 2),                // frame size 9
            (&[0x21, 0, 65], 2),               // frame size 65
        ];
        for (bytes, offset) in cases {
            let e = Control::parse(bytes);
            assert_eq!(e, Err(Error::OutOfRange { offset: *offset }), "{bytes:?}");
            let a = Answer::reject(bytes, &e.unwrap_err());
            assert_eq!(a.outcome, Outcome::OutOfRange);
            assert_eq!(a.detail, *offset);
            assert_eq!(a.opcode, bytes[0]);
        }
        let c = Control {
            token: 1,
            command: Command::RangeWindow {
                min_mm: 0,
                max_mm: 0x100_0000,
            },
        };
        assert_eq!(c.emit(&mut [0; 8]), Err(Error::OutOfRange { offset: 5 }));
    }

    #[test]
    fn answers() {
        let a = Answer {
            opcode: 0x14,
            token: 7,
            outcome: Outcome::OutOfRange,
            detail: 3,
        };
        assert_eq!(a.emit(), [0x14, 7, 3, 3]);
        assert_eq!(Answer::parse(&[0x14, 7, 3, 3]), Ok(a));
        for len in (0..=64).filter(|l| *l != 4) {
            assert_eq!(
                Answer::parse(&[0u8; 64][..len]),
                Err(Error::BadLength {
                    expected: 4,
                    actual: len as u8
                })
            );
        }
        let req = Control::parse(&[0x01, 9]).unwrap();
        assert_eq!(Answer::accept(&req).emit(), [0x01, 9, 0, 0]);
        let r = Answer::reject(&[0x7F], &Error::UnknownOpcode(0x7F));
        assert_eq!(r.emit(), [0x7F, 0, 1, 0]);
        for v in 0..=255u8 {
            assert_eq!(u8::from(Outcome::from(v)), v);
        }
    }
}
