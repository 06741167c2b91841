//! The `scip2can` binary under bad and large input: `decode` skips and counts malformed
//! candump lines and prints each scan as soon as it completes (also from a pipe that is
//! still open); it follows the receiver rules of SPEC 3.5 and 7 on frames written by
//! hand from the SPEC; `replay` runs in constant memory whatever the input's size.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, OnceLock};
use std::time::Duration;

use bridge::engine::BridgeConfig;
use can_wire::{DistanceEncoding, Encoding, FrameFormat, IdWindow, IntensityEncoding};
use scip2can_host::replay::{replay_reader, replay_stream, TimedFrame, LINE_CAP};
use scip2can_tests::recordings_or_skip;
use serde_json::Value;

/// The `scip2can` binary of this build (built once, into this test's target folder).
pub(crate) fn scip2can() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        // This test runs from <target>/<profile>/deps/.
        let exe = std::env::current_exe().expect("test executable");
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("<target>/<profile>");
        let target_dir = profile_dir.parent().expect("<target>");
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let mut build = Command::new(cargo);
        build
            .args([
                "build",
                "--quiet",
                "-p",
                "scip2can-host",
                "--bin",
                "scip2can",
            ])
            .env("CARGO_TARGET_DIR", target_dir)
            .current_dir(env!("CARGO_MANIFEST_DIR"));
        if profile_dir.file_name().is_some_and(|n| n == "release") {
            build.arg("--release");
        }
        let status = build.status().expect("run cargo build");
        assert!(status.success(), "building scip2can failed");
        profile_dir.join(format!("scip2can{}", std::env::consts::EXE_SUFFIX))
    })
}

fn spawn(args: &[&str]) -> Child {
    Command::new(scip2can())
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start scip2can")
}

// Golden frames of node 0 (IDs 0x130.. at the default window 0x100), written from
// SPEC 3: scans of 5 D12 points, no intensity, 1 step apart from step -2 of 1024,
// codes ABC (2748 mm), 000 (invalid), FFF (out of range), 123 (291 mm), FFF. The
// trailers' CRCs (CRC-16/IBM-3740 over A, B, the codes as u16 LE and the trailer's
// bytes 0..6) were computed by hand, not by the crate.

/// Scan 0x0107, whole and intact.
const INTACT: [&str; 5] = [
    "(0000000001.000000) can0 130#0701E80300000500", // A: seq, time 1000 ms, 5 points
    "(0000000001.000100) can0 140#07030001FEFF0004", // B: D12, step 1, first -2, ares 1024
    "(0000000001.000200) can0 150#007 0BC0A00FF3F12", // points 0..4 (see below)
    "(0000000001.000300) can0 150#0470FF0F",         // point 4
    "(0000000001.000400) can0 160#070105000200F194", // trailer: 5 sent, 2 valid
];

/// Scan 0x0108, truncated: header A announces 5 points, the bridge sent 4.
const TRUNCATED: [&str; 4] = [
    "(0000000002.000000) can0 130#0801E80300000500",
    "(0000000002.000100) can0 140#08030001FEFF0004",
    "(0000000002.000200) can0 150#0080BC0A00FF3F12",
    "(0000000002.000300) can0 160#0801041002005581", // 4 sent, truncated, 2 valid
];

/// Scan 0x0109, aborted after 4 points (reason 2: sensor line checksum).
const ABORTED: [&str; 4] = [
    "(0000000003.000000) can0 130#0901E80300000500",
    "(0000000003.000100) can0 140#09030001FEFF0004",
    "(0000000003.000200) can0 150#0090BC0A00FF3F12",
    "(0000000003.000300) can0 170#090102000400",
];

/// Scan 0x010A, header B lost: its data frame is an orphan, the trailer ends it.
const NO_HEADER_B: [&str; 3] = [
    "(0000000004.000000) can0 130#0A01E80300000500",
    "(0000000004.000200) can0 150#00A0BC0A00FF3F12",
    "(0000000004.000300) can0 160#0A0105000200ABCD",
];

/// The lines without the space put into `INTACT[2]` to make it malformed.
fn good(line: &str) -> String {
    line.replace("#007 0", "#0070")
}

