//! Temporal decimation: the per-scan publish decision.

use super::config::TemporalDecimation;

/// State of the publish decision across scans.
#[derive(Debug, Clone, Default)]
pub(crate) struct TemporalGate {
    /// `EveryNth`: scans offered since the last published one.
    since_published: u32,
    /// `MaxRate`: timestamp of the last published scan.
    last_published_ms: Option<u32>,
}

/// `2^bits - 1` for `bits` in 1..=32 (all ones for anything larger).
fn mask(bits: u8) -> u32 {
    match 1u32.checked_shl(u32::from(bits)) {
        Some(v) => v.wrapping_sub(1),
        None => u32::MAX,
    }
}

impl TemporalGate {
    /// Starts over (new settings).
    pub fn reset(&mut self) {
        *self = TemporalGate::default();
    }

    /// Whether the scan stamped `timestamp_ms` is published under `mode`.
    pub fn should_publish(&mut self, mode: TemporalDecimation, timestamp_ms: u32) -> bool {
        match mode {
            TemporalDecimation::All => true,
            TemporalDecimation::EveryNth(n) => {
                let publish = self.since_published == 0;
                self.since_published = self.since_published.saturating_add(1);
                if self.since_published >= u32::from(n) {
                    self.since_published = 0;
                }
                publish
            }
            TemporalDecimation::MaxRate {
                millihertz,
                timestamp_bits,
            } => {
                let publish = match self.last_published_ms {
                    None => true,
                    Some(last) => {
                        let elapsed = timestamp_ms.wrapping_sub(last) & mask(timestamp_bits);
                        u64::from(elapsed).saturating_mul(u64::from(millihertz)) >= 1_000_000
                    }
                };
                if publish {
                    self.last_published_ms = Some(timestamp_ms);
                }
                publish
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn decide(mode: TemporalDecimation, stamps: &[u32]) -> Vec<bool> {
        let mut g = TemporalGate::default();
        stamps.iter().map(|t| g.should_publish(mode, *t)).collect()
    }

    #[test]
    fn all_publishes_every_scan() {
        assert_eq!(decide(TemporalDecimation::All, &[0, 0, 5]), [true; 3]);
    }

    #[test]
    fn every_third_scan() {
        let got = decide(TemporalDecimation::EveryNth(3), &[0; 7]);
        assert_eq!(got, [true, false, false, true, false, false, true]);
        assert_eq!(decide(TemporalDecimation::EveryNth(1), &[0; 3]), [true; 3]);
    }

    #[test]
    fn rate_limit_with_40_hz_scans() {
        // UTM-30LX: a scan every 25 ms. At most 15 Hz = one per 66.67 ms:
        // 0 yes, 25 (25) no, 50 (50) no, 75 (75) yes, 100 (25) no, 125 no, 150 (75) yes.
        let stamps: Vec<u32> = (0..7).map(|i| i * 25).collect();
        let mode = TemporalDecimation::MaxRate {
            millihertz: 15_000,
            timestamp_bits: 24,
        };
        assert_eq!(
            decide(mode, &stamps),
            [true, false, false, true, false, false, true]
        );
        // Exactly at the interval publishes: 20 Hz = 50 ms.
        let mode = TemporalDecimation::MaxRate {
            millihertz: 20_000,
            timestamp_bits: 24,
        };
        assert_eq!(
            decide(mode, &stamps),
            [true, false, true, false, true, false, true]
        );
        // Half a hertz: one per 2000 ms.
        let mode = TemporalDecimation::MaxRate {
            millihertz: 500,
            timestamp_bits: 24,
        };
        assert_eq!(
            decide(mode, &[0, 1999, 2000, 3999, 4000]),
            [true, false, true, false, true]
        );
    }

    #[test]
    fn rate_limit_across_the_24_bit_wrap() {
        // Last published at 2^24 - 10; the next scan's stamp wrapped to 40: 50 ms later.
        let mode = TemporalDecimation::MaxRate {
            millihertz: 20_000,
            timestamp_bits: 24,
        };
        let top = (1u32 << 24) - 10;
        assert_eq!(decide(mode, &[top, 30, 40]), [true, false, true]);
        // With 32-bit stamps the same numbers are a huge jump: published at once.
        let mode32 = TemporalDecimation::MaxRate {
            millihertz: 20_000,
            timestamp_bits: 32,
        };
        assert_eq!(decide(mode32, &[top, 30, 40]), [true, true, false]);
        assert_eq!(mask(24), 0x00FF_FFFF);
        assert_eq!(mask(32), u32::MAX);
        assert_eq!(mask(1), 1);
    }

    #[test]
    fn reset_publishes_the_next_scan() {
        let mode = TemporalDecimation::EveryNth(5);
        let mut g = TemporalGate::default();
        assert!(g.should_publish(mode, 0));
        assert!(!g.should_publish(mode, 0));
        g.reset();
        assert!(g.should_publish(mode, 0));
    }
}
