//! candump log files: the `candump -l` / `candump -L` text format that can-utils,
//! python-can (`CanutilsLogReader`/`CanutilsLogWriter`), cantools and SavvyCAN read.
//!
//! One frame per line:
//! ```text
//! (0000000001.250000) can0 123#DEADBEEF          classic, 11-bit ID (3 hex digits)
//! (0000000001.250112) can0 1234ABCD#00           classic, 29-bit ID (8 hex digits)
//! (0000000001.250200) can0 123##1000102030405060708090A0B    CAN FD: flags nibble, data
//! (0000000001.250300) can0 123#R                 remote frame (optional DLC digit)
//! (0000000001.250400) can0 20000080#0000000000000000   error frame (CAN_ERR_FLAG)
//! ```
//! The timestamp is `(seconds.microseconds)`; the writer pads like candump (10 + 6
//! digits), the reader takes any number of digits (fractions beyond µs are cut). Data is
//! hex, two digits per byte, optionally separated by `.`. The CAN FD flags nibble holds
//! BRS (1, bit rate switch) and ESI (2, error state). A fourth field `R` or `T` (receive
//! or transmit, as python-can writes it) is accepted and ignored. Blank lines are
//! skipped; anything else that does not parse is a [`CandumpError::Line`] naming its line,
//! and the [`Reader`] goes on with the next line. A line longer than [`MAX_LINE`] bytes is
//! such an error too: the reader skips to its end without holding it, so memory stays
//! bounded whatever the input is.

use std::fmt;
use std::io::{self, BufRead, Write};

use embedded_can::{ExtendedId, Id, StandardId};

/// CAN FD flag: bit rate switch.
pub const FD_BRS: u8 = 0x1;
/// CAN FD flag: error state indicator.
pub const FD_ESI: u8 = 0x2;
/// The error-frame bit of an 8-digit identifier (`linux/can.h` `CAN_ERR_FLAG`).
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// The longest line the [`Reader`] takes, bytes without the line end. The longest
/// candump line (a 64-byte CAN FD frame with dot-separated bytes, a nanosecond
/// timestamp, a long interface name) is well under 512 bytes.
pub const MAX_LINE: usize = 4096;

/// What one log line carries.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LogFrame {
    /// A data frame.
    Data {
        /// Its identifier.
        id: Id,
        /// Its payload (0..=8 bytes classic, a CAN FD length for FD).
        data: Vec<u8>,
        /// `Some(flags)` for a CAN FD frame ([`FD_BRS`], [`FD_ESI`]), `None` for classic.
        fd_flags: Option<u8>,
    },
    /// A remote (RTR) frame.
    Remote {
        /// Its identifier.
        id: Id,
        /// The DLC, when the log gives one.
        dlc: Option<u8>,
    },
    /// An error frame (the identifier's error class bits, without `CAN_ERR_FLAG`).
    Error {
        /// Error class bits.
        class: u32,
        /// The error frame's data bytes.
        data: Vec<u8>,
    },
}

/// One line of a candump log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record {
    /// Time in microseconds (`sec * 1_000_000 + usec`).
    pub time_us: u64,
    /// Interface name (`can0`).
    pub interface: String,
    /// The frame.
    pub frame: LogFrame,
}

impl Record {
    /// A record of a scip2can frame.
    pub fn from_frame(time_us: u64, interface: &str, frame: &can_wire::Frame, brs: bool) -> Self {
        Self {
            time_us,
            interface: interface.to_owned(),
            frame: LogFrame::Data {
                id: frame.id(),
                data: frame.data().to_vec(),
                fd_flags: frame.is_fd().then_some(if brs { FD_BRS } else { 0 }),
            },
        }
    }

    /// The data frame as a scip2can frame; `None` for remote and error frames.
    pub fn to_frame(&self) -> Option<can_wire::Frame> {
        match &self.frame {
            // Lengths were checked when the line was parsed, so this cannot fail.
            LogFrame::Data { id, data, fd_flags } => {
                can_wire::Frame::new(*id, data, fd_flags.is_some()).ok()
            }
            _ => None,
        }
    }
}

fn write_hex(f: &mut fmt::Formatter<'_>, data: &[u8]) -> fmt::Result {
    data.iter().try_for_each(|b| write!(f, "{b:02X}"))
}

