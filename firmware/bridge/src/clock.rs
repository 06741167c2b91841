//! The sensor clock model: when each scan started, in the bridge's clock (µs).
//!
//! A scan carries the sensor's 24-bit millisecond counter, read when the scan started
//! (SCIP timestamp). That counter drifts against the bridge's clock, has 1 ms
//! resolution, restarts at a reboot or `RS`, and says nothing about the bridge's time.
//! [`ScanClock`] combines three observations, all in integer arithmetic:
//!
//! 1. **Scan phase in sensor time.** Scans follow each other at a fixed period. The
//!    stamp of scan `k` says its start `S_k` (sensor µs) lies in
//!    `[1000 × stamp, 1000 × stamp + 1000)`. Carried from scan to scan by the period,
//!    these intervals intersect; as drift or a non-integer period moves the scans across
//!    millisecond boundaries the intersection narrows well below the 1 ms resolution,
//!    and the period in sensor µs follows from the first and the latest interval.
//! 2. **Arrival envelope in bridge time.** The timestamp line of scan `k` arrives at
//!    `t_k + L + j_k`: its start `t_k`, a constant latency `L` (the rest of the scan,
//!    the sensor's processing and the UART bytes before the line ends) and a delay
//!    `j_k ≥ 0` (output jitter, a late board). Arrival times are upper bounds, so the
//!    model keeps their *lower envelope* along the scan index: a sample below the
//!    envelope moves it down at once, a sample above it is a delayed sample and lifts
//!    it by at most [`CREEP_US`] per scan (so the envelope follows a period that was
//!    estimated slightly short, and a burst of late samples cannot drag it). The period
//!    in bridge µs is the slope between minima of blocks of [`BLOCK`] scans.
//! 3. **`TM` calibration.** A `TM1` answer read at bridge time between sending and
//!    receiving says which millisecond the sensor's clock was in; several answers
//!    intersect. With the scan phase (1) and the two periods (drift = ratio of the
//!    periods) this places `S_k` in bridge time and gives `L` = envelope − start.
//!    `L` belongs to the sensor and its scan rate, not to its clock: it survives a
//!    reboot or `RS` of the sensor, after which the envelope alone places scans again.
//!
//! The estimate of a scan's start is `envelope − L`. It is `valid` once `L` is known
//! to [`VALID_SPAN_US`] and the envelope has seen [`WARMUP_SCANS`] scans. Published
//! times never go backwards: each is at least the previous one plus 1 µs.
//!
//! Resets: [`ScanClock::sensor_restarted`] (reboot, `RS`; also detected from a stamp
//! that goes back) drops the phase and the envelope but keeps `L`; a changed scan
//! period (stamps that no longer fit) drops `L` too (a new `TM` calibrates it again).
//! Fixed memory (a few hundred bytes), no floating point, every operation saturating.

/// Scans per block of the period fit.
pub const BLOCK: i64 = 32;
/// Blocks kept for the period fit (the slope spans up to this many blocks).
const BLOCKS: usize = 16;
/// How far a delayed sample lifts the envelope per scan, µs.
pub const CREEP_US: i64 = 2;
/// Envelope scans before an estimate is valid.
pub const WARMUP_SCANS: i64 = 2 * BLOCK;
/// Width of the latency interval below which the estimate is valid, µs.
pub const VALID_SPAN_US: i64 = 600;
/// A latency interval this much wider than the best one still refines it, µs.
const SPAN_SLACK_US: i64 = 64;
/// `TM1` answers intersected for one calibration.
pub const TM_SAMPLES: u8 = 24;
/// Fixed-point shift of the periods (µs × 2^16).
const Q: u32 = 16;
/// Longest scan period the model follows, Q16 (2^36: about 1.05 s a scan).
const MAX_PERIOD_Q: i64 = 1 << 36;
/// The period fit takes block minima up to this many scans apart.
const FIT_MAX_SCANS: i64 = 1 << 16;
/// The period fit takes block minima up to this many µs apart (about 19 hours).
const FIT_MAX_US: i64 = 1 << 36;
/// A `TM` anchor calibrates scans up to this many sensor µs away (about 19 hours).
const ANCHOR_MAX_US: i64 = 1 << 36;

/// A scan's estimated start in the bridge's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Estimate {
    /// Start of the scan, bridge µs (never less than the previous estimate + 1).
    pub time_us: u64,
    /// The model is calibrated and converged (a `TM` gave the latency, the envelope
    /// has enough scans); otherwise `time_us` is the arrival envelope alone.
    pub valid: bool,
}

