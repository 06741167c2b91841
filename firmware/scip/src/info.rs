//! VV / PP / II fields, the typed PP parameters, and the meaning of error codes.

use core::fmt;

/// A typed PP field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Param {
    /// `DMIN`: minimum distance in mm; smaller values are error codes.
    Dmin(u32),
    /// `DMAX`: maximum distance in mm.
    Dmax(u32),
    /// `ARES`: steps per full turn.
    Ares(u32),
    /// `AMIN`: first measurable step.
    Amin(u32),
    /// `AMAX`: last measurable step.
    Amax(u32),
    /// `AFRT`: the forward step.
    Afrt(u32),
    /// `SCAN`: motor speed in rpm.
    Scan(u32),
}

impl Param {
    /// Parses a PP field whose name is one of the typed ones and whose value is decimal.
    pub fn parse(name: &[u8], value: &[u8]) -> Option<Self> {
        let ctor: fn(u32) -> Param = match name {
            b"DMIN" => Param::Dmin,
            b"DMAX" => Param::Dmax,
            b"ARES" => Param::Ares,
            b"AMIN" => Param::Amin,
            b"AMAX" => Param::Amax,
            b"AFRT" => Param::Afrt,
            b"SCAN" => Param::Scan,
            _ => return None,
        };
        // Some firmware appends a unit or comment; the leading digits are the value.
        let digits = value.iter().take_while(|c| c.is_ascii_digit()).count();
        let digits = value
            .get(..digits)
            .filter(|d| !d.is_empty() && d.len() <= 9)?;
        let v = digits
            .iter()
            .fold(0u32, |acc, &c| acc * 10 + u32::from(c - b'0'));
        Some(ctor(v))
    }
}

/// A model family: how to read error codes below DMIN.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModelFamily {
    /// URG-04LX class (codes 0..=19).
    Urg04lx,
    /// UTM / UXM class (codes 1..=5).
    Utm,
    /// Ethernet models speaking SCIP 2.2 (UST): UTM codes plus 65533 for no echo.
    Ethernet,
    /// Not known yet (no PP or VV seen).
    Unknown,
}

impl ModelFamily {
    /// The family of a model string (`MODL` of PP or `PROD` of VV).
    pub fn from_model(model: &[u8]) -> Self {
        let has = |needle: &[u8]| model.windows(needle.len()).any(|w| w == needle);
        if has(b"URG-04LX") {
            Self::Urg04lx
        } else if has(b"UST") || has(b"-EW") || has(b"-E(") || has(b"UXM-30LX-E") {
            Self::Ethernet
        } else if has(b"UTM") || has(b"UXM") {
            Self::Utm
        } else {
            Self::Unknown
        }
    }
}

/// What an error code means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RangeError {
    /// No object in range / no echo (URG 0, UTM 1, Ethernet 65533).
    NoEcho,
    /// Reflected light too weak (URG 1..=5).
    LowIntensity,
    /// URG 6: maybe a 5.7 m object.
    Maybe5700,
    /// URG 7: error of the neighbouring step.
    NeighbourError,
    /// URG 9: the same error twice.
    RepeatedError,
    /// URG 16: maybe a 4096 mm object.
    Maybe4096,
    /// URG 19: not measurable.
    Unmeasurable,
    /// UTM 2: object too near.
    TooNear,
    /// UTM 3: measurement error.
    MeasurementError,
    /// UTM 4: out of range.
    OutOfRange,
    /// The 2-char encoding's over-range value 4095.
    OverRange,
    /// Any other code below DMIN.
    Other,
}

impl RangeError {
    /// A short name, as used in JSON output.
    pub const fn name(self) -> &'static str {
        match self {
            Self::NoEcho => "no_echo",
            Self::LowIntensity => "low_intensity",
            Self::Maybe5700 => "maybe_5700mm",
            Self::NeighbourError => "neighbour_error",
            Self::RepeatedError => "repeated_error",
            Self::Maybe4096 => "maybe_4096mm",
            Self::Unmeasurable => "unmeasurable",
            Self::TooNear => "too_near",
            Self::MeasurementError => "measurement_error",
            Self::OutOfRange => "out_of_range",
            Self::OverRange => "over_range",
            Self::Other => "other",
        }
    }
}

impl fmt::Display for RangeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A distance value read against the sensor's limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Range {
    /// A real distance in mm.
    Mm(u32),
    /// An error code (never a range).
    Error(RangeError),
}

/// What the decoder needs to tell ranges from error codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RangeLimits {
    /// Smallest real distance (PP `DMIN`).
    pub dmin: u32,
    /// Model family, for the meaning of codes.
    pub family: ModelFamily,
}

impl Default for RangeLimits {
    /// Before any PP: DMIN 20 (the smallest of all models), family unknown.
    fn default() -> Self {
        Self {
            dmin: 20,
            family: ModelFamily::Unknown,
        }
    }
}

