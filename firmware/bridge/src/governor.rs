//! The bandwidth governor: keeps the bridge inside its share of the CAN bus.
//!
//! - [`Governor::plan`] picks the angular decimation (and, if even the coarsest is too
//!   much, a temporal decimation) that keeps the *average* load under the budget, from the
//!   worst-case bus time of a scan (bit stuffing included, `can_wire::bandwidth`).
//! - [`Governor::admit`] decides at the start of each scan whether it may be sent: a
//!   token bucket of bus time (refilled at `share` of real time, capped at two scans'
//!   worth) must hold the scan's whole worst-case cost, and the transmit queue must be
//!   able to take every frame of the scan that the bus cannot drain while the scan's
//!   bytes are still arriving on the UART. Otherwise the scan is dropped whole — never
//!   half — and counted. The decision is made once, before the first frame, so the UART
//!   path never waits for the bus.
//!
//! The lossless coding `DL` costs what the scene makes it cost, so for it the governor
//! plans and admits with **real costs**: an estimate of the stream's bits per point,
//! learnt from the scans sent ([`Governor::observe`]: a running average, ¾ old + ¼ new;
//! before the first scan a prior of 10 bits per distance and 14 per intensity), with a
//! margin of 1/8. When a scan compresses worse than expected, the bus time it took beyond
//! its admission is charged as a **debt** ([`Governor::settle`]): following scans are
//! dropped whole until the share has paid it back, so the average load never exceeds the
//! share; one scan exceeds its admitted cost by at most the difference to the coding's
//! worst case (`can_wire::bandwidth::lossless_cost` with no estimate), which is D16's
//! cost plus 7 bits per block of 16 points. [`GovernorStats::over_estimate`] counts such
//! scans. The engine re-plans the decimation when the estimate moves by more than 1/8
//! from the one its plan used ([`Governor::replan_due`]).

use can_wire::bandwidth::{lossless_cost, scan_cost, BitRates, ScanCost};
use can_wire::{Encoding, FrameFormat};

/// Largest angular decimation the governor will choose.
pub const MAX_FACTOR: u8 = 16;

/// The bus and the bridge's share of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Budget {
    /// Bit rates of the bus.
    pub rates: BitRates,
    /// Classic or FD frames.
    pub format: FrameFormat,
    /// 29-bit identifiers.
    pub extended: bool,
    /// Share of the bus the bridge may use, in parts per thousand (1..=1000).
    pub share_permille: u16,
}

/// What the governor chose for a stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Plan {
    /// Angular decimation factor (1 = every point).
    pub factor: u8,
    /// Send every n-th scan (1 = every scan).
    pub every_nth: u8,
    /// Points per sent scan.
    pub points: u16,
    /// Worst-case cost of one sent scan.
    pub cost: ScanCost,
    /// Average worst-case bus load, parts per million.
    pub load_ppm: u64,
}

/// Counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GovernorStats {
    /// Scans admitted.
    pub admitted: u32,
    /// Scans dropped because the bus-time budget was spent.
    pub dropped_budget: u32,
    /// Scans dropped because the transmit queue could not take them.
    pub dropped_queue: u32,
    /// Lossless scans that took more bus time than they were admitted with.
    pub over_estimate: u32,
}

/// Prior bits per point ×16 of the lossless coding before any scan was seen: distance.
pub const PRIOR_DISTANCE_X16: u32 = 10 * 16;
/// Prior bits per point ×16 of the lossless coding: intensity.
pub const PRIOR_INTENSITY_X16: u32 = 14 * 16;

/// The governor. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Governor {
    budget: Budget,
    /// Bus time credit, ns.
    credit_ns: u64,
    last_ms: Option<u64>,
    /// Bus time owed by scans that took more than admitted, ns.
    debt_ns: u64,
    /// The lossless coding's bits per point ×16 learnt from the scans sent.
    estimate_x16: Option<u32>,
    /// The estimate the last plan used.
    planned_x16: Option<u32>,
    stats: GovernorStats,
}

impl Governor {
    /// A governor for `budget`; a zero share is taken as 1 ‰, above 1000 as 1000.
    pub fn new(budget: Budget) -> Self {
        Self {
            budget: Budget {
                share_permille: budget.share_permille.clamp(1, 1000),
                ..budget
            },
            credit_ns: 0,
            last_ms: None,
            debt_ns: 0,
            estimate_x16: None,
            planned_x16: None,
            stats: GovernorStats::default(),
        }
    }