/// A closed interval of µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Span {
    lo: i64,
    hi: i64,
}

impl Span {
    fn width(self) -> i64 {
        self.hi.saturating_sub(self.lo)
    }
    fn mid(self) -> i64 {
        self.lo.saturating_add(self.width() / 2)
    }
    fn shift(self, d: i64) -> Self {
        Span {
            lo: self.lo.saturating_add(d),
            hi: self.hi.saturating_add(d),
        }
    }
    fn intersect(self, o: Span) -> Option<Span> {
        let s = Span {
            lo: self.lo.max(o.lo),
            hi: self.hi.min(o.hi),
        };
        (s.lo <= s.hi).then_some(s)
    }
}

/// The current stream of the sensor's clock (since its last restart).
#[derive(Debug, Clone, Copy)]
struct Stream {
    /// Stamp (extended sensor ms) and scan index of the last scan.
    last_ms: i64,
    k: i64,
    /// Start of the last scan, sensor µs.
    phase: Span,
    /// First scan's index and start interval (the period fit's reference).
    ref_k: i64,
    ref_phase: Span,
    /// The narrowest start seen since the reference.
    best_k: i64,
    best_phase: Span,
    /// Sensor µs per scan, Q16; 0 until two scans were seen.
    period_s: i64,
    /// Uncertainty of `period_s`, Q16.
    period_s_err: i64,
    /// Arrival envelope of scan `k`, bridge µs.
    env: i64,
    /// Bridge µs per scan, Q16 (0 until the block fit has data, unless the last
    /// stream left one).
    period_b: i64,
    /// Uncertainty of `period_b`, Q16.
    period_b_err: i64,
    /// Scans seen in this stream.
    scans: i64,
    /// Minima (scan index, arrival − index × `period_b` at the block's start) of the
    /// last blocks, a ring; `blocks_len` valid, `blocks_head` next to write.
    blocks: [(i64, i64); BLOCKS],
    blocks_len: usize,
    blocks_head: usize,
    /// The block being filled: its number and minimum (index, arrival).
    block: i64,
    block_min: Option<(i64, i64)>,
}

/// `TM1` answers of one calibration: bridge time of sensor time `sensor_us`.
#[derive(Debug, Clone, Copy)]
struct Tm {
    sensor_us: i64,
    bridge: Span,
    samples: u8,
}

/// The sensor clock model ([module docs](self)).
#[derive(Debug, Clone)]
pub struct ScanClock {
    stream: Option<Stream>,
    tm: Option<Tm>,
    /// Latency from a scan's start to its timestamp line's arrival envelope, µs, and
    /// the width of the interval of the last calibration that moved it.
    latency: Option<(i64, i64)>,
    /// Bridge µs per scan (Q16) of the last stream: the motor keeps its rate across a
    /// restart of the sensor's clock.
    period_b: i64,
    last_out: Option<u64>,
    resets: u32,
}

impl Default for ScanClock {
    fn default() -> Self {
        Self::new()
    }
}

/// The period (Q16) and its uncertainty between the starts `p0` of scan `k0` and `p1`
/// of scan `k1` (not inlined: called three times a scan, small next to its callers).
#[inline(never)]
fn pair(k0: i64, p0: Span, k1: i64, p1: Span) -> Option<(i64, i64)> {
    let dk = k1.saturating_sub(k0);
    if dk <= 0 {
        return None;
    }
    let span = p1.mid().saturating_sub(p0.mid());
    let err = q(p1.width().saturating_add(p0.width()) / 2).checked_div(dk)?;
    Some((q(span).checked_div(dk)?, err))
}

/// µs to Q16, clamped to ±2^46 µs (a shift: cheaper than a saturating multiply).
fn q(us: i64) -> i64 {
    us.clamp(-(1 << 46), 1 << 46) << Q
}

fn unq(v: i64) -> i64 {
    // Round to nearest.
    v.saturating_add(1 << (Q - 1)) >> Q
}

impl ScanClock {
    /// A model that knows nothing yet.
    pub const fn new() -> Self {
        ScanClock {
            stream: None,
            tm: None,
            latency: None,
            period_b: 0,
            last_out: None,
            resets: 0,
        }
    }