fn json_lines(text: &str) -> Vec<Value> {
    text.lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

#[test]
fn decode_skips_malformed_lines_and_follows_the_receiver_rules() {
    // Line 3 is malformed (a space in the data), line 7 is not candump at all, line 12
    // is 5000 bytes long; everything else is decoded.
    let mut log = String::new();
    log += &format!("{}\n{}\n{}\n", INTACT[0], INTACT[1], INTACT[2]);
    log += &format!("{}\n{}\n{}\n", good(INTACT[2]), INTACT[3], INTACT[4]);
    log += "this is not a candump line\n";
    log += &TRUNCATED.map(|l| format!("{l}\n")).concat();
    log += &format!("{}\n", "0".repeat(5000));
    log += &ABORTED.map(|l| format!("{l}\n")).concat();
    log += &NO_HEADER_B.map(|l| format!("{l}\n")).concat();
    let mut child = spawn(&["decode", "--stats", "-"]);
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(log.as_bytes())
        .expect("write log");
    let out = child.wait_with_output().expect("decode");
    assert!(out.status.success(), "{out:?}");
    let stderr = String::from_utf8(out.stderr).expect("utf-8");
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("warning"))
        .collect();
    assert_eq!(
        warnings,
        [
            "warning: line 3: 4 fields, expected `(time) iface frame`; skipped",
            "warning: line 7: 6 fields, expected `(time) iface frame`; skipped",
            "warning: line 12: line longer than 4096 bytes; skipped",
        ]
    );
    let summary: Value =
        serde_json::from_str(stderr.lines().last().expect("summary")).expect("summary JSON");
    assert_eq!(summary["lines_skipped"], 3);
    assert_eq!(summary["frames"], 16);
    let node = &summary["bridges"][0];
    assert_eq!(node["node"], 0);
    // 0x0107 and the truncated 0x0108 intact; 0x010A incomplete (SPEC 7: its header
    // B was lost, which makes it damaged, not lost); 0x0109 aborted.
    assert_eq!(
        [
            &node["scans_intact"],
            &node["scans_damaged"],
            &node["scans_aborted"],
            &node["scans_lost"],
            &node["frames_lost"],
            &node["frames_orphaned"],
        ],
        [2, 1, 1, 0, 1, 1]
    );

    let scans = json_lines(&String::from_utf8(out.stdout).expect("utf-8"));
    assert_eq!(scans.len(), 3, "{scans:?}");
    let (intact, truncated, aborted) = (&scans[0], &scans[1], &scans[2]);
    assert_eq!(intact["seq"], 0x0107);
    assert_eq!(intact["completeness"], "intact");
    assert_eq!(
        intact["distances"],
        serde_json::json!([2748, null, null, 291, null])
    );
    assert_eq!(intact["out_of_range"], serde_json::json!([2, 4]));
    // The truncated scan lists the 4 points sent, none missing.
    assert_eq!(truncated["seq"], 0x0108);
    assert_eq!(truncated["completeness"], "intact");
    assert_eq!(truncated["flags"]["truncated"], true);
    assert_eq!(truncated["point_count"], 5);
    assert_eq!(truncated["received"], 4);
    assert_eq!(
        truncated["distances"],
        serde_json::json!([2748, null, null, 291])
    );
    assert_eq!(truncated.get("missing"), None);
    // The aborted scan's points are discarded (SPEC 3.5).
    assert_eq!(aborted["seq"], 0x0109);
    assert_eq!(aborted["completeness"], "aborted");
    assert_eq!(aborted["abort_reason"], "Checksum");
    assert_eq!(aborted["received"], 0);
    assert_eq!(aborted["distances"], serde_json::json!([]));
    assert_eq!(aborted.get("missing"), None);

    // CSV: one row per listed point, 5 + 4 + 0.
    let path = std::env::temp_dir().join(format!("scip2can-{}-rules.log", std::process::id()));
    std::fs::write(&path, &log).expect("write log");
    let out = Command::new(scip2can())
        .args(["decode", "--csv"])
        .arg(&path)
        .output()
        .expect("decode --csv");
    let _ = std::fs::remove_file(&path);
    assert!(out.status.success());
    let csv = String::from_utf8(out.stdout).expect("utf-8");
    let seqs: Vec<&str> = csv
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next())
        .collect();
    assert_eq!(
        seqs,
        ["263", "263", "263", "263", "263", "264", "264", "264", "264"]
    );
    let text = String::from_utf8(out.stderr).expect("utf-8");
    assert!(
        text.contains("0 remote/error frames skipped; 3 malformed lines skipped"),
        "{text}"
    );
}