impl RangeLimits {
    /// Classifies a decoded distance of a value `width` chars wide.
    #[inline]
    pub fn classify(&self, distance: u32, width: u8) -> Range {
        if distance >= self.dmin {
            if width == 2 && distance == 4095 {
                return Range::Error(RangeError::OverRange);
            }
            if width > 2 && self.has_band() && ETHERNET_CODES.contains(&distance) {
                // 65533 is the Ethernet models' no echo (`?om`); with the model unknown,
                // the codes of the model it may be (no Hokuyo measures 65.5 m).
                return Range::Error(if distance == 65533 {
                    RangeError::NoEcho
                } else {
                    RangeError::Other
                });
            }
            return Range::Mm(distance);
        }
        Range::Error(match (self.family, distance) {
            (ModelFamily::Urg04lx, 0) => RangeError::NoEcho,
            (ModelFamily::Urg04lx, 1..=5) => RangeError::LowIntensity,
            (ModelFamily::Urg04lx, 6) => RangeError::Maybe5700,
            (ModelFamily::Urg04lx, 7) => RangeError::NeighbourError,
            (ModelFamily::Urg04lx, 9) => RangeError::RepeatedError,
            (ModelFamily::Urg04lx, 16) => RangeError::Maybe4096,
            (ModelFamily::Urg04lx, 19) => RangeError::Unmeasurable,
            (ModelFamily::Utm | ModelFamily::Ethernet, 1) => RangeError::NoEcho,
            (ModelFamily::Utm | ModelFamily::Ethernet, 2) => RangeError::TooNear,
            (ModelFamily::Utm | ModelFamily::Ethernet, 3) => RangeError::MeasurementError,
            (ModelFamily::Utm | ModelFamily::Ethernet, 4) => RangeError::OutOfRange,
            _ => RangeError::Other,
        })
    }
}

/// The Ethernet models' error codes above DMIN (65533 = `?om`, no echo). They are error
/// codes for the Ethernet family and also while the model is unknown (a stream without
/// PP may come from one).
pub const ETHERNET_CODES: core::ops::RangeInclusive<u32> = 65533..=65535;

impl RangeLimits {
    /// Whether [`ETHERNET_CODES`] are error codes for this family.
    fn has_band(&self) -> bool {
        matches!(self.family, ModelFamily::Ethernet | ModelFamily::Unknown)
    }
}

/// The test [`RangeLimits::classify`] makes of whether a value is a range, with its
/// constants worked out once for one value width: for loops over a line's values.
/// Exact for every value a SCIP field can hold (below `2^24`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RangeTest {
    min: u32,
    /// A value at or above `min` that is still an error code (`u32::MAX` when none).
    not_a: u32,
    /// [`ETHERNET_CODES`] are error codes too.
    band: bool,
}

impl RangeTest {
    /// Whether `distance` is a range (`Range::Mm`).
    #[inline(always)]
    pub fn is_range(&self, distance: u32) -> bool {
        distance >= self.min
            && distance != self.not_a
            && !(self.band && distance.wrapping_sub(*ETHERNET_CODES.start()) <= 2)
    }

    /// The smallest range (DMIN).
    pub fn min(&self) -> u32 {
        self.min
    }

    /// The values at or above [`RangeTest::min`] that are error codes, when they are at
    /// most two; `u32::MAX` (never a SCIP value) stands for none. `None` when the test
    /// also excludes [`ETHERNET_CODES`] (three values).
    pub fn exceptions(&self) -> Option<[u32; 2]> {
        (!self.band).then_some([self.not_a, u32::MAX])
    }
}

impl RangeLimits {
    /// [`RangeLimits::classify`]'s range test for values `width` chars wide.
    pub fn range_test(&self, width: u8) -> RangeTest {
        RangeTest {
            min: self.dmin,
            not_a: if width == 2 { 4095 } else { u32::MAX },
            // A 2-char value is at most 4095.
            band: width > 2 && self.has_band(),
        }
    }
}

/// The typed PP parameters of a sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorParams {
    /// `DMIN` in mm.
    pub dmin: Option<u32>,
    /// `DMAX` in mm.
    pub dmax: Option<u32>,
    /// `ARES`: steps per turn.
    pub ares: Option<u32>,
    /// `AMIN`: first step.
    pub amin: Option<u32>,
    /// `AMAX`: last step.
    pub amax: Option<u32>,
    /// `AFRT`: forward step.
    pub afrt: Option<u32>,
    /// `SCAN`: motor speed in rpm.
    pub scan_rpm: Option<u32>,
    /// Model family from `MODL`.
    pub family: Option<ModelFamily>,
}

impl SensorParams {
    /// Records one PP field.
    pub fn apply(&mut self, name: &[u8], value: &[u8]) {
        if name == b"MODL" {
            self.family = Some(ModelFamily::from_model(value));
            return;
        }
        match Param::parse(name, value) {
            Some(Param::Dmin(v)) => self.dmin = Some(v),
            Some(Param::Dmax(v)) => self.dmax = Some(v),
            Some(Param::Ares(v)) => self.ares = Some(v),
            Some(Param::Amin(v)) => self.amin = Some(v),
            Some(Param::Amax(v)) => self.amax = Some(v),
            Some(Param::Afrt(v)) => self.afrt = Some(v),
            Some(Param::Scan(v)) => self.scan_rpm = Some(v),
            None => {}
        }
    }