    /// Forgets everything but the monotonic floor of published times (a new session).
    pub fn reset(&mut self) {
        self.stream = None;
        self.tm = None;
        self.latency = None;
        self.period_b = 0;
    }

    /// The sensor's clock restarted (reboot, `RS`): its phase and the envelope are
    /// void; the latency stays (same sensor, same scan rate).
    pub fn sensor_restarted(&mut self) {
        self.stream = None;
        self.tm = None;
        self.resets = self.resets.wrapping_add(1);
    }

    /// Times the model started over on a restart it was told of or detected.
    pub fn resets(&self) -> u32 {
        self.resets
    }

    /// Drift of the sensor's clock against the bridge's, parts per billion (positive:
    /// the sensor's clock runs fast), once both periods are known.
    pub fn drift_ppb(&self) -> Option<i64> {
        let s = self.stream?;
        if s.period_s == 0 || s.period_b == 0 || s.blocks_len < 2 {
            return None;
        }
        let diff = s.period_s.saturating_sub(s.period_b);
        diff.saturating_mul(1_000_000_000).checked_div(s.period_b)
    }

    /// Whether the latency is calibrated (a `TM` and enough scans).
    pub fn calibrated(&self) -> bool {
        self.latency.is_some()
    }

    /// A `TM1` answer: the sensor's clock read `sensor_ms` (extended, same base as the
    /// scans' stamps) between `sent_us` (request's last byte out) and `recv_us`
    /// (answer's timestamp line in), bridge µs. Answers of one exchange intersect; an
    /// answer that contradicts the ones before starts a new calibration.
    #[inline(never)]
    pub fn on_tm(&mut self, sensor_ms: u64, sent_us: u64, recv_us: u64) {
        let sensor_us = i64::try_from(sensor_ms)
            .unwrap_or(i64::MAX)
            .saturating_mul(1000);
        let sent = i64::try_from(sent_us).unwrap_or(i64::MAX);
        let recv = i64::try_from(recv_us).unwrap_or(i64::MAX).max(sent);
        // The clock showed `sensor_ms` at some bridge time in [sent, recv]; it turned
        // to that millisecond up to 1000 µs before.
        let here = Span {
            lo: sent.saturating_sub(1000),
            hi: recv,
        };
        let merged = self.tm.and_then(|tm| {
            // Back-to-back answers: the drift over their few ms is far below 1 µs.
            let moved = tm.bridge.shift(sensor_us.saturating_sub(tm.sensor_us));
            let both = moved.intersect(here)?;
            Some(Tm {
                sensor_us,
                bridge: both,
                samples: tm.samples.saturating_add(1),
            })
        });
        self.tm = Some(merged.unwrap_or(Tm {
            sensor_us,
            bridge: here,
            samples: 1,
        }));
        // Calibrate again from this exchange.
        self.latency = None;
    }

    /// Whether a calibration has its answers ([`TM_SAMPLES`]).
    pub fn tm_complete(&self) -> bool {
        self.tm.is_some_and(|t| t.samples >= TM_SAMPLES)
    }

    /// A scan: its stamp `sensor_ms` (extended sensor ms) and the bridge time its
    /// timestamp line ended arriving, µs. Returns the estimated start of the scan.
    #[inline(never)]
    pub fn on_scan(&mut self, sensor_ms: u64, arrival_us: u64) -> Estimate {
        let ms = i64::try_from(sensor_ms).unwrap_or(i64::MAX);
        let arrival = i64::try_from(arrival_us).unwrap_or(i64::MAX);
        let stamp = Span {
            lo: ms.saturating_mul(1000),
            hi: ms.saturating_mul(1000).saturating_add(999),
        };
        let stream = match self.stream {
            Some(s) => self.advance(s, ms, stamp, arrival),
            None => None,
        };
        let s = stream.unwrap_or(Stream {
            last_ms: ms,
            k: 0,
            phase: stamp,
            ref_k: 0,
            ref_phase: stamp,
            best_k: 0,
            best_phase: stamp,
            period_s: 0,
            period_s_err: 0,
            env: arrival,
            period_b: self.period_b,
            period_b_err: 0,
            scans: 0,
            blocks: [(0, 0); BLOCKS],
            blocks_len: 0,
            blocks_head: 0,
            block: 0,
            block_min: None,
        });
        let mut s = s;
        s.scans = s.scans.saturating_add(1);
        self.fit_blocks(&mut s, arrival);
        self.stream = Some(s);
        self.calibrate(&s);
        let warm = s.scans >= WARMUP_SCANS && s.period_b != 0;
        let (time, valid) = match self.latency {
            Some((l, _)) => (s.env.saturating_sub(l), warm),
            None => (s.env, false),
        };
        let time = u64::try_from(time.max(0)).unwrap_or(0);
        let out = match self.last_out {
            Some(last) => time.max(last.saturating_add(1)),
            None => time,
        };
        self.last_out = Some(out);
        Estimate {
            time_us: out,
            valid,
        }
    }

