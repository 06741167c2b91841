//! Host → sensor commands: typed requests, their encoder, and the echo parser.
//!
//! A [`Request`] is a [`Command`] plus an optional [`Tag`]. [`Request::encode`] writes the
//! exact bytes a host sends (LF-terminated); [`Request::parse`] reads the echo line a
//! sensor sends back (without its LF), so an echo round-trips into the same request.

use core::fmt;

/// Longest tag a sensor accepts (scip-reference §2).
pub const TAG_MAX: usize = 16;

/// Longest encoded request, LF included: `NE` + 13 digits + `;` + 16-char tag + LF.
pub const REQUEST_MAX: usize = 2 + 13 + 1 + TAG_MAX + 1;

/// The bit rates `SS` accepts, in bit/s.
pub const BIT_RATES: [u32; 7] = [19_200, 38_400, 57_600, 115_200, 250_000, 500_000, 750_000];

/// Why a request cannot be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The end step is before the start step.
    EndBeforeStart,
    /// A step is above 9999 (4 decimal digits).
    StepOutOfRange,
    /// Cluster count 0 or above 99.
    BadCluster,
    /// Skip count above 9 (1 decimal digit).
    BadSkip,
    /// Scan count above 99.
    BadCount,
    /// Multi-echo asked of a data set that has no multi-echo form (only D and E do).
    NoMultiEcho,
    /// `SS` with a bit rate not in [`BIT_RATES`].
    BadBitRate,
    /// `CR` speed not 0..=10 or 99.
    BadMotorSpeed,
    /// `TM` mode above 2.
    BadTimeMode,
    /// Tag longer than [`TAG_MAX`] chars.
    TagTooLong,
    /// Tag with a char outside printable ASCII `0x21..=0x7E`.
    BadTagChar,
    /// The output buffer is too small.
    BufferTooSmall,
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::EndBeforeStart => "end step is before start step",
            Self::StepOutOfRange => "step above 9999",
            Self::BadCluster => "cluster count must be 1..=99",
            Self::BadSkip => "skip count must be 0..=9",
            Self::BadCount => "scan count must be 0..=99",
            Self::NoMultiEcho => "multi-echo exists only for distance and distance+intensity",
            Self::BadBitRate => "bit rate not supported by SS",
            Self::BadMotorSpeed => "motor speed must be 0..=10 or 99",
            Self::BadTimeMode => "TM mode must be 0, 1 or 2",
            Self::TagTooLong => "tag longer than 16 chars",
            Self::BadTagChar => "tag char outside printable ASCII",
            Self::BufferTooSmall => "output buffer too small",
        })
    }
}

/// Why an echo line is not a known command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EchoError {
    /// The command code is not one of scip-reference §4.
    UnknownCommand,
    /// Parameters of the wrong length or not decimal.
    BadParameters,
    /// The tag is too long or has a bad char.
    BadTag,
}

impl fmt::Display for EchoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::UnknownCommand => "unknown command",
            Self::BadParameters => "bad command parameters",
            Self::BadTag => "bad tag",
        })
    }
}

/// What one step of a measurement carries, i.e. the second letter of G*/M*/H*/N*.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataSet {
    /// `D`: distance, 3 chars.
    Distance,
    /// `S`: distance, 2 chars (short range; 4095 = over range).
    ShortDistance,
    /// `E`: distance 3 chars + intensity 3 chars (SCIP 2.1).
    DistanceIntensity,
    /// `R`: distance 3 chars + reflection coefficient 2 chars, white paper = 256 (SCIP 2.1).
    DistanceReflectance,
    /// `I`: distance 3 chars + intensity/aux 4 chars (SCIP 2.1).
    DistanceAux,
}

impl DataSet {
    /// Chars of the distance value.
    pub const fn distance_width(self) -> u8 {
        match self {
            Self::ShortDistance => 2,
            _ => 3,
        }
    }

    /// Chars of the second channel (intensity, reflectance, aux), 0 when absent.
    pub const fn aux_width(self) -> u8 {
        match self {
            Self::Distance | Self::ShortDistance => 0,
            Self::DistanceIntensity => 3,
            Self::DistanceReflectance => 2,
            Self::DistanceAux => 4,
        }
    }

    const fn letter(self) -> u8 {
        match self {
            Self::Distance => b'D',
            Self::ShortDistance => b'S',
            Self::DistanceIntensity => b'E',
            Self::DistanceReflectance => b'R',
            Self::DistanceAux => b'I',
        }
    }

