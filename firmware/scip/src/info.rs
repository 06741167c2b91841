//! VV / PP / II fields, the typed PP parameters, and the meaning of error codes.

use core::fmt;

/// The name of a PP field the parameters are made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamName {
    /// `MODL`: the model string.
    Modl,
    /// `DMIN`.
    Dmin,
    /// `DMAX`.
    Dmax,
    /// `ARES`.
    Ares,
    /// `AMIN`.
    Amin,
    /// `AMAX`.
    Amax,
    /// `AFRT`.
    Afrt,
    /// `SCAN`.
    Scan,
}

impl ParamName {
    /// Every parameter, in the order a PP answer gives them.
    pub const ALL: [ParamName; 8] = [
        ParamName::Modl,
        ParamName::Dmin,
        ParamName::Dmax,
        ParamName::Ares,
        ParamName::Amin,
        ParamName::Amax,
        ParamName::Afrt,
        ParamName::Scan,
    ];

    /// The name of a PP field, if it is one of the parameters.
    pub fn from_name(name: &[u8]) -> Option<Self> {
        // The four letters as one word: one compare per name, no library call.
        let word = |n: &[u8; 4]| u32::from_le_bytes(*n);
        let name = word(name.try_into().ok()?);
        Some(match name {
            n if n == word(b"MODL") => Self::Modl,
            n if n == word(b"DMIN") => Self::Dmin,
            n if n == word(b"DMAX") => Self::Dmax,
            n if n == word(b"ARES") => Self::Ares,
            n if n == word(b"AMIN") => Self::Amin,
            n if n == word(b"AMAX") => Self::Amax,
            n if n == word(b"AFRT") => Self::Afrt,
            n if n == word(b"SCAN") => Self::Scan,
            _ => return None,
        })
    }

    /// The four letters of the field.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Modl => "MODL",
            Self::Dmin => "DMIN",
            Self::Dmax => "DMAX",
            Self::Ares => "ARES",
            Self::Amin => "AMIN",
            Self::Amax => "AMAX",
            Self::Afrt => "AFRT",
            Self::Scan => "SCAN",
        }
    }
}

impl fmt::Display for ParamName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why a PP answer's parameters are not trusted. A line's 6-bit sum cannot see a flip
/// of bit 6 or 7, so an intact-looking answer can still carry a damaged field: these
/// checks catch what the sum lets through.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamError {
    /// A field whose value is not whole: a number must be 1..=9 decimal digits and
    /// nothing else (a trailing `<-comment` aside); `MODL` must be printable ASCII.
    BadValue(ParamName),
    /// A field that came twice in one answer.
    Repeated(ParamName),
    /// A field that is missing.
    Missing(ParamName),
    /// `DMIN` is not below `DMAX`.
    DistanceOrder,
    /// Not `AMIN <= AFRT <= AMAX < ARES` (or `ARES` above 65535).
    StepOrder,
    /// `SCAN` outside [`SCAN_RPM_RANGE`].
    ScanSpeed,
    /// A value other than the one every unit of the model `MODL` names reports
    /// ([`KnownModel`]).
    NotTheModels(ParamName),
    /// `MODL` names another model than `VV`'s `PROD`.
    ModelConflict,
}

impl fmt::Display for ParamError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadValue(n) => write!(f, "PP {n}: damaged value"),
            Self::Repeated(n) => write!(f, "PP {n}: field repeated"),
            Self::Missing(n) => write!(f, "PP {n}: field missing"),
            Self::DistanceOrder => f.write_str("PP: DMIN not below DMAX"),
            Self::StepOrder => f.write_str("PP: not AMIN <= AFRT <= AMAX < ARES"),
            Self::ScanSpeed => f.write_str("PP: SCAN speed implausible"),
            Self::NotTheModels(n) => write!(f, "PP {n}: not the model's value"),
            Self::ModelConflict => f.write_str("PP MODL and VV PROD name different models"),
        }
    }
}

/// Motor speeds (`SCAN`, rpm) a sensor may report: Hokuyo scanners turn at 600 to 2400
/// rpm by default and `CR` changes that by a few percent; this range leaves a wide margin.
pub const SCAN_RPM_RANGE: core::ops::RangeInclusive<u32> = 60..=6000;

