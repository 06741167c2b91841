//! Following a time master over CAN (SPEC section 9): the bridge's clock (µs) mapped to
//! the master's (the robot's) from SYNC / FOLLOW-UP pairs.
//!
//! Pure state, no clock of its own: the caller gives the bridge time a SYNC was received
//! at ([`TimeSync::on_sync`]) and the master time its FOLLOW-UP carries
//! ([`TimeSync::on_follow_up`]); [`TimeSync::to_master`] maps any bridge time while the
//! sync holds. The filter is SPEC 9.3: an anchor `(B, M)`, the rate difference `drift`,
//! outliers rejected, a clock step taken after three in a row, expiry after
//! [`HOLD_US`].

/// How long a sync holds after the last accepted sample, µs (SPEC 9.3).
pub const HOLD_US: u64 = 10_000_000;
/// The smallest outlier limit, µs (SPEC 9.3).
pub const MIN_OUTLIER_US: i64 = 1_000;
/// The largest rate difference tracked, parts per billion (±1000 ppm).
pub const MAX_DRIFT_PPB: i64 = 1_000_000;
/// Rejections in a row after which the master's clock is taken as stepped.
pub const STEP_AFTER: u8 = 3;
/// Bridge times further than this from the anchor are not mapped (µs, about 12.7 days).
const MAX_MAP_SPAN_US: u64 = 1 << 40;
/// Bound of the mean error (µs): keeps the outlier limit bounded.
const MAX_MEAN_US: i64 = 1_000_000;
/// Samples closer together than this (µs) do not update the rate.
const MIN_RATE_SPAN_US: i64 = 100_000;
const PPB: i64 = 1_000_000_000;

/// Counters of the time sync (each wraps).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TimeSyncStats {
    /// SYNC frames taken (a repeat of the pending one is not).
    pub syncs: u32,
    /// Samples accepted into the mapping (including the ones that started it).
    pub samples: u32,
    /// Samples rejected as outliers.
    pub outliers: u32,
    /// FOLLOW-UP frames without a pending SYNC of their sequence.
    pub orphans: u32,
    /// SYNC frames repeating the pending one (ignored).
    pub duplicates: u32,
    /// Times the mapping started over (first sample, clock step).
    pub restarts: u32,
    /// Frames on the time identifier that did not parse (SPEC 9.2).
    pub malformed: u32,
}

/// The mapping `m(b) = M + (b − B) × (1 + drift)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Anchor {
    bridge_us: u64,
    master_us: i64,
}

/// The time sync state of one bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TimeSync {
    /// The SYNC waiting for its FOLLOW-UP: `(seq, bridge µs)`.
    pending: Option<(u8, u64)>,
    anchor: Option<Anchor>,
    drift_ppb: i64,
    /// Samples since the mapping (re)started.
    samples: u32,
    /// Mean `|e|` of accepted samples, µs.
    mean_abs_us: i64,
    rejects_in_row: u8,
    last_sample_us: u64,
    stats: TimeSyncStats,
}

impl TimeSync {
    /// No master seen yet.
    pub const fn new() -> Self {
        TimeSync {
            pending: None,
            anchor: None,
            drift_ppb: 0,
            samples: 0,
            mean_abs_us: 0,
            rejects_in_row: 0,
            last_sample_us: 0,
            stats: TimeSyncStats {
                syncs: 0,
                samples: 0,
                outliers: 0,
                orphans: 0,
                duplicates: 0,
                restarts: 0,
                malformed: 0,
            },
        }
    }

    /// A SYNC with sequence `seq` was received at `rx_bridge_us` (bridge clock).
    pub fn on_sync(&mut self, seq: u8, rx_bridge_us: u64) {
        if matches!(self.pending, Some((s, _)) if s == seq) {
            self.stats.duplicates = self.stats.duplicates.wrapping_add(1);
            return;
        }
        self.stats.syncs = self.stats.syncs.wrapping_add(1);
        self.pending = Some((seq, rx_bridge_us));
    }

    /// A FOLLOW-UP: the SYNC with sequence `seq` was sent at `master_us` (master clock).
    /// Returns whether it made a sample that was accepted.
    pub fn on_follow_up(&mut self, seq: u8, master_us: u64) -> bool {
        match self.pending {
            Some((s, rx)) if s == seq => {
                self.pending = None;
                match i64::try_from(master_us) {
                    Ok(m) if master_us <= can_wire::timesync::MAX_MASTER_US => self.sample(rx, m),
                    _ => false,
                }
            }
            _ => {
                self.stats.orphans = self.stats.orphans.wrapping_add(1);
                false
            }
        }
    }

    /// The master time of bridge time `bridge_us`, while the sync holds (at most
    /// [`HOLD_US`] after the last accepted sample); `None` before the first sample, after
    /// expiry, or when the result would be negative.
    pub fn to_master(&self, bridge_us: u64) -> Option<u64> {
        let a = self.anchor?;
        if bridge_us.saturating_sub(self.last_sample_us) > HOLD_US {
            return None;
        }
        u64::try_from(self.map(a, bridge_us)?).ok()
    }

    /// Whether a mapping holds at bridge time `now_us`.
    pub fn synced(&self, now_us: u64) -> bool {
        self.anchor.is_some() && now_us.saturating_sub(self.last_sample_us) <= HOLD_US
    }

    /// Bridge time of the last accepted sample, µs (`None` before the first).
    pub fn last_sample_us(&self) -> Option<u64> {
        self.anchor.map(|_| self.last_sample_us)
    }

    /// Mean absolute prediction error of the accepted samples, µs: the jitter of the
    /// exchange as the bridge sees it (0 until the third sample).
    pub fn mean_error_us(&self) -> u32 {
        u32::try_from(self.mean_abs_us).unwrap_or(u32::MAX)
    }

