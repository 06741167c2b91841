//! The real recordings: golden outputs of `scip2can parse`, chunking independence (random
//! and as the bytes really arrived), and the corrupted capture.
//!
//! Re-bless the golden files after an intended change of output:
//! `BLESS=1 cargo test -p scip2can-tests --test integration recordings`.

use std::path::{Path, PathBuf};

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use scip::Decoder;
use scip2can_tests::{oracle, recordings_or_skip, sensor_streams};

fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("golden")
}

fn golden_name(stream: &Path) -> String {
    let stem = stream.file_name().and_then(|n| n.to_str()).unwrap_or("x");
    format!("{}.jsonl", stem.trim_end_matches(".scip"))
}

fn parse_to_jsonl(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    scip2can_host::parse::run(bytes, &mut out).expect("in-memory parse");
    out
}

#[test]
fn every_recording_matches_its_golden_file() {
    let Some(dir) = recordings_or_skip("golden") else {
        return;
    };
    let streams = sensor_streams(&dir);
    let bless = std::env::var("BLESS").is_ok_and(|v| v == "1");
    let mut mismatches = Vec::new();
    for stream in &streams {
        let bytes = std::fs::read(stream).expect("read recording");
        let got = parse_to_jsonl(&bytes);
        let golden = golden_dir().join(golden_name(stream));
        golden_scans_agree_with_the_oracle(stream, &bytes, &got);
        if bless {
            std::fs::write(&golden, &got).expect("write golden");
            continue;
        }
        let want = std::fs::read(&golden)
            .unwrap_or_else(|e| panic!("{}: {e} (bless with BLESS=1)", golden.display()));
        if got != want {
            mismatches.push(golden.display().to_string());
        }
    }
    assert!(
        mismatches.is_empty(),
        "output differs from {mismatches:?}; re-bless with BLESS=1 if intended"
    );
}

/// The scans of a golden (or freshly blessed) output hold what the independent reader
/// decodes from the capture: same echoes, timestamps, distances and intensities, and the
/// damaged ones flagged.
fn golden_scans_agree_with_the_oracle(stream: &Path, bytes: &[u8], jsonl: &[u8]) {
    let name = stream.display();
    let objects: Vec<serde_json::Value> = jsonl
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .map(|l| serde_json::from_slice(l).expect("json line"))
        .filter(|o: &serde_json::Value| o.get("timestamp").is_some_and(|t| !t.is_null()))
        .filter(|o| o.get("distances").is_some())
        .collect();
    let want = oracle::scans(bytes);
    assert_eq!(objects.len(), want.len(), "{name}: scans");
    let numbers = |o: &serde_json::Value, key: &str| -> Vec<u32> {
        o.get(key)
            .and_then(|v| v.as_array())
            .map(|a| {
                a.iter()
                    .map(|v| v.as_u64().and_then(|v| u32::try_from(v).ok()).expect("u32"))
                    .collect()
            })
            .unwrap_or_default()
    };
    for (o, w) in objects.iter().zip(&want) {
        assert_eq!(o["command"], w.echo.as_str(), "{name}");
        assert_eq!(o["timestamp"], w.timestamp, "{name}");
        assert_eq!(o["damaged"].as_bool().unwrap_or(false), w.damaged, "{name}");
        if w.damaged {
            // What was decoded before the damage is a prefix of the lines that passed.
            let d = numbers(o, "distances");
            assert!(w.distances.starts_with(&d), "{name}: damaged prefix");
        } else {
            assert_eq!(numbers(o, "distances"), w.distances, "{name}");
            assert_eq!(numbers(o, "intensities"), w.intensities, "{name}");
        }
    }
}

/// Every event of a stream, as owned text, fed in the given chunk sizes (cycled).
fn events(bytes: &[u8], chunks: &[usize]) -> Vec<String> {
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    let mut rest = bytes;
    let mut i = 0;
    while !rest.is_empty() {
        let n = chunks
            .get(i % chunks.len().max(1))
            .copied()
            .unwrap_or(1)
            .clamp(1, rest.len());
        i += 1;
        let mut chunk = &rest[..n];
        rest = &rest[n..];
        while !chunk.is_empty() {
            let (used, ev) = dec.feed(chunk);
            assert!(used <= chunk.len());
            chunk = &chunk[used..];
            if let Some(ev) = ev {
                out.push(format!("{ev:?}"));
            }
        }
    }
    if let Some(ev) = dec.finish() {
        out.push(format!("{ev:?}"));
    }
    out
}

#[test]
fn any_chunking_gives_the_same_events() {
    let Some(dir) = recordings_or_skip("chunking") else {
        return;
    };
    for stream in sensor_streams(&dir) {
        let bytes = std::fs::read(&stream).expect("read");
        let whole = events(&bytes, &[usize::MAX]);
        let bytewise = events(&bytes, &[1]);
        assert_eq!(whole, bytewise, "{}", stream.display());
        let mut runner = TestRunner::new(Config {
            cases: 64,
            ..Config::default()
        });
        runner
            .run(&prop::collection::vec(1usize..200, 1..40), |chunks| {
                prop_assert_eq!(&events(&bytes, &chunks), &whole);
                Ok(())
            })
            .unwrap_or_else(|e| panic!("{}: {e}", stream.display()));
    }
}

/// The `.flexiport.logr` files: records of big-endian `u32 sec, u32 usec, u32 len` and
/// `len` bytes, exactly as the driver read them from the sensor.
fn logr_chunks(bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let mut rest = bytes;
    while rest.len() >= 12 {
        let len = u32::from_be_bytes([rest[8], rest[9], rest[10], rest[11]]) as usize;
        let end = (12 + len).min(rest.len());
        out.push(rest[12..end].to_vec());
        rest = &rest[end..];
    }
    out
}

