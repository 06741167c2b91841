//! From echoes to SCIP values: range noise, limits and error codes, and the second
//! channel of each data set (paper §3).
//!
//! - Received power falls with distance squared: intensity (GE/ME) =
//!   `INTENSITY_AT_1M × reflectance × fraction / d²` (d in metres), 18 bits.
//! - The reflection coefficient (GR/MR) is the surface's reflectance relative to white
//!   paper, × 256: it does not depend on distance. 12 bits.
//! - The aux value (GI/MI) is the received power at 64 × the intensity scale, 24 bits.
//! - Echoes nearer than DMIN, farther than DMAX, too weak or outside AMIN..AMAX become
//!   the model family's error codes; 2-char values (GS/MS) over 4095 become 4095.

use scip::DataSet;

use super::model::Model;
use super::scene::{Echo, Scene};

/// Intensity of a white-paper target at 1 m, full beam.
pub const INTENSITY_AT_1M: f64 = 20_000.0;
/// Echoes weaker than this intensity are not measured (weak-echo error code).
pub const WEAK_INTENSITY: f64 = 1.0;

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

/// A seeded scene with range noise.
#[derive(Debug, Clone)]
pub struct SceneSource {
    /// The world.
    pub scene: Scene,
    /// Seed of the range noise.
    pub seed: u64,
    /// Range noise standard deviation in mm (0 = exact).
    pub noise_mm: f64,
    echoes: Vec<Echo>,
}

impl SceneSource {
    /// A source over `scene` with noise `noise_mm` seeded by `seed`.
    pub fn new(scene: Scene, seed: u64, noise_mm: f64) -> Self {
        Self {
            scene,
            seed,
            noise_mm,
            echoes: Vec::new(),
        }
    }

    /// One normally distributed sample for (scan, step, echo): the same inputs always
    /// give the same noise, whatever was asked before.
    fn noise(&self, scan: u64, step: u32, echo: usize) -> f64 {
        if self.noise_mm <= 0.0 {
            return 0.0;
        }
        let key = self
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(scan.wrapping_mul(0xD1B5_4A32_D192_ED03))
            .wrapping_add(u64::from(step) << 2 | echo as u64);
        let mut rng = fastrand::Rng::with_seed(key);
        // Box–Muller.
        let u1 = rng.f64().max(1e-12);
        let u2 = rng.f64();
        self.noise_mm * (-2.0 * u1.ln()).sqrt() * (core::f64::consts::TAU * u2).cos()
    }
}

/// The value of one echo for `data`, or `None` when it cannot be measured (the caller
/// then sends the error code `code`).
pub fn echo_value(model: &Model, echo: &Echo, noise_mm: f64, data: DataSet) -> Result<Value, u32> {
    let d_mm = (echo.distance_mm + noise_mm).round();
    let d_m = (d_mm / 1000.0).max(0.05);
    let intensity = INTENSITY_AT_1M * echo.reflectance * echo.fraction / (d_m * d_m);
    if d_mm < f64::from(model.dmin) {
        return Err(model.too_near_code());
    }
    if d_mm > f64::from(model.dmax) {
        return Err(model.no_echo_code());
    }
    if intensity < WEAK_INTENSITY {
        return Err(model.weak_code());
    }
    let aux = match data {
        DataSet::Distance | DataSet::ShortDistance => 0.0,
        DataSet::DistanceIntensity => intensity.min(f64::from((1u32 << 18) - 1)),
        DataSet::DistanceReflectance => (256.0 * echo.reflectance).min(4095.0),
        DataSet::DistanceAux => (intensity * 64.0).min(f64::from((1u32 << 24) - 1)),
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
        let width = core::f64::consts::TAU / f64::from(model.ares);
        let mut echoes = core::mem::take(&mut self.echoes);
        self.scene
            .echoes(model.angle(f64::from(step)), width, t_s, &mut echoes);
        let mut first_error = None;
        for (i, e) in echoes.iter().enumerate() {
            match echo_value(model, e, self.noise(scan, step, i), data) {
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
    use crate::sim::model::ModelKind;

    #[test]
    fn intensity_falls_with_distance_squared() {
        let m = Model::new(ModelKind::Utm30lx);
        let at = |d: f64| Echo {
            distance_mm: d,
            reflectance: 1.0,
            fraction: 1.0,
        };
        let e = DataSet::DistanceIntensity;
        assert_eq!(echo_value(&m, &at(1000.0), 0.0, e), Ok((1000, 20_000)));
        assert_eq!(echo_value(&m, &at(2000.0), 0.0, e), Ok((2000, 5_000)));
        assert_eq!(echo_value(&m, &at(10_000.0), 0.0, e), Ok((10_000, 200)));
        // White paper is 256 at any distance.
        let r = DataSet::DistanceReflectance;
        assert_eq!(echo_value(&m, &at(1000.0), 0.0, r), Ok((1000, 256)));
        assert_eq!(echo_value(&m, &at(9000.0), 0.0, r), Ok((9000, 256)));
        assert_eq!(
            echo_value(&m, &at(2000.0), 0.0, DataSet::DistanceAux),
            Ok((2000, 320_000))
        );
        // Limits and codes.
        assert_eq!(echo_value(&m, &at(10.0), 0.0, e), Err(2));
        assert_eq!(echo_value(&m, &at(61_000.0), 0.0, e), Err(1));
        assert_eq!(
            echo_value(&m, &at(5000.0), 0.0, DataSet::ShortDistance),
            Ok((4095, 0))
        );
        let dark = Echo {
            distance_mm: 50_000.0,
            reflectance: 0.02,
            fraction: 1.0,
        };
        assert_eq!(echo_value(&m, &dark, 0.0, e), Err(1));
    }

    #[test]
    fn noise_is_deterministic_and_sized() {
        let s = SceneSource::new(Scene::empty(), 5, 10.0);
        assert_eq!(s.noise(3, 100, 0), s.noise(3, 100, 0));
        assert_ne!(s.noise(3, 100, 0), s.noise(4, 100, 0));
        let n = 4000;
        let var: f64 = (0..n).map(|i| s.noise(i, 7, 0).powi(2)).sum::<f64>() / n as f64;
        assert!((var.sqrt() - 10.0).abs() < 1.0, "sigma {}", var.sqrt());
    }

    #[test]
    fn steps_outside_the_field_are_no_echo() {
        let m = Model::new(ModelKind::Urg04lx);
        let mut s = SceneSource::new(Scene::wall(1000.0, 1.0), 1, 0.0);
        let mut out = Vec::new();
        s.step(&m, 0, 0.0, 10, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(0, 0)]);
        s.step(&m, 0, 0.0, 384, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(1000, 0)]);
    }
}
