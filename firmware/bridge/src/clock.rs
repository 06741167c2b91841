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
//!    intersect. With the narrowest scan start of (1) and the two periods (drift =
//!    ratio of the periods) this places that scan's start in bridge time and gives
//!    `L` = envelope (carried back to that scan) − start. A start is narrow right
//!    after the scans crossed one of the sensor's millisecond ticks; the anchor must
//!    be near it (the drift's uncertainty grows with the distance), so the model then
//!    asks for a fresh `TM` ([`ScanClock::wants_tm`]; the bridge stops the stream for
//!    it, a few scans). One crossing suffices: at ±100 ppm and 25 ms a scan the
//!    scans cross a tick within 10 s, whatever the phase (without the fresh `TM`, a
//!    second crossing is needed: up to 20 s). A clock without drift against a whole
//!    millisecond period never crosses: the estimate then stays not valid.
//!    `L` belongs to the sensor and its scan rate, not to its clock: it survives a
//!    reboot or `RS` of the sensor, after which the envelope alone places scans again.
//!
//! The estimate of a scan's start is `envelope − L`. It is `valid` once `L` is known
//! to [`VALID_SPAN_US`] and the envelope has seen [`WARMUP_SCANS`] scans. Published
//! times never go backwards: each is at least the previous valid one plus 1 µs.
//!
//! Resets: [`ScanClock::sensor_restarted`] (reboot, `RS`; also detected from a stamp
//! that goes back) drops the phase and the envelope but keeps `L`; a changed scan
//! period (stamps that no longer fit) drops `L` and the bridge period too (the next
//! crossing and a fresh `TM` calibrate them again, within seconds).
//!
//! Arithmetic: 32-bit. Times are `u32` µs that wrap (the bridge's clock and the
//! sensor's, its stamps times 1000), compared only through their differences, which
//! the model keeps within ±2^30 µs (about 18 minutes): marks and a `TM` anchor farther
//! from the latest scan are dropped, and two scans more than [`GAP_MAX_MS`] apart
//! start a new stream. Periods are µs × 2^8 in `i32`. The few products that need 64
//! bits go through one helper (`mul_div`); the least-squares fit sums in `i64`.
//! Fixed memory (a few hundred bytes), no floating point, no 128-bit arithmetic;
//! every operation saturating, or wrapping where its ranges are checked first.

/// Scans per block of the period fit.
pub const BLOCK: u32 = 32;
/// Blocks kept for the period fit (the slope spans up to this many blocks).
const BLOCKS: usize = 16;
/// How far a delayed sample lifts the envelope per scan, µs.
pub const CREEP_US: i32 = 2;
/// Envelope scans before an estimate is valid.
pub const WARMUP_SCANS: u32 = 2 * BLOCK;
/// Width of the latency interval below which the estimate is valid, µs.
pub const VALID_SPAN_US: i32 = 600;
/// A latency interval this much wider than the best one still refines it, µs.
const SPAN_SLACK_US: i32 = 64;
/// `TM1` answers intersected for one calibration.
pub const TM_SAMPLES: u8 = 24;
/// A scan start known this narrowly (µs, sensor time) while the latency is not:
/// the model asks for a fresh `TM` ([`ScanClock::wants_tm`]).
pub const NARROW_US: i32 = 200;
/// A `TM` anchor farther than this from a narrow scan start (sensor µs) is stale for
/// the calibration: the drift's uncertainty over the distance is too wide.
pub const TM_FRESH_US: i32 = 1_000_000;
/// Fresh `TM` exchanges the model asks for per stream of the sensor's clock.
pub const TM_ASKS: u8 = 2;
/// `TM1` answers this far apart (sensor ms) belong to different exchanges.
const TM_EXCHANGE_MS: u32 = 500;
/// Fixed-point shift of the periods (µs × 2^8).
const Q: u32 = 8;
/// 1 µs in the periods' fixed point.
const ONE_Q: i32 = 1 << Q;
/// Longest scan period the model follows, Q8 (2^20 µs: about 1.05 s a scan).
const MAX_PERIOD_Q: i32 = 1 << 28;
/// The period fit takes block minima up to this many scans apart.
const FIT_MAX_SCANS: u32 = 1 << 11;
/// The period fit takes block minima up to this many µs apart (about 18 minutes).
const FIT_MAX_US: u32 = 1 << 30;
/// Marks and `TM` anchors this far (µs) from the latest scan are dropped: every
/// distance the model takes between two times stays within ±2^31 µs.
const ANCHOR_MAX_US: i32 = 1 << 30;
/// The same, in the sensor's ms (a little less).
const ANCHOR_MAX_MS: u32 = 1 << 20;
/// Two scans this far apart (sensor ms, about 9 minutes) or farther: the stream
/// stopped for long; the next scan starts a new one (the latency stays).
pub const GAP_MAX_MS: u32 = 1 << 19;

