//! Pipeline settings, their validation, and the output length of a scan.

use core::fmt;

use super::point::ScanInfo;

/// A window of sensor steps, both ends included: the region of interest.
///
/// A point belongs to the window when its step (the first step of its cluster) lies in
/// `first..=last`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepWindow {
    /// First step kept.
    pub first: u16,
    /// Last step kept.
    pub last: u16,
}

impl StepWindow {
    /// Whether `step` lies inside the window.
    pub fn contains(&self, step: u16) -> bool {
        self.first <= step && step <= self.last
    }
}

/// The accepted range interval in millimetres, both ends included.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RangeWindow {
    /// Smallest range kept, mm.
    pub min_mm: u32,
    /// Largest range kept, mm.
    pub max_mm: u32,
}

impl RangeWindow {
    /// Whether `range_mm` lies inside the window.
    pub fn contains(&self, range_mm: u32) -> bool {
        self.min_mm <= range_mm && range_mm <= self.max_mm
    }
}

/// Speckle (isolated point) removal.
///
/// A valid point is *supported* by a neighbour (the point just before or just after it
/// in the region of interest) when that neighbour exists, is valid, and their ranges differ
/// by at most `max_jump_mm`. A valid point that no neighbour supports is made invalid.
/// Validity here is the one the points have when they reach this stage (after error
/// codes, range window and intensity threshold); the decision for one point never depends
/// on the decision for another, so two close points standing alone keep each other. A
/// point at an end of the region has only one neighbour, and a region of one point has
/// none: that lone point is always removed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpeckleFilter {
    /// Largest range difference, mm, at which a neighbour still supports a point.
    pub max_jump_mm: u32,
}

/// Width of the median filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MedianWidth {
    /// The point and one neighbour on each side.
    Three,
    /// The point and two neighbours on each side.
    Five,
}

impl MedianWidth {
    /// Neighbours on each side of the centre point (1 or 2).
    pub fn half(self) -> usize {
        match self {
            MedianWidth::Three => 1,
            MedianWidth::Five => 2,
        }
    }
}

/// How a group of `factor` consecutive points becomes one point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecimationMode {
    /// The group's first point, unchanged, whether it is valid or not.
    First,
    /// The valid point with the smallest range (the first of equals), with its own
    /// intensity, like the sensor's own clustering. Invalid when no point of the group is
    /// valid.
    Min,
    /// The mean of the group's valid ranges, rounded to the nearest mm (halves up); the
    /// intensity is the rounded mean of the intensities those valid points carry (none
    /// when none carries one). Invalid when no point of the group is valid.
    Mean,
}

/// Angular decimation: consecutive points of the region of interest, taken in groups of
/// `factor` from its first point on, each give one output point whose step is the
/// group's first step. The last group may be shorter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Decimation {
    /// Points per group, at least 1 (1 keeps every point).
    pub factor: u16,
    /// How a group is reduced.
    pub mode: DecimationMode,
}

/// Which scans are published at all; decided when a scan begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TemporalDecimation {
    /// Publish every scan.
    #[default]
    All,
    /// Publish the first scan and then every `n`-th one (`n` >= 1), counting the scans
    /// offered since the settings took effect.
    EveryNth(u16),
    /// Publish a scan when at least `1000 / hz` ms (in exact arithmetic:
    /// `elapsed_ms * millihertz >= 1_000_000`) have passed since the last published
    /// scan, by the sensor's timestamps. The first scan is always published. The elapsed
    /// time is taken modulo `2^timestamp_bits` (24 for the raw SCIP timer), so the wrap of
    /// the sensor's clock costs nothing. The published rate never exceeds the limit; with
    /// scans every `p` ms it is `1000 / (p * ceil(interval / p))` Hz.
    MaxRate {
        /// Highest rate in millihertz (1 Hz = 1000), at least 1.
        millihertz: u32,
        /// Width of the timestamp counter, 1..=32.
        timestamp_bits: u8,
    },
}