    const fn from_letter(c: u8) -> Option<Self> {
        Some(match c {
            b'D' => Self::Distance,
            b'S' => Self::ShortDistance,
            b'E' => Self::DistanceIntensity,
            b'R' => Self::DistanceReflectance,
            b'I' => Self::DistanceAux,
            _ => return None,
        })
    }
}

/// Single scan (`G`/`H`) or continuous stream (`M`/`N`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScanMode {
    /// One scan already being measured (needs `BM`).
    Single,
    /// `count` scans (0 = until `QT`/`RS`), laser switched on by the command.
    Continuous,
}

/// A measurement request: GD GS GE GR GI, MD MS ME MR MI, HD ND HE NE.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanRequest {
    /// Single or continuous.
    pub mode: ScanMode,
    /// What each step carries.
    pub data: DataSet,
    /// Multi-echo form (`H*`/`N*`).
    pub multi_echo: bool,
    /// First step.
    pub start: u16,
    /// Last step (inclusive).
    pub end: u16,
    /// Neighbouring steps merged into one value; the parser keeps a sensor's `00` as 0.
    pub cluster: u8,
    /// Scans skipped between two sent (continuous only).
    pub skip: u8,
    /// Scans to send, 0 = until stopped (continuous only); in a stream frame's echo,
    /// the scans still to come.
    pub count: u8,
}

impl ScanRequest {
    /// A distance request over `start..=end`, cluster 1, in the given mode.
    pub const fn distance(mode: ScanMode, start: u16, end: u16) -> Self {
        Self {
            mode,
            data: DataSet::Distance,
            multi_echo: false,
            start,
            end,
            cluster: 1,
            skip: 0,
            count: 0,
        }
    }

    /// Number of values per scan: `ceil((end - start + 1) / cluster)`, cluster 0 as 1.
    /// 0 when `end < start`; saturates at `u16::MAX` (only `0..=65535` in clusters of
    /// 1 would need 65536; SCIP steps have 4 digits).
    pub const fn value_count(&self) -> u16 {
        if self.end < self.start {
            return 0;
        }
        // `end >= start`: exact, at most 65536.
        let steps = (self.end as u32)
            .wrapping_sub(self.start as u32)
            .wrapping_add(1);
        let c = if self.cluster == 0 {
            1
        } else {
            self.cluster as u32
        };
        let n = steps.div_ceil(c);
        if n > u16::MAX as u32 {
            u16::MAX
        } else {
            n as u16
        }
    }

    /// The two command letters.
    pub const fn code(&self) -> [u8; 2] {
        let first = match (self.mode, self.multi_echo) {
            (ScanMode::Single, false) => b'G',
            (ScanMode::Continuous, false) => b'M',
            (ScanMode::Single, true) => b'H',
            (ScanMode::Continuous, true) => b'N',
        };
        [first, self.data.letter()]
    }

    fn validate(&self) -> Result<(), EncodeError> {
        if self.start > 9999 || self.end > 9999 {
            return Err(EncodeError::StepOutOfRange);
        }
        if self.end < self.start {
            return Err(EncodeError::EndBeforeStart);
        }
        if self.cluster == 0 || self.cluster > 99 {
            return Err(EncodeError::BadCluster);
        }
        if self.skip > 9 {
            return Err(EncodeError::BadSkip);
        }
        if self.count > 99 {
            return Err(EncodeError::BadCount);
        }
        if self.multi_echo && !matches!(self.data, DataSet::Distance | DataSet::DistanceIntensity) {
            return Err(EncodeError::NoMultiEcho);
        }
        Ok(())
    }
}

/// `TM` sub-command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimeMode {
    /// `TM0`: enter time-adjust mode.
    Enter,
    /// `TM1`: read the sensor's time.
    Read,
    /// `TM2`: leave time-adjust mode.
    Leave,
}