/// A scan's estimated start in the bridge's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Estimate {
    /// Start of the scan, bridge µs (never less than the previous valid estimate + 1).
    pub time_us: u64,
    /// The model is calibrated and converged (a `TM` gave the latency, the envelope
    /// has enough scans); otherwise `time_us` is the arrival envelope alone.
    pub valid: bool,
}

/// `a − b` of two wrapping µs times within ±2^31 µs of each other.
fn diff(a: u32, b: u32) -> i32 {
    a.wrapping_sub(b) as i32
}

/// A closed interval of wrapping µs, at most 2^30 µs wide.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Span {
    lo: u32,
    hi: u32,
}

impl Span {
    fn width(self) -> i32 {
        diff(self.hi, self.lo)
    }
    fn mid(self) -> u32 {
        self.lo.wrapping_add((self.width() / 2) as u32)
    }
    fn shift(self, d: i32) -> Self {
        Span {
            lo: self.lo.wrapping_add_signed(d),
            hi: self.hi.wrapping_add_signed(d),
        }
    }
    #[inline(never)]
    fn intersect(self, o: Span) -> Option<Span> {
        let s = Span {
            lo: if diff(o.lo, self.lo) > 0 {
                o.lo
            } else {
                self.lo
            },
            hi: if diff(o.hi, self.hi) < 0 {
                o.hi
            } else {
                self.hi
            },
        };
        (s.width() >= 0).then_some(s)
    }
}

/// `a × b / c` rounded, in 64 bits, saturated to `i32`; `i32::MAX` when `c` is 0.
/// The model's one out-of-line product: periods times scan counts, µs over periods.
#[inline(never)]
fn mul_div(a: i32, b: i32, c: i32) -> i32 {
    // |a × b| ≤ 2^62 and |c / 2| < 2^31: neither the product nor the sum wraps.
    let p = i64::from(a)
        .wrapping_mul(i64::from(b))
        .wrapping_add(i64::from(c / 2));
    p.checked_div(i64::from(c)).map_or(i32::MAX, |r| {
        r.clamp(i32::MIN.into(), i32::MAX.into()) as i32
    })
}

/// A period (Q8) times a scan count, µs.
fn mul_q(period: i32, n: i32) -> i32 {
    mul_div(period, n, ONE_Q)
}

/// µs over a scan count, Q8.
fn div_q(us: i32, n: i32) -> i32 {
    mul_div(us, ONE_Q, n)
}

/// The current stream of the sensor's clock (since its last restart).
#[derive(Debug, Clone, Copy)]
struct Stream {
    /// Stamp (sensor ms, low 32 bits) and scan index of the last scan.
    last_ms: u32,
    k: u32,
    /// Start of the last scan, sensor µs.
    phase: Span,
    /// First scan's index and start interval (the period fit's reference).
    reference: Mark,
    /// The narrowest start seen since the reference.
    best: Mark,
    /// Sensor µs per scan, Q8; 0 until two scans were seen.
    period_s: i32,
    /// Uncertainty of `period_s`, Q8.
    period_s_err: i32,
    /// Arrival envelope of scan `k`, bridge µs.
    env: u32,
    /// Bridge µs per scan, Q8 (0 until the block fit has data, unless the last
    /// stream left one).
    period_b: i32,
    /// Uncertainty of `period_b`, Q8.
    period_b_err: i32,
    /// Scans seen in this stream.
    scans: u32,
    /// Minima (scan index, arrival) of the detrended arrivals of the last blocks, a
    /// ring; `blocks_len` valid, `blocks_head` next to write.
    blocks: [(u32, u32); BLOCKS],
    blocks_len: usize,
    blocks_head: usize,
    /// The block being filled: its number and minimum (index, arrival).
    block: u32,
    block_min: Option<(u32, u32)>,
    /// Fresh `TM` exchanges asked for in this stream.
    tm_asks: u8,
    /// Scans the envelope has been carried by `period_b` (it settles onto the lowest
    /// arrivals over [`WARMUP_SCANS`]).
    env_scans: u32,
    /// Arrival of the stream's first scan, bridge µs (a coarse bridge period before
    /// the fit has one).
    first_arrival: u32,
}

/// `TM1` answers of one calibration: bridge time of sensor time `ms` (low 32 bits
/// of the extended ms).
#[derive(Debug, Clone, Copy)]
struct Tm {
    ms: u32,
    bridge: Span,
    samples: u8,
}

impl Tm {
    /// The anchor's sensor time, wrapping µs.
    fn sensor_us(&self) -> u32 {
        self.ms.wrapping_mul(1000)
    }
}

/// The sensor clock model ([module docs](self)).
#[derive(Debug, Clone)]
pub struct ScanClock {
    stream: Option<Stream>,
    tm: Option<Tm>,
    /// Latency from a scan's start to its timestamp line's arrival envelope, µs, and
    /// the width of the interval of the last calibration that moved it.
    latency: Option<(i32, i32)>,
    /// Bridge µs per scan (Q8) of the last stream: the motor keeps its rate across a
    /// restart of the sensor's clock.
    period_b: i32,
    /// The last valid estimate (the floor of the next ones).
    last_out: Option<u64>,
    resets: u32,
}