    /// The budget.
    pub fn budget(&self) -> &Budget {
        &self.budget
    }

    /// Counters.
    pub fn stats(&self) -> &GovernorStats {
        &self.stats
    }

    /// Bits per point ×16 the governor plans a lossless scan with: the estimate (or
    /// the prior) and a margin of 1/8.
    pub fn planning_bits_x16(&self, encoding: &Encoding) -> u32 {
        // Two small constants.
        let prior = PRIOR_DISTANCE_X16.wrapping_add(if encoding.intensity.is_present() {
            PRIOR_INTENSITY_X16
        } else {
            0
        });
        let e = self.estimate_x16.unwrap_or(prior);
        e.saturating_add(e / 8)
    }

    /// The cost of a scan of `points` points: worst case for the fixed-width encodings,
    /// the planning estimate for the lossless coding.
    pub fn cost(&self, points: u16, encoding: &Encoding) -> ScanCost {
        if encoding.distance.is_lossless() {
            return lossless_cost(
                points,
                encoding,
                Some(self.planning_bits_x16(encoding)),
                self.budget.format,
                self.budget.extended,
                self.budget.rates,
            );
        }
        scan_cost(
            points,
            encoding,
            self.budget.format,
            self.budget.extended,
            self.budget.rates,
        )
    }

    /// The smallest decimation (angular first, then temporal) whose average load fits the
    /// share, for scans of `points` points at `scans_per_s_milli` / 1000 scans per second.
    /// When even the coarsest does not fit, the coarsest is returned (its load says so).
    pub fn plan(&mut self, points: u16, encoding: &Encoding, scans_per_s_milli: u32) -> Plan {
        self.planned_x16 = encoding
            .distance
            .is_lossless()
            .then(|| self.planning_bits_x16(encoding));
        let limit = u64::from(self.budget.share_permille) * 1000;
        let mut best = None;
        for every_nth in 1..=u8::MAX {
            // `every_nth` is 1..=255.
            let rate = scans_per_s_milli
                .checked_div(u32::from(every_nth))
                .unwrap_or(0);
            for factor in 1..=MAX_FACTOR {
                let n = points.div_ceil(u16::from(factor));
                let cost = self.cost(n, encoding);
                let plan = Plan {
                    factor,
                    every_nth,
                    points: n,
                    cost,
                    load_ppm: cost.load_ppm(rate),
                };
                best = Some(plan);
                if plan.load_ppm <= limit {
                    return plan;
                }
            }
        }
        // Unreachable in practice (one scan in 255 always fits); keep the coarsest.
        best.unwrap_or(Plan {
            factor: MAX_FACTOR,
            every_nth: u8::MAX,
            points,
            cost: self.cost(points, encoding),
            load_ppm: u64::MAX,
        })
    }

    /// Decides, at the start of a scan, whether it is sent.
    ///
    /// `cost` is the scan's worst-case cost, `uart_us` the time its bytes take to arrive
    /// on the UART, `queue_free` the free frames of the transmit queue now.
    pub fn admit(&mut self, now_ms: u64, cost: &ScanCost, uart_us: u64, queue_free: usize) -> bool {
        self.refill(now_ms, cost);
        if self.debt_ns > 0 || self.credit_ns < cost.time_ns {
            self.stats.dropped_budget = self.stats.dropped_budget.wrapping_add(1);
            return false;
        }
        // Frames the bus carries (at our share) while the scan is still arriving.
        let frame_ns = cost
            .time_ns
            .checked_div(u64::from(cost.frames.max(1)))
            .unwrap_or(0);
        // `uart_us` comes from the caller: saturating.
        let share_ns = uart_us
            .saturating_mul(1000)
            .saturating_mul(u64::from(self.budget.share_permille))
            / 1000;
        let drained = share_ns.checked_div(frame_ns.max(1)).unwrap_or(0) as usize;
        let frames = cost.frames as usize;
        if frames > queue_free.saturating_add(drained) {
            self.stats.dropped_queue = self.stats.dropped_queue.wrapping_add(1);
            return false;
        }
        // `credit_ns >= cost.time_ns` here.
        self.credit_ns = self.credit_ns.wrapping_sub(cost.time_ns);
        self.stats.admitted = self.stats.admitted.wrapping_add(1);
        true
    }

