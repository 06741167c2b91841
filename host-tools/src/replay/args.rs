//! The flags of `scip2can replay` and the [`BridgeConfig`] they make.

use std::path::PathBuf;

use anyhow::{anyhow, bail, Context};
use bridge::engine::BridgeConfig;
use bridge::governor::Budget;
use bridge::pipeline::{
    Decimation, DecimationMode, MedianWidth, PipelineConfig, RangeWindow, SpeckleFilter,
    StepWindow, TemporalDecimation,
};
use bridge::session::SessionConfig;
use can_wire::bandwidth::BitRates;
use can_wire::{DistanceEncoding, Encoding, FrameFormat, IntensityEncoding};
use scip::DataSet;

use crate::decode::WindowArgs;

/// `scip2can replay` flags.
#[derive(Debug, Clone, clap::Args)]
pub struct ReplayArgs {
    /// A raw sensor → host stream, a `scip2can record` file, `-` for standard input, or
    /// `sim:key=value,...` (an in-process simulated sensor, e.g. `sim:model=urg04lx`).
    pub input: String,
    /// Write the candump log here (default: standard output).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Bus and wire encoding.
    #[command(flatten)]
    pub can: CanArgs,
    /// Scan pipeline.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// UART bit rate: the log's time is the stream position at this rate (10 bits/byte).
    #[arg(long, default_value_t = 115_200)]
    pub uart_baud: u32,
    /// Period of the bridge's status frames in ms (0: none).
    #[arg(long, default_value_t = 1000)]
    pub status_period: u32,
    /// Interface name written in the log.
    #[arg(long, default_value = "can0")]
    pub interface: String,
    /// Scan rate for the load report, Hz (default: from the stream's PP `SCAN`).
    #[arg(long)]
    pub scan_hz: Option<f64>,
    /// `sim:` only: stream scans until this many have begun.
    #[arg(long, default_value_t = 10)]
    pub scans: u32,
    /// `sim:` only: what the session streams: D (distance), S (short), E (distance and
    /// intensity).
    #[arg(long, default_value = "D", value_parser = parse_data_set)]
    pub sensor_data: DataSet,
    /// The sensor model of a stream that has no PP answer (urg04lx, utm30lx, ust10lx,
    /// ust20lx, uxm30lxe): its geometry and error codes. Without it such a stream's scans
    /// say "geometry unknown" (no angles). A PP answer in the stream wins.
    #[arg(long, value_parser = parse_model)]
    pub model: Option<KnownModel>,
}

/// A sensor model `--model` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KnownModel {
    /// URG-04LX.
    Urg04lx,
    /// UTM-30LX.
    Utm30lx,
    /// UST-10LX.
    Ust10lx,
    /// UST-20LX.
    Ust20lx,
    /// UXM-30LX-E.
    Uxm30lxE,
}

impl KnownModel {
    /// The PP parameters of the model (what its PP answer says): the simulator's models,
    /// and for the UST-20LX the UST-10LX's geometry with its own DMAX.
    pub fn params(self) -> scip::SensorParams {
        use crate::sim::model::{Model, ModelKind};
        let kind = match self {
            Self::Urg04lx => ModelKind::Urg04lx,
            Self::Utm30lx => ModelKind::Utm30lx,
            Self::Ust10lx | Self::Ust20lx => ModelKind::Ust10lx,
            Self::Uxm30lxE => ModelKind::Uxm30lxE,
        };
        let m = Model::new(kind);
        scip::SensorParams {
            dmin: Some(m.dmin),
            dmax: Some(if self == Self::Ust20lx {
                60_000
            } else {
                m.dmax
            }),
            ares: Some(m.ares),
            amin: Some(m.amin),
            amax: Some(m.amax),
            afrt: Some(m.afrt),
            scan_rpm: Some(m.scan_rpm),
            family: Some(m.family),
            // The UST-20LX has no table of its own in `scip` (its DMAX differs from the
            // UST-10LX's): its values are not checked against one.
            model: match self {
                Self::Urg04lx => Some(scip::KnownModel::Urg04lx),
                Self::Utm30lx => Some(scip::KnownModel::Utm30lx),
                Self::Ust10lx => Some(scip::KnownModel::Ust10lx),
                Self::Uxm30lxE => Some(scip::KnownModel::Uxm30lxE),
                Self::Ust20lx => None,
            },
            fault: None,
        }
    }
}

fn parse_model(s: &str) -> Result<KnownModel, String> {
    let norm: String = s
        .chars()
        .filter(|c| c.is_ascii_alphanumeric())
        .map(|c| c.to_ascii_lowercase())
        .collect();
    match norm.as_str() {
        "urg04lx" => Ok(KnownModel::Urg04lx),
        "utm30lx" => Ok(KnownModel::Utm30lx),
        "ust10lx" => Ok(KnownModel::Ust10lx),
        "ust20lx" => Ok(KnownModel::Ust20lx),
        "uxm30lxe" => Ok(KnownModel::Uxm30lxE),
        _ => Err(format!(
            "{s:?}: one of urg04lx, utm30lx, ust10lx, ust20lx, uxm30lxe"
        )),
    }
}