impl Default for ScanClock {
    fn default() -> Self {
        Self::new()
    }
}

/// A scan's index and its start interval, sensor µs.
#[derive(Debug, Clone, Copy)]
struct Mark {
    k: u32,
    phase: Span,
}

/// The period (Q8) and its uncertainty between the starts of scans `a` and `b`; the
/// uncertainty is `i32::MAX` (no period) unless `b` comes after `a`.
#[inline(never)]
fn pair(a: &Mark, b: &Mark) -> (i32, i32) {
    let dk = b.k.wrapping_sub(a.k) as i32;
    if dk <= 0 {
        return (0, i32::MAX);
    }
    // Phases are stamps narrowed (at most 999 µs wide), at most 2^30 µs apart.
    let span = diff(b.phase.mid(), a.phase.mid());
    let err = div_q(b.phase.width().saturating_add(a.phase.width()) / 2, dk);
    (div_q(span, dk), err)
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
        let s = self.stream.as_ref()?;
        if s.period_s == 0 || s.period_b == 0 || s.blocks_len < 2 {
            return None;
        }
        let diff = s.period_s.saturating_sub(s.period_b);
        Some(mul_div(diff, 1_000_000_000, s.period_b).into())
    }

    /// Whether the latency is calibrated (a `TM` and enough scans).
    pub fn calibrated(&self) -> bool {
        self.latency.is_some()
    }

    /// A `TM1` answer: the sensor's clock read `sensor_ms` (extended, same base as the
    /// scans' stamps) between `sent_us` (request's last byte out) and `recv_us`
    /// (answer's timestamp line in), bridge µs. Answers of one exchange intersect; an
    /// answer that contradicts the ones before, or comes more than half a second after
    /// them, starts a new anchor. The latency stays: it belongs to the sensor and its
    /// scan rate, which a `TM` does not change.
    #[inline(never)]
    pub fn on_tm(&mut self, sensor_ms: u64, sent_us: u64, recv_us: u64) {
        let sent = sent_us as u32;
        let ms = sensor_ms as u32;
        // The clock showed `sensor_ms` at some bridge time in [sent, recv]; it turned
        // to that millisecond up to 1000 µs before. (A round trip beyond 2^29 µs is
        // cut there, one that seems to go back is none: such a span is far too wide
        // to calibrate anyway, and `recv` before `sent` is no answer of that request.)
        let trip = ((recv_us as u32).wrapping_sub(sent) as i32).clamp(0, 1 << 29) as u32;
        let here = Span {
            lo: sent.wrapping_sub(1000),
            hi: sent.wrapping_add(trip),
        };
        let merged = self.tm.and_then(|tm| {
            // Back-to-back answers: the drift over their few ms is far below 1 µs.
            let apart = ms.wrapping_sub(tm.ms);
            if apart > TM_EXCHANGE_MS {
                return None;
            }
            let both = tm
                .bridge
                .shift((apart as i32).wrapping_mul(1000))
                .intersect(here)?;
            Some(Tm {
                ms,
                bridge: both,
                samples: tm.samples.saturating_add(1),
            })
        });
        self.tm = Some(merged.unwrap_or(Tm {
            ms,
            bridge: here,
            samples: 1,
        }));
    }

    /// Whether a fresh `TM` exchange would calibrate the latency now: a scan's start
    /// is known to [`NARROW_US`] in sensor time (the scans just crossed one of the
    /// sensor's millisecond ticks), the latency is not known, and the anchor is
    /// missing or more than [`TM_FRESH_US`] away (with the anchor far, the drift's
    /// uncertainty would need a second crossing, up to 1 ms / drift later: 10 s at
    /// 100 ppm). At most [`TM_ASKS`] a stream; the caller runs the exchange (the
    /// stream stops for it) and calls [`ScanClock::tm_requested`].
    pub fn wants_tm(&self) -> bool {
        let Some(s) = self.stream.as_ref() else {
            return false;
        };
        // The cheap tests first: this runs after every scan.
        if self.latency.is_some()
            || s.tm_asks >= TM_ASKS
            || s.period_s <= 0
            || s.best.k != s.k
            || s.best.phase.width() > NARROW_US
        {
            return false;
        }
        let stale = self
            .tm
            .is_none_or(|tm| diff(s.best.phase.lo, tm.sensor_us()).saturating_abs() > TM_FRESH_US);
        // Only a clock that runs at about the bridge's rate (within 2^-8, as the
        // calibration needs) is worth a TM: before the fit, the mean arrival period
        // stands in for the bridge period (2 ms of jitter over the stream's scans).
        let k = s.k as i32;
        let sensor = mul_q(s.period_s, 1);
        let bridge = if s.period_b > 0 {
            mul_q(s.period_b, 1)
        } else {
            mul_div(diff(s.env, s.first_arrival), 1, k)
        };
        let slack = (sensor >> 8).saturating_add(mul_div(2000, 1, k));
        stale && bridge.saturating_sub(sensor).saturating_abs() <= slack
    }

    /// The caller asked the sensor for a `TM` exchange ([`ScanClock::wants_tm`]): the
    /// old anchor is dropped, the answers make a new one.
    pub fn tm_requested(&mut self) {
        if let Some(s) = self.stream.as_mut() {
            s.tm_asks = s.tm_asks.saturating_add(1);
        }
        self.tm = None;
    }

    /// Whether a calibration has its answers ([`TM_SAMPLES`]).
    pub fn tm_complete(&self) -> bool {
        self.tm.is_some_and(|t| t.samples >= TM_SAMPLES)
    }

    /// A scan: its stamp `sensor_ms` (extended sensor ms) and the bridge time its
    /// timestamp line ended arriving, µs. Returns the estimated start of the scan.
    #[inline(never)]
    pub fn on_scan(&mut self, sensor_ms: u64, arrival_us: u64) -> Estimate {
        let ms = sensor_ms as u32;
        // An anchor this far away is dropped before its distance could wrap.
        if self
            .tm
            .is_some_and(|t| diff(ms, t.ms).unsigned_abs() > ANCHOR_MAX_MS)
        {
            self.tm = None;
        }
        let arrival = arrival_us as u32;
        let lo = ms.wrapping_mul(1000);
        let stamp = Span {
            lo,
            hi: lo.wrapping_add(999),
        };
        let step = match self.stream.as_mut() {
            Some(s) => s.advance(ms, stamp, arrival),
            None => Step::Next,
        };
        match step {
            Step::Next => {}
            // The clock went back (or stood still across two scans, or the stream
            // stopped for long): a restart.
            Step::Restart => self.sensor_restarted(),
            // The scans no longer follow the period: a new rate (or a restart the
            // stamps hide). The latency and the bridge period belonged to the old rate.
            Step::NewRate => {
                self.latency = None;
                self.period_b = 0;
                self.sensor_restarted();
            }
        }
        let period_b = self.period_b;
        let s = self
            .stream
            .get_or_insert_with(|| Stream::start(ms, stamp, arrival, period_b));
        s.scans = s.scans.saturating_add(1);
        s.fit_blocks(arrival);
        // The bridge period outlives the stream (the fit sets both).
        self.period_b = s.period_b;
        calibrate(self.tm.as_ref(), &mut self.latency, s);
        let s = &*s;
        let warm = s.scans >= WARMUP_SCANS && s.period_b != 0;
        let (time, valid) = match self.latency {
            Some((l, _)) => (s.env.wrapping_sub(l as u32), warm),
            None => (s.env, false),
        };
        // Back in the bridge's 64-bit clock: the envelope is near the arrival.
        let time = arrival_us.saturating_add_signed(diff(time, arrival).into());
        let out = match self.last_out {
            Some(last) => time.max(last.saturating_add(1)),
            None => time,
        };
        // Only valid estimates are published: they set the floor. (An envelope without
        // the latency lies some 25 ms later than the scan's start; as a floor it would
        // hold back the first valid estimates.)
        if valid {
            self.last_out = Some(out);
        }
        Estimate {
            time_us: out,
            valid,
        }
    }
}