    /// Carries the stream to a new scan; `None` if the stamp does not fit it (the
    /// sensor restarted or its period changed).
    #[inline(never)]
    fn advance(&mut self, mut s: Stream, ms: i64, stamp: Span, arrival: i64) -> Option<Stream> {
        let dms = ms.saturating_sub(s.last_ms);
        if dms <= 0 {
            // The clock went back (or stood still across two scans): a restart.
            self.sensor_restarted();
            return None;
        }
        let dus = dms.saturating_mul(1000);
        let (n, predicted) = if s.period_s == 0 {
            // Second scan: taken as the next one.
            (
                1,
                Span {
                    lo: stamp.lo,
                    hi: stamp.hi,
                },
            )
        } else {
            let n = q(dus)
                .saturating_add(s.period_s / 2)
                .checked_div(s.period_s)
                .unwrap_or(1)
                .max(1);
            let step = unq(s.period_s.saturating_mul(n));
            let err = unq(s.period_s_err.saturating_mul(n).saturating_mul(2)).saturating_add(2);
            let p = s.phase.shift(step);
            (
                n,
                Span {
                    lo: p.lo.saturating_sub(err),
                    hi: p.hi.saturating_add(err),
                },
            )
        };
        let Some(phase) = predicted.intersect(stamp) else {
            // The scans no longer follow the period: a new rate (or a restart the
            // stamps hide). The latency belonged to the old rate.
            self.latency = None;
            self.sensor_restarted();
            return None;
        };
        s.k = s.k.saturating_add(n);
        s.last_ms = ms;
        s.phase = phase;
        // Period in sensor µs between the reference start and this one, and between
        // the narrowest start seen and this one: the narrower pair becomes the
        // reference (two narrow starts many scans apart pin the period to a fraction
        // of a µs).
        if phase.width() < s.best_phase.width() {
            s.best_k = s.k;
            s.best_phase = phase;
        }
        let better = |a: Option<(i64, i64)>, b: Option<(i64, i64)>| match (a, b) {
            (Some(x), Some(y)) if y.1 < x.1 => Some(y),
            (x, y) => x.or(y),
        };
        let from_ref = pair(s.ref_k, s.ref_phase, s.k, phase);
        let from_best = pair(s.best_k, s.best_phase, s.k, phase);
        let ref_best = pair(s.ref_k, s.ref_phase, s.best_k, s.best_phase);
        if from_best.is_some_and(|b| from_ref.is_none_or(|r| b.1 < r.1)) {
            s.ref_k = s.best_k;
            s.ref_phase = s.best_phase;
        }
        let chosen = better(better(from_ref, from_best), ref_best);
        if let Some((p, err)) = chosen {
            s.period_s = p;
            s.period_s_err = err;
        }
        if s.period_b == 0 {
            // No bridge period yet: the envelope cannot be carried; it is the arrival.
            s.env = arrival;
            return Some(s);
        }
        // Envelope: a sample below it is the truth so far, one above it lifts it a little.
        let predicted_env = s.env.saturating_add(unq(s.period_b.saturating_mul(n)));
        let late = arrival.saturating_sub(predicted_env);
        s.env = predicted_env.saturating_add(late.min(CREEP_US.saturating_mul(n)));
        Some(s)
    }

    /// Block minima of the arrivals and the bridge period from their slope.
    #[inline(never)]
    fn fit_blocks(&mut self, s: &mut Stream, arrival: i64) {
        let block = s.k.checked_div(BLOCK).unwrap_or(0);
        if block != s.block {
            if let Some(min) = s.block_min.take() {
                if let Some(slot) = s.blocks.get_mut(s.blocks_head) {
                    *slot = min;
                }
                s.blocks_head = s
                    .blocks_head
                    .wrapping_add(1)
                    .checked_rem(BLOCKS)
                    .unwrap_or(0);
                s.blocks_len = s.blocks_len.saturating_add(1).min(BLOCKS);
                self.fit_period(s, arrival);
            }
            s.block = block;
        }
        // Minimum of arrival − k × period (the detrended arrival), kept as (k, arrival).
        let trend = if s.period_b != 0 {
            s.period_b
        } else {
            s.period_s
        };
        let detrend = |(k, a): (i64, i64)| a.saturating_sub(unq(trend.saturating_mul(k)));
        let here = (s.k, arrival);
        s.block_min = Some(match s.block_min {
            Some(m) if detrend(m) <= detrend(here) => m,
            _ => here,
        });
    }