/// The value of a numeric PP field: the whole of it decimal digits (1..=9 of them), or
/// digits followed by a `<-comment` (as some firmware appends to info lines). Anything
/// else is damaged: the leading digits of `1440` with bit 6 of its `4` flipped are not
/// the value.
fn whole_number(value: &[u8]) -> Option<u32> {
    let digits = value
        .windows(2)
        .position(|w| matches!(w, [b'<', b'-']))
        .map_or(value, |i| value.get(..i).unwrap_or(&[]));
    if digits.is_empty() || digits.len() > 9 || !digits.iter().all(u8::is_ascii_digit) {
        return None;
    }
    Some(
        digits
            .iter()
            // At most 9 digits (< 10^9): never wraps.
            .fold(0u32, |acc, &c| {
                acc.wrapping_mul(10)
                    .wrapping_add(u32::from(c.wrapping_sub(b'0')))
            }),
    )
}

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
    /// Parses a numeric PP field; `None` for another name or a damaged value (see
    /// [`Param::try_parse`] to tell them apart).
    pub fn parse(name: &[u8], value: &[u8]) -> Option<Self> {
        Self::try_parse(name, value).ok().flatten()
    }

    /// Parses a numeric PP field: `Ok(None)` for a name that is not one of them
    /// (`MODL` included), [`ParamError::BadValue`] for a value that is not a whole
    /// decimal number.
    pub fn try_parse(name: &[u8], value: &[u8]) -> Result<Option<Self>, ParamError> {
        match ParamName::from_name(name) {
            Some(which) => Self::of(which, value),
            None => Ok(None),
        }
    }

    /// [`Param::try_parse`] of a field whose name is known.
    fn of(which: ParamName, value: &[u8]) -> Result<Option<Self>, ParamError> {
        let ctor: fn(u32) -> Param = match which {
            ParamName::Dmin => Param::Dmin,
            ParamName::Dmax => Param::Dmax,
            ParamName::Ares => Param::Ares,
            ParamName::Amin => Param::Amin,
            ParamName::Amax => Param::Amax,
            ParamName::Afrt => Param::Afrt,
            ParamName::Scan => Param::Scan,
            ParamName::Modl => return Ok(None),
        };
        match whole_number(value) {
            Some(v) => Ok(Some(ctor(v))),
            None => Err(ParamError::BadValue(which)),
        }
    }
}

/// A model whose geometry every unit reports the same (scip-reference §6): its PP values
/// are checked against these.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KnownModel {
    /// URG-04LX and URG-04LX-UG01.
    Urg04lx,
    /// UTM-30LX and UTM-30LX-EW.
    Utm30lx,
    /// UXM-30LX-E.
    Uxm30lxE,
    /// UST-10LX.
    Ust10lx,
}

impl KnownModel {
    /// The model a `MODL` (PP) or `PROD` (VV) string names, if it is a known one.
    pub fn from_model(model: &[u8]) -> Option<Self> {
        let has = |needle: &[u8]| contains(model, needle);
        if has(b"URG-04LX") {
            Some(Self::Urg04lx)
        } else if has(b"UTM-30LX") {
            Some(Self::Utm30lx)
        } else if has(b"UXM-30LX-E") {
            Some(Self::Uxm30lxE)
        } else if has(b"UST-10LX") {
            Some(Self::Ust10lx)
        } else {
            None
        }
    }

    /// The model's DMIN, DMAX, ARES, AMIN, AMAX and AFRT (SCAN is not fixed: `CR`
    /// changes it).
    pub const fn values(self) -> [(ParamName, u32); 6] {
        let [dmin, dmax, ares, amin, amax, afrt] = match self {
            Self::Urg04lx => [20, 5600, 1024, 44, 725, 384],
            Self::Utm30lx => [23, 60_000, 1440, 0, 1080, 540],
            Self::Uxm30lxE => [100, 100_000, 1440, 0, 760, 380],
            Self::Ust10lx => [20, 30_000, 1440, 0, 1080, 540],
        };
        [
            (ParamName::Dmin, dmin),
            (ParamName::Dmax, dmax),
            (ParamName::Ares, ares),
            (ParamName::Amin, amin),
            (ParamName::Amax, amax),
            (ParamName::Afrt, afrt),
        ]
    }
}