/// How a scan continued the stream ([`Stream::advance`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// The scan follows the stream.
    Next,
    /// The sensor's clock went back (or stood still across two scans, or the stream
    /// stopped for [`GAP_MAX_MS`]): a restart.
    Restart,
    /// The stamp does not fit the period: a new scan rate (or a hidden restart).
    NewRate,
}

impl Stream {
    /// A stream starting with a scan of stamp `stamp` arriving at `arrival`.
    fn start(ms: u32, stamp: Span, arrival: u32, period_b: i32) -> Self {
        let first = Mark { k: 0, phase: stamp };
        Stream {
            last_ms: ms,
            k: 0,
            phase: stamp,
            reference: first,
            best: first,
            period_s: 0,
            period_s_err: 0,
            env: arrival,
            period_b,
            period_b_err: 0,
            scans: 0,
            blocks: [(0, 0); BLOCKS],
            blocks_len: 0,
            blocks_head: 0,
            block: 0,
            block_min: None,
            tm_asks: 0,
            env_scans: 0,
            first_arrival: arrival,
        }
    }

    /// Carries the stream to a new scan, unless the stamp does not fit it (the
    /// sensor restarted or its period changed).
    fn advance(&mut self, ms: u32, stamp: Span, arrival: u32) -> Step {
        let s = self;
        let dms = ms.wrapping_sub(s.last_ms);
        if dms.wrapping_sub(1) >= GAP_MAX_MS - 1 {
            return Step::Restart;
        }
        // Below 2^19 ms: the µs fit `i32`.
        let dus = dms.wrapping_mul(1000) as i32;
        let (n, predicted) = if s.period_s == 0 {
            // Second scan: taken as the next one.
            (1, stamp)
        } else {
            let n = div_q(dus, s.period_s).max(1);
            // The period's uncertainty over `n` scans, twice, and 2 µs of rounding;
            // capped far above any stamp (a wider span is no prediction).
            let err = mul_div(s.period_s_err, n, ONE_Q / 2)
                .clamp(0, 1 << 28)
                .wrapping_add(2);
            let p = s.phase.shift(mul_q(s.period_s, n));
            (
                n,
                Span {
                    lo: p.lo.wrapping_sub(err as u32),
                    hi: p.hi.wrapping_add(err as u32),
                },
            )
        };
        let Some(phase) = predicted.intersect(stamp) else {
            return Step::NewRate;
        };
        s.k = s.k.wrapping_add(n as u32);
        s.last_ms = ms;
        s.phase = phase;
        // Period in sensor µs between the reference start and this one, and between
        // the narrowest start seen and this one: the narrower pair becomes the
        // reference (two narrow starts many scans apart pin the period to a fraction
        // of a µs). Marks more than 2^30 µs back leave for this scan.
        let now = Mark { k: s.k, phase };
        if phase.width() < s.best.phase.width() || diff(phase.lo, s.best.phase.lo) > ANCHOR_MAX_US {
            s.best = now;
        }
        if diff(phase.lo, s.reference.phase.lo) > ANCHOR_MAX_US {
            s.reference = s.best;
        }
        // The lower uncertainty wins (`i32::MAX`: no period).
        let better = |a: (i32, i32), b: (i32, i32)| if b.1 < a.1 { b } else { a };
        let from_ref = pair(&s.reference, &now);
        let from_best = pair(&s.best, &now);
        let ref_best = pair(&s.reference, &s.best);
        if from_best.1 < from_ref.1 {
            s.reference = s.best;
        }
        let (p, err) = better(better(from_ref, from_best), ref_best);
        if err < i32::MAX {
            s.period_s = p;
            s.period_s_err = err;
        }
        if s.period_b == 0 {
            // No bridge period yet: the envelope cannot be carried; it is the arrival.
            s.env = arrival;
            return Step::Next;
        }
        // Envelope: a sample below it is the truth so far, one above it lifts it a
        // little (and one beyond 2^30 µs: the bridge's clock jumped, it starts over).
        let predicted_env = s.env.wrapping_add(mul_q(s.period_b, n) as u32);
        s.env_scans = s.env_scans.saturating_add(n as u32);
        let late = diff(arrival, predicted_env);
        let lift = if late > ANCHOR_MAX_US {
            late
        } else {
            late.min(CREEP_US.saturating_mul(n))
        };
        s.env = predicted_env.wrapping_add(lift as u32);
        Step::Next
    }