fn write_id(f: &mut fmt::Formatter<'_>, id: Id) -> fmt::Result {
    match id {
        Id::Standard(s) => write!(f, "{:03X}", s.as_raw()),
        Id::Extended(e) => write!(f, "{:08X}", e.as_raw()),
    }
}

impl fmt::Display for Record {
    /// The log line, without its line end.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (sec, usec) = (self.time_us / 1_000_000, self.time_us % 1_000_000);
        write!(f, "({sec:010}.{usec:06}) {} ", self.interface)?;
        match &self.frame {
            LogFrame::Data { id, data, fd_flags } => {
                write_id(f, *id)?;
                f.write_str("#")?;
                if let Some(flags) = fd_flags {
                    write!(f, "#{:X}", flags & 0xF)?;
                }
                write_hex(f, data)
            }
            LogFrame::Remote { id, dlc } => {
                write_id(f, *id)?;
                f.write_str("#R")?;
                match dlc {
                    Some(d) => write!(f, "{d}"),
                    None => Ok(()),
                }
            }
            LogFrame::Error { class, data } => {
                write!(f, "{:08X}#", (class & 0x1FFF_FFFF) | CAN_ERR_FLAG)?;
                write_hex(f, data)
            }
        }
    }
}

/// Why a line is not a candump log line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LineError {
    /// Not 3 fields (or 4 with a trailing `R`/`T`).
    Fields(usize),
    /// The timestamp is not `(seconds.fraction)`.
    Timestamp,
    /// The identifier is not 3 or 8 hex digits followed by `#`, or is out of range.
    Id,
    /// The data is not hex pairs (optionally `.`-separated).
    Data,
    /// More bytes than the frame format holds.
    TooLong {
        /// Bytes found.
        len: usize,
        /// Bytes allowed.
        max: usize,
    },
    /// A CAN FD frame whose length is not a CAN FD length (0..=8, 12, 16, 20, 24, 32,
    /// 48, 64).
    FdLength(usize),
    /// The CAN FD flags nibble is missing or not hex.
    FdFlags,
    /// A remote frame's DLC is not a digit 0..=8.
    RemoteDlc,
    /// The line is longer than [`MAX_LINE`] bytes (skipped unread).
    LineTooLong,
    /// The line is not UTF-8 text.
    NotText,
}

impl fmt::Display for LineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Fields(n) => write!(f, "{n} fields, expected `(time) iface frame`"),
            Self::Timestamp => f.write_str("timestamp is not (seconds.fraction)"),
            Self::Id => f.write_str("identifier is not 3 or 8 hex digits before '#'"),
            Self::Data => f.write_str("data is not pairs of hex digits"),
            Self::TooLong { len, max } => write!(f, "{len} data bytes, at most {max}"),
            Self::FdLength(n) => write!(f, "{n} bytes is not a CAN FD length"),
            Self::FdFlags => f.write_str("CAN FD flags nibble missing or not hex"),
            Self::RemoteDlc => f.write_str("remote frame DLC is not 0..=8"),
            Self::LineTooLong => write!(f, "line longer than {MAX_LINE} bytes"),
            Self::NotText => f.write_str("line is not UTF-8 text"),
        }
    }
}

/// An error reading a candump log.
#[derive(Debug)]
pub enum CandumpError {
    /// Reading the input failed.
    Io(io::Error),
    /// A line does not parse.
    Line {
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        kind: LineError,
    },
}

impl fmt::Display for CandumpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io(e) => write!(f, "reading the log: {e}"),
            Self::Line { line, kind } => write!(f, "line {line}: {kind}"),
        }
    }
}

impl std::error::Error for CandumpError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io(e) => Some(e),
            Self::Line { .. } => None,
        }
    }
}

fn parse_time(s: &str) -> Result<u64, LineError> {
    let inner = s
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or(LineError::Timestamp)?;
    let (sec, frac) = inner.split_once('.').ok_or(LineError::Timestamp)?;
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    if !digits(sec) || !digits(frac) {
        return Err(LineError::Timestamp);
    }
    let sec: u64 = sec.parse().map_err(|_| LineError::Timestamp)?;
    // The first six fraction digits are the microseconds, padded with zeros.
    let usec = frac
        .bytes()
        .chain(std::iter::repeat(b'0'))
        .take(6)
        .fold(0u64, |acc, d| acc * 10 + u64::from(d - b'0'));
    sec.checked_mul(1_000_000)
        .and_then(|t| t.checked_add(usec))
        .ok_or(LineError::Timestamp)
}