    /// Least-squares slope of the block minima: the bridge period, and from how far
    /// the minima stray from it, its uncertainty.
    ///
    /// In `i64`: the points are taken relative to the first, `x` (scans) below
    /// [`FIT_MAX_SCANS`] and `|y|` (µs) below [`FIT_MAX_US`], else the fit waits for
    /// better points. Then `n·Σxy`, `n·Σx²` and `(Σx)²` stay below 2^60 and the slope
    /// is taken as quotient and remainder, each scaled to Q16 within 2^56.
    #[inline(never)]
    fn fit_period(&mut self, s: &mut Stream, arrival: i64) {
        if s.blocks_len < 4 {
            return;
        }
        let pts = s.blocks.get(..s.blocks_len).unwrap_or(&[]);
        let Some(&(k0, a0)) = pts.iter().min_by_key(|p| p.0) else {
            return;
        };
        let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0i64, 0i64, 0i64, 0i64, 0i64);
        let mut x_max = 0i64;
        for &(k, a) in pts {
            let x = k.saturating_sub(k0);
            let y = a.saturating_sub(a0);
            if !(0..FIT_MAX_SCANS).contains(&x) || y.saturating_abs() >= FIT_MAX_US {
                return;
            }
            x_max = x_max.max(x);
            // Within the ranges above none of these wraps.
            n = n.wrapping_add(1);
            sx = sx.wrapping_add(x);
            sy = sy.wrapping_add(y);
            sxx = sxx.wrapping_add(x.wrapping_mul(x));
            sxy = sxy.wrapping_add(x.wrapping_mul(y));
        }
        let num = n.saturating_mul(sxy).saturating_sub(sx.saturating_mul(sy));
        let den = n.saturating_mul(sxx).saturating_sub(sx.saturating_mul(sx));
        if den <= 0 || num <= 0 {
            return;
        }
        // num / den in Q16: |num / den| < 2^36 (a slope of µs per scan), the
        // remainder below den < 2^41.
        let whole = num.checked_div(den).unwrap_or(0);
        let frac = num
            .checked_rem(den)
            .unwrap_or(0)
            .wrapping_shl(Q)
            .checked_div(den)
            .unwrap_or(0);
        let p = whole.saturating_mul(1 << Q).saturating_add(frac);
        if p <= 0 || p > MAX_PERIOD_Q {
            return;
        }
        // Spread of the residuals about the line (its intercept cancels out).
        let (mut lo, mut hi) = (i64::MAX, i64::MIN);
        for &(k, a) in pts {
            let x = k.saturating_sub(k0);
            // In range: checked in the loop above, and p ≤ 2^36.
            let r = a.wrapping_sub(a0).wrapping_sub(p.wrapping_mul(x) >> Q);
            lo = lo.min(r);
            hi = hi.max(r);
        }
        let spread = hi.saturating_sub(lo);
        if s.period_b == 0 {
            s.env = arrival;
        }
        s.period_b = p;
        self.period_b = p;
        // About two standard deviations of the slope: the residuals' spread (some
        // four deviations of the minima) over the span, times sqrt(12 / n) ≈ 1.
        s.period_b_err = q(spread.saturating_add(1))
            .checked_div(x_max.max(1).saturating_mul(2))
            .unwrap_or(i64::MAX);
    }

    /// Latency from the `TM` anchor and the scan phase, intersected over scans.
    #[inline(never)]
    fn calibrate(&mut self, s: &Stream) {
        let Some(tm) = self.tm else { return };
        if s.period_s <= 0 || s.period_b <= 0 || s.scans < WARMUP_SCANS {
            return;
        }
        // Bridge time of the scan's start interval: the anchor carried by the sensor
        // µs between them, scaled by bridge/sensor period (the drift). In `i64`: the
        // anchor at most ANCHOR_MAX_US away, the periods' ratio within 2^-8 of 1 and
        // taken as a Q30 difference (|ratio − 1| · 2^30 < 2^22), so `ds × ratio` stays
        // below 2^58; the periods at most MAX_PERIOD_Q (below 2^37).
        let ds = s.phase.lo.saturating_sub(tm.sensor_us);
        if ds.saturating_abs() > ANCHOR_MAX_US
            || s.period_s > MAX_PERIOD_Q
            || s.period_b > MAX_PERIOD_Q
        {
            return;
        }
        // Both periods are positive and at most 2^36 (the fit's bound for `period_b`):
        // plain arithmetic within the ranges above.
        let diff = s.period_b.wrapping_sub(s.period_s);
        if diff.wrapping_abs() > s.period_s >> 8 {
            return;
        }
        let ratio = diff.wrapping_shl(30).checked_div(s.period_s).unwrap_or(0);
        let ds_b = ds.wrapping_add(ds.wrapping_mul(ratio) >> 30);
        let start = Span {
            lo: tm.bridge.lo.saturating_add(ds_b),
            hi: tm
                .bridge
                .hi
                .saturating_add(ds_b)
                .saturating_add(s.phase.width()),
        };
        // What the period's error does over the distance to the anchor (a product that
        // saturates is far wider than any valid span).
        let extra = ds
            .saturating_abs()
            .saturating_mul(s.period_s_err.saturating_add(s.period_b_err))
            .checked_div(s.period_s)
            .unwrap_or(i64::MAX);
        let here = Span {
            lo: s.env.saturating_sub(start.hi).saturating_sub(extra),
            hi: s.env.saturating_sub(start.lo).saturating_add(extra),
        };
        // Only scans whose start is known well enough calibrate; the value follows
        // them smoothed (the envelope wanders by tens of µs with the jitter).
        if here.width() > VALID_SPAN_US {
            return;
        }
        let mid = here.mid();
        self.latency = Some(match self.latency {
            // Scans about as well placed as the best so far refine it; worse ones
            // (farther from the anchor, in a wider interval) leave it.
            Some((l, w)) if here.width() <= w.saturating_add(SPAN_SLACK_US) => (
                l.saturating_add(mid.saturating_sub(l) / 8),
                w.min(here.width()),
            ),
            Some(kept) if here.width() > kept.1 => kept,
            _ => (mid, here.width()),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A sensor in bridge µs: scans start at `t0 + k × period`; its clock reads
    /// `sigma + t × (1 + ppm / 10^6)` µs; a scan's line arrives `latency + jitter`
    /// after its start.
    struct Truth {
        sigma: i128,
        ppm: i128,
        period: i128,
        t0: i128,
        latency: i128,
        jitter: u64,
        rng: u64,
    }

    impl Truth {
        fn sensor_us(&self, t: i128) -> i128 {
            self.sigma + t + t * self.ppm / 1_000_000
        }
        fn stamp_ms(&self, t: i128) -> u64 {
            self.sensor_us(t).div_euclid(1000) as u64
        }
        fn noise(&mut self) -> u64 {
            self.rng = self
                .rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            if self.jitter == 0 {
                0
            } else {
                (self.rng >> 33) % (self.jitter + 1)
            }
        }
        /// 16 TM1 reads at odd spacing from `t`, 150 µs round trips.
        fn tm(&mut self, clock: &mut ScanClock, t: i128) {
            for i in 0..16 {
                let sent = t + i * 1370;
                let recv = sent + 150;
                clock.on_tm(self.stamp_ms(sent + 75), sent as u64, recv as u64);
            }
        }
        /// Scan `k`: its true start and the model's estimate.
        fn scan(&mut self, clock: &mut ScanClock, k: i128) -> (i128, Estimate) {
            let t = self.t0 + k * self.period;
            let arrival = t + self.latency + i128::from(self.noise());
            (t, clock.on_scan(self.stamp_ms(t), arrival as u64))
        }
    }

    fn truth(ppm: i128, jitter: u64) -> Truth {
        Truth {
            sigma: 123_456_789,
            ppm,
            period: 25_000,
            t0: 1_000_000,
            latency: 25_300,
            jitter,
            rng: 42,
        }
    }

    /// Errors (µs) of the valid scans among `from..to` (40 a second), sorted, and how
    /// many were not valid.
    fn errors(ppm: i128, jitter: u64, from: i128, to: i128) -> (Vec<i128>, usize) {
        let mut tr = truth(ppm, jitter);
        let mut c = ScanClock::new();
        tr.tm(&mut c, 500_000);
        let mut errs = Vec::new();
        let mut invalid = 0;
        for k in 0..to {
            let (t, e) = tr.scan(&mut c, k);
            if k >= from {
                if e.valid {
                    errs.push((i128::from(e.time_us) - t).abs());
                } else {
                    invalid += 1;
                }
            }
        }
        errs.sort();
        (errs, invalid)
    }

    fn p99(errs: &[i128]) -> i128 {
        errs[errs.len() * 99 / 100]
    }

    /// The sub-millisecond phase needs the scans to cross millisecond boundaries of
    /// the sensor's clock twice after the TM (1 ms of drift each): at ±100 ppm and a
    /// 25 ms period that is some 10-20 s. Until then the estimate is not valid; once
    /// valid, it holds to a third of a millisecond (p99; the worst within 0.5 ms).
    #[test]
    fn bounded_error_with_drift_and_jitter() {
        for ppm in [-100, 55, 100] {
            for jitter in [0, 1000, 2000] {
                let (e, invalid) = errors(ppm, jitter, 0, 4800);
                let what = format!("{ppm} ppm, jitter {jitter} µs");
                assert!(invalid <= 1000, "{what}: {invalid} scans not valid");
                assert!(p99(&e) <= 300, "{what}: p99 {} µs", p99(&e));
                assert!(e[e.len() - 1] <= 500, "{what}: worst {} µs", e[e.len() - 1]);
            }
        }
        // A slow drift takes longer to calibrate; valid or not, never wrong.
        for jitter in [0, 1000, 2000] {
            let (e, _) = errors(-37, jitter, 0, 4800);
            assert!(e.is_empty() || p99(&e) <= 300, "-37 ppm, jitter {jitter}");
        }
    }

    #[test]
    fn a_sensor_restart_keeps_the_latency_and_reconverges() {
        let mut tr = truth(100, 2000);
        let mut c = ScanClock::new();
        tr.tm(&mut c, 500_000);
        for k in 0..1200 {
            tr.scan(&mut c, k);
        }
        // Reboot: the clock restarts near 0 (it read 3.3 s at the next scan), the motor
        // at a new phase.
        tr.t0 += 3_333_333;
        tr.sigma = 3_300_000 - (tr.t0 + 1200 * 25_000);
        let mut last = 0;
        for k in 1200..2000 {
            let (t, e) = tr.scan(&mut c, k);
            assert!(e.time_us > last);
            last = e.time_us;
            // Valid again within 2 s, and right.
            if k >= 1280 {
                assert!(e.valid, "scan {k}");
                let err = (i128::from(e.time_us) - t).abs();
                assert!(err <= 300, "scan {k}: {} vs {t}", e.time_us);
            }
        }
        assert_eq!(c.resets(), 1);
    }

    #[test]
    fn without_tm_the_estimate_is_not_valid() {
        let mut tr = truth(50, 1000);
        let mut c = ScanClock::new();
        for k in 0..200 {
            assert!(!tr.scan(&mut c, k).1.valid);
        }
    }

    proptest! {
        #[test]
        fn output_never_goes_back_and_never_overflows(
            steps in proptest::collection::vec((0u64..=1u64 << 33, 0u64..=u64::MAX, 0u8..4), 1..200),
        ) {
            let mut c = ScanClock::new();
            let mut last = None;
            for (ms, arrival, tm) in steps {
                match tm {
                    0 => c.on_tm(ms, arrival, arrival.saturating_add(100)),
                    1 => c.sensor_restarted(),
                    _ => {}
                }
                let e = c.on_scan(ms, arrival);
                if let Some(l) = last {
                    prop_assert!(e.time_us > l);
                }
                last = Some(e.time_us);
            }
        }

        #[test]
        fn a_long_run_past_2_pow_32_ms_stays_monotonic(start in 0u64..1 << 32, ppm in -200i128..200) {
            let mut tr = truth(ppm, 2000);
            tr.sigma = i128::from(start) * 1000;
            let mut c = ScanClock::new();
            tr.tm(&mut c, 0);
            let mut last = 0;
            for k in 0..300 {
                let e = tr.scan(&mut c, k).1;
                prop_assert!(e.time_us > last);
                last = e.time_us;
            }
        }
    }
}
