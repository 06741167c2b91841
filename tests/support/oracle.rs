//! A small SCIP 2.0 reader written from the protocol reference alone, sharing no code
//! with the `scip` crate: the integration tests take their expected values from it (and
//! from numbers read off the captures by hand), never from the decoder under test.
//!
//! It knows only what the tests need: responses split at the empty line, the line sum
//! (`(sum of the bytes before it) & 0x3F) + 0x30`), N-char values
//! (`sum((c - 0x30) << 6k)`, first char most significant), the echo of the
//! `GD`/`GS`/`GE`/`MD`/`MS`/`ME` requests and the PP field `DMIN`. It is slow and
//! allocates freely; it does not resynchronise inside a response.

/// Decodes one SCIP value of 2, 3 or 4 chars: each char carries 6 bits (`c - 0x30`),
/// the first char the most significant.
pub fn value(chars: &[u8]) -> u32 {
    chars.iter().fold(0u32, |acc, &c| {
        (acc << 6) | u32::from(c.wrapping_sub(0x30) & 0x3F)
    })
}

/// Whether a line ends in its correct sum char (`line` without its LF).
pub fn sum_ok(line: &[u8]) -> bool {
    let Some((&sum, body)) = line.split_last() else {
        return false;
    };
    let s: u32 = body.iter().map(|&b| u32::from(b)).sum();
    (s & 0x3F) as u8 + 0x30 == sum
}

/// One response as it lay in the stream: its lines (echo first), and whether it was
/// closed by an empty line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawResponse {
    /// Every line, without LF; the echo first.
    pub lines: Vec<Vec<u8>>,
    /// An empty line closed it (the capture did not end inside it).
    pub terminated: bool,
}

/// Splits a sensor → host stream into responses at the empty lines.
pub fn responses(bytes: &[u8]) -> Vec<RawResponse> {
    let mut out = Vec::new();
    let mut lines = Vec::new();
    let mut rest = bytes;
    loop {
        match rest.iter().position(|&b| b == b'\n') {
            Some(i) => {
                let line = &rest[..i];
                rest = &rest[i + 1..];
                if line.is_empty() {
                    if !lines.is_empty() {
                        out.push(RawResponse {
                            lines: std::mem::take(&mut lines),
                            terminated: true,
                        });
                    }
                } else {
                    lines.push(line.to_vec());
                }
            }
            None => {
                if !rest.is_empty() {
                    lines.push(rest.to_vec());
                }
                if !lines.is_empty() {
                    out.push(RawResponse {
                        lines,
                        terminated: false,
                    });
                }
                return out;
            }
        }
    }
}

/// The smallest range of the stream's PP answer (`DMIN:20;...`), 20 mm without one.
pub fn dmin(bytes: &[u8]) -> u32 {
    responses(bytes)
        .iter()
        .flat_map(|r| r.lines.iter())
        .find_map(|l| {
            let v = l.strip_prefix(b"DMIN:")?;
            let end = v.iter().position(|&b| b == b';')?;
            std::str::from_utf8(&v[..end]).ok()?.parse().ok()
        })
        .unwrap_or(20)
}

/// A measurement request read from its echo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanEcho {
    /// Chars per value: 2 (`GS`/`MS`) or 3.
    pub width: usize,
    /// Distance and intensity pairs (`GE`/`ME`).
    pub intensity: bool,
    /// Start and end step, cluster count.
    pub start: u32,
    /// End step.
    pub end: u32,
    /// Steps per value (0 counts as 1).
    pub cluster: u32,
}

impl ScanEcho {
    /// Reads `GD0044072501`, `ME0000108001100;tag` and the like; `None` for any other echo.
    pub fn parse(echo: &[u8]) -> Option<Self> {
        let (width, intensity) = match echo.get(..2)? {
            b"GD" | b"MD" => (3, false),
            b"GS" | b"MS" => (2, false),
            b"GE" | b"ME" => (3, true),
            _ => return None,
        };
        let digits = |r: std::ops::Range<usize>| -> Option<u32> {
            std::str::from_utf8(echo.get(r)?).ok()?.parse().ok()
        };
        Some(Self {
            width,
            intensity,
            start: digits(2..6)?,
            end: digits(6..10)?,
            cluster: digits(10..12)?.max(1),
        })
    }