fn parse_hex(s: &str) -> Result<Vec<u8>, LineError> {
    let digits: Vec<u8> = s.bytes().filter(|&b| b != b'.').collect();
    if !digits.len().is_multiple_of(2) {
        return Err(LineError::Data);
    }
    digits
        .chunks(2)
        .map(|pair| {
            let text = std::str::from_utf8(pair).map_err(|_| LineError::Data)?;
            if !text.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Err(LineError::Data);
            }
            u8::from_str_radix(text, 16).map_err(|_| LineError::Data)
        })
        .collect()
}

fn parse_frame(s: &str) -> Result<LogFrame, LineError> {
    let (id_text, rest) = s.split_once('#').ok_or(LineError::Id)?;
    if !id_text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(LineError::Id);
    }
    let raw = u32::from_str_radix(id_text, 16).map_err(|_| LineError::Id)?;
    let id = match id_text.len() {
        3 => Id::Standard(StandardId::new(raw as u16).ok_or(LineError::Id)?),
        8 if raw & CAN_ERR_FLAG != 0 => {
            let data = parse_hex(rest)?;
            if data.len() > 8 {
                return Err(LineError::TooLong {
                    len: data.len(),
                    max: 8,
                });
            }
            return Ok(LogFrame::Error {
                class: raw & !CAN_ERR_FLAG,
                data,
            });
        }
        8 => Id::Extended(ExtendedId::new(raw).ok_or(LineError::Id)?),
        _ => return Err(LineError::Id),
    };
    if let Some(dlc) = rest.strip_prefix(['R', 'r']) {
        let dlc = match dlc {
            "" => None,
            d => Some(
                d.parse::<u8>()
                    .ok()
                    .filter(|d| *d <= 8)
                    .ok_or(LineError::RemoteDlc)?,
            ),
        };
        return Ok(LogFrame::Remote { id, dlc });
    }
    if let Some(fd) = rest.strip_prefix('#') {
        let mut chars = fd.chars();
        let flags = chars
            .next()
            .and_then(|c| c.to_digit(16))
            .ok_or(LineError::FdFlags)? as u8;
        let data = parse_hex(chars.as_str())?;
        if data.len() > can_wire::frame::MAX_LEN {
            return Err(LineError::TooLong {
                len: data.len(),
                max: can_wire::frame::MAX_LEN,
            });
        }
        if !can_wire::frame::is_valid_len(data.len()) {
            return Err(LineError::FdLength(data.len()));
        }
        return Ok(LogFrame::Data {
            id,
            data,
            fd_flags: Some(flags),
        });
    }
    let data = parse_hex(rest)?;
    if data.len() > can_wire::frame::CLASSIC_LEN {
        return Err(LineError::TooLong {
            len: data.len(),
            max: can_wire::frame::CLASSIC_LEN,
        });
    }
    Ok(LogFrame::Data {
        id,
        data,
        fd_flags: None,
    })
}

/// Parses one non-blank line.
pub fn parse_line(line: &str) -> Result<Record, LineError> {
    let fields: Vec<&str> = line.split_whitespace().collect();
    let fields = match fields.as_slice() {
        [t, i, f] | [t, i, f, "R" | "T" | "r" | "t"] => [*t, *i, *f],
        other => return Err(LineError::Fields(other.len())),
    };
    let [time, interface, frame] = fields;
    Ok(Record {
        time_us: parse_time(time)?,
        interface: interface.to_owned(),
        frame: parse_frame(frame)?,
    })
}

/// Reads a candump log line by line, in bounded memory.
///
/// Each item is a record or the error of one line; after a [`CandumpError::Line`] the
/// next call goes on with the next line. A read error ([`CandumpError::Io`]) ends the
/// iteration. Lines are handed out as soon as their line end arrives (nothing waits
/// for more input than one line), and a line longer than [`MAX_LINE`] is dropped as it
/// is read ([`LineError::LineTooLong`]), never held whole.
#[derive(Debug)]
pub struct Reader<R: BufRead> {
    input: R,
    line: usize,
    buf: Vec<u8>,
    done: bool,
}

/// How one line came out of the input.
enum RawLine {
    /// The line (in `Reader::buf`, without its line end).
    Text,
    /// Longer than [`MAX_LINE`]: dropped.
    TooLong,
    /// End of input.
    End,
}

