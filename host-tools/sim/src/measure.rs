//! From echoes to SCIP values: range noise, held values, limits and error codes, and
//! the second channel of each data set (paper §3).
//!
//! - Received power falls with distance squared: `INTENSITY_AT_1M × reflectance ×
//!   fraction / d²` (d in metres). Echoes weaker than [`WEAK_INTENSITY`] are not
//!   measured; the aux value (GI/MI) is this power × 64, 24 bits.
//! - The intensity (GE/ME) is what the real units send: nearly independent of range
//!   (the UTM-30LX capture reads about 2 400 from 0.05 to 6 m):
//!   `INTENSITY_SCALE × reflectance × fraction × max(d, 0.1 m)^-0.2`, 18 bits.
//! - The reflection coefficient (GR/MR) is the surface's reflectance relative to white
//!   paper, × 256: it does not depend on distance. 12 bits.
//! - Echoes nearer than DMIN, farther than DMAX, too weak or outside AMIN..AMAX become
//!   the model family's error codes; 2-char values (GS/MS) over 4095 become 4095.
//! - Noise ([`Noise`]): a normal range error whose σ grows with range, a chance per
//!   step of repeating the step before (real units send runs of equal values), and a
//!   normal intensity error relative to the intensity. Every draw is a function of
//!   (seed, scan, step): the same scan is the same bytes whatever was asked before.

use scip::DataSet;

use super::model::{Model, Noise};
use super::scene::{Echo, Scene};

/// Received power of a white-paper target at 1 m, full beam.
pub const INTENSITY_AT_1M: f64 = 20_000.0;
/// Echoes of less received power than this are not measured (weak-echo error code).
pub const WEAK_INTENSITY: f64 = 1.0;
/// The intensity (GE/ME) of a white-paper target at 1 m, full beam.
pub const INTENSITY_SCALE: f64 = 3_500.0;
/// How the intensity falls with range: `d^-INTENSITY_RANGE_EXPONENT`.
pub const INTENSITY_RANGE_EXPONENT: f64 = 0.2;
/// Longest run of steps that repeat one value.
pub const MAX_HOLD: u32 = 8;

/// One echo as sent: distance (mm or error code) and the second channel.
pub type Value = (u32, u32);

/// What a simulated sensor measures: the values of one step of one scan.
pub trait Source: Send {
    /// Pushes the echoes of `step` in scan number `scan` onto `out` (cleared first),
    /// nearest first, at least one. `t_s` is the scene time of the step in seconds.
    fn step(
        &mut self,
        model: &Model,
        scan: u64,
        t_s: f64,
        step: u32,
        data: DataSet,
        out: &mut Vec<Value>,
    );
}

/// A seeded scene with noise.
#[derive(Debug, Clone)]
pub struct SceneSource {
    /// The world.
    pub scene: Scene,
    /// Seed of the noise.
    pub seed: u64,
    /// The noise ([`Noise::EXACT`] = the scene's exact values).
    pub noise: Noise,
    echoes: Vec<Echo>,
}

/// What a draw is for (one independent stream of draws each).
#[derive(Debug, Clone, Copy)]
enum Draw {
    Range = 0,
    Intensity = 1,
    Hold = 2,
}

impl SceneSource {
    /// A source over `scene` with `noise` seeded by `seed`.
    pub fn new(scene: Scene, seed: u64, noise: Noise) -> Self {
        Self {
            scene,
            seed,
            noise,
            echoes: Vec::new(),
        }
    }

    /// The generator of one draw for (scan, step, echo): the same inputs always give the
    /// same numbers, whatever was asked before.
    fn rng(&self, what: Draw, scan: u64, step: u32, echo: usize) -> fastrand::Rng {
        let key = self
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(scan.wrapping_mul(0xD1B5_4A32_D192_ED03))
            .wrapping_add((what as u64).wrapping_mul(0xA24B_AED4_963E_E407))
            .wrapping_add(u64::from(step) << 2 | echo as u64);
        fastrand::Rng::with_seed(key)
    }

    /// One standard normal sample for (what, scan, step, echo).
    fn normal(&self, what: Draw, scan: u64, step: u32, echo: usize) -> f64 {
        let mut rng = self.rng(what, scan, step, echo);
        // Box–Muller.
        let u1 = rng.f64().max(1e-12);
        let u2 = rng.f64();
        (-2.0 * u1.ln()).sqrt() * (core::f64::consts::TAU * u2).cos()
    }

    /// The range error in mm of an echo at `distance_mm` for (scan, step, echo).
    fn noise(&self, scan: u64, step: u32, echo: usize, distance_mm: f64) -> f64 {
        let sigma = self.noise.sigma_at(distance_mm);
        if sigma <= 0.0 {
            return 0.0;
        }
        sigma * self.normal(Draw::Range, scan, step, echo)
    }