/// Settings of the scan pipeline. Every stage is off when its field is `None`.
///
/// The stages run in this fixed order: sequence check and region of interest, error codes
/// to invalid points (always), range window, intensity threshold, speckle removal, median,
/// angular decimation. Temporal decimation is decided before all of them, when the scan
/// begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PipelineConfig {
    /// Region of interest: points whose step is outside are dropped (not output at all).
    pub roi: Option<StepWindow>,
    /// Range window: valid points whose range is outside become invalid.
    pub range_window: Option<RangeWindow>,
    /// Intensity threshold: a valid point that carries an intensity below this becomes
    /// invalid. Points without intensity are not affected.
    pub min_intensity: Option<u32>,
    /// Speckle removal.
    pub speckle: Option<SpeckleFilter>,
    /// Median filter over valid ranges.
    pub median: Option<MedianWidth>,
    /// Angular decimation.
    pub decimation: Option<Decimation>,
    /// Temporal decimation (which scans are published).
    pub temporal: TemporalDecimation,
}

/// Why a [`PipelineConfig`] was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// The region of interest ends before it starts (`first > last`).
    RoiReversed,
    /// The range window ends before it starts (`min_mm > max_mm`).
    RangeWindowReversed,
    /// The angular decimation factor is 0.
    DecimationFactorZero,
    /// `TemporalDecimation::EveryNth(0)`.
    ScanDivisorZero,
    /// `TemporalDecimation::MaxRate` with a rate of 0 mHz.
    RateZero,
    /// `TemporalDecimation::MaxRate` with a timestamp width outside 1..=32 bits.
    TimestampBitsOutOfRange,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ConfigError::RoiReversed => "region of interest ends before it starts",
            ConfigError::RangeWindowReversed => "range window ends before it starts",
            ConfigError::DecimationFactorZero => "angular decimation factor is 0",
            ConfigError::ScanDivisorZero => "temporal decimation keeps every 0th scan",
            ConfigError::RateZero => "temporal rate limit is 0 Hz",
            ConfigError::TimestampBitsOutOfRange => "timestamp width is not 1..=32 bits",
        })
    }
}

#[cfg(feature = "std")]
impl std::error::Error for ConfigError {}

impl PipelineConfig {
    /// Whether every per-point stage is off (no region, range window, intensity
    /// threshold, speckle, median, nor a decimation factor above 1): points then go
    /// straight from input to output.
    pub(crate) fn is_passthrough(&self) -> bool {
        self.filters_off() && self.decimation.is_none_or(|d| d.factor <= 1)
    }

    /// No region, range window, intensity threshold, speckle filter nor median.
    fn filters_off(&self) -> bool {
        self.roi.is_none()
            && self.range_window.is_none()
            && self.min_intensity.is_none()
            && self.speckle.is_none()
            && self.median.is_none()
    }

    /// Checks every parameter; the pipeline only ever runs validated settings.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if let Some(roi) = self.roi {
            if roi.first > roi.last {
                return Err(ConfigError::RoiReversed);
            }
        }
        if let Some(w) = self.range_window {
            if w.min_mm > w.max_mm {
                return Err(ConfigError::RangeWindowReversed);
            }
        }
        if let Some(d) = self.decimation {
            if d.factor == 0 {
                return Err(ConfigError::DecimationFactorZero);
            }
        }
        match self.temporal {
            TemporalDecimation::All => {}
            TemporalDecimation::EveryNth(0) => return Err(ConfigError::ScanDivisorZero),
            TemporalDecimation::EveryNth(_) => {}
            TemporalDecimation::MaxRate {
                millihertz,
                timestamp_bits,
            } => {
                if millihertz == 0 {
                    return Err(ConfigError::RateZero);
                }
                if !(1..=32).contains(&timestamp_bits) {
                    return Err(ConfigError::TimestampBitsOutOfRange);
                }
            }
        }
        Ok(())
    }

    /// The angular decimation factor in force (1 when decimation is off).
    pub fn decimation_factor(&self) -> u16 {
        match self.decimation {
            Some(d) => d.factor.max(1),
            None => 1,
        }
    }

    /// Number of scan points inside the region of interest for a scan of this geometry.
    ///
    /// Point `i` of the scan has step `first_step + i * cluster`; it counts when that step
    /// lies in the region. Returns 0 for a geometry that [`ScanInfo::point_count`] refuses.
    pub fn roi_len(&self, scan: &ScanInfo) -> usize {
        let Some(count) = scan.point_count() else {
            return 0;
        };
        let Some(roi) = self.roi else {
            return count;
        };
        let first = u32::from(scan.first_step);
        let cluster = u32::from(scan.cluster_size());
        let Ok(count32) = u32::try_from(count) else {
            return 0;
        };
        // Index of the first point at or after roi.first.
        let lo = match u32::from(roi.first).checked_sub(first) {
            Some(offset) => match offset.checked_add(cluster.saturating_sub(1)) {
                Some(up) => up.checked_div(cluster).unwrap_or(0),
                None => return 0,
            },
            None => 0,
        };
        // One past the index of the last point at or before roi.last.
        let hi = match u32::from(roi.last).checked_sub(first) {
            Some(offset) => offset
                .checked_div(cluster)
                .unwrap_or(0)
                .saturating_add(1)
                .min(count32),
            None => 0,
        };
        usize::try_from(hi.saturating_sub(lo)).unwrap_or(0)
    }
}