impl<R: BufRead> Reader<R> {
    /// A reader of `input`.
    pub fn new(input: R) -> Self {
        Self {
            input,
            line: 0,
            buf: Vec::with_capacity(MAX_LINE),
            done: false,
        }
    }

    /// Number of lines read so far (the number of the last one, 1-based).
    pub fn line(&self) -> usize {
        self.line
    }

    /// The next line into `buf`, keeping at most [`MAX_LINE`] bytes of it.
    fn read_line(&mut self) -> io::Result<RawLine> {
        self.buf.clear();
        let mut started = false;
        let mut too_long = false;
        loop {
            let chunk = match self.input.fill_buf() {
                Ok(c) => c,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            if chunk.is_empty() {
                // End of input; a last line without a line end still counts.
                return Ok(match (started, too_long) {
                    (false, _) => RawLine::End,
                    (true, false) => RawLine::Text,
                    (true, true) => RawLine::TooLong,
                });
            }
            started = true;
            let end = chunk.iter().position(|&b| b == b'\n');
            let part = chunk.get(..end.unwrap_or(chunk.len())).unwrap_or(&[]);
            if !too_long {
                if self.buf.len() + part.len() > MAX_LINE {
                    too_long = true;
                    self.buf.clear();
                } else {
                    self.buf.extend_from_slice(part);
                }
            }
            let used = end.map_or(chunk.len(), |i| i + 1);
            self.input.consume(used);
            if end.is_some() {
                return Ok(if too_long {
                    RawLine::TooLong
                } else {
                    RawLine::Text
                });
            }
        }
    }
}

impl<R: BufRead> Iterator for Reader<R> {
    type Item = Result<Record, CandumpError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.done {
            let raw = match self.read_line() {
                Ok(raw) => raw,
                Err(e) => {
                    self.done = true;
                    return Some(Err(CandumpError::Io(e)));
                }
            };
            let line_error = |line, kind| Some(Err(CandumpError::Line { line, kind }));
            match raw {
                RawLine::End => self.done = true,
                RawLine::TooLong => {
                    self.line += 1;
                    return line_error(self.line, LineError::LineTooLong);
                }
                RawLine::Text => {
                    self.line += 1;
                    let Ok(text) = std::str::from_utf8(&self.buf) else {
                        return line_error(self.line, LineError::NotText);
                    };
                    let text = text.trim();
                    if text.is_empty() {
                        continue;
                    }
                    return Some(parse_line(text).map_err(|kind| CandumpError::Line {
                        line: self.line,
                        kind,
                    }));
                }
            }
        }
        None
    }
}