    /// The factor on the intensity of (scan, step, echo): 1 + a normal error.
    fn intensity_factor(&self, scan: u64, step: u32, echo: usize) -> f64 {
        if self.noise.intensity <= 0.0 {
            return 1.0;
        }
        (1.0 + self.noise.intensity * self.normal(Draw::Intensity, scan, step, echo)).max(0.0)
    }

    /// The step whose value `step` sends: itself, or the step before when it repeats
    /// it (and so on, at most [`MAX_HOLD`] steps back, never before `first`).
    fn source_step(&self, scan: u64, step: u32, first: u32) -> u32 {
        if self.noise.hold <= 0.0 {
            return step;
        }
        let mut src = step;
        while src > first
            && step - src < MAX_HOLD
            && self.rng(Draw::Hold, scan, src, 0).f64() < self.noise.hold
        {
            src -= 1;
        }
        src
    }
}

/// The value of one echo for `data`, or `None` when it cannot be measured (the caller
/// then sends the error code `code`). `noise_mm` is added to the range, the intensity
/// is multiplied by `intensity_factor` (1 = exact).
pub fn echo_value(
    model: &Model,
    echo: &Echo,
    noise_mm: f64,
    intensity_factor: f64,
    data: DataSet,
) -> Result<Value, u32> {
    let d_mm = (echo.distance_mm + noise_mm).round();
    let d_m = (d_mm / 1000.0).max(0.05);
    let power = INTENSITY_AT_1M * echo.reflectance * echo.fraction / (d_m * d_m);
    if d_mm < f64::from(model.dmin) {
        return Err(model.too_near_code());
    }
    if d_mm > f64::from(model.dmax) {
        return Err(model.no_echo_code());
    }
    if power < WEAK_INTENSITY {
        return Err(model.weak_code());
    }
    let intensity = INTENSITY_SCALE
        * echo.reflectance
        * echo.fraction
        * d_m.max(0.1).powf(-INTENSITY_RANGE_EXPONENT)
        * intensity_factor;
    let aux = match data {
        DataSet::Distance | DataSet::ShortDistance => 0.0,
        DataSet::DistanceIntensity => intensity.min(f64::from((1u32 << 18) - 1)),
        DataSet::DistanceReflectance => (256.0 * echo.reflectance).min(4095.0),
        DataSet::DistanceAux => (power * 64.0).min(f64::from((1u32 << 24) - 1)),
    };
    let mut d = d_mm as u32;
    if data == DataSet::ShortDistance {
        d = d.min(4095);
    }
    Ok((d, aux.round() as u32))
}