/// Reads lines of `child`'s standard output on a thread.
pub(crate) fn line_reader(child: &mut Child) -> mpsc::Receiver<String> {
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

#[test]
fn decode_prints_each_scan_while_its_input_is_still_open() {
    let mut child = spawn(&["decode", "-"]);
    let mut stdin = child.stdin.take().expect("stdin");
    let lines = line_reader(&mut child);
    // A generous limit: only a decoder that waits for the end of its input hits it.
    let wait = Duration::from_secs(30);
    let scans: [(u16, Vec<String>); 2] = [
        (0x0107, INTACT.iter().map(|l| good(l)).collect()),
        (0x0108, TRUNCATED.iter().map(|l| l.to_string()).collect()),
    ];
    for (seq, scan) in scans {
        for line in scan {
            // Written line by line, like candump does.
            writeln!(stdin, "{line}").expect("write a line");
            stdin.flush().expect("flush");
            std::thread::sleep(Duration::from_millis(20));
        }
        let got = lines.recv_timeout(wait).unwrap_or_else(|_| {
            let _ = child.kill();
            panic!("scan {seq:#x} did not appear while the input was open")
        });
        let v: Value = serde_json::from_str(&got).expect("JSON line");
        assert_eq!(
            (v["type"].as_str(), v["seq"].as_u64()),
            (Some("scan"), Some(u64::from(seq)))
        );
    }
    drop(stdin);
    let status = child.wait().expect("decode ends");
    assert!(status.success());
    assert!(lines.recv_timeout(wait).is_err(), "nothing more");
}

/// The peak resident set of a running process, kB (`VmHWM` of /proc/<pid>/status).
#[cfg(target_os = "linux")]
fn peak_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[cfg(target_os = "linux")]
#[test]
fn replay_runs_in_constant_memory() {
    let Some(dir) = recordings_or_skip("replay memory") else {
        return;
    };
    // The UTM-30LX recording 600 times over: 4.7 MB, 651 618 frames (the old replay
    // held the whole input, every frame and every record: 150 MB at this size).
    let one = std::fs::read(dir.join("hokuyoaist_example_utm_30lx.rx.scip")).expect("read");
    let copies = 600;
    let mut child = spawn(&["replay", "-"]);
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = std::thread::spawn(move || {
        for _ in 0..copies {
            if stdin.write_all(&one).is_err() {
                break;
            }
        }
    });
    // Sampled while the replay is alive: it waits on the pipe until this test reads
    // its output, and VmHWM is the peak so far.
    let pid = child.id();
    let mut stdout = child.stdout.take().expect("stdout");
    let (mut peak, mut lines) = (0u64, 0usize);
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = stdout.read(&mut buf).expect("read the log");
        if n == 0 {
            break;
        }
        lines += buf[..n].iter().filter(|&&b| b == b'\n').count();
        peak = peak.max(peak_kb(pid).unwrap_or(0));
    }
    writer.join().expect("writer");
    let out = child.wait_with_output().expect("replay");
    assert!(out.status.success(), "{out:?}");
    let report = String::from_utf8(out.stderr).expect("utf-8");
    assert!(
        report.contains(&format!("scans: {copies} in, {copies} sent")),
        "{report}"
    );
    assert!(report.contains(&format!("frames: {lines} (")), "{report}");
    assert!(peak > 0, "no sample of the replay's memory");
    assert!(peak < 40_000, "peak resident set {peak} kB");
}

fn config() -> BridgeConfig {
    BridgeConfig {
        encoding: Encoding {
            distance: DistanceEncoding::D16,
            intensity: IntensityEncoding::I16,
            unit_exp: 0,
        },
        ..BridgeConfig::new(
            IdWindow::DEFAULT.node(0).expect("node 0"),
            FrameFormat::Classic,
        )
    }
}

/// A reader that hands out at most 7 bytes per read.
struct Trickle<'a>(&'a [u8]);

impl Read for Trickle<'_> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let n = self.0.len().min(out.len()).min(7);
        out[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        Ok(n)
    }
}

#[test]
fn replay_reads_lines_across_reads_and_bounds_an_overlong_line() {
    let Some(dir) = recordings_or_skip("replay chunks") else {
        return;
    };
    let utm = std::fs::read(dir.join("hokuyoaist_example_utm_30lx.rx.scip")).expect("read");
    // A line 2.5 times the cap (no SCIP line is that long), then the recording twice.
    let mut bytes = vec![b'x'; LINE_CAP * 5 / 2];
    bytes.push(b'\n');
    bytes.extend_from_slice(&utm);
    bytes.extend_from_slice(&utm);
    let whole = replay_stream(&bytes, config()).expect("replay");
    let mut frames: Vec<TimedFrame> = Vec::new();
    let mut sink = |f: &TimedFrame| {
        frames.push(*f);
        Ok(())
    };
    let trickled = replay_reader(Trickle(&bytes), config(), None, &mut sink).expect("replay");
    assert_eq!(frames, whole.frames);
    assert!(trickled.frames.is_empty());
    assert_eq!(trickled.stats.scans_sent, 2);
    assert_eq!(trickled.stream_ns, whole.stream_ns);
    // The scan frames are those of the recording without the garbage line.
    let alone = replay_stream(&[&utm[..], &utm].concat(), config()).expect("replay");
    let scan_frames = |fs: &[TimedFrame]| -> Vec<Vec<u8>> {
        fs.iter()
            .filter(|f| {
                !matches!(
                    IdWindow::DEFAULT.classify(f.frame.id()),
                    Some((_, can_wire::Kind::Status))
                )
            })
            .map(|f| f.frame.data().to_vec())
            .collect()
    };
    assert_eq!(scan_frames(&frames), scan_frames(&alone.frames));
}