    /// Scan period in microseconds from `SCAN` (rpm), if known and non-zero.
    pub fn scan_period_us(&self) -> Option<u32> {
        self.scan_rpm.filter(|&r| r > 0).map(|r| 60_000_000 / r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_parse() {
        assert_eq!(Param::parse(b"DMIN", b"20"), Some(Param::Dmin(20)));
        assert_eq!(Param::parse(b"SCAN", b"2400"), Some(Param::Scan(2400)));
        assert_eq!(Param::parse(b"DMIN", b"x"), None);
        assert_eq!(Param::parse(b"DMIN", b"12345678901"), None);
        assert_eq!(Param::parse(b"MODL", b"20"), None);
        let mut p = SensorParams::default();
        p.apply(b"MODL", b"UTM-30LX(Hokuyo Automatic Co.,Ltd.)");
        p.apply(b"SCAN", b"2400");
        assert_eq!(p.family, Some(ModelFamily::Utm));
        assert_eq!(p.scan_period_us(), Some(25_000));
    }

    #[test]
    fn families() {
        assert_eq!(
            ModelFamily::from_model(b"URG-04LX(Hokuyo Automatic Co.,Ltd.)"),
            ModelFamily::Urg04lx
        );
        assert_eq!(
            ModelFamily::from_model(b"SOKUIKI Sensor URG-04LX-UG01(Simple-URG)"),
            ModelFamily::Urg04lx
        );
        assert_eq!(ModelFamily::from_model(b"UST-10LX"), ModelFamily::Ethernet);
        assert_eq!(
            ModelFamily::from_model(b"UXM-30LX-E"),
            ModelFamily::Ethernet
        );
        assert_eq!(ModelFamily::from_model(b"foo"), ModelFamily::Unknown);
    }

    #[test]
    fn classification() {
        let urg = RangeLimits {
            dmin: 20,
            family: ModelFamily::Urg04lx,
        };
        assert_eq!(urg.classify(0, 3), Range::Error(RangeError::NoEcho));
        assert_eq!(urg.classify(6, 3), Range::Error(RangeError::Maybe5700));
        assert_eq!(urg.classify(19, 3), Range::Error(RangeError::Unmeasurable));
        assert_eq!(urg.classify(12, 3), Range::Error(RangeError::Other));
        assert_eq!(urg.classify(20, 3), Range::Mm(20));
        assert_eq!(urg.classify(4095, 2), Range::Error(RangeError::OverRange));
        assert_eq!(urg.classify(4095, 3), Range::Mm(4095));
        let utm = RangeLimits {
            dmin: 23,
            family: ModelFamily::Utm,
        };
        assert_eq!(utm.classify(1, 3), Range::Error(RangeError::NoEcho));
        assert_eq!(utm.classify(22, 3), Range::Error(RangeError::Other));
        assert_eq!(utm.classify(65533, 3), Range::Mm(65533));
        let ust = RangeLimits {
            dmin: 20,
            family: ModelFamily::Ethernet,
        };
        assert_eq!(ust.classify(65533, 3), Range::Error(RangeError::NoEcho));
        assert_eq!(ust.classify(65535, 3), Range::Error(RangeError::Other));
        assert_eq!(ust.classify(65532, 3), Range::Mm(65532));
        // Model unknown (a stream without PP): the Ethernet codes are no ranges.
        let unknown = RangeLimits::default();
        assert_eq!(unknown.classify(65533, 3), Range::Error(RangeError::NoEcho));
        assert_eq!(unknown.classify(65534, 3), Range::Error(RangeError::Other));
        assert_eq!(unknown.classify(65535, 4), Range::Error(RangeError::Other));
        assert_eq!(unknown.classify(65536, 3), Range::Mm(65536));
        assert_eq!(unknown.classify(65532, 3), Range::Mm(65532));
    }

    #[test]
    fn range_test_agrees_with_classify() {
        let families = [
            ModelFamily::Unknown,
            ModelFamily::Urg04lx,
            ModelFamily::Utm,
            ModelFamily::Ethernet,
        ];
        for family in families {
            for dmin in [0, 20, 23] {
                let limits = RangeLimits { dmin, family };
                for width in [2, 3, 4] {
                    let test = limits.range_test(width);
                    let values = (0..70_000).chain([(1 << 18) - 1, (1 << 24) - 1]);
                    for d in values {
                        assert_eq!(
                            test.is_range(d),
                            matches!(limits.classify(d, width), Range::Mm(_)),
                            "{family:?} dmin {dmin} width {width} value {d}"
                        );
                    }
                }
            }
        }
    }
}