/// Writes one record and a line end.
pub fn write_record(out: &mut impl Write, record: &Record) -> io::Result<()> {
    writeln!(out, "{record}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    fn std_id(raw: u16) -> Id {
        Id::Standard(StandardId::new(raw).unwrap())
    }

    fn read_all(text: &str) -> Vec<Result<Record, CandumpError>> {
        Reader::new(text.as_bytes()).collect()
    }

    const CLASSIC: &str = "(0000000001.250000) can0 123#DEADBEEF";
    const EXTENDED: &str = "(0000000012.000001) vcan1 1234ABCD#00";
    const FD: &str = "(0000000000.000100) can0 135##1000102030405060708090A0B";
    const REMOTE: &str = "(0000000000.000000) can0 7FF#R3";
    const ERROR: &str = "(0000000000.000000) can0 20000080#0000000000000000";

    #[test]
    fn golden_lines_parse() {
        assert_eq!(
            parse_line(CLASSIC),
            Ok(Record {
                time_us: 1_250_000,
                interface: "can0".into(),
                frame: LogFrame::Data {
                    id: std_id(0x123),
                    data: vec![0xDE, 0xAD, 0xBE, 0xEF],
                    fd_flags: None,
                },
            })
        );
        let ext = parse_line(EXTENDED).unwrap();
        assert_eq!(ext.time_us, 12_000_001);
        assert_eq!(ext.interface, "vcan1");
        assert_eq!(
            ext.frame,
            LogFrame::Data {
                id: Id::Extended(ExtendedId::new(0x1234_ABCD).unwrap()),
                data: vec![0],
                fd_flags: None,
            }
        );
        let fd = parse_line(FD).unwrap();
        assert_eq!(
            fd.frame,
            LogFrame::Data {
                id: std_id(0x135),
                data: (0..12).collect(),
                fd_flags: Some(FD_BRS),
            }
        );
        assert_eq!(
            parse_line(REMOTE).unwrap().frame,
            LogFrame::Remote {
                id: std_id(0x7FF),
                dlc: Some(3)
            }
        );
        assert_eq!(
            parse_line(ERROR).unwrap().frame,
            LogFrame::Error {
                class: 0x80,
                data: vec![0; 8]
            }
        );
    }

    #[test]
    fn golden_lines_round_trip_byte_exact() {
        for line in [CLASSIC, EXTENDED, FD, REMOTE, ERROR] {
            assert_eq!(parse_line(line).unwrap().to_string(), line);
        }
    }

    #[test]
    fn other_spellings_are_accepted() {
        // python-can's writer: 6 decimals, unpadded seconds, a direction field.
        let r = parse_line("(1.5) can0 123#de.ad R").unwrap();
        assert_eq!(r.time_us, 1_500_000);
        assert_eq!(
            r.frame,
            LogFrame::Data {
                id: std_id(0x123),
                data: vec![0xDE, 0xAD],
                fd_flags: None
            }
        );
        // Nanoseconds are cut to microseconds; empty payloads and FD flag 0.
        assert_eq!(
            parse_line("(2.123456789) c 001#").unwrap().time_us,
            2_123_456
        );
        assert_eq!(
            parse_line("(0.0) c 001##0").unwrap().frame,
            LogFrame::Data {
                id: std_id(1),
                data: vec![],
                fd_flags: Some(0)
            }
        );
    }

    #[test]
    fn scip2can_frames_round_trip() {
        let id = std_id(0x150);
        for (data, fd) in [(&[1u8, 2, 3][..], false), (&[7u8; 64][..], true)] {
            let frame = can_wire::Frame::new(id, data, fd).unwrap();
            let rec = Record::from_frame(3_000_042, "can0", &frame, true);
            let text = rec.to_string();
            assert_eq!(text.contains("##1"), fd, "{text}");
            let back = parse_line(&text).unwrap();
            assert_eq!(back, rec);
            assert_eq!(back.to_frame(), Some(frame));
        }
        assert_eq!(parse_line(REMOTE).unwrap().to_frame(), None);
    }

    #[test]
    fn the_writer_writes_candump_lines() {
        let frame = can_wire::Frame::new(std_id(0x105), &[0xAB; 12], true).unwrap();
        let mut out = Vec::new();
        write_record(&mut out, &Record::from_frame(59, "can0", &frame, false)).unwrap();
        assert_eq!(
            out,
            b"(0000000000.000059) can0 105##0ABABABABABABABABABABABAB\n"
        );
    }

    #[test]
    fn malformed_lines_are_typed_errors_with_line_numbers() {
        let cases: &[(&str, LineError)] = &[
            ("(1.0) can0", LineError::Fields(2)),
            ("(1.0) can0 123#00 X", LineError::Fields(4)),
            ("1.0 can0 123#00", LineError::Timestamp),
            ("(1) can0 123#00", LineError::Timestamp),
            ("(1.x) can0 123#00", LineError::Timestamp),
            ("(1.0) can0 12#00", LineError::Id),
            ("(1.0) can0 12G#00", LineError::Id),
            ("(1.0) can0 800#00", LineError::Id),
            ("(1.0) can0 123400#00", LineError::Id),
            ("(1.0) can0 40000000#00", LineError::Id),
            ("(1.0) can0 12300", LineError::Id),
            ("(1.0) can0 123#0", LineError::Data),
            ("(1.0) can0 123#0G", LineError::Data),
            (
                "(1.0) can0 123#000102030405060708",
                LineError::TooLong { len: 9, max: 8 },
            ),
            (
                "(1.0) can0 123##1000102030405060708",
                LineError::FdLength(9),
            ),
            ("(1.0) can0 123##", LineError::FdFlags),
            ("(1.0) can0 123##X00", LineError::FdFlags),
            ("(1.0) can0 123#R9", LineError::RemoteDlc),
        ];
        for (line, want) in cases {
            assert_eq!(parse_line(line).as_ref().err(), Some(want), "{line}");
        }
        let too_long = format!("(1.0) can0 123##0{}", "00".repeat(65));
        assert_eq!(
            parse_line(&too_long),
            Err(LineError::TooLong { len: 65, max: 64 })
        );

        // The reader skips blank lines and counts them.
        let text = format!("{CLASSIC}\n\n   \n(1.0) can0 123#0\n{FD}\n");
        let got = read_all(&text);
        assert_eq!(got.len(), 3);
        assert!(got[0].is_ok() && got[2].is_ok());
        match &got[1] {
            Err(CandumpError::Line { line, kind }) => {
                assert_eq!((*line, kind), (4, &LineError::Data));
                assert_eq!(
                    got[1].as_ref().unwrap_err().to_string(),
                    "line 4: data is not pairs of hex digits"
                );
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_reader_goes_on_after_bad_lines() {
        let mut text = format!("{CLASSIC}\ngarbage\n").into_bytes();
        text.extend_from_slice(b"\xff\xfe\n");
        text.extend_from_slice(format!("{FD}\n(1.0) can0 123#0\n{REMOTE}").as_bytes());
        let got: Vec<_> = Reader::new(&text[..])
            .map(|r| r.map_err(|e| e.to_string()))
            .collect();
        assert_eq!(got.len(), 6);
        assert_eq!(got[0], Ok(parse_line(CLASSIC).unwrap()));
        assert_eq!(
            got[1],
            Err("line 2: 1 fields, expected `(time) iface frame`".into())
        );
        assert_eq!(got[2], Err("line 3: line is not UTF-8 text".into()));
        assert_eq!(got[3], Ok(parse_line(FD).unwrap()));
        assert_eq!(
            got[4],
            Err("line 5: data is not pairs of hex digits".into())
        );
        // The last line has no line end.
        assert_eq!(got[5], Ok(parse_line(REMOTE).unwrap()));
    }

    #[test]
    fn an_overlong_line_is_skipped_without_holding_it() {
        // 100 MB of one line, then two good lines; read through a small buffer.
        let long = io::repeat(b'7').take(100 << 20);
        let rest = format!("\n{CLASSIC}\r\n{EXTENDED}\n");
        let input = io::BufReader::with_capacity(1000, long.chain(rest.as_bytes()));
        let mut reader = Reader::new(input);
        match reader.next() {
            Some(Err(CandumpError::Line { line: 1, kind })) => {
                assert_eq!(kind, LineError::LineTooLong);
            }
            other => panic!("{other:?}"),
        }
        assert!(
            reader.buf.capacity() <= MAX_LINE,
            "{}",
            reader.buf.capacity()
        );
        assert_eq!(
            reader.next().unwrap().unwrap(),
            parse_line(CLASSIC).unwrap()
        );
        assert_eq!(
            reader.next().unwrap().unwrap(),
            parse_line(EXTENDED).unwrap()
        );
        assert!(reader.next().is_none());
        assert_eq!(reader.line(), 3);
        // A line of exactly MAX_LINE bytes is read (and fails to parse as a frame);
        // one byte more is too long, also as the last line without a line end.
        let exact = format!("{}\n", " ".repeat(MAX_LINE - 3) + "x y");
        assert!(matches!(
            Reader::new(exact.as_bytes()).next(),
            Some(Err(CandumpError::Line {
                kind: LineError::Fields(2),
                ..
            }))
        ));
        let over = "x".repeat(MAX_LINE + 1);
        assert!(matches!(
            Reader::new(over.as_bytes()).next(),
            Some(Err(CandumpError::Line {
                kind: LineError::LineTooLong,
                ..
            }))
        ));
    }

    /// Gives its text once, then fails the test if read again.
    struct Once(Option<&'static [u8]>);

    impl io::Read for Once {
        fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
            let text = self.0.take().expect("read past the available input");
            out[..text.len()].copy_from_slice(text);
            Ok(text.len())
        }
    }

    #[test]
    fn a_line_is_handed_out_without_waiting_for_more_input() {
        let line = b"(0000000001.250000) can0 123#DEADBEEF\n";
        let mut reader = Reader::new(io::BufReader::new(Once(Some(line))));
        assert_eq!(
            reader.next().unwrap().unwrap(),
            parse_line(CLASSIC).unwrap()
        );
    }

    /// Fails every read.
    struct Broken;

    impl io::Read for Broken {
        fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
            Err(io::Error::other("disk on fire"))
        }
    }

    #[test]
    fn a_read_error_ends_the_reader() {
        let mut reader = Reader::new(io::BufReader::new(Broken));
        assert!(matches!(reader.next(), Some(Err(CandumpError::Io(_)))));
        assert!(reader.next().is_none());
    }
}
