//! The simulated sensor models: their VV/PP/II text, limits, link and capabilities.
//!
//! URG-04LX and UTM-30LX text is byte for byte what the real units in the project's
//! recordings answered; UST-10LX and UXM-30LX-E text follows the same layout with the
//! PP values of scip-reference §6 (no capture of those models exists yet).

use scip::ModelFamily;

/// Which model a simulator plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ModelKind {
    /// URG-04LX: RS-232 at 19200 bit/s by default, boots in SCIP 1.1.
    Urg04lx,
    /// UTM-30LX: USB, SCIP 2.0 with the 2.1 intensity and multi-echo commands.
    Utm30lx,
    /// UST-10LX: Ethernet, SCIP 2.2 flavour (`%ST`, `%SL`, its own status codes).
    Ust10lx,
    /// UXM-30LX-E: 100 m outdoor sensor on Ethernet, SCIP 2.1.
    Uxm30lxE,
}

impl ModelKind {
    /// Every model, in the order of the help text.
    pub const ALL: [ModelKind; 4] = [
        ModelKind::Urg04lx,
        ModelKind::Utm30lx,
        ModelKind::Ust10lx,
        ModelKind::Uxm30lxE,
    ];

    /// The short name used on the command line (`urg04lx`, `utm30lx`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Urg04lx => "urg04lx",
            Self::Utm30lx => "utm30lx",
            Self::Ust10lx => "ust10lx",
            Self::Uxm30lxE => "uxm30lxe",
        }
    }

    /// Parses a model name: the short name or the product name, any case, `-`/`_` ignored.
    pub fn parse(text: &str) -> Option<Self> {
        let norm: String = text
            .chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .map(|c| c.to_ascii_lowercase())
            .collect();
        Self::ALL.into_iter().find(|m| m.name() == norm)
    }
}

/// What makes a simulated unit's values rougher than the scene: the measure of
/// [`super::measure`]. The URG-04LX and UTM-30LX figures are fitted to the real captures
/// (BENCHMARKS.md, "Simulated noise against the real captures"); the UST-10LX and
/// UXM-30LX-E keep a constant σ (no capture of them to fit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// Range noise σ at 0 m, mm.
    pub sigma_mm: f64,
    /// Growth of the range noise σ per metre of range, mm.
    pub sigma_per_m: f64,
    /// Chance that a step repeats the value of the step before (real units send runs of
    /// equal values: about 30 % of consecutive pairs in the captures).
    pub hold: f64,
    /// Intensity noise σ relative to the intensity.
    pub intensity: f64,
}

impl Noise {
    /// No noise at all: the scene's exact values.
    pub const EXACT: Noise = Noise::constant(0.0);

    /// A constant range noise σ of `sigma_mm`, nothing else (`--noise`).
    pub const fn constant(sigma_mm: f64) -> Self {
        Self {
            sigma_mm,
            sigma_per_m: 0.0,
            hold: 0.0,
            intensity: 0.0,
        }
    }

    /// The range noise σ in mm at `distance_mm`.
    pub fn sigma_at(&self, distance_mm: f64) -> f64 {
        self.sigma_mm + self.sigma_per_m * distance_mm / 1000.0
    }

    /// Whether nothing is added to the scene's values.
    pub fn is_exact(&self) -> bool {
        self.sigma_mm <= 0.0 && self.sigma_per_m <= 0.0 && self.hold <= 0.0 && self.intensity <= 0.0
    }
}

/// How the model talks to its host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkKind {
    /// RS-232 (or USB CDC) with a settable bit rate; the power-on rate.
    Serial(u32),
    /// USB full speed (SS accepted, but the rate means nothing).
    Usb,
    /// Ethernet (SS refused).
    Ethernet,
}