/// Whether `needle` (not empty) occurs in `model`: out of line, so that the model names'
/// needles share one loop. A window is compared further only where its first byte is
/// the needle's, byte by byte (no library call per window: a model string has dozens).
#[inline(never)]
fn contains(model: &[u8], needle: &[u8]) -> bool {
    let Some((&first, rest)) = needle.split_first() else {
        return false;
    };
    model.windows(needle.len()).any(|w| match w.split_first() {
        Some((&c, more)) => c == first && more.iter().zip(rest).all(|(a, b)| a == b),
        None => false,
    })
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
        let has = |needle: &[u8]| contains(model, needle);
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

    /// The value at or above [`RangeTest::min`] that is an error code besides the
    /// [`RangeTest::band`] (`u32::MAX` when none).
    pub fn exception(&self) -> u32 {
        self.not_a
    }

    /// The first of the three error codes [`ETHERNET_CODES`] when the test excludes
    /// them.
    pub fn band(&self) -> Option<u32> {
        self.band.then_some(*ETHERNET_CODES.start())
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

/// The typed PP parameters of a sensor, as collected from one PP answer's fields.
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
    /// The known model `MODL` names, if any.
    pub model: Option<KnownModel>,
    /// The first damaged or repeated field of the answer (its value was not taken).
    pub fault: Option<ParamError>,
}

impl SensorParams {
    /// No field yet.
    pub const EMPTY: Self = Self {
        dmin: None,
        dmax: None,
        ares: None,
        amin: None,
        amax: None,
        afrt: None,
        scan_rpm: None,
        family: None,
        model: None,
        fault: None,
    };

    /// Records one PP field. A damaged value (see [`Param::try_parse`]) or a field seen
    /// before is not taken, and recorded as the answer's [`SensorParams::fault`].
    pub fn apply(&mut self, name: &[u8], value: &[u8]) {
        self.apply_parsed(name, value);
    }

    /// [`SensorParams::apply`], returning what [`Param::parse`] gives for the field
    /// (a repeated field's value too, though it is not taken): the name is looked up
    /// and the value parsed once for both.
    pub(crate) fn apply_parsed(&mut self, name: &[u8], value: &[u8]) -> Option<Param> {
        let which = ParamName::from_name(name)?;
        if which == ParamName::Modl {
            if self.family.is_some() {
                self.fault.get_or_insert(ParamError::Repeated(which));
            } else if value.is_empty() || !value.iter().all(|c| (0x20..0x7F).contains(c)) {
                self.fault.get_or_insert(ParamError::BadValue(which));
            } else {
                self.family = Some(ModelFamily::from_model(value));
                self.model = KnownModel::from_model(value);
            }
            return None;
        }
        let parsed = Param::of(which, value);
        if self.get(which).is_some() {
            self.fault.get_or_insert(ParamError::Repeated(which));
            return parsed.ok().flatten();
        }
        match parsed {
            Ok(Some(Param::Dmin(v))) => self.dmin = Some(v),
            Ok(Some(Param::Dmax(v))) => self.dmax = Some(v),
            Ok(Some(Param::Ares(v))) => self.ares = Some(v),
            Ok(Some(Param::Amin(v))) => self.amin = Some(v),
            Ok(Some(Param::Amax(v))) => self.amax = Some(v),
            Ok(Some(Param::Afrt(v))) => self.afrt = Some(v),
            Ok(Some(Param::Scan(v))) => self.scan_rpm = Some(v),
            Ok(None) => {}
            Err(e) => {
                self.fault.get_or_insert(e);
            }
        }
        parsed.ok().flatten()
    }

    /// A field's value (`MODL`: 0 when present), if it was received whole.
    fn get(&self, name: ParamName) -> Option<u32> {
        match name {
            ParamName::Modl => self.family.map(|_| 0),
            ParamName::Dmin => self.dmin,
            ParamName::Dmax => self.dmax,
            ParamName::Ares => self.ares,
            ParamName::Amin => self.amin,
            ParamName::Amax => self.amax,
            ParamName::Afrt => self.afrt,
            ParamName::Scan => self.scan_rpm,
        }
    }

    /// Whether the parameters can be trusted: every field there once and whole,
    /// `DMIN < DMAX`, `AMIN <= AFRT <= AMAX < ARES <= 65535`, `SCAN` in
    /// [`SCAN_RPM_RANGE`], and, when `MODL` names a [`KnownModel`], that model's values.
    /// The first failed check is returned (the model's values are checked last, so that
    /// a caller may accept a unit that differs from its model's table but answers the
    /// same twice).
    pub fn check(&self) -> Result<(), ParamError> {
        if let Some(e) = self.fault {
            return Err(e);
        }
        let all = ParamName::ALL;
        let mut v = [0u32; 8];
        for (slot, name) in v.iter_mut().zip(all) {
            *slot = self.get(name).ok_or(ParamError::Missing(name))?;
        }
        let [_, dmin, dmax, ares, amin, amax, afrt, scan] = v;
        if dmin >= dmax {
            return Err(ParamError::DistanceOrder);
        }
        if !(amin <= afrt && afrt <= amax && amax < ares && ares <= 65_535) {
            return Err(ParamError::StepOrder);
        }
        if !SCAN_RPM_RANGE.contains(&scan) {
            return Err(ParamError::ScanSpeed);
        }
        if let Some(model) = self.model {
            for (name, value) in model.values() {
                if self.get(name) != Some(value) {
                    return Err(ParamError::NotTheModels(name));
                }
            }
        }
        Ok(())
    }

    /// Scan period in microseconds from `SCAN` (rpm), if known and non-zero.
    pub fn scan_period_us(&self) -> Option<u32> {
        self.scan_rpm.and_then(|r| 60_000_000u32.checked_div(r))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_parse() {
        assert_eq!(Param::parse(b"DMIN", b"20"), Some(Param::Dmin(20)));
        assert_eq!(Param::parse(b"SCAN", b"2400"), Some(Param::Scan(2400)));
        assert_eq!(Param::parse(b"AMIN", b"0"), Some(Param::Amin(0)));
        assert_eq!(Param::parse(b"DMIN", b"x"), None);
        assert_eq!(Param::parse(b"DMIN", b"12345678901"), None);
        assert_eq!(Param::parse(b"MODL", b"20"), None);
        let mut p = SensorParams::default();
        p.apply(b"MODL", b"UTM-30LX(Hokuyo Automatic Co.,Ltd.)");
        p.apply(b"SCAN", b"2400");
        assert_eq!(p.family, Some(ModelFamily::Utm));
        assert_eq!(p.model, Some(KnownModel::Utm30lx));
        assert_eq!(p.scan_period_us(), Some(25_000));
    }

    #[test]
    fn a_value_is_parsed_whole_or_not_at_all() {
        // `1440` with bit 6 of a digit flipped (the line sum cannot see it): not 144, 14
        // or 1, but a damaged field.
        for bad in [&b"144t"[..], b"14t0", b"1t40", b"q440", b"54p", b""] {
            assert_eq!(
                Param::try_parse(b"ARES", bad),
                Err(ParamError::BadValue(ParamName::Ares)),
                "{bad:?}"
            );
        }
        // Bit 7: not ASCII at all.
        assert_eq!(
            Param::try_parse(b"AFRT", &[b'5', b'4' | 0x80, b'0']),
            Err(ParamError::BadValue(ParamName::Afrt))
        );
        assert_eq!(
            Param::try_parse(b"DMIN", b"1234567890"),
            Err(ParamError::BadValue(ParamName::Dmin))
        );
        assert_eq!(
            Param::try_parse(b"ARES", b"1440"),
            Ok(Some(Param::Ares(1440)))
        );
        assert_eq!(
            Param::try_parse(b"ARES", b"1440<-default"),
            Ok(Some(Param::Ares(1440)))
        );
        assert_eq!(
            Param::try_parse(b"ARES", b"<-1440"),
            Err(ParamError::BadValue(ParamName::Ares))
        );
        assert_eq!(Param::try_parse(b"FOO", b"1t"), Ok(None));
        assert_eq!(Param::try_parse(b"MODL", b"x"), Ok(None));
    }

    /// The UTM-30LX's PP fields as the capture in the project's recordings has them.
    const UTM: [(&[u8], &[u8]); 8] = [
        (b"MODL", b"UTM-30LX(Hokuyo Automatic Co.,Ltd.)"),
        (b"DMIN", b"23"),
        (b"DMAX", b"60000"),
        (b"ARES", b"1440"),
        (b"AMIN", b"0"),
        (b"AMAX", b"1080"),
        (b"AFRT", b"540"),
        (b"SCAN", b"2400"),
    ];

    fn params(fields: &[(&[u8], &[u8])]) -> SensorParams {
        let mut p = SensorParams::default();
        for (n, v) in fields {
            p.apply(n, v);
        }
        p
    }

    fn with(name: &'static [u8], value: &'static [u8]) -> SensorParams {
        let mut f = UTM;
        for slot in &mut f {
            if slot.0 == name {
                slot.1 = value;
            }
        }
        params(&f)
    }

    #[test]
    fn checks() {
        let p = params(&UTM);
        assert_eq!(p.check(), Ok(()));
        assert_eq!(
            (p.ares, p.afrt, p.amin, p.amax, p.dmin, p.dmax, p.scan_rpm),
            (
                Some(1440),
                Some(540),
                Some(0),
                Some(1080),
                Some(23),
                Some(60000),
                Some(2400)
            )
        );
        // Damaged, missing, repeated.
        assert_eq!(
            with(b"ARES", b"144t").check(),
            Err(ParamError::BadValue(ParamName::Ares))
        );
        assert_eq!(with(b"ARES", b"144t").ares, None);
        assert_eq!(
            params(&UTM[..7]).check(),
            Err(ParamError::Missing(ParamName::Scan))
        );
        assert_eq!(
            params(&UTM[1..]).check(),
            Err(ParamError::Missing(ParamName::Modl))
        );
        let mut p = params(&UTM);
        p.apply(b"AFRT", b"541");
        assert_eq!(p.check(), Err(ParamError::Repeated(ParamName::Afrt)));
        assert_eq!(p.afrt, Some(540));
        // A flip to another printable char: taken, but no longer a known model.
        let p = with(b"MODL", b"UTM-s0LX(Hokuyo Automatic Co.,Ltd.)");
        assert_eq!(
            (p.check(), p.model, p.family),
            (Ok(()), None, Some(ModelFamily::Utm))
        );
        assert_eq!(
            with(b"MODL", &[b'U' ^ 0x40, b'T', b'M']).check(),
            Err(ParamError::BadValue(ParamName::Modl))
        );
        // Implausible relations (an unknown model, so that only they are checked).
        let odd = |name, value| {
            let mut p = with(name, value);
            p.model = None;
            p.check()
        };
        assert_eq!(odd(b"MODL", b"X"), Ok(()));
        assert_eq!(odd(b"DMIN", b"60000"), Err(ParamError::DistanceOrder));
        assert_eq!(odd(b"AFRT", b"1081"), Err(ParamError::StepOrder));
        assert_eq!(odd(b"AMIN", b"541"), Err(ParamError::StepOrder));
        assert_eq!(odd(b"ARES", b"1080"), Err(ParamError::StepOrder));
        assert_eq!(odd(b"SCAN", b"0"), Err(ParamError::ScanSpeed));
        assert_eq!(odd(b"SCAN", b"24000"), Err(ParamError::ScanSpeed));
        assert_eq!(odd(b"ARES", b"2048"), Ok(()));
        // The model's own values.
        assert_eq!(
            with(b"ARES", b"2048").check(),
            Err(ParamError::NotTheModels(ParamName::Ares))
        );
        assert_eq!(
            with(b"AFRT", b"541").check(),
            Err(ParamError::NotTheModels(ParamName::Afrt))
        );
        assert_eq!(
            with(b"SCAN", b"2200").check(),
            Ok(()),
            "CR may change the speed"
        );
    }

    #[test]
    fn known_models() {
        for (text, model) in [
            (
                &b"URG-04LX(Hokuyo Automatic Co.,Ltd.)"[..],
                KnownModel::Urg04lx,
            ),
            (
                b"SOKUIKI Sensor URG-04LX-UG01(Simple-URG)",
                KnownModel::Urg04lx,
            ),
            (b"SOKUIKI Sensor TOP-URG UTM-30LX", KnownModel::Utm30lx),
            (
                b"UXM-30LX-E(Hokuyo Automatic Co.,Ltd.)",
                KnownModel::Uxm30lxE,
            ),
            (b"UST-10LX", KnownModel::Ust10lx),
        ] {
            assert_eq!(KnownModel::from_model(text), Some(model));
        }
        assert_eq!(KnownModel::from_model(b"UST-20LX"), None);
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

    /// The word lookup of the names against the names spelled out, and near misses.
    #[test]
    fn names_by_word() {
        let all = ParamName::ALL;
        for n in all {
            assert_eq!(ParamName::from_name(n.as_str().as_bytes()), Some(n));
        }
        for other in [
            &b""[..],
            b"DMI",
            b"DMINX",
            b"dmin",
            b"DMIn",
            b"NIMD",
            b"MODL ",
            b"\0MODL",
            b"PROD",
        ] {
            assert_eq!(ParamName::from_name(other), None, "{other:?}");
        }
    }

    /// `contains` against the plain definition (some window equals the needle), at
    /// the start, the end, cut off at the end, and with the first byte repeated.
    #[test]
    fn contains_agrees_with_windows() {
        let reference = |model: &[u8], needle: &[u8]| {
            !needle.is_empty() && model.windows(needle.len()).any(|w| w == needle)
        };
        let models: [&[u8]; 9] = [
            b"",
            b"U",
            b"UTM-30LX(Hokuyo Automatic Co.,Ltd.)",
            b"UUTM",
            b"xxUXM-30LX-",
            b"UXM-30LX-E",
            b"URG-04LX-UG01",
            b"SOKUIKI Sensor UST-10LX",
            b"-E(-EW",
        ];
        let needles: [&[u8]; 9] = [
            b"",
            b"U",
            b"UTM",
            b"UXM-30LX-E",
            b"URG-04LX",
            b"-EW",
            b"-E(",
            b"UST",
            b"X",
        ];
        for model in models {
            for needle in needles {
                assert_eq!(
                    contains(model, needle),
                    reference(model, needle),
                    "{model:?} {needle:?}"
                );
            }
        }
    }

    /// What `apply_parsed` returns is `Param::parse` of the field, whether the field
    /// is taken, repeated or damaged; the parameters recorded, by hand.
    #[test]
    fn apply_parsed_returns_the_parse() {
        let fields: [(&[u8], &[u8]); 12] = [
            (b"MODL", b"URG-04LX(Hokuyo Automatic Co.,Ltd.)"),
            (b"DMIN", b"20"),
            (b"DMAX", b"5600<-comment"),
            (b"ARES", b"1024"),
            (b"AMIN", b"44"),
            (b"AMAX", b"725"),
            (b"AFRT", b"38q"),
            (b"SCAN", b"600"),
            (b"DMIN", b"21"),
            (b"MODL", b"UTM-30LX"),
            (b"PROD", b"x"),
            (b"SCAN", b"x"),
        ];
        let mut a = SensorParams::default();
        for (name, value) in fields {
            assert_eq!(a.apply_parsed(name, value), Param::parse(name, value));
        }
        // The first of each taken, the damaged one not, the first fault kept.
        assert_eq!(a.model, Some(KnownModel::Urg04lx));
        assert_eq!(
            (a.ares, a.amin, a.amax, a.scan_rpm),
            (Some(1024), Some(44), Some(725), Some(600))
        );
        assert_eq!(a.dmin, Some(20));
        assert_eq!(a.dmax, Some(5600));
        assert_eq!(a.afrt, None);
        assert_eq!(a.family, Some(ModelFamily::Urg04lx));
        assert_eq!(a.fault, Some(ParamError::BadValue(ParamName::Afrt)));
    }
}