impl Source for SceneSource {
    fn step(
        &mut self,
        model: &Model,
        scan: u64,
        t_s: f64,
        step: u32,
        data: DataSet,
        out: &mut Vec<Value>,
    ) {
        out.clear();
        if step < model.amin || step > model.amax {
            out.push((model.no_echo_code(), 0));
            return;
        }
        // A held step sends the range of the step it repeats (its angle and its range
        // noise); its intensity noise is its own, as in the captures.
        let src = self.source_step(scan, step, model.amin);
        let width = core::f64::consts::TAU / f64::from(model.ares);
        let mut echoes = core::mem::take(&mut self.echoes);
        self.scene
            .echoes(model.angle(f64::from(src)), width, t_s, &mut echoes);
        let mut first_error = None;
        for (i, e) in echoes.iter().enumerate() {
            let noise = self.noise(scan, src, i, e.distance_mm);
            let factor = self.intensity_factor(scan, step, i);
            match echo_value(model, e, noise, factor, data) {
                Ok(v) => out.push(v),
                Err(code) => {
                    first_error.get_or_insert(code);
                }
            }
        }
        self.echoes = echoes;
        if out.is_empty() {
            out.push((first_error.unwrap_or(model.no_echo_code()), 0));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{ModelKind, Noise};

    #[test]
    fn power_falls_with_distance_squared_and_intensity_barely() {
        let m = Model::new(ModelKind::Utm30lx);
        let at = |d: f64| Echo {
            distance_mm: d,
            reflectance: 1.0,
            fraction: 1.0,
        };
        let e = DataSet::DistanceIntensity;
        // 3500 × d^-0.2: 3500, 3500 / 2^0.2 = 3046.9, 3500 / 10^0.2 = 2208.4.
        assert_eq!(echo_value(&m, &at(1000.0), 0.0, 1.0, e), Ok((1000, 3500)));
        assert_eq!(echo_value(&m, &at(2000.0), 0.0, 1.0, e), Ok((2000, 3047)));
        assert_eq!(
            echo_value(&m, &at(10_000.0), 0.0, 1.0, e),
            Ok((10_000, 2208))
        );
        assert_eq!(echo_value(&m, &at(1000.0), 0.0, 1.02, e), Ok((1000, 3570)));
        // White paper is 256 at any distance.
        let r = DataSet::DistanceReflectance;
        assert_eq!(echo_value(&m, &at(1000.0), 0.0, 1.0, r), Ok((1000, 256)));
        assert_eq!(echo_value(&m, &at(9000.0), 0.0, 1.0, r), Ok((9000, 256)));
        assert_eq!(
            echo_value(&m, &at(2000.0), 0.0, 1.0, DataSet::DistanceAux),
            Ok((2000, 320_000))
        );
        // Limits and codes.
        assert_eq!(echo_value(&m, &at(10.0), 0.0, 1.0, e), Err(2));
        assert_eq!(echo_value(&m, &at(61_000.0), 0.0, 1.0, e), Err(1));
        assert_eq!(
            echo_value(&m, &at(5000.0), 0.0, 1.0, DataSet::ShortDistance),
            Ok((4095, 0))
        );
        let dark = Echo {
            distance_mm: 50_000.0,
            reflectance: 0.02,
            fraction: 1.0,
        };
        assert_eq!(echo_value(&m, &dark, 0.0, 1.0, e), Err(1));
    }

    #[test]
    fn noise_is_deterministic_and_sized() {
        let s = SceneSource::new(Scene::empty(), 5, Noise::constant(10.0));
        assert_eq!(s.noise(3, 100, 0, 1000.0), s.noise(3, 100, 0, 1000.0));
        assert_ne!(s.noise(3, 100, 0, 1000.0), s.noise(4, 100, 0, 1000.0));
        let n = 4000;
        let sigma = |s: &SceneSource, d: f64| {
            let var: f64 = (0..n).map(|i| s.noise(i, 7, 0, d).powi(2)).sum::<f64>() / n as f64;
            var.sqrt()
        };
        assert!((sigma(&s, 1000.0) - 10.0).abs() < 1.0);
        // σ = 1 + 2 mm per metre: 3 mm at 1 m, 9 mm at 4 m.
        let grows = Noise {
            sigma_mm: 1.0,
            sigma_per_m: 2.0,
            hold: 0.0,
            intensity: 0.05,
        };
        let g = SceneSource::new(Scene::empty(), 5, grows);
        assert!((sigma(&g, 1000.0) - 3.0).abs() < 0.3);
        assert!((sigma(&g, 4000.0) - 9.0).abs() < 0.9);
        let var: f64 = (0..n)
            .map(|i| (g.intensity_factor(i, 7, 0) - 1.0).powi(2))
            .sum::<f64>()
            / n as f64;
        assert!((var.sqrt() - 0.05).abs() < 0.005);
        let exact = SceneSource::new(Scene::empty(), 5, Noise::EXACT);
        assert_eq!(exact.noise(3, 100, 0, 5000.0), 0.0);
        assert_eq!(exact.intensity_factor(3, 100, 0), 1.0);
    }

    #[test]
    fn held_steps_repeat_the_step_before_exactly() {
        let m = Model::new(ModelKind::Utm30lx);
        let noise = Noise {
            sigma_mm: 1000.0,
            sigma_per_m: 0.0,
            hold: 0.3,
            intensity: 0.0,
        };
        // A wall at 20 m with σ 1 m: two values not held are equal only by a rare chance.
        let mut s = SceneSource::new(Scene::wall(20_000.0, 0.8), 9, noise);
        let mut a = Vec::new();
        let mut b = Vec::new();
        let (mut held, mut steps, mut run, mut longest) = (0, 0, 1, 1);
        for step in 301..=467 {
            s.step(&m, 2, 0.0, step - 1, DataSet::Distance, &mut a);
            s.step(&m, 2, 0.0, step, DataSet::Distance, &mut b);
            steps += 1;
            let same = s.source_step(2, step, m.amin) == s.source_step(2, step - 1, m.amin);
            assert_eq!(a == b, same, "step {step}: {a:?} {b:?}");
            if same {
                held += 1;
                run += 1;
                longest = longest.max(run);
            } else {
                run = 1;
            }
        }
        assert!(longest <= MAX_HOLD);
        // About 30 % held.
        assert!(
            (held as f64 / steps as f64 - 0.3).abs() < 0.1,
            "{held} of {steps}"
        );
        // The same scan again, in another order: the same values.
        let mut again = Vec::new();
        s.step(&m, 2, 0.0, 400, DataSet::Distance, &mut again);
        s.step(&m, 2, 0.0, 399, DataSet::Distance, &mut a);
        s.step(&m, 2, 0.0, 400, DataSet::Distance, &mut b);
        assert_eq!(again, b);
    }

    #[test]
    fn steps_outside_the_field_are_no_echo() {
        let m = Model::new(ModelKind::Urg04lx);
        let mut s = SceneSource::new(Scene::wall(1000.0, 1.0), 1, Noise::EXACT);
        let mut out = Vec::new();
        s.step(&m, 0, 0.0, 10, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(0, 0)]);
        s.step(&m, 0, 0.0, 384, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(1000, 0)]);
    }
}
