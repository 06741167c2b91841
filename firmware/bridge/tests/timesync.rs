//! The time sync state (SPEC 9.3) against simulated clocks whose offset and rate are
//! known: the master's clock is `m(t) = m0 + t × (1 + ppm / 10^6)` for the bridge's clock
//! `t`, computed here in floating point, independently of the bridge's integer filter.

use bridge::timesync::{TimeSync, HOLD_US};
use proptest::prelude::*;

/// A simulated master clock against the bridge's.
#[derive(Debug, Clone, Copy)]
struct Clocks {
    m0: u64,
    ppm: f64,
}

impl Clocks {
    fn master(&self, bridge_us: u64) -> u64 {
        let rate_part = bridge_us as f64 * self.ppm * 1e-6;
        (self.m0 as i128 + bridge_us as i128 + rate_part.round() as i128) as u64
    }
}

/// Sends pair `k` (seq `k % 16`) with its SYNC received at bridge time `rx`, `delay` µs
/// after the master sent it.
fn pair(s: &mut TimeSync, c: &Clocks, k: u32, rx: u64, delay: u64) -> bool {
    let seq = (k % 16) as u8;
    s.on_sync(seq, rx);
    s.on_follow_up(seq, c.master(rx - delay))
}

fn err(s: &TimeSync, c: &Clocks, b: u64) -> i64 {
    s.to_master(b).expect("synced") as i64 - c.master(b) as i64
}

const SEC: u64 = 1_000_000;
/// 2026-01-01 in Unix µs.
const EPOCH_2026: u64 = 1_767_225_600_000_000;

#[test]
fn constant_offset_is_exact_after_one_pair() {
    let c = Clocks {
        m0: EPOCH_2026,
        ppm: 0.0,
    };
    let mut s = TimeSync::new();
    assert_eq!(s.to_master(5 * SEC), None);
    assert!(!s.synced(5 * SEC));
    assert!(pair(&mut s, &c, 0, 5 * SEC, 0));
    assert!(s.synced(5 * SEC));
    for b in [0, 5 * SEC, 5 * SEC + 1, 7 * SEC + 123_456, 15 * SEC] {
        assert_eq!(s.to_master(b), Some(EPOCH_2026 + b), "at {b}");
    }
}

#[test]
fn drift_is_tracked_from_the_second_pair() {
    for ppm in [-120.0, -50.0, 0.0, 37.5, 100.0] {
        let c = Clocks {
            m0: EPOCH_2026,
            ppm,
        };
        let mut s = TimeSync::new();
        for k in 0..30u32 {
            let rx = 1_000 + u64::from(k) * SEC;
            assert!(pair(&mut s, &c, k, rx, 0), "pair {k} at {ppm} ppm");
            if k >= 1 {
                // Up to the next pair and up to expiry.
                for b in [rx, rx + SEC / 2, rx + SEC, rx + HOLD_US] {
                    let e = err(&s, &c, b);
                    let bound = 2 + (b - rx) as i64 / 500_000;
                    assert!(
                        e.abs() <= bound,
                        "{ppm} ppm pair {k} at +{}: {e} µs",
                        b - rx
                    );
                }
            }
        }
        assert_eq!(s.stats().outliers, 0);
        // The truth is rounded to 1 µs per second: the rate to within 1 ppm.
        assert!(
            (s.drift_ppb() as f64 - ppm * 1000.0).abs() < 1000.0,
            "{}",
            s.drift_ppb()
        );
    }
}

/// A deterministic jitter of 0..=max µs.
fn jitter(k: u32, max: u64) -> u64 {
    (u64::from(k).wrapping_mul(2_654_435_761) >> 7) % (max + 1)
}

