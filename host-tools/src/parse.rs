//! `scip2can parse`: a raw sensor-to-host SCIP stream → one JSON object per response.
//!
//! Each line of output is one response:
//! `{"command": "<echo>", "status": "00", "timestamp": <ms|null>, "fields": {...},
//!   "distances": [...], "intensities": [...], "echoes": [[...]], "errors": [...]}`.
//! Keys other than `command`, `status` and `timestamp` are left out when empty.
//! `distances` holds the first echo of every step as sent, error codes included; each
//! error code is named in `errors` (`{"index", "code", "meaning"}`). `intensities` holds
//! the second channel (intensity, reflectance or aux). `echoes` (multi-echo commands
//! only) holds every echo of every step. A damaged response carries `"damaged": true`
//! and a decode error in `errors` (`{"kind", "line", "offset", "message"}`), with what
//! was decoded before the damage. Garbage between responses gives an object with
//! `command` null.
//!
//! The input may also be a `scip2can record` file: its sensor → host chunks are decoded
//! (see [`sensor_side`]).

use std::io::{self, Read, Write};

use scip::{Decoder, Event, Range};
use serde::Serialize;
use serde_json::{Map, Value};

/// One response, as printed.
#[derive(Debug, Default, Serialize)]
pub struct ResponseJson {
    /// The echo line as text (lossy for non-UTF-8 garbage), null outside a response.
    pub command: Option<String>,
    /// The status chars, null when the response broke before its status.
    pub status: Option<String>,
    /// The scan timestamp (or TM1 time) in ms.
    pub timestamp: Option<u32>,
    /// VV/PP/II fields in order.
    #[serde(skip_serializing_if = "Map::is_empty")]
    pub fields: Map<String, Value>,
    /// First-echo distances, as sent.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub distances: Vec<u32>,
    /// Second channel of each first echo.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub intensities: Vec<u32>,
    /// All echoes per step (multi-echo commands).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub echoes: Vec<Vec<u32>>,
    /// Other payload lines (e.g. `%ST`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub payload: Vec<String>,
    /// Error codes among the distances, and the decode error of a damaged response.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<Value>,
    /// True when the response is damaged.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub damaged: bool,
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Turns decoder events into [`ResponseJson`] objects.
///
/// A damaged response stays open while the decoder skips its remaining lines (which may
/// report more bad lines); it is handed out once the decoder is between responses.
#[derive(Debug, Default)]
pub struct Collector {
    current: Option<ResponseJson>,
    multi_echo: bool,
}

impl Collector {
    /// Feeds `input` to `dec` until it is used up, collecting finished responses.
    pub fn feed(&mut self, dec: &mut Decoder, mut input: &[u8], out: &mut Vec<ResponseJson>) {
        while !input.is_empty() {
            let (used, ev) = dec.feed(input);
            input = input.get(used..).unwrap_or(&[]);
            if let Some(ev) = ev {
                self.event(ev, out);
            }
            if dec.between_responses() {
                self.flush_damaged(out);
            }
        }
    }

    /// The stream ended: a response still open is handed out as damaged.
    pub fn finish(&mut self, dec: &mut Decoder, out: &mut Vec<ResponseJson>) {
        if let Some(ev) = dec.finish() {
            self.event(ev, out);
        }
        self.flush_damaged(out);
    }

    fn flush_damaged(&mut self, out: &mut Vec<ResponseJson>) {
        if self.current.as_ref().is_some_and(|r| r.damaged) {
            out.extend(self.current.take());
        }
    }

    /// Takes one event.
    pub fn event(&mut self, ev: Event<'_>, out: &mut Vec<ResponseJson>) {
        match ev {
            Event::Start { echo, request } => {
                self.flush_damaged(out);
                self.multi_echo = matches!(
                    request.map(|r| r.command),
                    Some(scip::Command::Scan(s)) if s.multi_echo
                );
                self.current = Some(ResponseJson {
                    command: Some(text(echo)),
                    ..Default::default()
                });
            }
            Event::Status(s) => self.cur().status = Some(s.as_str().to_owned()),
            Event::Field(f) => {
                self.cur()
                    .fields
                    .insert(text(f.name), Value::String(text(f.value)));
            }
            Event::Timestamp(t) => self.cur().timestamp = Some(t),
            Event::Data(line) => {
                let has_aux = line.data.aux_width() > 0;
                let multi = self.multi_echo;
                let cur = self.cur();
                for r in line.indexed() {
                    if r.echo == 0 {
                        if let Range::Error(e) = line.range(&r.reading()) {
                            cur.errors.push(serde_json::json!({
                                "index": r.index, "code": r.distance, "meaning": e.name()
                            }));
                        }
                        cur.distances.push(r.distance);
                        if has_aux {
                            cur.intensities.push(r.aux);
                        }
                        if multi {
                            cur.echoes.push(vec![r.distance]);
                        }
                    } else if let Some(step) = cur.echoes.last_mut() {
                        step.push(r.distance);
                    }
                }
            }
            Event::Payload(p) => self.cur().payload.push(text(p)),
            Event::End(_) => out.extend(self.current.take()),
            Event::Error(e) => {
                let cur = self.cur();
                cur.damaged = true;
                cur.errors.push(serde_json::json!({
                    "kind": e.kind.name(), "line": e.line, "offset": e.offset,
                    "message": e.kind.to_string()
                }));
            }
        }
    }

    fn cur(&mut self) -> &mut ResponseJson {
        self.current.get_or_insert_with(ResponseJson::default)
    }
}

/// Decodes a whole byte stream into responses.
pub fn parse_bytes(bytes: &[u8]) -> Vec<ResponseJson> {
    let mut dec = Decoder::new();
    let mut col = Collector::default();
    let mut out = Vec::new();
    col.feed(&mut dec, bytes, &mut out);
    col.finish(&mut dec, &mut out);
    out
}

/// Reads a stream to its end and writes one JSON line per response; returns how many.
pub fn run(input: impl Read, mut out: impl Write) -> io::Result<usize> {
    let mut input = sensor_side(input)?;
    let mut dec = Decoder::new();
    let mut col = Collector::default();
    let mut buf = vec![0u8; 64 * 1024];
    let mut done = Vec::new();
    let mut count = 0;
    loop {
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        col.feed(&mut dec, buf.get(..n).unwrap_or(&[]), &mut done);
        count += write_all(&mut done, &mut out)?;
    }
    col.finish(&mut dec, &mut done);
    count += write_all(&mut done, &mut out)?;
    out.flush()?;
    Ok(count)
}

fn write_all(done: &mut Vec<ResponseJson>, out: &mut impl Write) -> io::Result<usize> {
    let n = done.len();
    for r in done.drain(..) {
        serde_json::to_writer(&mut *out, &r)?;
        out.write_all(b"\n")?;
    }
    Ok(n)
}

/// The sensor → host bytes of `input`: the `<` chunks of a record file
/// (`crate::sensor::record_file`), or `input` itself for a raw stream.
pub fn sensor_side<'a>(input: impl Read + 'a) -> io::Result<Box<dyn Read + 'a>> {
    crate::sensor::record_file::sensor_side(input)
}
