//! Unwrapping the sensor's 24-bit millisecond clock into a monotonic count.

/// Mask of the sensor's 24-bit millisecond timer.
pub const TIMESTAMP_MASK: u32 = 0x00FF_FFFF;

/// Turns successive 24-bit timestamps into a monotonic `u64` millisecond count.
///
/// A step backwards is taken as one wrap of the 24-bit counter (every 2^24 ms ≈ 4.66 h),
/// which holds as long as successive timestamps are less than one wrap apart.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TimestampUnwrapper {
    last: Option<u32>,
    high: u64,
}

impl TimestampUnwrapper {
    /// A fresh unwrapper: the first timestamp comes out as itself.
    pub const fn new() -> Self {
        Self {
            last: None,
            high: 0,
        }
    }

    /// The unwrapped value of the next 24-bit timestamp (higher bits are ignored).
    pub fn unwrap(&mut self, raw: u32) -> u64 {
        let raw = raw & TIMESTAMP_MASK;
        if let Some(last) = self.last {
            if raw < last {
                // Saturates only after 2^40 wraps of the 24-bit counter (35 million
                // years of 1 ms ticks); the result never decreases.
                self.high = self.high.saturating_add(1 << 24);
            }
        }
        self.last = Some(raw);
        self.high.saturating_add(u64::from(raw))
    }

    /// Forgets the history (after a sensor reset, whose timer restarts at 0).
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps() {
        let mut u = TimestampUnwrapper::new();
        assert_eq!(u.unwrap(0xFF_FFF0), 0xFF_FFF0);
        assert_eq!(u.unwrap(0xFF_FFFF), 0xFF_FFFF);
        assert_eq!(u.unwrap(0x10), 0x100_0010);
        assert_eq!(u.unwrap(0x10), 0x100_0010);
        assert_eq!(u.unwrap(0xFF_0000), 0x1FF_0000);
        assert_eq!(u.unwrap(5), 0x200_0005);
        assert_eq!(u.unwrap(0xFF00_0006), 0x200_0006);
        u.reset();
        assert_eq!(u.unwrap(7), 7);
    }
}