/// Bus, identifiers and wire encoding.
#[derive(Debug, Clone, clap::Args)]
pub struct CanArgs {
    /// CAN FD frames (bit rate switch when --data-bitrate differs from --bitrate).
    #[arg(long, conflicts_with = "classic")]
    pub fd: bool,
    /// Classic CAN frames (the default).
    #[arg(long)]
    pub classic: bool,
    /// Nominal (arbitration) bit rate, bit/s.
    #[arg(long, default_value_t = 1_000_000)]
    pub bitrate: u32,
    /// CAN FD data phase bit rate, bit/s.
    #[arg(long, default_value_t = 5_000_000)]
    pub data_bitrate: u32,
    /// CAN FD data frame length: 12, 16, 20, 24, 32, 48 or 64.
    #[arg(long, default_value_t = 64)]
    pub frame_len: u8,
    /// Distance code: dl (lossless predictive coding, SPEC 4.2: exact, about 6 bits per
    /// point on real scans), d16, d14, d12.
    #[arg(long, default_value = "dl", value_parser = parse_distance)]
    pub encoding: DistanceEncoding,
    /// Intensity code: none, i8, i12, i16 (only for streams that carry intensity).
    #[arg(long, default_value = "i16", value_parser = parse_intensity)]
    pub intensity: IntensityEncoding,
    /// Range unit in mm, a power of two 1..=32768.
    #[arg(long, default_value_t = 1)]
    pub unit_mm: u32,
    /// Share of the bus the bridge may use, percent.
    #[arg(long, default_value_t = 100.0)]
    pub share: f64,
    /// Node number of the bridge, 0..=15.
    #[arg(long, default_value_t = 0)]
    pub node: u8,
    /// Identifier window.
    #[command(flatten)]
    pub window: WindowArgs,
}

/// The pipeline's stages (each off unless given).
#[derive(Debug, Clone, clap::Args)]
pub struct PipelineArgs {
    /// Region of interest, sensor steps FIRST:LAST.
    #[arg(long, value_parser = parse_pair::<u16>)]
    pub roi: Option<(u16, u16)>,
    /// Range window MIN:MAX in mm; ranges outside become invalid.
    #[arg(long, value_parser = parse_pair::<u32>)]
    pub range: Option<(u32, u32)>,
    /// Points with an intensity below this become invalid.
    #[arg(long)]
    pub min_intensity: Option<u32>,
    /// Speckle removal: largest jump (mm) at which a neighbour supports a point.
    #[arg(long)]
    pub speckle: Option<u32>,
    /// Median of 3 or 5.
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(["3", "5"]))]
    pub median: Option<String>,
    /// Angular decimation K[:first|min|mean] (mode first by default).
    #[arg(long, value_parser = parse_decimation)]
    pub decimate: Option<Decimation>,
    /// Publish every n-th scan.
    #[arg(long, conflicts_with = "max_rate")]
    pub every_nth: Option<u16>,
    /// Publish at most this many scans per second (by the sensor's timestamps).
    #[arg(long)]
    pub max_rate: Option<f64>,
}

/// Parses a data-set letter (`D`, `S`, `E`, ...).
pub fn parse_data_set(s: &str) -> Result<DataSet, String> {
    match s {
        "D" | "d" => Ok(DataSet::Distance),
        "S" | "s" => Ok(DataSet::ShortDistance),
        "E" | "e" => Ok(DataSet::DistanceIntensity),
        _ => Err(format!("{s:?}: one of D, S, E")),
    }
}

fn parse_distance(s: &str) -> Result<DistanceEncoding, String> {
    match s.to_ascii_lowercase().as_str() {
        "d16" => Ok(DistanceEncoding::D16),
        "d14" => Ok(DistanceEncoding::D14),
        "d12" => Ok(DistanceEncoding::D12),
        "dl" | "lossless" => Ok(DistanceEncoding::Lossless),
        _ => Err(format!("{s:?}: one of dl, d16, d14, d12")),
    }
}

fn parse_intensity(s: &str) -> Result<IntensityEncoding, String> {
    match s.to_ascii_lowercase().as_str() {
        "none" => Ok(IntensityEncoding::None),
        "i8" => Ok(IntensityEncoding::I8),
        "i12" => Ok(IntensityEncoding::I12),
        "i16" => Ok(IntensityEncoding::I16),
        _ => Err(format!("{s:?}: one of none, i8, i12, i16")),
    }
}