/// A SCIP command without its tag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// `SCIP2.0`: switch a SCIP 1.1 sensor to SCIP 2.0.
    Scip20,
    /// `VV`: version information.
    Version,
    /// `PP`: sensor parameters.
    Parameters,
    /// `II`: status information.
    Info,
    /// `BM`: laser on.
    LaserOn,
    /// `QT`: laser off, stops any stream.
    LaserOff,
    /// `RS`: reset to power-on state.
    Reset,
    /// `RT`: reset, keeping motor speed and bit rate.
    PartialReset,
    /// `SS`: bit rate in bit/s.
    BitRate(u32),
    /// `CR`: motor speed step (0 default, 1..=10, 99 reset).
    MotorSpeed(u8),
    /// `TM0`/`TM1`/`TM2`.
    Time(TimeMode),
    /// `HS0`/`HS1`: high sensitivity off/on.
    Sensitivity(bool),
    /// A measurement (G*/M*/H*/N*).
    Scan(ScanRequest),
    /// `%ST`: state (SCIP 2.2).
    State,
    /// `%SL`: sleep (SCIP 2.2).
    Sleep,
}

/// A tag: up to 16 printable chars echoed back after `;`.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Tag {
    bytes: [u8; TAG_MAX],
    len: u8,
}

impl Tag {
    /// A tag from bytes; checks length and chars.
    pub fn new(text: &[u8]) -> Result<Self, EncodeError> {
        if text.len() > TAG_MAX {
            return Err(EncodeError::TagTooLong);
        }
        let mut bytes = [0u8; TAG_MAX];
        for (slot, &c) in bytes.iter_mut().zip(text) {
            if !(0x21..=0x7E).contains(&c) {
                return Err(EncodeError::BadTagChar);
            }
            *slot = c;
        }
        Ok(Self {
            bytes,
            len: text.len() as u8,
        })
    }

    /// The tag's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// The tag as text (always ASCII).
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(self.as_bytes()).unwrap_or("")
    }

    /// True when empty (no `;tag` part).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl fmt::Debug for Tag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Tag({:?})", self.as_str())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Tag {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "Tag({=[u8]:a})", self.as_bytes())
    }
}

/// A command with its optional tag: what the host sends and the sensor echoes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Request {
    /// The command.
    pub command: Command,
    /// The tag, empty when absent.
    pub tag: Tag,
}

impl From<Command> for Request {
    fn from(command: Command) -> Self {
        Self {
            command,
            tag: Tag::default(),
        }
    }
}

/// A small cursor that writes into a byte slice without panicking.
struct Writer<'a> {
    out: &'a mut [u8],
    pos: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) -> Result<(), EncodeError> {
        let end = self
            .pos
            .checked_add(b.len())
            .ok_or(EncodeError::BufferTooSmall)?;
        self.out
            .get_mut(self.pos..end)
            .ok_or(EncodeError::BufferTooSmall)?
            .copy_from_slice(b);
        self.pos = end;
        Ok(())
    }

    /// `value` as exactly `width` decimal digits (the caller checked it fits).
    fn digits(&mut self, value: u32, width: u32) -> Result<(), EncodeError> {
        let mut buf = [0u8; 10];
        let mut v = value;
        let w = width as usize;
        for slot in buf.iter_mut().take(w).rev() {
            // `v % 10` is a digit: never wraps.
            *slot = b'0'.wrapping_add((v % 10) as u8);
            v /= 10;
        }
        self.bytes(buf.get(..w).unwrap_or(&[]))
    }
}

impl Request {
    /// A request without a tag.
    pub const fn new(command: Command) -> Self {
        Self {
            command,
            tag: Tag {
                bytes: [0; TAG_MAX],
                len: 0,
            },
        }
    }

    /// The same request with a tag.
    pub fn with_tag(self, tag: &[u8]) -> Result<Self, EncodeError> {
        Ok(Self {
            tag: Tag::new(tag)?,
            ..self
        })
    }