#[test]
fn the_reads_as_they_really_arrived_give_the_same_events() {
    let Some(dir) = recordings_or_skip("logr") else {
        return;
    };
    for model in ["urg_04lx", "utm_30lx"] {
        let logr = std::fs::read(dir.join(format!("hokuyoaist_example_{model}.flexiport.logr")))
            .expect("read logr");
        let rx = std::fs::read(dir.join(format!("hokuyoaist_example_{model}.rx.scip")))
            .expect("read rx");
        let chunks = logr_chunks(&logr);
        assert!(chunks.len() > 100, "{model}: only {} reads", chunks.len());
        assert_eq!(chunks.concat(), rx, "{model}: logr and rx differ");
        let sizes: Vec<usize> = chunks.iter().map(Vec::len).collect();
        assert_eq!(events(&rx, &sizes), events(&rx, &[usize::MAX]), "{model}");
    }
}

#[test]
fn recordings_decode_with_the_values_the_sensors_sent() {
    let Some(dir) = recordings_or_skip("values") else {
        return;
    };
    let read = |name: &str| std::fs::read(dir.join(name)).expect("read");
    let urg = scip2can_host::parse::parse_bytes(&read("hokuyoaist_example_urg_04lx.rx.scip"));
    let gd = urg.last().expect("a GD response");
    assert_eq!(gd.command.as_deref(), Some("GD0044072501"));
    // 725 - 44 + 1 steps; the first value is "068" = 0*4096 + 6*64 + 8.
    assert_eq!(gd.distances.len(), 682);
    assert_eq!(gd.distances[0], 392);
    assert!(!gd.damaged);

    let utm = scip2can_host::parse::parse_bytes(&read("hokuyoaist_example_utm_30lx.rx.scip"));
    let me = utm.last().expect("an ME frame");
    assert_eq!(me.command.as_deref(), Some("ME0000108001100"));
    assert_eq!(me.status.as_deref(), Some("99"));
    assert_eq!((me.distances.len(), me.intensities.len()), (1081, 1081));
    // "00]" = 45 mm, then intensity "0LA" = 28*64 + 17.
    assert_eq!((me.distances[0], me.intensities[0]), (45, 1809));

    let tag = scip2can_host::parse::parse_bytes(&read("snark_gd_0000_0010_tag.scip"));
    assert_eq!(tag.len(), 1);
    assert_eq!(tag[0].command.as_deref(), Some("GD0000001000;GD00000999"));
    assert_eq!(
        tag[0].distances,
        [387, 410, 431, 452, 454, 449, 441, 441, 441, 453, 448]
    );
}

/// Lines of a file whose sum char does not match, by an oracle independent of the
/// decoder: a measurement line is `data + sum`; the sum covers all bytes before it.
fn bad_lines(bytes: &[u8]) -> Vec<usize> {
    let lines: Vec<&[u8]> = bytes.split(|&b| b == b'\n').collect();
    let mut bad = Vec::new();
    let mut line_in_response = 0;
    for (i, line) in lines.iter().enumerate() {
        if line.is_empty() {
            line_in_response = 0;
            continue;
        }
        let is_last_unterminated = i == lines.len() - 1;
        if line_in_response >= 1 && !is_last_unterminated {
            let (body, sum) = line.split_at(line.len() - 1);
            let s = (body.iter().map(|&b| u32::from(b)).sum::<u32>() & 0x3F) as u8 + 0x30;
            if s != sum[0] {
                bad.push(line_in_response);
            }
        }
        line_in_response += 1;
    }
    bad
}

#[test]
fn the_corrupted_recording_reports_every_bad_line() {
    let Some(dir) = recordings_or_skip("corrupted") else {
        return;
    };
    let bytes = std::fs::read(dir.join("eeros_md_0046_0600.scip")).expect("read");
    let expected_lines = bad_lines(&bytes);
    assert_eq!(
        expected_lines.len(),
        5,
        "the README says 5 of 30 lines fail"
    );

    let out = scip2can_host::parse::parse_bytes(&bytes);
    assert_eq!(out.len(), 2);
    // The ack of the MD request is intact.
    assert_eq!(out[0].command.as_deref(), Some("MD0046060000001"));
    assert_eq!(out[0].status.as_deref(), Some("00"));
    assert!(!out[0].damaged && out[0].errors.is_empty());
    // The scan frame is damaged: each bad line named with its kind, then the cut end.
    let frame = &out[1];
    assert!(frame.damaged);
    let kinds: Vec<(&str, u64)> = frame
        .errors
        .iter()
        .filter_map(|e| Some((e.get("kind")?.as_str()?, e.get("line")?.as_u64()?)))
        .collect();
    let mut want: Vec<(&str, u64)> = expected_lines
        .iter()
        .map(|&l| ("bad_sum", l as u64))
        .collect();
    // The capture ends inside the frame's last line (no LF): that line is cut short.
    let last_line = bytes
        .split(|&b| b == b'\n')
        .rev()
        .take_while(|l| !l.is_empty())
        .count()
        - 1;
    want.push(("truncated", last_line as u64));
    assert_eq!(kinds, want);
    // Nothing after the first bad line is published: the values decoded before it are
    // those of the lines before it.
    let first_bad = expected_lines[0];
    assert!(frame.distances.len() <= (first_bad - 2) * 64 / 3 + 1);
}