#[test]
fn jitter_is_averaged() {
    let c = Clocks {
        m0: EPOCH_2026,
        ppm: 40.0,
    };
    let mut s = TimeSync::new();
    for k in 0..60u32 {
        let rx = (u64::from(k) + 1) * SEC + 77;
        pair(&mut s, &c, k, rx, 200 + jitter(k, 600));
    }
    // The mean delay is 500 µs; the mapping is late by about that, never by more than
    // the largest delay.
    let e = err(&s, &c, 61 * SEC);
    assert!((-900..=-100).contains(&e), "{e}");
    assert!(s.mean_error_us() <= 600, "{}", s.mean_error_us());
    assert_eq!(s.stats().restarts, 1);
}

#[test]
fn lost_duplicated_reordered_and_mismatched_frames() {
    let c = Clocks {
        m0: 1_000_000_000,
        ppm: 0.0,
    };
    let mut s = TimeSync::new();
    // FOLLOW-UP before its SYNC: an orphan, no sample.
    assert!(!s.on_follow_up(1, c.master(SEC)));
    s.on_sync(1, SEC);
    assert_eq!(s.stats().orphans, 1);
    assert_eq!(s.to_master(SEC), None);
    // Its pending SYNC is replaced by the next one, whose pair works.
    s.on_sync(2, 2 * SEC);
    // A repeated SYNC (same seq, later): ignored, the first reception counts.
    s.on_sync(2, 2 * SEC + 40_000);
    assert_eq!(s.stats().duplicates, 1);
    // A FOLLOW-UP of another sequence: orphan, the pending SYNC stays.
    assert!(!s.on_follow_up(3, c.master(3 * SEC)));
    assert_eq!(s.stats().orphans, 2);
    assert!(s.on_follow_up(2, c.master(2 * SEC)));
    assert_eq!(s.to_master(2 * SEC + 5), Some(c.master(2 * SEC + 5)));
    // A FOLLOW-UP repeated: its SYNC was used, so an orphan; nothing changes.
    assert!(!s.on_follow_up(2, c.master(2 * SEC) + 30_000));
    assert_eq!(s.to_master(2 * SEC + 5), Some(c.master(2 * SEC + 5)));
    // Lost FOLLOW-UP: the SYNC is replaced by the next.
    s.on_sync(3, 3 * SEC);
    s.on_sync(4, 4 * SEC);
    assert!(s.on_follow_up(4, c.master(4 * SEC)));
    assert_eq!(s.stats().samples, 2);
    assert_eq!(s.to_master(4 * SEC + 9), Some(c.master(4 * SEC + 9)));
}

#[test]
fn sequence_wraps() {
    let c = Clocks { m0: 42, ppm: -20.0 };
    let mut s = TimeSync::new();
    for k in 0..50u32 {
        assert!(pair(&mut s, &c, k, u64::from(k) * SEC / 2 + 3, 0), "{k}");
    }
    assert_eq!(s.stats().samples, 50);
    assert!(err(&s, &c, 25 * SEC).abs() <= 2);
}

#[test]
fn expires_after_hold_and_restarts() {
    let c = Clocks {
        m0: EPOCH_2026,
        ppm: 0.0,
    };
    let mut s = TimeSync::new();
    pair(&mut s, &c, 0, SEC, 0);
    assert!(s.to_master(SEC + HOLD_US).is_some());
    assert!(s.synced(SEC + HOLD_US));
    assert_eq!(s.to_master(SEC + HOLD_US + 1), None);
    assert!(!s.synced(SEC + HOLD_US + 1));
    // A master with another offset after the gap is taken as is.
    let c2 = Clocks {
        m0: EPOCH_2026 + 3_600 * SEC,
        ppm: 0.0,
    };
    assert!(pair(&mut s, &c2, 1, 20 * SEC, 0));
    assert_eq!(s.to_master(20 * SEC), Some(c2.master(20 * SEC)));
}