/// A sensor model: everything the simulator answers that does not depend on state.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// Which model.
    pub kind: ModelKind,
    /// The VV fields in order (VEND, PROD, FIRM, PROT, SERI).
    pub version: Vec<(String, String)>,
    /// The PP `MODL` text (also II's `MODL`).
    pub modl: String,
    /// PP `DMIN` in mm.
    pub dmin: u32,
    /// PP `DMAX` in mm.
    pub dmax: u32,
    /// PP `ARES`: steps per turn.
    pub ares: u32,
    /// PP `AMIN`: first measurable step.
    pub amin: u32,
    /// PP `AMAX`: last measurable step.
    pub amax: u32,
    /// PP `AFRT`: the forward step.
    pub afrt: u32,
    /// PP `SCAN`: default motor speed in rpm.
    pub scan_rpm: u32,
    /// How error codes are chosen (and read by the decoder).
    pub family: ModelFamily,
    /// Speaks the SCIP 2.2 dialect (`%ST`, `%SL`, `0F`/`0H`/`0D` statuses).
    pub scip22: bool,
    /// Boots in SCIP 1.1 and needs `SCIP2.0`.
    pub boots_scip11: bool,
    /// The link.
    pub link: LinkKind,
    /// Answers GE/ME, GR/MR, GI/MI.
    pub intensity: bool,
    /// Answers the multi-echo HD/ND/HE/NE.
    pub multi_echo: bool,
    /// Accepts `CR` (motor speed steps).
    pub motor_speed: bool,
    /// Range noise, held values and intensity noise (see [`Noise`]).
    pub noise: Noise,
    /// The II `TIME` as 4 SCIP chars (UST) instead of 6 hex digits.
    pub time_encoded: bool,
}

fn fields(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|(n, v)| ((*n).to_owned(), (*v).to_owned()))
        .collect()
}

impl Model {
    /// The model's description as the real unit gives it.
    pub fn new(kind: ModelKind) -> Self {
        match kind {
            ModelKind::Urg04lx => Self {
                kind,
                version: fields(&[
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", "SOKUIKI Sensor URG-04LX"),
                    ("FIRM", "3.1.04(02/Aug./2007)"),
                    ("PROT", "SCIP 2.0"),
                    ("SERI", "H0706400"),
                ]),
                modl: "URG-04LX(Hokuyo Automatic Co.,Ltd.)".into(),
                dmin: 20,
                dmax: 5600,
                ares: 1024,
                amin: 44,
                amax: 725,
                afrt: 384,
                scan_rpm: 600,
                family: ModelFamily::Urg04lx,
                scip22: false,
                boots_scip11: true,
                link: LinkKind::Serial(19_200),
                intensity: false,
                multi_echo: false,
                motor_speed: true,
                noise: Noise {
                    sigma_mm: 1.0,
                    sigma_per_m: 1.5,
                    hold: 0.28,
                    intensity: 0.013,
                },
                time_encoded: false,
            },
            ModelKind::Utm30lx => Self {
                kind,
                version: fields(&[
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", "SOKUIKI Sensor TOP-URG UTM-30LX"),
                    ("FIRM", "P.1.05(17/Apr./2009)"),
                    ("PROT", "SCIP 2.0"),
                    ("SERI", "00903971"),
                ]),
                modl: "UTM-30LX(Hokuyo Automatic Co.,Ltd.)".into(),
                dmin: 23,
                dmax: 60_000,
                ares: 1440,
                amin: 0,
                amax: 1080,
                afrt: 540,
                scan_rpm: 2400,
                family: ModelFamily::Utm,
                scip22: false,
                boots_scip11: false,
                link: LinkKind::Usb,
                intensity: true,
                multi_echo: true,
                motor_speed: false,
                noise: Noise {
                    sigma_mm: 1.0,
                    sigma_per_m: 0.4,
                    hold: 0.28,
                    intensity: 0.013,
                },
                time_encoded: false,
            },
            ModelKind::Ust10lx => Self {
                kind,
                version: fields(&[
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", "SOKUIKI Sensor UST-10LX"),
                    ("FIRM", "1.0.4(02/Sep./2014)"),
                    ("PROT", "SCIP 2.2"),
                    ("SERI", "H1412345"),
                ]),
                modl: "UST-10LX".into(),
                dmin: 20,
                dmax: 30_000,
                ares: 1440,
                amin: 0,
                amax: 1080,
                afrt: 540,
                scan_rpm: 2400,
                family: ModelFamily::Ethernet,
                scip22: true,
                boots_scip11: false,
                link: LinkKind::Ethernet,
                intensity: true,
                multi_echo: false,
                motor_speed: false,
                noise: Noise {
                    intensity: 0.01,
                    ..Noise::constant(15.0)
                },
                time_encoded: true,
            },
            ModelKind::Uxm30lxE => Self {
                kind,
                version: fields(&[
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", "SOKUIKI Sensor UXM-30LX-E"),
                    ("FIRM", "1.1.2(20/Jun./2013)"),
                    ("PROT", "SCIP 2.1"),
                    ("SERI", "H1300123"),
                ]),
                modl: "UXM-30LX-E(Hokuyo Automatic Co.,Ltd.)".into(),
                dmin: 100,
                dmax: 100_000,
                ares: 1440,
                amin: 0,
                amax: 760,
                afrt: 380,
                scan_rpm: 1200,
                family: ModelFamily::Ethernet,
                scip22: false,
                boots_scip11: false,
                link: LinkKind::Ethernet,
                intensity: true,
                multi_echo: true,
                motor_speed: false,
                noise: Noise {
                    intensity: 0.01,
                    ..Noise::constant(30.0)
                },
                time_encoded: false,
            },
        }
    }