    /// Writes the command line (LF-terminated) into `out`; returns the bytes written.
    /// Parameters a sensor would refuse are an error.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        self.write(out, true)
    }

    /// Writes the line as a sensor echoes it, LF-terminated: like [`Self::encode`] but
    /// without refusing parameters, so that any parsed echo (e.g. a sensor's cluster
    /// `00`) is written back byte for byte. Fields must still fit their digits.
    pub fn encode_echo(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        self.write(out, false)
    }

    fn write(&self, out: &mut [u8], validate: bool) -> Result<usize, EncodeError> {
        let mut w = Writer { out, pos: 0 };
        match self.command {
            Command::Scip20 => w.bytes(b"SCIP2.0")?,
            Command::Version => w.bytes(b"VV")?,
            Command::Parameters => w.bytes(b"PP")?,
            Command::Info => w.bytes(b"II")?,
            Command::LaserOn => w.bytes(b"BM")?,
            Command::LaserOff => w.bytes(b"QT")?,
            Command::Reset => w.bytes(b"RS")?,
            Command::PartialReset => w.bytes(b"RT")?,
            Command::State => w.bytes(b"%ST")?,
            Command::Sleep => w.bytes(b"%SL")?,
            Command::BitRate(rate) => {
                if validate && !BIT_RATES.contains(&rate) || rate > 999_999 {
                    return Err(EncodeError::BadBitRate);
                }
                w.bytes(b"SS")?;
                w.digits(rate, 6)?;
            }
            Command::MotorSpeed(speed) => {
                if validate && speed > 10 && speed != 99 || speed > 99 {
                    return Err(EncodeError::BadMotorSpeed);
                }
                w.bytes(b"CR")?;
                w.digits(u32::from(speed), 2)?;
            }
            Command::Time(mode) => {
                w.bytes(b"TM")?;
                w.bytes(match mode {
                    TimeMode::Enter => b"0",
                    TimeMode::Read => b"1",
                    TimeMode::Leave => b"2",
                })?;
            }
            Command::Sensitivity(on) => w.bytes(if on { b"HS1" } else { b"HS0" })?,
            Command::Scan(scan) => {
                if validate {
                    scan.validate()?;
                } else if scan.start > 9999 || scan.end > 9999 {
                    return Err(EncodeError::StepOutOfRange);
                } else if scan.cluster > 99 || scan.skip > 9 || scan.count > 99 {
                    return Err(EncodeError::BadCount);
                }
                w.bytes(&scan.code())?;
                w.digits(u32::from(scan.start), 4)?;
                w.digits(u32::from(scan.end), 4)?;
                w.digits(u32::from(scan.cluster), 2)?;
                if scan.mode == ScanMode::Continuous {
                    w.digits(u32::from(scan.skip), 1)?;
                    w.digits(u32::from(scan.count), 2)?;
                }
            }
        }
        if !self.tag.is_empty() {
            w.bytes(b";")?;
            w.bytes(self.tag.as_bytes())?;
        }
        w.bytes(b"\n")?;
        Ok(w.pos)
    }

    /// Parses an echo line (without LF): the command as the sensor received it.
    pub fn parse(line: &[u8]) -> Result<Self, EchoError> {
        let mut parts = line.splitn(2, |&c| c == b';');
        let body = parts.next().unwrap_or(&[]);
        let tag = parts.next().unwrap_or(&[]);
        let tag = Tag::new(tag).map_err(|_| EchoError::BadTag)?;
        Ok(Self {
            command: parse_command(body)?,
            tag,
        })
    }
}

/// A command line split into its parts without judging them: what a sensor looks at
/// to choose the status of a malformed command (scip-reference §4: `01`..`07` for bad
/// numeric fields, `0C` for missing parameters, `0E` unknown command, `0G` tag too long,
/// `0H` bad tag chars).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawRequest<'a> {
    /// The command code: `SCIP2.0`, `%ST`/`%SL` and other `%`-commands whole (3 chars),
    /// otherwise the first two chars (fewer when the line is shorter).
    pub code: &'a [u8],
    /// What follows the code up to `;` or the end of the line.
    pub params: &'a [u8],
    /// The text after the first `;`, `None` when there is no `;`.
    pub tag: Option<&'a [u8]>,
}

impl<'a> RawRequest<'a> {
    /// Splits a command line (without its line end). Never fails.
    pub fn split(line: &'a [u8]) -> Self {
        let mut parts = line.splitn(2, |&c| c == b';');
        let body = parts.next().unwrap_or(&[]);
        let tag = parts.next();
        let code_len = if body.starts_with(b"SCIP") {
            body.len()
        } else if body.first() == Some(&b'%') {
            3
        } else {
            2
        };
        let code_len = code_len.min(body.len());
        Self {
            code: body.get(..code_len).unwrap_or(&[]),
            params: body.get(code_len..).unwrap_or(&[]),
            tag,
        }
    }

    /// Checks the tag as a sensor does: `Err(TagTooLong)` above [`TAG_MAX`] chars,
    /// `Err(BadTagChar)` for a char outside printable ASCII.
    pub fn check_tag(&self) -> Result<Tag, EncodeError> {
        Tag::new(self.tag.unwrap_or(&[]))
    }

    /// The decimal value of `params[range]`, `None` when it is missing or not all digits.
    pub fn decimal_field(&self, range: core::ops::Range<usize>) -> Option<u32> {
        self.params.get(range).and_then(decimal)
    }
}