/// How many points the pipeline emits for an intact scan of this geometry under `config`:
/// the points in the region of interest, divided by the decimation factor and rounded up
/// (the last group may be short).
///
/// This takes the scan geometry rather than a bare point count because the region of
/// interest is a window of *steps*. The value is known at `begin_scan`, before any point
/// arrives, so a header can announce it; [`super::Pipeline::begin_scan`] returns it for
/// the settings that scan actually uses. A scan that is cut short emits fewer points,
/// never more.
pub fn output_len(config: &PipelineConfig, scan: &ScanInfo) -> usize {
    config
        .roi_len(scan)
        .div_ceil(usize::from(config.decimation_factor()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(first: u16, last: u16, cluster: u16) -> ScanInfo {
        ScanInfo {
            seq: 0,
            timestamp_ms: 0,
            first_step: first,
            last_step: last,
            cluster,
        }
    }

    #[test]
    fn default_config_is_valid_and_passes_everything() {
        let c = PipelineConfig::default();
        assert_eq!(c.validate(), Ok(()));
        // URG-04LX GD0044072501: 682 steps.
        assert_eq!(output_len(&c, &scan(44, 725, 1)), 682);
        // UTM-30LX ME0000108001101: 1081 steps.
        assert_eq!(output_len(&c, &scan(0, 1080, 1)), 1081);
    }

    #[test]
    fn every_bad_parameter_has_its_error() {
        let base = PipelineConfig::default();
        let cases = [
            (
                PipelineConfig {
                    roi: Some(StepWindow { first: 10, last: 9 }),
                    ..base
                },
                ConfigError::RoiReversed,
            ),
            (
                PipelineConfig {
                    range_window: Some(RangeWindow {
                        min_mm: 2,
                        max_mm: 1,
                    }),
                    ..base
                },
                ConfigError::RangeWindowReversed,
            ),
            (
                PipelineConfig {
                    decimation: Some(Decimation {
                        factor: 0,
                        mode: DecimationMode::Min,
                    }),
                    ..base
                },
                ConfigError::DecimationFactorZero,
            ),
            (
                PipelineConfig {
                    temporal: TemporalDecimation::EveryNth(0),
                    ..base
                },
                ConfigError::ScanDivisorZero,
            ),
            (
                PipelineConfig {
                    temporal: TemporalDecimation::MaxRate {
                        millihertz: 0,
                        timestamp_bits: 24,
                    },
                    ..base
                },
                ConfigError::RateZero,
            ),
            (
                PipelineConfig {
                    temporal: TemporalDecimation::MaxRate {
                        millihertz: 10_000,
                        timestamp_bits: 0,
                    },
                    ..base
                },
                ConfigError::TimestampBitsOutOfRange,
            ),
            (
                PipelineConfig {
                    temporal: TemporalDecimation::MaxRate {
                        millihertz: 10_000,
                        timestamp_bits: 33,
                    },
                    ..base
                },
                ConfigError::TimestampBitsOutOfRange,
            ),
        ];
        for (config, err) in cases {
            assert_eq!(config.validate(), Err(err), "{config:?}");
        }
    }

    #[test]
    fn edge_parameters_are_accepted() {
        let c = PipelineConfig {
            roi: Some(StepWindow { first: 5, last: 5 }),
            range_window: Some(RangeWindow {
                min_mm: 7,
                max_mm: 7,
            }),
            min_intensity: Some(0),
            speckle: Some(SpeckleFilter { max_jump_mm: 0 }),
            median: Some(MedianWidth::Five),
            decimation: Some(Decimation {
                factor: u16::MAX,
                mode: DecimationMode::Mean,
            }),
            temporal: TemporalDecimation::MaxRate {
                millihertz: 1,
                timestamp_bits: 32,
            },
        };
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn roi_len_by_hand() {
        let roi = |first, last| PipelineConfig {
            roi: Some(StepWindow { first, last }),
            ..PipelineConfig::default()
        };
        // Steps 44..=725, ROI 100..=199: 100 points.
        assert_eq!(roi(100, 199).roi_len(&scan(44, 725, 1)), 100);
        // ROI wider than the scan on both sides.
        assert_eq!(roi(0, 2000).roi_len(&scan(44, 725, 1)), 682);
        // ROI entirely before / after the scan.
        assert_eq!(roi(0, 43).roi_len(&scan(44, 725, 1)), 0);
        assert_eq!(roi(726, 800).roi_len(&scan(44, 725, 1)), 0);
        // Cluster 3 from step 10 to 30: point steps 10,13,16,19,22,25,28 (7 points).
        assert_eq!(scan(10, 30, 3).point_count(), Some(7));
        // ROI 12..=22 holds 13,16,19,22.
        assert_eq!(roi(12, 22).roi_len(&scan(10, 30, 3)), 4);
        // ROI 29..=30 holds none (28 < 29, next would be 31 > 30).
        assert_eq!(roi(29, 30).roi_len(&scan(10, 30, 3)), 0);
        // ROI 11..=12 falls between points 10 and 13.
        assert_eq!(roi(11, 12).roi_len(&scan(10, 30, 3)), 0);
        // Single step ROI on a point.
        assert_eq!(roi(28, 28).roi_len(&scan(10, 30, 3)), 1);
        // Bad geometry gives 0.
        assert_eq!(roi(0, 100).roi_len(&scan(30, 10, 1)), 0);
        // Full u16 range.
        assert_eq!(
            PipelineConfig::default().roi_len(&scan(0, u16::MAX, 1)),
            65536
        );
        assert_eq!(roi(0, u16::MAX).roi_len(&scan(0, u16::MAX, 1)), 65536);
    }

    #[test]
    fn output_len_rounds_the_last_group_up() {
        let dec = |factor| PipelineConfig {
            decimation: Some(Decimation {
                factor,
                mode: DecimationMode::First,
            }),
            ..PipelineConfig::default()
        };
        assert_eq!(output_len(&dec(1), &scan(0, 19, 1)), 20);
        assert_eq!(output_len(&dec(3), &scan(0, 19, 1)), 7); // 6 full groups + 2
        assert_eq!(output_len(&dec(4), &scan(0, 19, 1)), 5);
        assert_eq!(output_len(&dec(100), &scan(0, 19, 1)), 1);
        assert_eq!(output_len(&dec(3), &scan(0, 0, 1)), 1);
        assert_eq!(output_len(&dec(3), &scan(5, 4, 1)), 0);
    }

    #[test]
    fn errors_display() {
        extern crate std;
        use std::string::ToString;
        assert_eq!(
            ConfigError::RoiReversed.to_string(),
            "region of interest ends before it starts"
        );
        assert_eq!(
            ConfigError::RateZero.to_string(),
            "temporal rate limit is 0 Hz"
        );
    }
}
