//! The time synchronisation frames: SYNC and FOLLOW-UP on one broadcast identifier
//! (SPEC section 9).

use embedded_can::{ExtendedId, Id, StandardId};

use crate::error::check_len;
use crate::{Error, Frame, IdWindow};

/// The default time identifier (11-bit), just below the default window (SPEC 9.1).
pub const DEFAULT_TIME_ID: u16 = 0x0FF;
/// Length of a SYNC frame.
pub const SYNC_LEN: usize = 1;
/// Length of a FOLLOW-UP frame.
pub const FOLLOW_UP_LEN: usize = 8;
/// Largest master time a FOLLOW-UP carries (56 bits of µs).
pub const MAX_MASTER_US: u64 = (1 << 56) - 1;
/// Sequence numbers run modulo this.
pub const SEQ_MODULUS: u8 = 16;

const TYPE_SYNC: u8 = 1;
const TYPE_FOLLOW_UP: u8 = 2;

/// A parsed time frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimeFrame {
    /// The master sent this frame at the time its FOLLOW-UP will carry.
    Sync {
        /// Sequence, 0..16.
        seq: u8,
    },
    /// The master's send time of the SYNC with the same sequence.
    FollowUp {
        /// Sequence of the SYNC it describes, 0..16.
        seq: u8,
        /// The SYNC's send time, µs of the master's clock, below 2^56.
        master_us: u64,
    },
}

impl TimeFrame {
    /// Parses a time frame's payload.
    pub fn parse(data: &[u8]) -> Result<TimeFrame, Error> {
        let first = *data.first().ok_or(Error::BadLength {
            expected: SYNC_LEN as u8,
            actual: 0,
        })?;
        let seq = first >> 4;
        match first & 0x0F {
            TYPE_SYNC => {
                check_len(data, SYNC_LEN)?;
                Ok(TimeFrame::Sync { seq })
            }
            TYPE_FOLLOW_UP => {
                check_len(data, FOLLOW_UP_LEN)?;
                let mut le = [0u8; 8];
                if let (Some(dst), Some(src)) = (le.get_mut(..7), data.get(1..8)) {
                    dst.copy_from_slice(src);
                }
                Ok(TimeFrame::FollowUp {
                    seq,
                    master_us: u64::from_le_bytes(le),
                })
            }
            _ => Err(Error::OutOfRange { offset: 0 }),
        }
    }

    /// The frame's sequence.
    pub const fn seq(&self) -> u8 {
        match *self {
            TimeFrame::Sync { seq } | TimeFrame::FollowUp { seq, .. } => seq,
        }
    }

    /// Writes the payload into `out`; returns its length. Fails for a sequence of 16 or
    /// more (byte 0) or a master time of 2^56 µs or more (byte 1).
    pub fn encode(&self, out: &mut [u8; FOLLOW_UP_LEN]) -> Result<usize, Error> {
        let seq = self.seq();
        if seq >= SEQ_MODULUS {
            return Err(Error::OutOfRange { offset: 0 });
        }
        *out = [0; FOLLOW_UP_LEN];
        match *self {
            TimeFrame::Sync { .. } => {
                out[0] = TYPE_SYNC | seq << 4;
                Ok(SYNC_LEN)
            }
            TimeFrame::FollowUp { master_us, .. } => {
                if master_us > MAX_MASTER_US {
                    return Err(Error::OutOfRange { offset: 1 });
                }
                let le = master_us.to_le_bytes();
                out[0] = TYPE_FOLLOW_UP | seq << 4;
                if let (Some(dst), Some(src)) = (out.get_mut(1..8), le.get(..7)) {
                    dst.copy_from_slice(src);
                }
                Ok(FOLLOW_UP_LEN)
            }
        }
    }

    /// The classic CAN frame of this time frame on identifier `id`.
    pub fn to_frame(&self, id: Id) -> Result<Frame, Error> {
        let mut buf = [0u8; FOLLOW_UP_LEN];
        let len = self.encode(&mut buf)?;
        Frame::new(id, buf.get(..len).unwrap_or_default(), false)
    }
}

