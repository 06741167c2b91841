//! The scan abort frame (SPEC section 3.5).

use crate::error::check_len;
use crate::header::{byte, le16, put};
use crate::Error;

mod field {
    use core::ops::Range;
    pub const SEQ: Range<usize> = 0..2;
    pub const REASON: usize = 2;
    pub const DETAIL: usize = 3;
    pub const SENT: Range<usize> = 4..6;
}

/// Length of an abort frame.
pub const ABORT_LEN: usize = 6;

/// Why a scan was abandoned. Unknown codes parse as [`AbortReason::Unknown`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AbortReason {
    /// The sensor answered with an error status.
    SensorError,
    /// A sensor line failed its checksum.
    Checksum,
    /// The sensor went silent.
    Timeout,
    /// The CAN transmit queue overflowed.
    QueueOverflow,
    /// Streaming was stopped by a control command.
    Stopped,
    /// Settings changed mid-scan.
    Reconfigured,
    /// The sensor restarted.
    SensorRestart,
    /// The sensor sent malformed data.
    BadData,
    /// The link to the sensor (a TCP connection) was lost.
    LinkLost,
    /// A code this version does not know.
    Unknown(u8),
}

impl From<u8> for AbortReason {
    fn from(v: u8) -> Self {
        match v {
            1 => AbortReason::SensorError,
            2 => AbortReason::Checksum,
            3 => AbortReason::Timeout,
            4 => AbortReason::QueueOverflow,
            5 => AbortReason::Stopped,
            6 => AbortReason::Reconfigured,
            7 => AbortReason::SensorRestart,
            8 => AbortReason::BadData,
            9 => AbortReason::LinkLost,
            other => AbortReason::Unknown(other),
        }
    }
}

impl From<AbortReason> for u8 {
    fn from(r: AbortReason) -> u8 {
        match r {
            AbortReason::SensorError => 1,
            AbortReason::Checksum => 2,
            AbortReason::Timeout => 3,
            AbortReason::QueueOverflow => 4,
            AbortReason::Stopped => 5,
            AbortReason::Reconfigured => 6,
            AbortReason::SensorRestart => 7,
            AbortReason::BadData => 8,
            AbortReason::LinkLost => 9,
            AbortReason::Unknown(v) => v,
        }
    }
}

/// A parsed abort frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Abort {
    /// Sequence number of the abandoned scan.
    pub seq: u16,
    /// Why.
    pub reason: AbortReason,
    /// Reason-specific detail (e.g. a SCIP status code), else 0.
    pub detail: u8,
    /// Points sent before the abort, 0..=4095.
    pub points_sent: u16,
}

impl Abort {
    /// Parse and validate abort bytes.
    pub fn parse(data: &[u8]) -> Result<Abort, Error> {
        check_len(data, ABORT_LEN)?;
        let sent = le16(data, field::SENT);
        if sent > 0x0FFF {
            return Err(Error::OutOfRange {
                offset: field::SENT.start as u8,
            });
        }
        Ok(Abort {
            seq: le16(data, field::SEQ),
            reason: byte(data, field::REASON).into(),
            detail: byte(data, field::DETAIL),
            points_sent: sent,
        })
    }

    /// The frame bytes.
    pub fn emit(&self) -> Result<[u8; ABORT_LEN], Error> {
        if self.points_sent > 0x0FFF {
            return Err(Error::OutOfRange {
                offset: field::SENT.start as u8,
            });
        }
        let mut b = [0u8; ABORT_LEN];
        put(&mut b, field::SEQ, &self.seq.to_le_bytes());
        b[field::REASON] = self.reason.into();
        b[field::DETAIL] = self.detail;
        put(&mut b, field::SENT, &self.points_sent.to_le_bytes());
        Ok(b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOLDEN: [u8; 6] = [0xFF, 0xFF, 0x02, 0x21, 0xA9, 0x02];

    #[test]
    fn golden() {
        let a = Abort {
            seq: 0xFFFF,
            reason: AbortReason::Checksum,
            detail: 0x21,
            points_sent: 681,
        };
        assert_eq!(a.emit(), Ok(GOLDEN));
        assert_eq!(Abort::parse(&GOLDEN), Ok(a));
    }

    #[test]
    fn reasons_round_trip() {
        for v in 0..=255u8 {
            assert_eq!(u8::from(AbortReason::from(v)), v);
        }
        assert_eq!(AbortReason::from(0), AbortReason::Unknown(0));
        // SPEC 3.5: 9 is the sensor link lost.
        assert_eq!(AbortReason::from(9), AbortReason::LinkLost);
    }

    #[test]
    fn rejects() {
        for len in (0..=64).filter(|l| *l != 6) {
            assert_eq!(
                Abort::parse(&[0u8; 64][..len]),
                Err(Error::BadLength {
                    expected: 6,
                    actual: len as u8
                })
            );
        }
        let mut b = GOLDEN;
        b[5] = 0x10;
        assert_eq!(Abort::parse(&b), Err(Error::OutOfRange { offset: 4 }));
    }
}
