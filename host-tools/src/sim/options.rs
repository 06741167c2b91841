//! Simulator options: the `scip2can sim` flags and the `sim:key=value,...` sensor spec
//! of the clients, one struct for both.

use std::path::PathBuf;

use anyhow::{anyhow, bail, Context};

use super::faults::{FaultConfig, LineNoise};
use super::measure::{SceneSource, Source};
use super::model::{Model, ModelKind, Noise};
use super::replay::{Recording, ReplaySource};
use super::scene::Scene;
use super::session::{ClockModel, Sensor};

/// What the sensor sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SceneSpec {
    /// A room drawn from the seed (walls, boxes, glass, a moving cylinder).
    Room,
    /// One flat wall across the forward direction at this many mm, reflectance 0.8.
    Wall(f64),
    /// Nothing: every step out of range.
    Empty,
}

impl std::str::FromStr for SceneSpec {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> anyhow::Result<Self> {
        match s.split_once(':') {
            None if s == "room" => Ok(Self::Room),
            None if s == "empty" => Ok(Self::Empty),
            Some(("wall", mm)) => Ok(Self::Wall(
                mm.parse()
                    .with_context(|| format!("wall distance {mm:?}"))?,
            )),
            _ => bail!("unknown scene {s:?} (room, empty, wall:<mm>)"),
        }
    }
}

/// Everything that makes a simulated sensor.
#[derive(Debug, Clone, clap::Args)]
pub struct SimOptions {
    /// Model: urg04lx, utm30lx, ust10lx, uxm30lxe.
    #[arg(long, default_value = "utm30lx", value_parser = parse_model)]
    pub model: ModelKind,
    /// Seed of the scene and its range noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scene: room, empty, or wall:MM (a flat wall MM millimetres ahead).
    #[arg(long, default_value = "room")]
    pub scene: SceneSpec,
    /// A constant range noise σ in mm instead of the model's noise (σ growing with range,
    /// repeated values, intensity noise); 0 = the scene's exact values.
    #[arg(long)]
    pub noise: Option<f64>,
    /// Serve the scans (and VV/PP text) of a record file or raw capture instead of a scene.
    #[arg(long)]
    pub replay: Option<PathBuf>,
    /// Boot in SCIP 1.1 (default: only the URG-04LX does).
    #[arg(long)]
    pub scip11: Option<bool>,
    /// The sensor clock at power-on, ms (e.g. 16777000 to see the 24-bit wrap soon).
    #[arg(long, default_value_t = 0)]
    pub clock: u32,
    /// Drift of the sensor's clock against the caller's, ppm (positive: fast).
    #[arg(long, default_value_t = 0.0)]
    pub drift_ppm: f64,
    /// Where the sensor clock's millisecond ticks fall at time 0, µs (0..1000).
    #[arg(long, default_value_t = 0)]
    pub clock_phase_us: u64,
    /// Output jitter: each stream frame leaves up to this many µs late.
    #[arg(long, default_value_t = 0)]
    pub jitter_us: u64,
    /// Sensor time runs this many times faster than real time (transports only).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Fault: chance per measurement response of one flipped bit.
    #[arg(long, default_value_t = 0.0)]
    pub flip: f64,
    /// Fault: chance per measurement response of one dropped byte.
    #[arg(long, default_value_t = 0.0)]
    pub drop: f64,
    /// Fault: chance per measurement response of one inserted byte.
    #[arg(long, default_value_t = 0.0)]
    pub insert: f64,
    /// Fault: chance per measurement response of a stall.
    #[arg(long, default_value_t = 0.0)]
    pub stall: f64,
    /// Length of a stall in ms.
    #[arg(long, default_value_t = 300)]
    pub stall_ms: u64,
    /// Fault: chance per stream frame of a hardware-fault status (50..97) instead of data.
    #[arg(long, default_value_t = 0.0)]
    pub hwfault: f64,
    /// Fault: reboot in the middle of this stream frame (0 = the first since boot).
    #[arg(long)]
    pub reboot_at: Option<u64>,
    /// Seed of the fault draws.
    #[arg(long, default_value_t = 1)]
    pub fault_seed: u64,
    /// Line noise: chance per byte sent of an error event (bit flip, dropped byte,
    /// inserted byte or a burst of up to 8 garbled bytes, a quarter each), on every byte,
    /// caught by a sum or not.
    #[arg(long, default_value_t = 0.0)]
    pub ber: f64,
}

fn parse_model(s: &str) -> Result<ModelKind, String> {
    ModelKind::parse(s).ok_or_else(|| {
        let names: Vec<_> = ModelKind::ALL.iter().map(|m| m.name()).collect();
        format!("unknown model {s:?} (one of {})", names.join(", "))
    })
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            model: ModelKind::Utm30lx,
            seed: 1,
            scene: SceneSpec::Room,
            noise: None,
            replay: None,
            scip11: None,
            clock: 0,
            drift_ppm: 0.0,
            clock_phase_us: 0,
            jitter_us: 0,
            speed: 1.0,
            flip: 0.0,
            drop: 0.0,
            insert: 0.0,
            stall: 0.0,
            stall_ms: 300,
            hwfault: 0.0,
            reboot_at: None,
            fault_seed: 1,
            ber: 0.0,
        }
    }
}