    /// A lossless scan sent: `points` points took `stream_bytes` bytes of segment stream.
    /// Updates the estimate of the coding's bits per point.
    pub fn observe(&mut self, points: u16, stream_bytes: u32) {
        if points == 0 {
            return;
        }
        // A u32 × 128 fits 64 bits; `points > 0`.
        let x = u32::try_from(
            u64::from(stream_bytes)
                .wrapping_mul(128)
                .checked_div(u64::from(points))
                .unwrap_or(0),
        )
        .unwrap_or(u32::MAX);
        self.estimate_x16 = Some(match self.estimate_x16 {
            None => x,
            // u32 values in 64 bits: no overflow, and the mean of four fits a u32.
            Some(e) => (u64::from(e).wrapping_mul(3).wrapping_add(u64::from(x)) / 4) as u32,
        });
    }

    /// A scan admitted with `admitted` cost took `actual` bus time: what it took beyond
    /// its admission is spent from the credit, the rest owed as debt.
    pub fn settle(&mut self, admitted: &ScanCost, actual: &ScanCost) {
        let extra = actual.time_ns.saturating_sub(admitted.time_ns);
        if extra == 0 {
            return;
        }
        self.stats.over_estimate = self.stats.over_estimate.wrapping_add(1);
        let paid = extra.min(self.credit_ns);
        // `paid` is at most both `credit_ns` and `extra`.
        self.credit_ns = self.credit_ns.wrapping_sub(paid);
        self.debt_ns = self.debt_ns.saturating_add(extra.wrapping_sub(paid));
    }

    /// Bus time owed, ns.
    pub fn debt_ns(&self) -> u64 {
        self.debt_ns
    }

    /// Whether the lossless estimate moved by more than 1/8 from the one the last plan
    /// used.
    pub fn replan_due(&self, encoding: &Encoding) -> bool {
        match self.planned_x16 {
            Some(p) if encoding.distance.is_lossless() => {
                self.planning_bits_x16(encoding).abs_diff(p) > p / 8
            }
            _ => false,
        }
    }