    /// Values (steps after clustering) a full answer carries.
    pub fn values(&self) -> usize {
        (self.end.saturating_sub(self.start) / self.cluster + 1) as usize
    }
}

/// One measurement response: a scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Scan {
    /// The echo line.
    pub echo: String,
    /// The two status chars.
    pub status: String,
    /// The timestamp in ms.
    pub timestamp: u32,
    /// Distances as sent (error codes included), of the lines before any damage.
    pub distances: Vec<u32>,
    /// Intensities (empty unless the request asked for them).
    pub intensities: Vec<u32>,
    /// Chars per distance (2 or 3).
    pub width: usize,
    /// A line failed its sum, the response was cut short, or it does not hold the
    /// number of values its echo asked for.
    pub damaged: bool,
}

/// Every measurement response with a timestamp (the data answers; an `MD`/`ME`
/// acknowledgement has none), in stream order.
pub fn scans(bytes: &[u8]) -> Vec<Scan> {
    let mut out = Vec::new();
    for r in responses(bytes) {
        let Some(echo) = r.lines.first().and_then(|e| ScanEcho::parse(e)) else {
            continue;
        };
        // Echo, status, timestamp, data lines.
        let [_, status, stamp, data @ ..] = r.lines.as_slice() else {
            continue;
        };
        let mut damaged = !r.terminated || !sum_ok(status) || !sum_ok(stamp) || stamp.len() != 5;
        let mut chars = Vec::new();
        for line in data {
            if !sum_ok(line) {
                damaged = true;
                break;
            }
            chars.extend_from_slice(&line[..line.len() - 1]);
        }
        let per_value = if echo.intensity { 2 } else { 1 } * echo.width;
        if chars.len() % per_value != 0 || chars.len() / per_value != echo.values() {
            damaged = true;
        }
        let mut distances = Vec::new();
        let mut intensities = Vec::new();
        for v in chars.chunks_exact(per_value) {
            distances.push(value(&v[..echo.width]));
            if echo.intensity {
                intensities.push(value(&v[echo.width..]));
            }
        }
        out.push(Scan {
            echo: String::from_utf8_lossy(&r.lines[0]).into_owned(),
            status: String::from_utf8_lossy(&status[..status.len().min(2)]).into_owned(),
            timestamp: value(&stamp[..stamp.len().min(4)]),
            distances,
            intensities,
            width: echo.width,
            damaged,
        });
    }
    out
}

/// Whether a distance is a range rather than an error code: at least DMIN, and not the
/// 2-char over-range code 4095.
pub fn is_range(distance: u32, width: usize, dmin: u32) -> bool {
    distance >= dmin && !(width == 2 && distance == 4095)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_and_sums_from_the_reference_examples() {
        // The reference's 2-, 3- and 4-char examples.
        assert_eq!(value(b"CB"), 1234);
        assert_eq!(value(b"1Dh"), 5432);
        assert_eq!(value(b"m2@0"), 16_000_000);
        assert!(sum_ok(b"00P"));
        assert!(!sum_ok(b"00Q"));
        assert!(sum_ok(b"G]\\VF"));
    }

    #[test]
    fn a_tagged_gd_answer() {
        let bytes = b"GD0000001000;GD00000999\n00P\nG]\\VF\n06306J06_07407607106i06i06i07507\
0n\n\n";
        let s = scans(bytes);
        assert_eq!(s.len(), 1);
        assert!(!s[0].damaged);
        assert_eq!(s[0].timestamp, (23 << 18) | (45 << 12) | (44 << 6) | 38);
        assert_eq!(
            s[0].distances,
            [387, 410, 431, 452, 454, 449, 441, 441, 441, 453, 448]
        );
        // One byte less: cut short and one value short.
        let cut = &bytes[..bytes.len() - 1];
        assert!(scans(cut)[0].damaged);
    }
}