#[test]
fn outlier_rejected_and_step_taken_after_three() {
    let c = Clocks {
        m0: EPOCH_2026,
        ppm: 0.0,
    };
    let mut s = TimeSync::new();
    for k in 0..5u32 {
        pair(&mut s, &c, k, u64::from(k) * SEC, 0);
    }
    // A SYNC delayed 50 ms (a busy bus or host): rejected, the mapping stays exact.
    assert!(!pair(&mut s, &c, 5, 5 * SEC, 50_000));
    assert_eq!(s.stats().outliers, 1);
    assert_eq!(s.to_master(5 * SEC), Some(c.master(5 * SEC)));
    // Good samples reset the run of rejections.
    assert!(pair(&mut s, &c, 6, 6 * SEC, 0));
    // The master's clock steps by +2 s: two rejections, then it is taken.
    let stepped = Clocks {
        m0: EPOCH_2026 + 2 * SEC,
        ppm: 0.0,
    };
    assert!(!pair(&mut s, &stepped, 7, 7 * SEC, 0));
    assert!(!pair(&mut s, &stepped, 8, 8 * SEC, 0));
    assert_eq!(s.to_master(8 * SEC), Some(c.master(8 * SEC)));
    assert!(pair(&mut s, &stepped, 9, 9 * SEC, 0));
    assert_eq!(s.to_master(9 * SEC), Some(stepped.master(9 * SEC)));
    assert_eq!(s.stats().restarts, 2);
}

#[test]
fn reset_forgets_the_mapping() {
    let c = Clocks { m0: 5, ppm: 0.0 };
    let mut s = TimeSync::new();
    pair(&mut s, &c, 0, SEC, 0);
    s.on_sync(1, 2 * SEC);
    s.reset();
    assert_eq!(s.to_master(SEC), None);
    assert!(!s.on_follow_up(1, 7));
    assert_eq!(s.stats().samples, 1);
}

#[test]
fn extreme_inputs_do_not_panic() {
    let mut s = TimeSync::new();
    s.on_sync(0, u64::MAX);
    s.on_follow_up(0, u64::MAX);
    s.on_sync(1, 0);
    s.on_follow_up(1, (1 << 56) - 1);
    s.on_sync(2, u64::MAX);
    s.on_follow_up(2, 0);
    let _ = s.to_master(u64::MAX);
    let _ = s.to_master(0);
}

proptest! {
    /// Any offset, rate within ±200 ppm, period, and loss pattern: once two pairs were
    /// taken (since the last restart after a gap) the mapping is within a few µs of the master's clock (no delay, no jitter).
    #[test]
    fn mapping_tracks_any_clock(
        m0 in 0u64..(1 << 55),
        ppm in -200.0f64..200.0,
        period in 100_000u64..2_000_000,
        start in 0u64..(1 << 40),
        lost in proptest::collection::vec(0u8..4, 40),
    ) {
        let c = Clocks { m0, ppm };
        let mut s = TimeSync::new();
        let mut taken = 0;
        let mut last = start;
        for (k, loss) in lost.iter().enumerate() {
            let k = k as u32;
            let rx = start + u64::from(k) * period;
            let seq = (k % 16) as u8;
            // 0: lose the SYNC, 1: lose the FOLLOW-UP, 2: repeat the SYNC later, 3: fine.
            if *loss != 0 {
                s.on_sync(seq, rx);
            }
            if *loss == 2 {
                s.on_sync(seq, rx + 5_000);
            }
            let restarts = s.stats().restarts;
            if *loss != 1 && s.on_follow_up(seq, c.master(rx)) {
                // Pairs since the mapping (re)started (after a gap beyond the hold).
                taken = if s.stats().restarts != restarts { 1 } else { taken + 1 };
                last = rx;
            }
            if taken >= 2 {
                let b = last + period / 2;
                let e = s.to_master(b).map(|m| m as i64 - c.master(b) as i64);
                // Rate rounded to 1 ppb over at most 2 periods of loss, plus rounding.
                let bound = 3 + (b - last + period * 2) as i64 / 100_000;
                prop_assert!(matches!(e, Some(e) if e.abs() <= bound), "{:?} at pair {}", e, k);
            }
        }
    }
}
