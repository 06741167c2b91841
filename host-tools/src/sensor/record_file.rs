//! The record file: both directions of a SCIP session with timestamps.
//!
//! ```text
//! # scip2can record v1
//! # sensor: tcp://127.0.0.1:10940        (any number of '#' comment lines)
//! > 0 3
//! VV
//!
//! < 1520 109
//! VV
//! 00P
//! VEND:...
//! ```
//! After the first line (exactly `# scip2can record v1`) and any comment lines, the
//! file is a sequence of chunks. Each chunk is a header line
//! `<dir> <t_us> <len>` — `>` for host → sensor, `<` for sensor → host, `t_us` the
//! microseconds since the recording started (when the bytes were written or read),
//! `len` the byte count in decimal — followed by exactly `len` raw bytes and one `\n`.
//! The bytes are exactly what crossed the link, in the order they crossed it, cut
//! wherever a read or write ended; nothing is escaped, so any bytes (garbage, partial
//! lines) survive. Concatenating the `<` chunks gives the raw sensor stream that
//! `scip2can parse` reads; `scip2can sim --replay FILE` serves its scans.

use std::io::{self, BufRead, BufReader, Read, Write};

/// The first line of every record file (LF included).
pub const MAGIC: &[u8] = b"# scip2can record v1\n";

/// Which way bytes went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Host → sensor (`>`).
    ToSensor,
    /// Sensor → host (`<`).
    FromSensor,
}

impl Direction {
    fn mark(self) -> char {
        match self {
            Self::ToSensor => '>',
            Self::FromSensor => '<',
        }
    }
}

/// One chunk of a record.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Chunk {
    /// Which way.
    pub direction: Direction,
    /// µs since the recording started.
    pub t_us: u64,
    /// The bytes.
    pub bytes: Vec<u8>,
}

/// Writes a record file.
#[derive(Debug)]
pub struct RecordWriter<W: Write> {
    out: W,
}

impl<W: Write> RecordWriter<W> {
    /// Starts a record: the magic line and one `# ` comment line per entry.
    pub fn new(mut out: W, comments: &[String]) -> io::Result<Self> {
        out.write_all(MAGIC)?;
        for c in comments {
            writeln!(out, "# {}", c.replace('\n', " "))?;
        }
        Ok(Self { out })
    }

    /// Appends one chunk (nothing for empty `bytes`).
    pub fn chunk(&mut self, direction: Direction, t_us: u64, bytes: &[u8]) -> io::Result<()> {
        if bytes.is_empty() {
            return Ok(());
        }
        writeln!(self.out, "{} {} {}", direction.mark(), t_us, bytes.len())?;
        self.out.write_all(bytes)?;
        self.out.write_all(b"\n")
    }

    /// Flushes the output.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    /// Gives the output back.
    pub fn into_inner(self) -> W {
        self.out
    }
}

/// The longest chunk a record may hold: one read of a serial port or socket is far
/// shorter; a header claiming more is a damaged (or hostile) file, refused before any
/// allocation.
pub const MAX_CHUNK: usize = 1 << 20;

/// The longest chunk header or comment line.
const MAX_LINE: u64 = 1024;

fn bad(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

/// Reads the chunks of a record file (after its magic line).
#[derive(Debug)]
pub struct RecordReader<R: BufRead> {
    input: R,
    line: Vec<u8>,
}

impl<R: BufRead> RecordReader<R> {
    /// A reader over `input`, which must start with [`MAGIC`].
    pub fn new(mut input: R) -> io::Result<Self> {
        let mut first = Vec::new();
        input.read_until(b'\n', &mut first)?;
        if first != MAGIC {
            return Err(bad("not a scip2can record (first line)".into()));
        }
        Ok(Self {
            input,
            line: Vec::new(),
        })
    }

    /// The next chunk, `None` at the end of the file.
    pub fn next_chunk(&mut self) -> io::Result<Option<Chunk>> {
        loop {
            self.line.clear();
            let n = (&mut self.input)
                .take(MAX_LINE)
                .read_until(b'\n', &mut self.line)?;
            if n == 0 {
                return Ok(None);
            }
            if self.line.last() != Some(&b'\n') && n as u64 == MAX_LINE {
                return Err(bad(format!(
                    "a chunk header or comment line longer than {MAX_LINE} bytes"
                )));
            }
            if self.line.first() != Some(&b'#') {
                break;
            }
        }
        let text = String::from_utf8_lossy(&self.line).trim_end().to_owned();
        let mut parts = text.split(' ');
        let direction = match parts.next() {
            Some(">") => Direction::ToSensor,
            Some("<") => Direction::FromSensor,
            _ => return Err(bad(format!("bad chunk header {text:?}"))),
        };
        let num = |p: Option<&str>| -> io::Result<u64> {
            p.and_then(|s| s.parse().ok())
                .ok_or_else(|| bad(format!("bad chunk header {text:?}")))
        };
        let t_us = num(parts.next())?;
        let len = usize::try_from(num(parts.next())?).map_err(|e| bad(e.to_string()))?;
        if len > MAX_CHUNK {
            return Err(bad(format!(
                "chunk at {t_us} µs claims {len} bytes, more than {MAX_CHUNK}"
            )));
        }
        let mut bytes = vec![0u8; len];
        self.input.read_exact(&mut bytes)?;
        let mut lf = [0u8; 1];
        self.input.read_exact(&mut lf)?;
        if lf != *b"\n" {
            return Err(bad(format!("chunk at {t_us} µs not followed by LF")));
        }
        Ok(Some(Chunk {
            direction,
            t_us,
            bytes,
        }))
    }
}

/// A [`Read`] over the sensor → host bytes of a record.
struct SensorSide<R: BufRead> {
    reader: RecordReader<R>,
    buf: Vec<u8>,
    pos: usize,
}

impl<R: BufRead> Read for SensorSide<R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        while self.pos >= self.buf.len() {
            match self.reader.next_chunk()? {
                None => return Ok(0),
                Some(c) if c.direction == Direction::FromSensor => {
                    self.buf = c.bytes;
                    self.pos = 0;
                }
                Some(_) => {}
            }
        }
        let rest = self.buf.get(self.pos..).unwrap_or(&[]);
        let n = rest.len().min(out.len());
        out.get_mut(..n)
            .unwrap_or(&mut [])
            .copy_from_slice(rest.get(..n).unwrap_or(&[]));
        self.pos += n;
        Ok(n)
    }
}

