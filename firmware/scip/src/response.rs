//! The sensor side: writing responses (echo, status, fields, timestamps, data lines).
//!
//! Used by the simulator and by tests that build streams; the same sum and value code as
//! the decoder. Output goes to any `FnMut(&[u8])` sink, one line or less per call, so it
//! works without allocation.

use crate::command::{DataSet, Request, REQUEST_MAX};
use crate::decoder::DATA_CHARS;
use crate::sum::checksum;
use crate::value;

/// Writes one response at a time into a byte sink.
#[derive(Debug)]
pub struct ResponseWriter<F: FnMut(&[u8])> {
    out: F,
    line: [u8; DATA_CHARS + 2],
    len: usize,
    data: DataSet,
}

impl<F: FnMut(&[u8])> ResponseWriter<F> {
    /// A writer into `out`.
    pub fn new(out: F) -> Self {
        Self {
            out,
            line: [0; DATA_CHARS + 2],
            len: 0,
            data: DataSet::Distance,
        }
    }

    /// Gives the sink back.
    pub fn into_inner(self) -> F {
        self.out
    }

    /// The echo of a request (its exact command line).
    pub fn echo(&mut self, request: &Request) {
        let mut buf = [0u8; REQUEST_MAX];
        if let Ok(n) = request.encode_echo(&mut buf) {
            (self.out)(buf.get(..n).unwrap_or(&[]));
        }
        if let crate::Command::Scan(s) = request.command {
            self.data = s.data;
        }
    }

    /// An echo line given as raw bytes (a command as received, even a malformed one);
    /// LF is added.
    pub fn echo_raw(&mut self, echo: &[u8]) {
        (self.out)(echo);
        (self.out)(b"\n");
    }

    /// A status line: two chars, their sum, LF.
    pub fn status(&mut self, status: [u8; 2]) {
        let s = checksum(&status);
        (self.out)(&[status[0], status[1], s, b'\n']);
    }

    /// A SCIP 1.1 status line: one char, LF.
    pub fn status_scip11(&mut self, status: u8) {
        (self.out)(&[status, b'\n']);
    }

    /// A `NAME:VALUE;S` line (sum over `NAME:VALUE`, as sensors send it).
    pub fn field(&mut self, name: &[u8], value: &[u8]) {
        let s = checksum(name)
            .wrapping_sub(0x30)
            .wrapping_add(b':')
            .wrapping_add(checksum(value).wrapping_sub(0x30));
        // At most 0x3F + 0x30: never wraps.
        let s = (s & 0x3F).wrapping_add(0x30);
        (self.out)(name);
        (self.out)(b":");
        (self.out)(value);
        (self.out)(&[b';', s, b'\n']);
    }

    /// A payload line with its sum (e.g. `%ST`'s `000`).
    pub fn line(&mut self, body: &[u8]) {
        (self.out)(body);
        (self.out)(&[checksum(body), b'\n']);
    }

    /// A 4-char timestamp line (24-bit ms; higher bits dropped).
    pub fn timestamp(&mut self, ms: u32) {
        let mut t = [0u8; 4];
        // 24 bits always fit in 4 chars.
        let _ = value::encode(ms & 0x00FF_FFFF, &mut t);
        self.line(&t);
    }

    /// Appends one value of `width` chars to the data lines (wrapping at 64 chars).
    /// Values too large for the width are clamped to its maximum.
    pub fn value(&mut self, v: u32, width: u8) {
        let w = usize::from(width.clamp(1, 4));
        // The largest value of w chars: 2^(6w) - 1.
        let max = [0, 0x3F, 0xFFF, 0x3_FFFF, 0xFF_FFFF]
            .get(w)
            .copied()
            .unwrap_or(0);
        let mut chars = [0u8; 4];
        let chars = chars.get_mut(..w).unwrap_or(&mut []);
        let _ = value::encode(v.min(max), chars);
        for &c in chars.iter() {
            self.data_char(c);
        }
    }

    /// Appends one step: its distance and, when the data set has one, its second channel.
    pub fn step(&mut self, distance: u32, aux: u32) {
        self.value(distance, self.data.distance_width());
        let aw = self.data.aux_width();
        if aw > 0 {
            self.value(aux, aw);
        }
    }

    /// Appends an extra echo of the step just written (multi-echo): `&` then the step.
    pub fn extra_echo(&mut self, distance: u32, aux: u32) {
        self.data_char(b'&');
        self.step(distance, aux);
    }

    fn data_char(&mut self, c: u8) {
        if let Some(slot) = self.line.get_mut(self.len) {
            *slot = c;
            // `len` indexed a slot of the line: never saturates.
            self.len = self.len.saturating_add(1);
        }
        if self.len == DATA_CHARS {
            self.flush_data();
        }
    }

    fn flush_data(&mut self) {
        if self.len == 0 {
            return;
        }
        let body = self.line.get(..self.len).unwrap_or(&[]);
        let s = checksum(body);
        (self.out)(body);
        (self.out)(&[s, b'\n']);
        self.len = 0;
    }

    /// Ends the response: the last partial data line, then the empty line.
    pub fn end(&mut self) {
        self.flush_data();
        (self.out)(b"\n");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Command, ScanMode, ScanRequest};

    #[test]
    fn writes_the_real_tagged_gd_response() {
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        let req = Request::parse(b"GD0000001000;GD00000999").unwrap();
        w.echo(&req);
        w.status(*b"00");
        w.timestamp(crate::value::decode(b"G]\\V").unwrap());
        for d in [387, 410, 431, 452, 454, 449, 441, 441, 441, 453, 448] {
            w.step(d, 0);
        }
        w.end();
        let _ = w.into_inner();
        assert_eq!(
            out,
            b"GD0000001000;GD00000999\n00P\nG]\\VF\n06306J06_07407607106i06i06i075070n\n\n"
        );
    }

    #[test]
    fn fields_and_long_lines() {
        let mut out = Vec::new();
        let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
        w.field(b"DMIN", b"20");
        w.field(b"SCSP", b"Initial(600[rpm])<-Default setting by user");
        let scan = ScanRequest::distance(ScanMode::Single, 0, 29);
        w.echo(&Request::new(Command::Scan(scan)));
        for _ in 0..30 {
            w.step(1000, 0);
        }
        w.end();
        let _ = w.into_inner();
        let text = core::str::from_utf8(&out).unwrap();
        let lines: Vec<&str> = text.split('\n').collect();
        assert_eq!(lines[0], "DMIN:20;4");
        assert_eq!(
            lines[1],
            "SCSP:Initial(600[rpm])<-Default setting by user;A"
        );
        // 30 values * 3 chars = 90 chars: one 64-char line, one 26-char line.
        assert_eq!(lines[3].len(), 65);
        assert_eq!(lines[4].len(), 27);
        assert_eq!(lines[5], "");
    }
}
