//! Control frames: every request validated, applied, and answered (accepted, or rejected
//! with a reason).

use can_wire::control::{Command as Ctl, DecimationMode as CtlMode, MedianWindow};
use can_wire::{Answer, Control, Encoding, FrameFormat, Outcome};

use crate::pipeline::{
    Decimation, DecimationMode, MedianWidth, PipelineConfig, RangeWindow, SpeckleFilter,
    StepWindow, TemporalDecimation,
};

/// Speckle threshold used when a control frame switches the speckle filter on, mm.
pub const SPECKLE_JUMP_MM: u32 = 100;

/// What a control request asks of the engine, after validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Apply {
    /// Start the sensor session.
    Start,
    /// Stop it.
    Stop,
    /// Queue the sensor-information status pages.
    SensorInfo,
    /// Reset the counters.
    ResetCounters,
    /// New pipeline settings (from the next scan on).
    Pipeline(PipelineConfig),
    /// New point encoding (from the next scan on).
    Encoding(Encoding),
    /// New frame format (from the next scan on).
    Format(FrameFormat),
}

/// Turns a parsed request into what to apply, or the outcome and detail that reject it.
pub fn plan(
    control: &Control,
    current: &PipelineConfig,
    fd_capable: bool,
) -> Result<Apply, (Outcome, u8)> {
    let mut p = *current;
    let apply = match control.command {
        Ctl::Start => Apply::Start,
        Ctl::Stop => Apply::Stop,
        Ctl::RequestSensorInfo => Apply::SensorInfo,
        Ctl::ResetCounters => Apply::ResetCounters,
        Ctl::RangeWindow { min_mm, max_mm } => {
            p.range_window = Some(RangeWindow { min_mm, max_mm });
            Apply::Pipeline(p)
        }
        Ctl::Speckle { enabled } => {
            p.speckle = enabled.then_some(SpeckleFilter {
                max_jump_mm: SPECKLE_JUMP_MM,
            });
            Apply::Pipeline(p)
        }
        Ctl::Median { window } => {
            p.median = match window {
                MedianWindow::Off => None,
                MedianWindow::Three => Some(MedianWidth::Three),
                MedianWindow::Five => Some(MedianWidth::Five),
            };
            Apply::Pipeline(p)
        }
        Ctl::IntensityThreshold { threshold } => {
            p.min_intensity = (threshold != 0).then_some(u32::from(threshold));
            Apply::Pipeline(p)
        }
        Ctl::AngularDecimation { k, mode } => {
            p.decimation = (k > 1).then_some(Decimation {
                factor: u16::from(k),
                mode: match mode {
                    CtlMode::Every => DecimationMode::First,
                    CtlMode::Min => DecimationMode::Min,
                    CtlMode::Mean => DecimationMode::Mean,
                },
            });
            Apply::Pipeline(p)
        }
        Ctl::RegionOfInterest {
            start_step,
            end_step,
        } => {
            p.roi = Some(StepWindow {
                first: start_step,
                last: end_step,
            });
            Apply::Pipeline(p)
        }
        Ctl::TemporalDecimation {
            every_nth,
            max_rate_centihz,
        } => {
            p.temporal = match (every_nth, max_rate_centihz) {
                (0, _) => return Err((Outcome::OutOfRange, 2)),
                (1, 0) => TemporalDecimation::All,
                (n, 0) => TemporalDecimation::EveryNth(u16::from(n)),
                (1, rate) => TemporalDecimation::MaxRate {
                    millihertz: u32::from(rate) * 10,
                    timestamp_bits: 24,
                },
                // The pipeline runs one temporal rule at a time.
                (_, _) => return Err((Outcome::Unsupported, 0)),
            };
            Apply::Pipeline(p)
        }
        Ctl::Encoding(e) => Apply::Encoding(e),
        Ctl::FrameSize { max_len } => {
            let format = if max_len == 8 {
                FrameFormat::Classic
            } else if fd_capable {
                FrameFormat::Fd { max_len }
            } else {
                return Err((Outcome::Unsupported, 2));
            };
            if format.validate().is_err() {
                return Err((Outcome::OutOfRange, 2));
            }
            Apply::Format(format)
        }
    };
    if let Apply::Pipeline(cfg) = &apply {
        if cfg.validate().is_err() {
            return Err((Outcome::OutOfRange, 2));
        }
    }
    Ok(apply)
}

/// The answer for a request that [`plan`] rejected.
pub fn rejection(control: &Control, outcome: Outcome, detail: u8) -> Answer {
    Answer {
        outcome,
        detail,
        ..Answer::accept(control)
    }
}
