//! Replay: a recorded stream's scans served in place of a scene.
//!
//! The recording (a record file or a raw `.scip` capture) is decoded with the `scip`
//! decoder; every intact measurement response becomes one scan, and its VV and PP
//! fields replace the model's text and limits. Scan `k` of the simulator is recorded
//! scan `k mod n`; a step the recorded request did not cover reads as "no echo".

use scip::{Command, DataSet, Decoder, Event};

use super::measure::{Source, Value};
use super::model::Model;

/// One recorded scan.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedScan {
    /// First step of the recorded request.
    pub start: u32,
    /// Its cluster (1 when 0).
    pub cluster: u32,
    /// The recorded data set.
    pub data: DataSet,
    /// Per value: every echo as (distance, second channel).
    pub values: Vec<Vec<Value>>,
}

/// The scans and the texts of a recording.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recording {
    /// VV fields of the last intact VV response.
    pub version: Vec<(String, String)>,
    /// PP fields of the last intact PP response.
    pub parameters: Vec<(String, String)>,
    /// Intact scans in order.
    pub scans: Vec<RecordedScan>,
}

impl Recording {
    /// Decodes a sensor → host byte stream.
    pub fn from_stream(bytes: &[u8]) -> Self {
        let mut rec = Recording::default();
        let mut dec = Decoder::new();
        let mut input = bytes;
        let mut fields: Vec<(String, String)> = Vec::new();
        let mut scan: Option<RecordedScan> = None;
        let mut kind: Option<Command> = None;
        let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        while !input.is_empty() {
            let (used, ev) = dec.feed(input);
            input = input.get(used..).unwrap_or(&[]);
            match ev {
                Some(Event::Start { request, .. }) => {
                    fields.clear();
                    kind = request.map(|r| r.command);
                    scan = match kind {
                        Some(Command::Scan(s)) => Some(RecordedScan {
                            start: u32::from(s.start),
                            cluster: u32::from(s.cluster.max(1)),
                            data: s.data,
                            values: Vec::new(),
                        }),
                        _ => None,
                    };
                }
                Some(Event::Field(f)) => fields.push((text(f.name), text(f.value))),
                Some(Event::Data(line)) => {
                    if let Some(s) = scan.as_mut() {
                        for r in line.indexed() {
                            if r.echo == 0 {
                                s.values.push(vec![(r.distance, r.aux)]);
                            } else if let Some(v) = s.values.last_mut() {
                                v.push((r.distance, r.aux));
                            }
                        }
                    }
                }
                Some(Event::End(_)) => match kind {
                    Some(Command::Version) => rec.version = core::mem::take(&mut fields),
                    Some(Command::Parameters) => {
                        rec.parameters = core::mem::take(&mut fields);
                    }
                    Some(Command::Scan(_)) => {
                        if let Some(s) = scan.take().filter(|s| !s.values.is_empty()) {
                            rec.scans.push(s);
                        }
                    }
                    _ => {}
                },
                Some(Event::Error(_)) => scan = None,
                _ => {}
            }
        }
        rec
    }
}

/// A [`Source`] that serves recorded scans in a loop.
#[derive(Debug, Clone)]
pub struct ReplaySource {
    scans: Vec<RecordedScan>,
}

impl ReplaySource {
    /// A source over the scans of `recording` (at least one is needed to see anything).
    pub fn new(recording: &Recording) -> Self {
        Self {
            scans: recording.scans.clone(),
        }
    }
}

impl Source for ReplaySource {
    fn step(
        &mut self,
        model: &Model,
        scan: u64,
        _t_s: f64,
        step: u32,
        data: DataSet,
        out: &mut Vec<Value>,
    ) {
        out.clear();
        let n = self.scans.len() as u64;
        let rec = (n > 0)
            .then(|| self.scans.get(usize::try_from(scan % n).unwrap_or(0)))
            .flatten();
        let values = rec.and_then(|r| {
            let idx = step.checked_sub(r.start)? / r.cluster;
            r.values.get(usize::try_from(idx).ok()?).map(|v| (r, v))
        });
        match values {
            Some((r, v)) => {
                for &(d, aux) in v {
                    // A second channel that was not recorded reads 0.
                    let aux = if r.data.aux_width() > 0 && data.aux_width() > 0 {
                        aux
                    } else {
                        0
                    };
                    let d = if data == DataSet::ShortDistance {
                        d.min(4095)
                    } else {
                        d
                    };
                    out.push((d, aux));
                }
            }
            None => out.push((model.no_echo_code(), 0)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ModelKind;

    #[test]
    fn replays_the_tagged_capture() {
        let stream =
            b"GD0000001000;GD00000999\n00P\nG]\\VF\n06306J06_07407607106i06i06i075070n\n\n";
        let rec = Recording::from_stream(stream);
        assert_eq!(rec.scans.len(), 1);
        let mut src = ReplaySource::new(&rec);
        let m = Model::new(ModelKind::Utm30lx);
        let mut out = Vec::new();
        src.step(&m, 5, 0.0, 0, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(387, 0)]);
        src.step(&m, 5, 0.0, 10, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(448, 0)]);
        src.step(&m, 5, 0.0, 11, DataSet::Distance, &mut out);
        assert_eq!(out, vec![(1, 0)]);
    }
}