    /// The tracked rate difference of the master's clock against the bridge's, ppb.
    pub fn drift_ppb(&self) -> i64 {
        self.drift_ppb
    }

    /// A frame on the time identifier that did not parse: counted.
    pub fn on_malformed(&mut self) {
        self.stats.malformed = self.stats.malformed.wrapping_add(1);
    }

    /// The counters.
    pub fn stats(&self) -> &TimeSyncStats {
        &self.stats
    }

    /// Forgets the mapping and any pending SYNC (counters stay).
    pub fn reset(&mut self) {
        *self = TimeSync {
            stats: self.stats,
            ..TimeSync::new()
        };
    }

    /// `m(b)`; `None` more than [`MAX_MAP_SPAN_US`] from the anchor. Within that span
    /// nothing can overflow: `|dt × drift| <= 2^40 × 10^6 < 2^63`, and master times are
    /// below 2^56 (SPEC 9.2), so wrapping operations are exact and cheap.
    fn map(&self, a: Anchor, bridge_us: u64) -> Option<i64> {
        let dt = signed_diff(bridge_us, a.bridge_us)?;
        if dt.unsigned_abs() > MAX_MAP_SPAN_US {
            return None;
        }
        let correction = dt.wrapping_mul(self.drift_ppb).wrapping_div(PPB);
        Some(a.master_us.wrapping_add(dt).wrapping_add(correction))
    }

    /// Out of line, like [`TimeSync::reject`] and [`TimeSync::accept`]: each has several
    /// callers (a frame of their 64-bit fields each, inlined).
    #[inline(never)]
    fn restart(&mut self, rx: u64, m: i64) {
        self.anchor = Some(Anchor {
            bridge_us: rx,
            master_us: m,
        });
        // The rate is kept: the next sample measures it again from this anchor.
        self.samples = 1;
        self.mean_abs_us = 0;
        self.rejects_in_row = 0;
        self.last_sample_us = rx;
        self.stats.restarts = self.stats.restarts.wrapping_add(1);
        self.stats.samples = self.stats.samples.wrapping_add(1);
    }

    #[inline(never)]
    fn reject(&mut self, rx: u64, m: i64) -> bool {
        self.stats.outliers = self.stats.outliers.wrapping_add(1);
        self.rejects_in_row = self.rejects_in_row.saturating_add(1);
        if self.rejects_in_row >= STEP_AFTER {
            self.restart(rx, m);
            return true;
        }
        false
    }

    /// One `(bridge rx, master tx)` pair (SPEC 9.3).
    fn sample(&mut self, rx: u64, m: i64) -> bool {
        let Some(a) = self.anchor.filter(|_| self.samples > 0) else {
            self.restart(rx, m);
            return true;
        };
        // Expired: start over rather than extrapolate an old rate.
        if rx.saturating_sub(self.last_sample_us) > HOLD_US {
            self.restart(rx, m);
            return true;
        }
        let dt = match signed_diff(rx, a.bridge_us) {
            Some(dt) if dt > 0 => dt,
            // Not after the anchor: a SYNC older than the last one used.
            _ => return self.reject(rx, m),
        };
        // From here `0 < dt <= HOLD_US` (the anchor is the last sample), so `|e| <= dt`
        // and `|e| <= limit <= 8 × MAX_MEAN_US` keep every product below 2^63.
        let Some(predicted) = self.map(a, rx) else {
            return self.reject(rx, m);
        };
        let e = m.wrapping_sub(predicted);
        let rate = |e: i64| e.wrapping_mul(PPB).checked_div(dt).unwrap_or(0);
        if self.samples == 1 {
            // The second sample: the rate from the two.
            let mut drift = self.drift_ppb;
            if dt >= MIN_RATE_SPAN_US && e.unsigned_abs() <= dt.unsigned_abs() {
                drift = drift.wrapping_add(rate(e));
            }
            if e.unsigned_abs() > dt.unsigned_abs() || drift.wrapping_abs() > MAX_DRIFT_PPB {
                // Rates this far apart are no clocks of one robot: a step.
                self.restart(rx, m);
                return true;
            }
            self.drift_ppb = drift;
            return self.accept(rx, m);
        }
        let limit = self.mean_abs_us.wrapping_mul(8).max(MIN_OUTLIER_US);
        let abs = e.wrapping_abs();
        if abs > limit {
            return self.reject(rx, m);
        }
        if dt >= MIN_RATE_SPAN_US {
            self.drift_ppb = self
                .drift_ppb
                .wrapping_add(rate(e).wrapping_div(8))
                .clamp(-MAX_DRIFT_PPB, MAX_DRIFT_PPB);
        }
        let mean = self.mean_abs_us;
        self.mean_abs_us = mean
            .wrapping_add(abs.wrapping_sub(mean).wrapping_div(8))
            .min(MAX_MEAN_US);
        self.accept(rx, predicted.wrapping_add(e.wrapping_div(2)))
    }

    #[inline(never)]
    fn accept(&mut self, rx: u64, master: i64) -> bool {
        self.anchor = Some(Anchor {
            bridge_us: rx,
            master_us: master,
        });
        self.samples = self.samples.saturating_add(1);
        self.rejects_in_row = 0;
        self.last_sample_us = rx;
        self.stats.samples = self.stats.samples.wrapping_add(1);
        true
    }
}

/// `a − b` as a signed number, `None` beyond ±2^63.
fn signed_diff(a: u64, b: u64) -> Option<i64> {
    if a >= b {
        i64::try_from(a.wrapping_sub(b)).ok()
    } else {
        i64::try_from(b.wrapping_sub(a))
            .ok()
            .map(|d| d.saturating_neg())
    }
}
