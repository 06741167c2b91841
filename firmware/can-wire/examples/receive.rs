//! A receiver: reads a candump log (a file, or standard input) and prints every scan,
//! status frame and control answer of the bridges of the default identifier window, with
//! the time each was received.
//!
//! ```text
//! cargo run -p can-wire --example receive -- capture.log
//! candump -L can0 | cargo run -p can-wire --example receive
//! ```
//!
//! A robot's own code does the same with the frames of its CAN driver: give each frame's
//! identifier and data to [`Decoder::push`], and keep the time the frame arrived with the
//! event it completes. This example's only other work is reading candump's text
//! (`(seconds) interface ID#DATA`, CAN FD as `ID##<flags>DATA`).

use std::io::{BufRead, BufReader};

use can_wire::{Completeness, Decoder, Distance, Event, IdWindow, MAX_POINTS};
use embedded_can::{ExtendedId, Id, StandardId};

/// Points per scan the decoder holds: every point a header can announce.
const POINTS: usize = MAX_POINTS as usize;
/// Bridges followed at once (a window has 16 nodes).
const BRIDGES: usize = 16;

/// One candump line: (time in seconds, identifier, data); `None` for lines that are
/// not data frames (remote and error frames, comments, malformed text).
fn parse_line(line: &str) -> Option<(f64, Id, Vec<u8>)> {
    let mut words = line.split_whitespace();
    let time: f64 = words
        .next()?
        .strip_prefix('(')?
        .strip_suffix(')')?
        .parse()
        .ok()?;
    let _interface = words.next()?;
    let (id_text, rest) = words.next()?.split_once('#')?;
    // CAN FD: `##` then one hex digit of flags before the data.
    let data_text = match rest.strip_prefix('#') {
        Some(fd) => fd.get(1..)?,
        None => rest,
    };
    if data_text.starts_with('R') {
        return None;
    }
    let raw = u32::from_str_radix(id_text, 16).ok()?;
    let id = if id_text.len() > 3 {
        Id::Extended(ExtendedId::new(raw)?)
    } else {
        Id::Standard(StandardId::new(u16::try_from(raw).ok()?)?)
    };
    let data = (0..data_text.len() / 2)
        .map(|i| u8::from_str_radix(data_text.get(2 * i..2 * i + 2)?, 16).ok())
        .collect::<Option<Vec<u8>>>()?;
    Some((time, id, data))
}

fn main() -> std::io::Result<()> {
    let input: Box<dyn BufRead> = match std::env::args().nth(1) {
        Some(path) if path != "-" => Box::new(BufReader::new(std::fs::File::open(path)?)),
        _ => Box::new(BufReader::new(std::io::stdin())),
    };
    // About 650 kB with room for every point of 16 bridges: on the heap.
    let mut decoder: Box<Decoder<POINTS, BRIDGES>> = Box::new(Decoder::new(IdWindow::DEFAULT));
    let mut last_time = 0.0;
    let mut nodes = Vec::new();
    for line in input.lines() {
        let Some((time, id, data)) = parse_line(&line?) else {
            continue;
        };
        last_time = time;
        match decoder.push(id, &data) {
            Ok(Some(event)) => print_event(time, &event, &mut nodes),
            Ok(None) => {}
            // A frame of the window that is not valid: counted in the node's statistics.
            Err(e) => eprintln!("{time:.6}: frame {id:?} rejected: {e:?}"),
        }
    }
    // At the end of input (or after a timeout on a live bus), a scan still in
    // progress is finished as incomplete.
    for node in nodes.clone() {
        if let Some(scan) = decoder.flush(node) {
            print_event(last_time, &Event::Scan { node, scan }, &mut nodes);
        }
    }
    for node in nodes {
        if let Some(s) = decoder.stats(node) {
            println!("node {node}: {s:?}");
        }
    }
    Ok(())
}

fn print_event(time: f64, event: &Event<'_, POINTS>, nodes: &mut Vec<u8>) {
    match event {
        Event::Scan { node, scan } => {
            if !nodes.contains(node) {
                nodes.push(*node);
            }
            let h = scan.header();
            let verdict = match scan.completeness() {
                Completeness::Intact => "intact".to_string(),
                other => format!("{other:?}"),
            };
            // The scan's own time (sensor time, or the bridge's clock when time_synced)
            // is in the header; `time` is when its last frame arrived.
            println!(
                "{time:.6}: node {node} scan {} (t = {} ms): {verdict}, {} of {} points",
                h.seq,
                h.timestamp_ms,
                scan.received(),
                scan.listed()
            );
            // Only points of an intact or incomplete scan are the values sent.
            if matches!(
                scan.completeness(),
                Completeness::Intact | Completeness::Incomplete { .. }
            ) {
                for (i, point) in scan.points().enumerate().take(3) {
                    let angle = h.angle(i as u16).map_or("?".into(), |a| format!("{a:.4}"));
                    let what = match point.map(|p| p.distance) {
                        Some(Distance::Mm(mm)) => format!("{mm} mm"),
                        Some(other) => format!("{other:?}"),
                        None => "missing".into(),
                    };
                    println!("    point {i} at {angle} rad: {what}");
                }
            }
        }
        Event::Status { node, status } => println!("{time:.6}: node {node} status {status:?}"),
        Event::Answer { node, answer } => println!("{time:.6}: node {node} answer {answer:?}"),
        Event::Control { node, control } => {
            println!("{time:.6}: node {node} control {control:?}")
        }
    }
}