impl SimOptions {
    /// Parses `key=value` pairs separated by commas, the keys named like the flags
    /// (`model=urg04lx,seed=3,scene=wall:2000,noise=0,speed=20,flip=0.01`).
    pub fn from_spec(spec: &str) -> anyhow::Result<Self> {
        let mut o = Self::default();
        for pair in spec.split(',').filter(|p| !p.is_empty()) {
            let (k, v) = pair
                .split_once('=')
                .ok_or_else(|| anyhow!("sim option {pair:?} is not key=value"))?;
            let num = |v: &str| -> anyhow::Result<f64> {
                v.parse().with_context(|| format!("sim option {k}={v}"))
            };
            let int = |v: &str| -> anyhow::Result<u64> {
                v.parse().with_context(|| format!("sim option {k}={v}"))
            };
            match k {
                "model" => o.model = parse_model(v).map_err(|e| anyhow!(e))?,
                "seed" => o.seed = int(v)?,
                "scene" => o.scene = v.parse()?,
                "noise" => o.noise = Some(num(v)?),
                "replay" => o.replay = Some(PathBuf::from(v)),
                "scip11" => o.scip11 = Some(matches!(v, "1" | "true" | "yes")),
                "clock" => o.clock = u32::try_from(int(v)?)?,
                "drift_ppm" => o.drift_ppm = num(v)?,
                "clock_phase_us" => o.clock_phase_us = int(v)?,
                "jitter_us" => o.jitter_us = int(v)?,
                "speed" => o.speed = num(v)?,
                "flip" => o.flip = num(v)?,
                "drop" => o.drop = num(v)?,
                "insert" => o.insert = num(v)?,
                "stall" => o.stall = num(v)?,
                "stall_ms" => o.stall_ms = int(v)?,
                "hwfault" => o.hwfault = num(v)?,
                "reboot_at" => o.reboot_at = Some(int(v)?),
                "fault_seed" => o.fault_seed = int(v)?,
                "ber" => o.ber = num(v)?,
                _ => bail!("unknown sim option {k:?}"),
            }
        }
        if o.speed.is_nan() || o.speed <= 0.0 {
            bail!("speed must be > 0");
        }
        if !(-1000.0..=1000.0).contains(&o.drift_ppm) {
            bail!("drift_ppm must be within ±1000");
        }
        if o.clock_phase_us >= 1000 || o.jitter_us > 1_000_000 {
            bail!("clock_phase_us must be below 1000 and jitter_us at most 1000000");
        }
        if !(0.0..=1.0).contains(&o.ber) {
            bail!("ber must be a chance per byte, 0..=1");
        }
        Ok(o)
    }

    /// The fault configuration.
    pub fn faults(&self) -> FaultConfig {
        FaultConfig {
            flip: self.flip,
            drop: self.drop,
            insert: self.insert,
            stall: self.stall,
            stall_ms: self.stall_ms,
            hardware: self.hwfault,
            reboot_at_frame: self.reboot_at,
            seed: self.fault_seed,
            line: LineNoise::uniform(self.ber),
        }
    }

    /// Builds the sensor (reads the replay file, if any).
    pub fn build(&self) -> anyhow::Result<Sensor> {
        let mut model = Model::new(self.model);
        let source: Box<dyn Source> = match &self.replay {
            Some(path) => {
                let bytes =
                    std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
                let stream = crate::sensor::record_file::sensor_bytes(&bytes)
                    .with_context(|| format!("reading {}", path.display()))?;
                let rec = Recording::from_stream(&stream);
                if rec.scans.is_empty() {
                    bail!("{} holds no intact scan to replay", path.display());
                }
                model = model.with_recorded(&rec.version, &rec.parameters);
                Box::new(ReplaySource::new(&rec))
            }
            None => {
                let scene = match self.scene {
                    SceneSpec::Room => Scene::room(self.seed),
                    SceneSpec::Wall(mm) => Scene::wall(mm, 0.8),
                    SceneSpec::Empty => Scene::empty(),
                };
                let noise = self.noise.map_or(model.noise, Noise::constant);
                Box::new(SceneSource::new(scene, self.seed, noise))
            }
        };
        let scip11 = self.scip11.unwrap_or(model.boots_scip11);
        let mut sensor = Sensor::new(model, source, self.faults(), self.clock, scip11);
        sensor.set_clock_model(ClockModel {
            drift_ppb: (self.drift_ppm * 1000.0).round() as i64,
            phase_us: self.clock_phase_us,
            jitter_us: self.jitter_us,
            seed: self.fault_seed,
        });
        Ok(sensor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_parsing() {
        let o =
            SimOptions::from_spec("model=urg04lx,seed=9,scene=wall:2500,noise=0,flip=0.5,speed=4")
                .unwrap();
        assert_eq!(o.model, ModelKind::Urg04lx);
        assert_eq!(o.seed, 9);
        assert_eq!(o.scene, SceneSpec::Wall(2500.0));
        assert_eq!(o.noise, Some(0.0));
        assert_eq!(o.faults().flip, 0.5);
        assert_eq!(o.speed, 4.0);
        assert!(SimOptions::from_spec("model=foo").is_err());
        assert!(SimOptions::from_spec("colour=red").is_err());
        assert!(SimOptions::from_spec("seed").is_err());
        assert!(SimOptions::from_spec("speed=0").is_err());
        assert!(SimOptions::from_spec("").is_ok());
        let o = SimOptions::from_spec("drift_ppm=-100,jitter_us=2000,clock_phase_us=300").unwrap();
        assert_eq!(
            (o.drift_ppm, o.jitter_us, o.clock_phase_us),
            (-100.0, 2000, 300)
        );
        assert!(SimOptions::from_spec("drift_ppm=5000").is_err());
        assert!(SimOptions::from_spec("clock_phase_us=1000").is_err());
    }
}