fn parse_pair<T: std::str::FromStr>(s: &str) -> Result<(T, T), String> {
    let (a, b) = s.split_once(':').ok_or(format!("{s:?} is not A:B"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<T>()
            .map_err(|_| format!("{v:?} is not a number"))
    };
    Ok((num(a)?, num(b)?))
}

fn parse_decimation(s: &str) -> Result<Decimation, String> {
    let (k, mode) = s.split_once(':').unwrap_or((s, "first"));
    let factor = k.parse().map_err(|_| format!("{k:?} is not a factor"))?;
    let mode = match mode {
        "first" => DecimationMode::First,
        "min" => DecimationMode::Min,
        "mean" => DecimationMode::Mean,
        m => return Err(format!("{m:?}: one of first, min, mean")),
    };
    Ok(Decimation { factor, mode })
}

impl PipelineArgs {
    /// The pipeline settings (validated by the bridge).
    pub fn config(&self) -> anyhow::Result<PipelineConfig> {
        let temporal = match (self.every_nth, self.max_rate) {
            (Some(n), _) => TemporalDecimation::EveryNth(n),
            (None, Some(hz)) => {
                if !(hz.is_finite() && hz > 0.0) {
                    bail!("--max-rate must be > 0 Hz");
                }
                TemporalDecimation::MaxRate {
                    millihertz: (hz * 1000.0).round().clamp(1.0, f64::from(u32::MAX)) as u32,
                    timestamp_bits: 24,
                }
            }
            (None, None) => TemporalDecimation::All,
        };
        Ok(PipelineConfig {
            roi: self.roi.map(|(first, last)| StepWindow { first, last }),
            range_window: self
                .range
                .map(|(min_mm, max_mm)| RangeWindow { min_mm, max_mm }),
            min_intensity: self.min_intensity,
            speckle: self
                .speckle
                .map(|max_jump_mm| SpeckleFilter { max_jump_mm }),
            median: self.median.as_deref().map(|m| match m {
                "5" => MedianWidth::Five,
                _ => MedianWidth::Three,
            }),
            decimation: self.decimate,
            temporal,
        })
    }
}

impl CanArgs {
    /// The frame format.
    pub fn format(&self) -> FrameFormat {
        if self.fd {
            FrameFormat::Fd {
                max_len: self.frame_len,
            }
        } else {
            FrameFormat::Classic
        }
    }

    /// The bit rates (classic: the nominal rate for both).
    pub fn rates(&self) -> BitRates {
        BitRates {
            nominal: self.bitrate,
            data: if self.fd {
                self.data_bitrate
            } else {
                self.bitrate
            },
        }
    }

    /// Whether FD frames switch bit rate (the log's BRS flag).
    pub fn brs(&self) -> bool {
        self.fd && self.data_bitrate != self.bitrate
    }

    /// The wire encoding.
    pub fn wire_encoding(&self) -> anyhow::Result<Encoding> {
        if !self.unit_mm.is_power_of_two() || self.unit_mm > 1 << 15 {
            bail!("--unit-mm {} is not a power of two 1..=32768", self.unit_mm);
        }
        Ok(Encoding {
            distance: self.encoding,
            intensity: self.intensity,
            unit_exp: self.unit_mm.trailing_zeros() as u8,
        })
    }
}

impl ReplayArgs {
    /// The bridge configuration the flags describe.
    pub fn bridge_config(&self) -> anyhow::Result<BridgeConfig> {
        bridge_config(
            &self.can,
            &self.pipeline,
            self.uart_baud,
            self.status_period,
            self.sensor_data,
        )
    }
}

/// The bridge configuration of bus, pipeline and session flags (shared by `replay` and
/// `bridge`).
pub fn bridge_config(
    c: &CanArgs,
    pipeline: &PipelineArgs,
    uart_baud: u32,
    status_period: u32,
    sensor_data: DataSet,
) -> anyhow::Result<BridgeConfig> {
    if c.bitrate == 0 || c.data_bitrate == 0 {
        bail!("bit rates must be > 0");
    }
    if !(c.share.is_finite() && c.share > 0.0 && c.share <= 100.0) {
        bail!("--share must be in (0, 100] percent");
    }
    c.format()
        .validate()
        .map_err(|_| anyhow!("--frame-len {} is not a CAN FD length above 8", c.frame_len))?;
    let window = c.window.window()?;
    let mut session = SessionConfig::default();
    session.scan.data = sensor_data;
    Ok(BridgeConfig {
        session,
        pipeline: pipeline.config()?,
        encoding: c.wire_encoding()?,
        budget: Budget {
            rates: c.rates(),
            format: c.format(),
            extended: window.is_extended(),
            share_permille: (c.share * 10.0).round().clamp(1.0, 1000.0) as u16,
        },
        ids: window
            .node(c.node)
            .map_err(|_| anyhow!("--node {} is not 0..=15", c.node))
            .context("CAN identifiers")?,
        uart_bit_rate: uart_baud,
        status_period_ms: status_period,
        fd_capable: c.fd,
        link: bridge::link::LinkKind::Uart,
    })
}