    /// Block minima of the arrivals and the bridge period from their slope.
    #[inline(never)]
    fn fit_blocks(&mut self, arrival: u32) {
        let s = self;
        let block = s.k / BLOCK;
        if block != s.block {
            if let Some(min) = s.block_min.take() {
                if let Some(slot) = s.blocks.get_mut(s.blocks_head) {
                    *slot = min;
                }
                s.blocks_head = s.blocks_head.wrapping_add(1) % BLOCKS;
                s.blocks_len = s.blocks_len.wrapping_add(1).min(BLOCKS);
                s.fit_period(arrival);
            }
            s.block = block;
        }
        // Minimum of arrival − k × period (the detrended arrival), kept as (k,
        // arrival): the kept one stays unless this one lies lower.
        let trend = if s.period_b != 0 {
            s.period_b
        } else {
            s.period_s
        };
        let k = s.k;
        s.block_min = Some(match s.block_min {
            Some(m) if diff(arrival, m.1) >= mul_q(trend, k.wrapping_sub(m.0) as i32) => m,
            _ => (k, arrival),
        });
    }

    /// Least-squares slope of the block minima: the bridge period, and from how far
    /// the minima stray from it, its uncertainty.
    ///
    /// The points are taken relative to the first, `|x|` (scans) below
    /// [`FIT_MAX_SCANS`] and `|y|` (µs) below [`FIT_MAX_US`], else the fit waits for
    /// better points. With n ≤ 16 points `n·Σx²` and `(Σx)²` stay below 2^30 (`i32`),
    /// `n·Σxy` and `Σx·Σy` below 2^50 (`i64`), so the slope in Q8 is one division.
    fn fit_period(&mut self, arrival: u32) {
        let s = self;
        if s.blocks_len < 4 {
            return;
        }
        let pts = s.blocks.get(..s.blocks_len).unwrap_or(&[]);
        let Some(&(k0, a0)) = pts.first() else {
            return;
        };
        let (mut n, mut sx, mut sxx, mut x_lo, mut x_hi) = (0i32, 0i32, 0i32, 0i32, 0i32);
        let (mut sy, mut sxy) = (0i64, 0i64);
        for &(k, a) in pts {
            let x = k.wrapping_sub(k0) as i32;
            let y = diff(a, a0);
            if x.unsigned_abs() >= FIT_MAX_SCANS || y.unsigned_abs() >= FIT_MAX_US {
                return;
            }
            x_lo = x_lo.min(x);
            x_hi = x_hi.max(x);
            n = n.wrapping_add(1);
            sx = sx.wrapping_add(x);
            sxx = sxx.wrapping_add(x.wrapping_mul(x));
            sy = sy.wrapping_add(y.into());
            sxy = sxy.wrapping_add(i64::from(x).wrapping_mul(y.into()));
        }
        let num = i64::from(n)
            .wrapping_mul(sxy)
            .wrapping_sub(i64::from(sx).wrapping_mul(sy));
        let den = n.wrapping_mul(sxx).wrapping_sub(sx.wrapping_mul(sx));
        if den <= 0 || num <= 0 {
            return;
        }
        let p = (num << Q).checked_div(den.into()).unwrap_or(0);
        if p > i64::from(MAX_PERIOD_Q) {
            return;
        }
        let p = p as i32;
        // Spread of the residuals about the line (its intercept cancels out).
        let (mut lo, mut hi) = (i32::MAX, i32::MIN);
        for &(k, a) in pts {
            let r = diff(a, a0).wrapping_sub(mul_q(p, k.wrapping_sub(k0) as i32));
            lo = lo.min(r);
            hi = hi.max(r);
        }
        let spread = hi.saturating_sub(lo);
        if s.period_b == 0 {
            s.env = arrival;
            s.env_scans = 0;
        }
        s.period_b = p;
        // About two standard deviations of the slope: the residuals' spread (some
        // four deviations of the minima) over the span, times sqrt(12 / n) ≈ 1.
        s.period_b_err = mul_div(
            spread.saturating_add(1),
            ONE_Q,
            x_hi.wrapping_sub(x_lo).wrapping_mul(2),
        );
    }
}