    fn refill(&mut self, now_ms: u64, cost: &ScanCost) {
        let cap = cost.time_ns.saturating_mul(2);
        match self.last_ms {
            None => self.credit_ns = cap,
            Some(last) => {
                let dt_ms = now_ms.saturating_sub(last);
                let mut add = dt_ms
                    .saturating_mul(1_000_000)
                    .saturating_mul(u64::from(self.budget.share_permille))
                    / 1000;
                let repay = add.min(self.debt_ns);
                // `repay` is at most both.
                self.debt_ns = self.debt_ns.wrapping_sub(repay);
                add = add.wrapping_sub(repay);
                self.credit_ns = self.credit_ns.saturating_add(add).min(cap);
            }
        }
        self.last_ms = Some(now_ms);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use can_wire::{DistanceEncoding, IntensityEncoding};

    const D12: Encoding = Encoding {
        distance: DistanceEncoding::D12,
        intensity: IntensityEncoding::None,
        unit_exp: 0,
    };

    fn classic(share: u16) -> Governor {
        Governor::new(Budget {
            rates: BitRates::CLASSIC_1M,
            format: FrameFormat::Classic,
            extended: false,
            share_permille: share,
        })
    }

    #[test]
    fn urg04lx_full_resolution_fits_a_quarter_of_classic_1m() {
        let mut g = classic(250);
        let plan = g.plan(682, &D12, 10_000);
        assert_eq!((plan.factor, plan.every_nth), (1, 1));
        assert!(plan.load_ppm <= 250_000, "{plan:?}");
    }

    #[test]
    fn a_small_share_decimates_then_skips_scans() {
        let mut g = classic(100);
        let plan = g.plan(682, &D12, 10_000);
        assert!(plan.factor > 1 && plan.every_nth == 1, "{plan:?}");
        assert!(plan.load_ppm <= 100_000);
        // The factor is the smallest that fits.
        let finer = g.cost(682u16.div_ceil(u16::from(plan.factor - 1)), &D12);
        assert!(finer.load_ppm(10_000) > 100_000);

        // 40 Hz UTM-30LX in 1 ‰ of a classic bus: even 1/16 of the points does not fit,
        // so scans are skipped too.
        let mut g = classic(1);
        let plan = g.plan(1081, &D12, 40_000);
        assert_eq!(plan.factor, MAX_FACTOR);
        assert!(plan.every_nth > 1 && plan.load_ppm <= 1000, "{plan:?}");
    }

    #[test]
    fn admission_spends_and_refills_bus_time() {
        let mut g = classic(250);
        let cost = g.cost(682, &D12);
        // 682 points * 3 bytes at 19200 bit/s ≈ 1.07 s of UART time: plenty of drain.
        assert!(g.admit(0, &cost, 1_000_000, 8));
        assert!(g.admit(0, &cost, 1_000_000, 8));
        // Two scans' credit spent: the third at the same instant is dropped whole.
        assert!(!g.admit(0, &cost, 1_000_000, 8));
        assert_eq!(g.stats().dropped_budget, 1);
        // A quarter of the bus refills one scan's cost in 4 × its bus time.
        let wait_ms = (cost.time_ns * 4).div_ceil(1_000_000);
        assert!(g.admit(wait_ms, &cost, 1_000_000, 8));
        assert_eq!(g.stats().admitted, 3);
    }

    #[test]
    fn admission_needs_queue_room_for_what_the_bus_cannot_drain() {
        let mut g = classic(1000);
        let cost = g.cost(682, &D12);
        // Bytes arriving instantly (a replay at full speed): the queue must hold it all.
        assert!(!g.admit(0, &cost, 0, cost.frames as usize - 1));
        assert_eq!(g.stats().dropped_queue, 1);
        assert!(g.admit(0, &cost, 0, cost.frames as usize));
    }

    #[test]
    fn a_lossless_scan_dearer_than_planned_is_paid_back_by_dropping_whole_scans() {
        let dl = Encoding {
            distance: DistanceEncoding::Lossless,
            intensity: IntensityEncoding::None,
            unit_exp: 0,
        };
        let mut g = classic(500);
        // Prior: 10 bits per point, margin 1/8: planned at 11.25 bits (180 / 16).
        assert_eq!(g.planning_bits_x16(&dl), 160 + 20);
        let planned = g.cost(682, &dl);
        assert!(g.admit(0, &planned, 1_000_000, 64));
        // It took twice the bus time it was admitted with.
        let actual = ScanCost {
            time_ns: planned.time_ns * 2,
            ..planned
        };
        g.settle(&planned, &actual);
        assert_eq!(g.stats().over_estimate, 1);
        // The bucket started with two scans' worth: the admission spent one, the extra
        // takes the other; nothing is owed, but the next scan finds no credit.
        assert_eq!(g.debt_ns(), 0);
        assert!(!g.admit(0, &planned, 1_000_000, 64));
        // Twice more than planned again: now a debt, and scans are dropped until the
        // share has paid it back (at 50 % of the bus: twice the debt in time).
        g.settle(
            &planned,
            &ScanCost {
                time_ns: planned.time_ns * 3,
                ..planned
            },
        );
        let debt = g.debt_ns();
        assert!(debt > 0);
        let repaid_ms = (debt * 2).div_ceil(1_000_000);
        assert!(!g.admit(repaid_ms - 1, &planned, 1_000_000, 64));
        assert!(g.admit(
            repaid_ms + (planned.time_ns * 2).div_ceil(1_000_000),
            &planned,
            1_000_000,
            64
        ));
        // What was learnt: 682 points in 600 bytes are 7.04 bits (112 / 16); the plan
        // follows (margin 1/8: 126).
        g.observe(682, 600);
        assert_eq!(g.planning_bits_x16(&dl), 112 + 14);
    }

    #[test]
    fn a_huge_uart_time_saturates_instead_of_overflowing() {
        let mut g = classic(250);
        let cost = g.cost(682, &D12);
        // Bytes that take (nearly) forever to arrive: the bus drains every frame
        // meanwhile, so the scan needs no free slot at all.
        assert!(g.admit(0, &cost, u64::MAX, 0));
        assert_eq!(g.stats().dropped_queue, 0);
    }
}