/// The time identifier `raw` in the format of `window` (SPEC 9.1). Fails when it does not
/// fit the format or lies inside the window.
pub fn time_id(raw: u32, window: &IdWindow) -> Result<Id, Error> {
    if matches!(raw.checked_sub(window.base()), Some(off) if off < crate::id::WINDOW_SPAN) {
        return Err(Error::BadIdWindow);
    }
    let id = if window.is_extended() {
        ExtendedId::new(raw).map(Id::Extended)
    } else {
        u16::try_from(raw)
            .ok()
            .and_then(StandardId::new)
            .map(Id::Standard)
    };
    id.ok_or(Error::BadIdWindow)
}

#[cfg(test)]
mod tests {
    use super::*;

    // Golden bytes written from SPEC 9.2 by hand.
    #[test]
    fn golden_sync() {
        assert_eq!(TimeFrame::parse(&[0x51]), Ok(TimeFrame::Sync { seq: 5 }));
        let mut b = [0xAA; 8];
        assert_eq!(TimeFrame::Sync { seq: 15 }.encode(&mut b), Ok(1));
        assert_eq!(b[0], 0xF1);
    }

    #[test]
    fn golden_follow_up() {
        // seq 3, master time 0x01_2345_6789_ABCD µs.
        let bytes = [0x32, 0xCD, 0xAB, 0x89, 0x67, 0x45, 0x23, 0x01];
        let f = TimeFrame::FollowUp {
            seq: 3,
            master_us: 0x01_2345_6789_ABCD,
        };
        assert_eq!(TimeFrame::parse(&bytes), Ok(f));
        let mut b = [0; 8];
        assert_eq!(f.encode(&mut b), Ok(8));
        assert_eq!(b, bytes);
        // 2026-01-01T00:00:00Z = 1_767_225_600 s after the epoch.
        let t = 1_767_225_600_000_000u64; // 0x0006_4748_4620_4000
        let bytes = [0x02, 0x00, 0x40, 0x20, 0x46, 0x48, 0x47, 0x06];
        assert_eq!(
            TimeFrame::parse(&bytes),
            Ok(TimeFrame::FollowUp {
                seq: 0,
                master_us: t
            })
        );
    }

    #[test]
    fn rejects() {
        assert!(matches!(
            TimeFrame::parse(&[]),
            Err(Error::BadLength { .. })
        ));
        assert!(matches!(
            TimeFrame::parse(&[0x01, 0]),
            Err(Error::BadLength { .. })
        ));
        assert!(matches!(
            TimeFrame::parse(&[0x02; 7]),
            Err(Error::BadLength { .. })
        ));
        for t in [0u8, 3, 15] {
            assert_eq!(
                TimeFrame::parse(&[t, 0, 0, 0, 0, 0, 0, 0]),
                Err(Error::OutOfRange { offset: 0 })
            );
        }
        let mut b = [0; 8];
        assert!(TimeFrame::Sync { seq: 16 }.encode(&mut b).is_err());
        assert!(TimeFrame::FollowUp {
            seq: 0,
            master_us: 1 << 56
        }
        .encode(&mut b)
        .is_err());
    }

    #[test]
    fn ids() {
        let w = IdWindow::DEFAULT;
        assert_eq!(
            time_id(u32::from(DEFAULT_TIME_ID), &w),
            Ok(Id::Standard(StandardId::new(0x0FF).unwrap()))
        );
        assert_eq!(time_id(0x100, &w), Err(Error::BadIdWindow));
        assert_eq!(time_id(0x17F, &w), Err(Error::BadIdWindow));
        assert!(time_id(0x180, &w).is_ok());
        assert_eq!(time_id(0x800, &w), Err(Error::BadIdWindow));
        let x = IdWindow::extended(0x1000).unwrap();
        assert_eq!(
            time_id(0x0FF, &x),
            Ok(Id::Extended(ExtendedId::new(0x0FF).unwrap()))
        );
    }
}