/// Parses `n` decimal digits; `None` for a non-digit or a value beyond `u32`.
fn decimal(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() {
        return None;
    }
    digits.iter().try_fold(0u32, |acc, &c| {
        if c.is_ascii_digit() {
            // A digit: the subtraction never wraps.
            acc.checked_mul(10)?
                .checked_add(u32::from(c.wrapping_sub(b'0')))
        } else {
            None
        }
    })
}

fn parse_command(body: &[u8]) -> Result<Command, EchoError> {
    let bad = EchoError::BadParameters;
    let exact = |cmd: Command, params: &[u8]| {
        if params.is_empty() {
            Ok(cmd)
        } else {
            Err(bad)
        }
    };
    match body {
        b"SCIP2.0" => return Ok(Command::Scip20),
        b"%ST" => return Ok(Command::State),
        b"%SL" => return Ok(Command::Sleep),
        _ => {}
    }
    let (code, params) = match (body.get(..2), body.get(2..)) {
        (Some(c), Some(p)) => (c, p),
        _ => return Err(EchoError::UnknownCommand),
    };
    match code {
        b"VV" => exact(Command::Version, params),
        b"PP" => exact(Command::Parameters, params),
        b"II" => exact(Command::Info, params),
        b"BM" => exact(Command::LaserOn, params),
        b"QT" => exact(Command::LaserOff, params),
        b"RS" => exact(Command::Reset, params),
        b"RT" => exact(Command::PartialReset, params),
        b"SS" if params.len() == 6 => Ok(Command::BitRate(decimal(params).ok_or(bad)?)),
        b"CR" if params.len() == 2 => Ok(Command::MotorSpeed(decimal(params).ok_or(bad)? as u8)),
        b"TM" => match params {
            b"0" => Ok(Command::Time(TimeMode::Enter)),
            b"1" => Ok(Command::Time(TimeMode::Read)),
            b"2" => Ok(Command::Time(TimeMode::Leave)),
            _ => Err(bad),
        },
        b"HS" => match params {
            b"0" => Ok(Command::Sensitivity(false)),
            b"1" => Ok(Command::Sensitivity(true)),
            _ => Err(bad),
        },
        [first @ (b'G' | b'M' | b'H' | b'N'), letter] => {
            let data = DataSet::from_letter(*letter).ok_or(EchoError::UnknownCommand)?;
            let (mode, multi_echo) = match first {
                b'G' => (ScanMode::Single, false),
                b'M' => (ScanMode::Continuous, false),
                b'H' => (ScanMode::Single, true),
                _ => (ScanMode::Continuous, true),
            };
            if multi_echo && !matches!(data, DataSet::Distance | DataSet::DistanceIntensity) {
                return Err(EchoError::UnknownCommand);
            }
            let expected = if mode == ScanMode::Continuous { 13 } else { 10 };
            if params.len() != expected {
                return Err(bad);
            }
            let field = |r: core::ops::Range<usize>| params.get(r).and_then(decimal).ok_or(bad);
            let (skip, count) = if mode == ScanMode::Continuous {
                (field(10..11)? as u8, field(11..13)? as u8)
            } else {
                (0, 0)
            };
            Ok(Command::Scan(ScanRequest {
                mode,
                data,
                multi_echo,
                start: field(0..4)? as u16,
                end: field(4..8)? as u16,
                cluster: field(8..10)? as u8,
                skip,
                count,
            }))
        }
        b"SS" | b"CR" => Err(bad),
        _ => Err(EchoError::UnknownCommand),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_count_and_decimal_do_not_overflow() {
        // 65536 steps in clusters of 1: more values than a u16 holds.
        let all = ScanRequest::distance(ScanMode::Single, 0, u16::MAX);
        assert_eq!(all.value_count(), u16::MAX);
        assert_eq!(
            ScanRequest::distance(ScanMode::Single, 44, 725).value_count(),
            682
        );
        assert_eq!(decimal(b"4294967295"), Some(u32::MAX));
        assert_eq!(decimal(b"4294967296"), None);
        assert_eq!(decimal(b"99999999999"), None);
    }

    fn enc(r: Request) -> ([u8; REQUEST_MAX], usize) {
        let mut out = [0u8; REQUEST_MAX];
        let n = r.encode(&mut out).unwrap();
        (out, n)
    }

    fn scan(mode: ScanMode, data: DataSet, start: u16, end: u16, cluster: u8) -> ScanRequest {
        ScanRequest {
            mode,
            data,
            multi_echo: false,
            start,
            end,
            cluster,
            skip: 0,
            count: 0,
        }
    }

    #[test]
    fn encodes_real_requests() {
        let gd = Request::new(Command::Scan(scan(
            ScanMode::Single,
            DataSet::Distance,
            44,
            725,
            1,
        )));
        let (b, n) = enc(gd);
        assert_eq!(&b[..n], b"GD0044072501\n");

        let mut me = scan(ScanMode::Continuous, DataSet::DistanceIntensity, 0, 1080, 1);
        me.skip = 1;
        me.count = 1;
        let (b, n) = enc(Request::new(Command::Scan(me)));
        assert_eq!(&b[..n], b"ME0000108001101\n");

        let tagged = Request::new(Command::Scan(scan(
            ScanMode::Single,
            DataSet::Distance,
            0,
            10,
            1,
        )))
        .with_tag(b"GD00000999")
        .unwrap();
        let (b, n) = enc(tagged);
        assert_eq!(&b[..n], b"GD0000001001;GD00000999\n");

        for (cmd, text) in [
            (Command::Scip20, &b"SCIP2.0\n"[..]),
            (Command::Version, b"VV\n"),
            (Command::Parameters, b"PP\n"),
            (Command::Info, b"II\n"),
            (Command::LaserOn, b"BM\n"),
            (Command::LaserOff, b"QT\n"),
            (Command::Reset, b"RS\n"),
            (Command::PartialReset, b"RT\n"),
            (Command::BitRate(115_200), b"SS115200\n"),
            (Command::BitRate(19_200), b"SS019200\n"),
            (Command::MotorSpeed(0), b"CR00\n"),
            (Command::MotorSpeed(99), b"CR99\n"),
            (Command::Time(TimeMode::Enter), b"TM0\n"),
            (Command::Time(TimeMode::Read), b"TM1\n"),
            (Command::Time(TimeMode::Leave), b"TM2\n"),
            (Command::Sensitivity(true), b"HS1\n"),
            (Command::State, b"%ST\n"),
            (Command::Sleep, b"%SL\n"),
        ] {
            let (b, n) = enc(Request::new(cmd));
            assert_eq!(&b[..n], text);
            let parsed = Request::parse(&b[..n - 1]).unwrap();
            assert_eq!(parsed.command, cmd);
        }
    }

    #[test]
    fn every_scan_code() {
        let mut seen = 0;
        for mode in [ScanMode::Single, ScanMode::Continuous] {
            for data in [
                DataSet::Distance,
                DataSet::ShortDistance,
                DataSet::DistanceIntensity,
                DataSet::DistanceReflectance,
                DataSet::DistanceAux,
            ] {
                for multi_echo in [false, true] {
                    let mut s = scan(mode, data, 0, 1080, 3);
                    s.multi_echo = multi_echo;
                    let r = Request::new(Command::Scan(s));
                    let mut out = [0u8; REQUEST_MAX];
                    match r.encode(&mut out) {
                        Ok(n) => {
                            seen += 1;
                            assert_eq!(Request::parse(&out[..n - 1]), Ok(r));
                        }
                        Err(e) => {
                            assert!(multi_echo);
                            assert_eq!(e, EncodeError::NoMultiEcho);
                        }
                    }
                }
            }
        }
        // 10 G/M codes + HD ND HE NE.
        assert_eq!(seen, 14);
    }

    #[test]
    fn invalid_parameters() {
        let bad = |s: ScanRequest| Request::new(Command::Scan(s)).encode(&mut [0u8; 64]);
        let base = scan(ScanMode::Continuous, DataSet::Distance, 10, 20, 1);
        assert_eq!(
            bad(ScanRequest { end: 9, ..base }),
            Err(EncodeError::EndBeforeStart)
        );
        assert_eq!(
            bad(ScanRequest { cluster: 0, ..base }),
            Err(EncodeError::BadCluster)
        );
        assert_eq!(
            bad(ScanRequest {
                cluster: 100,
                ..base
            }),
            Err(EncodeError::BadCluster)
        );
        assert_eq!(
            bad(ScanRequest { count: 100, ..base }),
            Err(EncodeError::BadCount)
        );
        assert_eq!(
            bad(ScanRequest { skip: 10, ..base }),
            Err(EncodeError::BadSkip)
        );
        assert_eq!(
            bad(ScanRequest {
                end: 10_000,
                ..base
            }),
            Err(EncodeError::StepOutOfRange)
        );
        let r = |c| Request::new(c).encode(&mut [0u8; 64]);
        assert_eq!(r(Command::BitRate(9600)), Err(EncodeError::BadBitRate));
        assert_eq!(r(Command::MotorSpeed(11)), Err(EncodeError::BadMotorSpeed));
        assert_eq!(Tag::new(b"12345678901234567"), Err(EncodeError::TagTooLong));
        assert_eq!(Tag::new(b"a b"), Err(EncodeError::BadTagChar));
        assert_eq!(Tag::new(b"a\n"), Err(EncodeError::BadTagChar));
        assert_eq!(r(Command::Version).map(|_| ()), Ok(()));
        assert_eq!(
            Request::new(Command::Version).encode(&mut [0u8; 2]),
            Err(EncodeError::BufferTooSmall)
        );
    }

    #[test]
    fn raw_split() {
        let r = RawRequest::split(b"GD004407250A;tag");
        assert_eq!(
            (r.code, r.params, r.tag),
            (&b"GD"[..], &b"004407250A"[..], Some(&b"tag"[..]))
        );
        assert_eq!(r.decimal_field(0..4), Some(44));
        assert_eq!(r.decimal_field(8..10), None);
        assert_eq!(r.decimal_field(8..12), None);
        assert_eq!(r.check_tag().unwrap().as_bytes(), b"tag");
        let r = RawRequest::split(b"SCIP2.0");
        assert_eq!((r.code, r.params, r.tag), (&b"SCIP2.0"[..], &b""[..], None));
        let r = RawRequest::split(b"%ST;");
        assert_eq!(
            (r.code, r.params, r.tag),
            (&b"%ST"[..], &b""[..], Some(&b""[..]))
        );
        let r = RawRequest::split(b"V");
        assert_eq!((r.code, r.params), (&b"V"[..], &b""[..]));
        let r = RawRequest::split(b"");
        assert_eq!((r.code, r.params, r.tag), (&b""[..], &b""[..], None));
        let r = RawRequest::split(b"VV;12345678901234567");
        assert_eq!(r.check_tag(), Err(EncodeError::TagTooLong));
        let r = RawRequest::split(b"VV;a\x01");
        assert_eq!(r.check_tag(), Err(EncodeError::BadTagChar));
        let r = RawRequest::split(b"VV;a;b");
        assert_eq!(r.tag, Some(&b"a;b"[..]));
    }

    #[test]
    fn echo_parsing() {
        let r = Request::parse(b"GD0000001000;GD00000999").unwrap();
        assert_eq!(r.tag.as_bytes(), b"GD00000999");
        match r.command {
            Command::Scan(s) => {
                assert_eq!((s.start, s.end, s.cluster), (0, 10, 0));
                assert_eq!(s.value_count(), 11);
            }
            _ => panic!("not a scan"),
        }
        let r = Request::parse(b"ME0000108001100").unwrap();
        match r.command {
            Command::Scan(s) => {
                assert_eq!((s.skip, s.count, s.value_count()), (1, 0, 1081));
                assert_eq!(s.data.aux_width(), 3);
            }
            _ => panic!("not a scan"),
        }
        assert_eq!(Request::parse(b"XX"), Err(EchoError::UnknownCommand));
        assert_eq!(Request::parse(b""), Err(EchoError::UnknownCommand));
        assert_eq!(Request::parse(b"V"), Err(EchoError::UnknownCommand));
        assert_eq!(Request::parse(b"VV1"), Err(EchoError::BadParameters));
        assert_eq!(Request::parse(b"GD00440725"), Err(EchoError::BadParameters));
        assert_eq!(
            Request::parse(b"GD004407250A"),
            Err(EchoError::BadParameters)
        );
        assert_eq!(
            Request::parse(b"HS0044072501"),
            Err(EchoError::BadParameters)
        );
        assert_eq!(
            Request::parse(b"HR0044072501"),
            Err(EchoError::UnknownCommand)
        );
        assert_eq!(
            Request::parse(b"VV;12345678901234567"),
            Err(EchoError::BadTag)
        );
        assert_eq!(Request::parse(b"SS11520"), Err(EchoError::BadParameters));
    }
}