/// The sensor → host byte stream of `input`: the `<` chunks of a record file, or the
/// input itself when it is not a record (a raw `.scip` capture).
pub fn sensor_side<'a>(input: impl Read + 'a) -> io::Result<Box<dyn Read + 'a>> {
    let mut input = BufReader::new(input);
    let head = input.fill_buf()?;
    // A SCIP stream never starts with '#' (no command does); a record always does.
    if head.first() == Some(&b'#') {
        Ok(Box::new(SensorSide {
            reader: RecordReader::new(input)?,
            buf: Vec::new(),
            pos: 0,
        }))
    } else {
        Ok(Box::new(input))
    }
}

/// The sensor → host bytes of a whole file's contents (record or raw capture).
pub fn sensor_bytes(contents: &[u8]) -> io::Result<Vec<u8>> {
    let mut out = Vec::new();
    sensor_side(contents)?.read_to_end(&mut out)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_golden_bytes() {
        let mut w = RecordWriter::new(Vec::new(), &["sensor: sim".into()]).unwrap();
        w.chunk(Direction::ToSensor, 0, b"VV\n").unwrap();
        w.chunk(Direction::FromSensor, 1520, b"VV\n00P\n").unwrap();
        w.chunk(Direction::FromSensor, 1600, b"\n").unwrap();
        w.chunk(Direction::FromSensor, 1700, b"").unwrap();
        let file = w.into_inner();
        assert_eq!(
            file,
            b"# scip2can record v1\n# sensor: sim\n> 0 3\nVV\n\n< 1520 7\nVV\n00P\n\n< 1600 1\n\n\n"
        );
        let mut r = RecordReader::new(&file[..]).unwrap();
        let c = r.next_chunk().unwrap().unwrap();
        assert_eq!(
            (c.direction, c.t_us, &c.bytes[..]),
            (Direction::ToSensor, 0, &b"VV\n"[..])
        );
        assert_eq!(r.next_chunk().unwrap().unwrap().t_us, 1520);
        assert_eq!(r.next_chunk().unwrap().unwrap().bytes, b"\n");
        assert_eq!(r.next_chunk().unwrap(), None);
        assert_eq!(sensor_bytes(&file).unwrap(), b"VV\n00P\n\n");
    }

    #[test]
    fn raw_streams_pass_through() {
        let raw = b"VV\n00P\n\n";
        assert_eq!(sensor_bytes(raw).unwrap(), raw);
        assert_eq!(sensor_bytes(b"").unwrap(), b"");
    }

    #[test]
    fn damaged_records_are_errors() {
        let cut = b"# scip2can record v1\n< 5 10\nVV\n";
        assert!(sensor_bytes(cut).is_err());
        let header = b"# scip2can record v1\n? 5 1\nx\n";
        assert!(sensor_bytes(header).is_err());
        let no_lf = b"# scip2can record v1\n< 5 1\nxy";
        assert!(sensor_bytes(no_lf).is_err());
    }

    /// A header claiming a huge chunk, or a header line without end, is an error at once
    /// (it used to allocate what the header claimed: 100 GB aborted the process).
    #[test]
    fn huge_claims_are_refused_before_allocating() {
        let huge = b"# scip2can record v1\n< 5 100000000000\nVV\n";
        let e = sensor_bytes(huge).unwrap_err();
        assert!(e.to_string().contains("claims 100000000000 bytes"), "{e}");
        let mut endless = b"# scip2can record v1\n< 5 ".to_vec();
        endless.extend(std::iter::repeat_n(b'7', 5000));
        let e = sensor_bytes(&endless).unwrap_err();
        assert!(e.to_string().contains("longer than 1024"), "{e}");
    }
}