/// Latency from the `TM` anchor and the scan phase, intersected over scans.
fn calibrate(tm: Option<&Tm>, latency: &mut Option<(i32, i32)>, s: &Stream) {
    let Some(tm) = tm else { return };
    if s.period_s <= 0
        || s.period_b <= 0
        || s.period_s > MAX_PERIOD_Q
        || s.period_b > MAX_PERIOD_Q
        || s.scans < WARMUP_SCANS
        || s.env_scans < 2 * WARMUP_SCANS
    {
        return;
    }
    // The narrowest start of the stream (where the scans crossed a millisecond
    // tick of the sensor's clock), and the envelope carried back to it.
    let dk = s.k.wrapping_sub(s.best.k) as i32;
    // Bridge time of the scan's start interval: the anchor carried by the sensor
    // µs between them, scaled by bridge/sensor period (the drift). The anchor and
    // the mark are within 2^30 µs of the latest scan, so `ds` fits; the periods
    // within 2^-8 of each other, so the drift's correction is below 2^22 µs.
    let ds = diff(s.best.phase.lo, tm.sensor_us());
    if ds.saturating_abs() > ANCHOR_MAX_US {
        return;
    }
    // Both periods are positive and at most 2^28: no overflow.
    let dp = s.period_b.wrapping_sub(s.period_s);
    if dp.abs() > s.period_s >> 8 {
        return;
    }
    let ds_b = ds.wrapping_add(mul_div(ds, dp, s.period_s));
    let start_lo = tm.bridge.lo.wrapping_add(ds_b as u32);
    let start_hi = tm
        .bridge
        .hi
        .wrapping_add(ds_b as u32)
        .wrapping_add(s.best.phase.width() as u32);
    let env = s.env.wrapping_sub(mul_q(s.period_b, dk) as u32);
    // What the period's error does over the distance to the anchor (a product that
    // saturates is far wider than any valid span).
    let extra = mul_div(
        ds.saturating_abs(),
        s.period_s_err.saturating_add(s.period_b_err),
        s.period_s,
    )
    .saturating_add(mul_q(s.period_b_err, dk));
    let lo = diff(env, start_hi).saturating_sub(extra);
    let hi = diff(env, start_lo).saturating_add(extra);
    let width = hi.saturating_sub(lo);
    // Only scans whose start is known well enough calibrate; the value follows
    // them smoothed (the envelope wanders by tens of µs with the jitter).
    if !(0..=VALID_SPAN_US).contains(&width) {
        return;
    }
    let mid = lo.wrapping_add(width / 2);
    *latency = Some(match *latency {
        // Scans about as well placed as the best so far refine it; worse ones
        // (farther from the anchor, in a wider interval) leave it.
        Some((l, w)) if width <= w.saturating_add(SPAN_SLACK_US) => {
            (l.saturating_add(mid.saturating_sub(l) / 8), w.min(width))
        }
        Some(kept) if width > kept.1 => kept,
        _ => (mid, width),
    });
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

    /// A stream of `scans` scans from 1 s on (a TM at 0.5 s) from a sensor whose clock
    /// is `phase_us` past one of its ticks; the bridge runs a TM exchange whenever the
    /// model asks for one (the stream stops for it: 8 scans missed). Returns the index
    /// of the first valid scan and the errors (µs) of the valid ones from 10 s on.
    fn stream(ppm: i128, jitter: u64, phase_us: i128, scans: i128) -> (Option<i128>, Vec<i128>) {
        let mut tr = truth(ppm, jitter);
        tr.sigma += phase_us;
        tr.rng = phase_us as u64;
        let mut c = ScanClock::new();
        tr.tm(&mut c, 500_000);
        let mut errs = Vec::new();
        let mut first = None;
        let mut k = 0;
        while k < scans {
            let (t, e) = tr.scan(&mut c, k);
            if e.valid {
                first = first.or(Some(k));
                if k * tr.period >= 10_000_000 {
                    errs.push((i128::from(e.time_us) - t).abs());
                }
            }
            k += 1;
            if c.wants_tm() {
                c.tm_requested();
                tr.tm(&mut c, t + 30_000);
                k += 8;
            }
        }
        errs.sort();
        (first, errs)
    }

    /// At ±100 ppm the scans cross a millisecond tick of the sensor's clock within
    /// 1 ms / (25 ms × 100 ppm) = 400 scans (10 s); a TM right after pins the latency.
    /// Whatever the phase of the sensor's ticks, the estimate is valid by 11 s and,
    /// from 10 s on, within 0.3 ms of the truth (all of it, not only the p99).
    #[test]
    fn valid_by_eleven_seconds_at_100_ppm_whatever_the_phase() {
        for ppm in [-100, 100] {
            for jitter in [0, 1000, 2000] {
                for phase in (0..1000).step_by(50) {
                    let what = format!("{ppm} ppm, jitter {jitter} µs, phase {phase} µs");
                    let (first, e) = stream(ppm, jitter, phase, 800);
                    let first = first.unwrap_or(i128::MAX);
                    assert!(first <= 440, "{what}: first valid scan {first}");
                    assert!(e.len() >= 340, "{what}: {} valid scans", e.len());
                    assert!(e[e.len() - 1] <= 300, "{what}: worst {} µs", e[e.len() - 1]);
                }
            }
        }
    }

    /// A slow drift crosses a tick later (0 ppm with a whole-millisecond period:
    /// never), so the estimate is valid later or never; valid, it is never wrong.
    #[test]
    fn a_slow_drift_is_valid_later_but_never_wrong() {
        for ppm in [-37, -30, 0, 30, 55] {
            for jitter in [0, 2000] {
                for phase in (0..1000).step_by(100) {
                    let (_, e) = stream(ppm, jitter, phase, 2000);
                    let worst = e.last().copied().unwrap_or(0);
                    assert!(
                        worst <= 300,
                        "{ppm} ppm, jitter {jitter}, phase {phase}: {worst} µs"
                    );
                }
            }
        }
        // 0 ppm: the scans keep their phase to the ticks: not valid, honestly.
        assert_eq!(stream(0, 1000, 500, 2000).0, None);
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

    /// The motor slows from 25 ms to 27.777 ms a scan mid-stream (and a scan's line
    /// comes later after its start): the latency of the old rate is void at once, the
    /// model asks for a TM at the next crossing of a tick (at once: 27 777 µs is no
    /// whole millisecond) and is valid again, right, within 6 s. Published times never
    /// go back, and no estimate is wrong on the way.
    #[test]
    fn a_changed_scan_rate_recalibrates() {
        let mut tr = truth(100, 2000);
        let mut c = ScanClock::new();
        tr.tm(&mut c, 500_000);
        let (mut k, mut last, mut valid_after) = (0, 0, None);
        let change = 600;
        while k < 1000 {
            if k == change {
                tr.t0 -= change * 2_777;
                tr.period = 27_777;
                tr.latency = 28_100;
            }
            let (t, e) = tr.scan(&mut c, k);
            assert!(e.time_us > last, "scan {k}");
            if e.valid {
                last = e.time_us;
                let err = (i128::from(e.time_us) - t).abs();
                assert!(err <= 300, "scan {k}: {err} µs");
                if k >= change {
                    valid_after = valid_after.or(Some(k));
                }
            } else {
                assert!(k < 440 || k >= change, "scan {k} not valid");
            }
            k += 1;
            if c.wants_tm() {
                c.tm_requested();
                tr.tm(&mut c, t + 30_000);
                k += 8;
            }
        }
        let again = valid_after.map(|v| (v - change) * 27_777);
        assert!(
            again.is_some_and(|us| us <= 6_000_000),
            "valid again after {again:?} µs"
        );
        assert_eq!(c.resets(), 1);
    }

    /// The model keeps its times as 32-bit µs that wrap: a bridge clock that passes
    /// 2^32 µs (71.6 min) mid-stream, or runs far beyond it, changes nothing: valid
    /// by 11 s, within 0.3 ms of the truth from 10 s on, never going back.
    #[test]
    fn the_bridge_clock_past_2_pow_32_us() {
        for t0 in [(1i128 << 32) - 8_000_000, 5 << 40, (1 << 33) - 20_000_000] {
            let mut tr = truth(100, 2000);
            tr.t0 = t0;
            let mut c = ScanClock::new();
            tr.tm(&mut c, t0 - 500_000);
            let (mut k, mut last, mut first) = (0, 0, None);
            while k < 800 {
                let (t, e) = tr.scan(&mut c, k);
                if e.valid {
                    assert!(e.time_us > last, "t0 {t0}, scan {k}");
                    last = e.time_us;
                    first = first.or(Some(k));
                    if k >= 400 {
                        let err = (i128::from(e.time_us) - t).abs();
                        assert!(err <= 300, "t0 {t0}, scan {k}: {err} µs");
                    }
                }
                k += 1;
                if c.wants_tm() {
                    c.tm_requested();
                    tr.tm(&mut c, t + 30_000);
                    k += 8;
                }
            }
            assert!(first.is_some_and(|f| f <= 440), "t0 {t0}: first {first:?}");
        }
    }

    /// A stream that stops for longer than [`GAP_MAX_MS`] starts over (a reset) and
    /// keeps the latency: valid again within 2 s of its return, and right.
    #[test]
    fn a_long_pause_starts_a_new_stream() {
        let mut tr = truth(100, 2000);
        let mut c = ScanClock::new();
        tr.tm(&mut c, 500_000);
        for k in 0..800 {
            tr.scan(&mut c, k);
        }
        assert!(c.calibrated());
        // 20 minutes without scans (the motor and both clocks run on).
        let pause = 48_000;
        for k in 800 + pause..800 + pause + 200 {
            let (t, e) = tr.scan(&mut c, k);
            if k >= 800 + pause + 80 {
                assert!(e.valid, "scan {k}");
                let err = (i128::from(e.time_us) - t).abs();
                assert!(err <= 300, "scan {k}: {err} µs");
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
        /// Arbitrary stamps, arrivals, `TM` answers and restarts: no panic, and the
        /// valid estimates only go forward (every estimate lies past the last valid).
        #[test]
        fn output_never_goes_back_and_never_overflows(
            steps in proptest::collection::vec((0u64..=1u64 << 33, 0u64..=u64::MAX, 0u8..5), 1..200),
        ) {
            let mut c = ScanClock::new();
            let mut last = None;
            for (ms, arrival, tm) in steps {
                match tm {
                    0 => c.on_tm(ms, arrival, arrival.saturating_add(100)),
                    1 => c.sensor_restarted(),
                    2 if c.wants_tm() => c.tm_requested(),
                    _ => {}
                }
                let e = c.on_scan(ms, arrival);
                if let Some(l) = last {
                    prop_assert!(e.time_us > l);
                }
                if e.valid {
                    last = Some(e.time_us);
                }
            }
        }

        /// A sensor's stamps (its extended clock anywhere up to 2^33 ms, so streams
        /// run across 2^32 ms) with arbitrary arrival times: no panic, valid estimates
        /// only go forward.
        #[test]
        fn real_stamps_with_arbitrary_arrivals(
            start in 0u64..1 << 33,
            arrivals in proptest::collection::vec(0u64..=u64::MAX, 1..300),
        ) {
            let tr = truth(100, 0);
            let mut c = ScanClock::new();
            let mut last = None;
            for (k, arrival) in arrivals.into_iter().enumerate() {
                let t = tr.t0 + k as i128 * tr.period;
                let e = c.on_scan(start + tr.stamp_ms(t), arrival);
                if c.wants_tm() {
                    c.tm_requested();
                }
                if let Some(l) = last {
                    prop_assert!(e.time_us > l);
                }
                if e.valid {
                    last = Some(e.time_us);
                }
            }
        }

        /// Long streams from anywhere on the extended clock (across 2^32 ms), any drift
        /// within ±1000 ppm, TMs when asked: valid estimates go forward and, at 100 to
        /// 300 ppm either way, come within 0.3 ms of the truth (at ±1000 ppm the
        /// latency's interval is near its 0.6 ms limit: a few tens of µs more).
        #[test]
        fn a_long_run_past_2_pow_32_ms_stays_monotonic(
            start in 0u64..1 << 33,
            ppm in -1000i128..1000,
        ) {
            let mut tr = truth(ppm, 2000);
            tr.sigma = i128::from(start) * 1000;
            let mut c = ScanClock::new();
            tr.tm(&mut c, 500_000);
            let mut last = 0;
            let mut k = 0;
            while k < 800 {
                let (t, e) = tr.scan(&mut c, k);
                if e.valid {
                    prop_assert!(e.time_us > last);
                    last = e.time_us;
                    if (100..=300).contains(&ppm.abs()) {
                        prop_assert!((i128::from(e.time_us) - t).abs() <= 300);
                    }
                }
                k += 1;
                if c.wants_tm() {
                    c.tm_requested();
                    tr.tm(&mut c, t + 30_000);
                    k += 8;
                }
            }
        }
    }
}
