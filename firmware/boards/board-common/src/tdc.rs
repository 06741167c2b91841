//! CAN FD transmitter delay compensation, derived from the data phase's bit timing.
//!
//! Above about 1 Mbit/s the transceiver's loop delay (TX pin to RX pin, 100-200 ns) is a
//! large part of a data bit, so the transmitter checks its own bits at a *secondary
//! sample point*: the measured loop delay plus an offset (ISO 11898-1, CiA 601-3). The
//! offset is the data phase's sample point, in minimum time quanta (kernel clock
//! periods): the secondary sample point then falls where the receivers sample. It
//! depends on the data bit timing actually programmed, so it is computed from the
//! controller's register fields, not chosen by hand.
//!
//! Sans-IO and host-tested; the FDCAN board reads its `DBTP` fields and writes
//! `TDCR.TDCO` with the result.

/// The largest offset the FDCAN's `TDCR.TDCO` holds (7 bits).
pub const TDCO_MAX: u8 = 127;

/// A data phase bit timing as the FDCAN's `DBTP` register holds it: each field is its
/// value minus one (`DBRP` = prescaler - 1, `DTSEG1` = time segment 1 - 1, `DTSEG2` =
/// time segment 2 - 1). A bit is `1 + tseg1 + tseg2` time quanta of `prescaler` minimum
/// time quanta each (the synchronisation segment is one quantum).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataBitTiming {
    /// `DBTP.DBRP`: prescaler - 1 (0..=31).
    pub dbrp: u8,
    /// `DBTP.DTSEG1`: time segment 1 (propagation + phase 1) - 1 (0..=31).
    pub dtseg1: u8,
    /// `DBTP.DTSEG2`: time segment 2 - 1 (0..=15).
    pub dtseg2: u8,
}

impl DataBitTiming {
    /// Minimum time quanta (kernel clock periods) per time quantum.
    pub const fn prescaler(&self) -> u32 {
        self.dbrp as u32 + 1
    }

    /// Minimum time quanta per data bit.
    pub const fn bit_mtq(&self) -> u32 {
        self.prescaler() * (1 + (self.dtseg1 as u32 + 1) + (self.dtseg2 as u32 + 1))
    }

    /// Minimum time quanta from the start of a bit to its sample point (after the
    /// synchronisation segment and time segment 1).
    pub const fn sample_point_mtq(&self) -> u32 {
        self.prescaler() * (1 + (self.dtseg1 as u32 + 1))
    }

    /// The transmitter delay compensation offset (`TDCR.TDCO`) for this timing: the
    /// sample point in minimum time quanta. `None` when it does not fit the register's
    /// 7 bits (then compensation cannot be set up for this timing).
    pub const fn tdc_offset(&self) -> Option<u8> {
        let mtq = self.sample_point_mtq();
        if mtq <= TDCO_MAX as u32 {
            Some(mtq as u8)
        } else {
            None
        }
    }

    /// The data bit rate on a kernel clock of `kernel_hz`.
    pub const fn bit_rate(&self, kernel_hz: u32) -> u32 {
        kernel_hz / self.bit_mtq()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_is_the_sample_point_in_kernel_clocks() {
        // The G474 board: 5 Mbit/s on an 80 MHz kernel clock is 16 kernel clocks per
        // bit; embassy programs prescaler 2, tseg1 6, tseg2 1 (DBTP fields 1, 5, 0): a
        // bit of 2 × (1 + 6 + 1) = 16, sampled after 2 × (1 + 6) = 14 (87.5 %).
        let t = DataBitTiming {
            dbrp: 1,
            dtseg1: 5,
            dtseg2: 0,
        };
        assert_eq!(t.bit_mtq(), 16);
        assert_eq!(t.bit_rate(80_000_000), 5_000_000);
        assert_eq!(t.tdc_offset(), Some(14));
        // 2 Mbit/s at 80 MHz, prescaler 1 and 40 quanta sampled at 80 %: 1 + 31 = 32.
        let t = DataBitTiming {
            dbrp: 0,
            dtseg1: 30,
            dtseg2: 7,
        };
        assert_eq!((t.bit_mtq(), t.bit_rate(80_000_000)), (40, 2_000_000));
        assert_eq!(t.tdc_offset(), Some(32));
        // TDCO has 7 bits (at most 127): prescaler 4 × (1 + 30) = 124 fits,
        // prescaler 4 × (1 + 32) = 132 does not.
        let fits = DataBitTiming {
            dbrp: 3,
            dtseg1: 29,
            dtseg2: 3,
        };
        assert_eq!(fits.tdc_offset(), Some(124));
        let too_far = DataBitTiming {
            dbrp: 3,
            dtseg1: 31,
            dtseg2: 3,
        };
        assert_eq!(too_far.tdc_offset(), None);
        // Every field value: the offset never exceeds the bit, and fits or is refused.
        for dbrp in 0..32 {
            for dtseg1 in 0..32 {
                let t = DataBitTiming {
                    dbrp,
                    dtseg1,
                    dtseg2: 15,
                };
                match t.tdc_offset() {
                    Some(o) => assert!(u32::from(o) < t.bit_mtq() && o <= TDCO_MAX),
                    None => assert!(t.sample_point_mtq() > 127),
                }
            }
        }
    }
}