    /// The PP fields in order, as text.
    pub fn parameters(&self, scan_rpm: u32) -> Vec<(String, String)> {
        vec![
            ("MODL".into(), self.modl.clone()),
            ("DMIN".into(), self.dmin.to_string()),
            ("DMAX".into(), self.dmax.to_string()),
            ("ARES".into(), self.ares.to_string()),
            ("AMIN".into(), self.amin.to_string()),
            ("AMAX".into(), self.amax.to_string()),
            ("AFRT".into(), self.afrt.to_string()),
            ("SCAN".into(), scan_rpm.to_string()),
        ]
    }

    /// The power-on bit rate (serial models), `None` for USB and Ethernet.
    pub fn default_bit_rate(&self) -> Option<u32> {
        match self.link {
            LinkKind::Serial(rate) => Some(rate),
            _ => None,
        }
    }

    /// Scan period in microseconds at `rpm`.
    pub fn scan_period_us(rpm: u32) -> u64 {
        60_000_000 / u64::from(rpm.max(1))
    }

    /// The angle of `step` in radians, counter-clockwise from forward.
    pub fn angle(&self, step: f64) -> f64 {
        (step - f64::from(self.afrt)) * core::f64::consts::TAU / f64::from(self.ares)
    }

    /// The error code for "no echo / nothing in range" of this model's family.
    pub fn no_echo_code(&self) -> u32 {
        match self.family {
            ModelFamily::Urg04lx => 0,
            ModelFamily::Ethernet => 65_533,
            _ => 1,
        }
    }

    /// The error code for "object nearer than DMIN".
    pub fn too_near_code(&self) -> u32 {
        match self.family {
            ModelFamily::Urg04lx => 19,
            _ => 2,
        }
    }

    /// The error code for "reflected light too weak".
    pub fn weak_code(&self) -> u32 {
        match self.family {
            ModelFamily::Urg04lx => 1,
            _ => self.no_echo_code(),
        }
    }

    /// Replaces texts and PP limits with those of a recorded session (VV/PP fields),
    /// keeping this model's behaviour for everything not recorded.
    pub fn with_recorded(
        mut self,
        version: &[(String, String)],
        params: &[(String, String)],
    ) -> Self {
        if !version.is_empty() {
            self.version = version.to_vec();
        }
        for (name, value) in params {
            let num = value
                .chars()
                .take_while(char::is_ascii_digit)
                .collect::<String>()
                .parse::<u32>()
                .ok();
            match (name.as_str(), num) {
                ("MODL", _) => {
                    self.modl = value.clone();
                    self.family = ModelFamily::from_model(value.as_bytes());
                }
                ("DMIN", Some(v)) => self.dmin = v,
                ("DMAX", Some(v)) => self.dmax = v,
                ("ARES", Some(v)) if v > 0 => self.ares = v,
                ("AMIN", Some(v)) => self.amin = v,
                ("AMAX", Some(v)) => self.amax = v,
                ("AFRT", Some(v)) => self.afrt = v,
                ("SCAN", Some(v)) if v > 0 => self.scan_rpm = v,
                _ => {}
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for m in ModelKind::ALL {
            assert_eq!(ModelKind::parse(m.name()), Some(m));
        }
        assert_eq!(ModelKind::parse("URG-04LX"), Some(ModelKind::Urg04lx));
        assert_eq!(ModelKind::parse("UXM-30LX-E"), Some(ModelKind::Uxm30lxE));
        assert_eq!(ModelKind::parse("utm"), None);
    }

    #[test]
    fn periods_and_angles() {
        let urg = Model::new(ModelKind::Urg04lx);
        assert_eq!(Model::scan_period_us(urg.scan_rpm), 100_000);
        assert_eq!(Model::scan_period_us(2400), 25_000);
        assert!((urg.angle(384.0)).abs() < 1e-12);
        // 256 steps of 1024 are a quarter turn.
        assert!((urg.angle(640.0) - core::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn family_matches_the_decoder() {
        for m in ModelKind::ALL {
            let model = Model::new(m);
            assert_eq!(ModelFamily::from_model(model.modl.as_bytes()), model.family);
        }
    }
}
