//! Live decoding and the Foxglove WebSocket server: `bridge --foxglove` on the
//! simulator seen by a client speaking `foxglove.websocket.v1` (with a client that
//! closes and one that never reads beside it), `decode` following an SLCAN adapter on
//! TCP and a growing file, and frames of another protocol on the bridges' identifiers.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use can_wire::Frame;
use serde_json::Value;
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket};

use crate::host_streaming::{line_reader, scip2can};

fn spawn(args: &[&str]) -> Child {
    Command::new(scip2can())
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start scip2can")
}

/// Lines of `child`'s standard error, on a thread.
fn stderr_lines(child: &mut Child) -> mpsc::Receiver<String> {
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// The Foxglove server address (`HOST:PORT`) that `child` prints on its standard error
/// (`ws://HOST:PORT`), waiting up to a minute; and the rest of its standard error lines.
fn server_address(child: &mut Child) -> (mpsc::Receiver<String>, String) {
    let errs = stderr_lines(child);
    loop {
        let line = errs
            .recv_timeout(Duration::from_secs(60))
            .expect("the server's address");
        if let Some(a) = line.split("ws://").nth(1) {
            return (errs, a.trim().to_owned());
        }
    }
}

type Ws = WebSocket<TcpStream>;

/// A client of the server at `addr` (`HOST:PORT`) offering the Foxglove WebSocket
/// protocol under both its names: `foxglove.websocket.v1` (its first name, the one of
/// the ROS bridges) and `foxglove.sdk.v1` (the same messages, the name the Foxglove SDK
/// server negotiates); it checks that the server picked one of them.
fn connect(addr: &str) -> Ws {
    let stream = TcpStream::connect(addr).expect("connect");
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .expect("timeout");
    let mut req = format!("ws://{addr}/").into_client_request().expect("url");
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        "foxglove.websocket.v1, foxglove.sdk.v1"
            .parse()
            .expect("header"),
    );
    let (ws, resp) = tungstenite::client(req, stream).expect("WebSocket handshake");
    assert_eq!(
        resp.headers()
            .get("Sec-WebSocket-Protocol")
            .and_then(|v| v.to_str().ok()),
        Some("foxglove.sdk.v1")
    );
    ws
}

/// Reads until the channel of `topic` is advertised; returns its advertisement, after
/// checking that `serverInfo` came first.
fn advertised(ws: &mut Ws, topic: &str) -> Value {
    let mut saw_info = false;
    let deadline = Instant::now() + Duration::from_secs(60);
    while Instant::now() < deadline {
        let Message::Text(text) = ws.read().expect("read") else {
            continue;
        };
        let v: Value = serde_json::from_str(text.as_str()).expect("JSON");
        match v["op"].as_str() {
            Some("serverInfo") => saw_info = true,
            Some("advertise") => {
                assert!(saw_info, "advertise before serverInfo");
                let channels = v["channels"].as_array().expect("channels");
                if let Some(c) = channels.iter().find(|c| c["topic"] == topic) {
                    return c.clone();
                }
            }
            _ => {}
        }
    }
    panic!("{topic} was not advertised");
}

fn subscribe(ws: &mut Ws, sub: u32, channel: &Value) {
    let msg = serde_json::json!({"op": "subscribe",
        "subscriptions": [{"id": sub, "channelId": channel["id"]}]});
    ws.send(Message::text(msg.to_string())).expect("subscribe");
}

/// The next `messageData` (opcode 1) of subscription `sub`: its payload.
fn message_data(ws: &mut Ws, sub: u32) -> Vec<u8> {
    loop {
        if let Message::Binary(b) = ws.read().expect("read") {
            // opcode, subscription id (u32 LE), receive time (u64 LE), payload.
            if b.first() == Some(&1) && b.get(1..5) == Some(&sub.to_le_bytes()[..]) {
                return b[13..].to_vec();
            }
        }
    }
}

fn varint(b: &[u8], i: &mut usize) -> u64 {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let byte = b[*i];
        *i += 1;
        v |= u64::from(byte & 0x7F) << shift;
        if byte & 0x80 == 0 {
            break;
        }
    }
    v
}

/// The fields of a `foxglove.LaserScan` this test checks, decoded from the protobuf
/// wire format by hand: start_angle (4), end_angle (5), ranges (6, packed doubles),
/// frame_id (2).
#[derive(Debug, Default)]
struct Scan {
    frame_id: String,
    start: f64,
    end: f64,
    ranges: Vec<f64>,
}

fn laser_scan(b: &[u8]) -> Scan {
    let mut s = Scan::default();
    let mut i = 0;
    let f64_at = |b: &[u8], i: usize| f64::from_le_bytes(b[i..i + 8].try_into().unwrap());
    while i < b.len() {
        let key = varint(b, &mut i);
        let (field, wire) = (key >> 3, key & 7);
        match wire {
            0 => {
                varint(b, &mut i);
            }
            1 => {
                let v = f64_at(b, i);
                i += 8;
                match field {
                    4 => s.start = v,
                    5 => s.end = v,
                    6 => s.ranges.push(v),
                    _ => {}
                }
            }
            2 => {
                let len = varint(b, &mut i) as usize;
                let body = &b[i..i + len];
                match field {
                    2 => s.frame_id = String::from_utf8(body.to_vec()).unwrap(),
                    6 => s.ranges.extend((0..len / 8).map(|k| f64_at(body, 8 * k))),
                    _ => {}
                }
                i += len;
            }
            5 => i += 4,
            w => panic!("wire type {w}"),
        }
    }
    s
}

/// The simulator's wall 2000 mm ahead, as the UTM-30LX sees it (1081 steps, 1440 per
/// turn, front step 540: ±135°): a beam at θ hits it at 2 m / cos θ; behind the sensor
/// there is nothing.
fn check_wall(s: &Scan) {
    use std::f64::consts::PI;
    assert_eq!(s.ranges.len(), 1081);
    assert!((s.start + 0.75 * PI).abs() < 1e-5, "start {}", s.start);
    assert!((s.end - 0.75 * PI).abs() < 1e-5, "end {}", s.end);
    assert_eq!(s.ranges[540], 2.0);
    let inc = (s.end - s.start) / 1080.0;
    for (i, &r) in s.ranges.iter().enumerate() {
        let theta = s.start + inc * i as f64;
        if theta.abs() < PI / 3.0 {
            let want = 2.0 / theta.cos();
            assert!(
                (r - want).abs() <= 0.0011,
                "point {i}: {r} m, wall at {want} m"
            );
        } else if theta.abs() > PI / 2.0 + 0.01 {
            assert!(!r.is_finite(), "point {i} behind the sensor: {r} m");
        }
    }
}

#[test]
fn a_foxglove_client_receives_the_bridge_scans_and_closed_or_slow_clients_do_not_stop_it() {
    let dir = std::env::temp_dir().join(format!("scip2can-fox-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("bus.log");
    let can = format!("candump:{}", log.display());
    let mut child = spawn(&[
        "bridge",
        "sim:model=utm30lx,scene=wall:2000,noise=0",
        "--fd",
        "--can",
        &can,
        "--foxglove",
        "127.0.0.1:0",
        "--seconds",
        "12",
    ]);
    let (errs, addr) = server_address(&mut child);
    // A client that subscribes and goes away without a close handshake, and one that
    // subscribes and never reads.
    let mut gone = connect(&addr);
    let c = advertised(&mut gone, "/scip2can/node0/scan");
    subscribe(&mut gone, 3, &c);
    drop(gone);
    let mut slow = connect(&addr);
    let c = advertised(&mut slow, "/scip2can/node0/scan");
    subscribe(&mut slow, 4, &c);

    let mut ws = connect(&addr);
    let scan = advertised(&mut ws, "/scip2can/node0/scan");
    assert_eq!(scan["encoding"], "protobuf");
    assert_eq!(scan["schemaName"], "foxglove.LaserScan");
    subscribe(&mut ws, 7, &scan);
    let start = Instant::now();
    let mut n = 0;
    while start.elapsed() < Duration::from_secs(4) {
        let s = laser_scan(&message_data(&mut ws, 7));
        assert_eq!(s.frame_id, "scip2can_node0");
        check_wall(&s);
        n += 1;
    }
    // UTM-30LX at 40 Hz for 4 s is 160 scans, whatever the other two clients do (half
    // of them at least: this machine may be busy with other work).
    assert!(n >= 80, "only {n} scans in 4 s");

    // The bridge's own status: state, counters, bus load.
    let mut ws2 = connect(&addr);
    let status = advertised(&mut ws2, "/scip2can/bridge");
    assert_eq!(status["encoding"], "json");
    subscribe(&mut ws2, 1, &status);
    let v: Value = serde_json::from_slice(&message_data(&mut ws2, 1)).expect("status JSON");
    assert_eq!(v["state"], "Streaming");
    assert_eq!(v["plan"]["points"], 1081);
    assert!(v["scans_sent"].as_u64().unwrap() > 40, "{v}");
    let load = v["bus_load_percent"].as_f64().unwrap();
    assert!(load > 1.0 && load < 100.0, "{v}");
    assert_eq!(v["foxglove_clients"], 3);
    drop(ws2);
    drop(ws);
    drop(slow);

    let status = child.wait().expect("bridge ends");
    assert!(status.success());
    let last: Vec<String> = errs.try_iter().collect();
    let summary = last
        .iter()
        .find(|l| l.starts_with("scip2can bridge:") && l.contains("scans sent"))
        .unwrap_or_else(|| panic!("no summary in {last:?}"));
    // 12 s at 40 Hz is 480 scans (half at least, as above). (Aborted and dropped scans
    // are not checked: a starved machine makes the in-process simulator late.)
    let sent: u32 = summary
        .split_whitespace()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .expect("scans sent");
    assert!(sent >= 240, "{summary}");
    let _ = std::fs::remove_dir_all(&dir);
}

// Golden frames of node 0 written from SPEC 3 (the same as host_streaming's): scan
// 0x0107, 5 D12 points, codes ABC (2748 mm), 000 (invalid), FFF (out of range), 123
// (291 mm), FFF; and 0x0108, truncated to 4 points.
const INTACT: [(u16, &str); 5] = [
    (0x130, "0701E80300000500"),
    (0x140, "07030001FEFF0004"),
    (0x150, "0070BC0A00FF3F12"),
    (0x150, "0470FF0F"),
    (0x160, "070105000200F194"),
];
const TRUNCATED: [(u16, &str); 4] = [
    (0x130, "0801E80300000500"),
    (0x140, "08030001FEFF0004"),
    (0x150, "0080BC0A00FF3F12"),
    (0x160, "0801041002005581"),
];

fn candump(t: f64, (id, data): (u16, &str)) -> String {
    format!("({t:.6}) can0 {id:03X}#{data}\n")
}

fn slcan((id, data): (u16, &str)) -> String {
    format!("t{id:03X}{}{data}\r", data.len() / 2)
}

fn expect_scan(lines: &mpsc::Receiver<String>, child: &mut Child, seq: u64) -> Value {
    let got = lines
        .recv_timeout(Duration::from_secs(30))
        .unwrap_or_else(|_| {
            let _ = child.kill();
            panic!("scan {seq:#x} did not appear while the input was open")
        });
    let v: Value = serde_json::from_str(&got).expect("JSON line");
    assert_eq!(
        (v["type"].as_str(), v["seq"].as_u64()),
        (Some("scan"), Some(seq))
    );
    v
}

#[test]
fn decode_follows_an_slcan_adapter_on_tcp() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let mut child = spawn(&["decode", "--stats", &format!("slcan:tcp://{addr}")]);
    let lines = line_reader(&mut child);
    // Accepted within a limit: a decoder that never connects fails the test.
    listener.set_nonblocking(true).unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut sock = loop {
        match listener.accept() {
            Ok((sock, _)) => break sock,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => {
                let _ = child.kill();
                panic!("the decoder did not connect: {e}");
            }
        }
    };
    sock.set_nonblocking(false).unwrap();
    // The decoder opens the channel (C, S8, O); an adapter answers each with CR.
    sock.set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 64];
    while got.iter().filter(|&&b| b == b'\r').count() < 3 {
        let n = sock.read(&mut buf).expect("the decoder's commands");
        assert!(n > 0, "the decoder closed the port");
        got.extend_from_slice(&buf[..n]);
    }
    assert_eq!(got, b"C\rS8\rO\r");
    sock.write_all(b"\r\r\r").unwrap();
    for (seq, scan) in [(0x107, &INTACT[..]), (0x108, &TRUNCATED[..])] {
        for &f in scan {
            sock.write_all(slcan(f).as_bytes()).unwrap();
            std::thread::sleep(Duration::from_millis(20));
        }
        let v = expect_scan(&lines, &mut child, seq);
        assert_eq!(v["completeness"], "intact");
    }
    drop(sock);
    let out = child.wait_with_output().expect("decode ends");
    assert!(out.status.success());
    let stderr = String::from_utf8(out.stderr).unwrap();
    let summary: Value = serde_json::from_str(stderr.lines().last().unwrap()).unwrap();
    assert_eq!(summary["frames"], 9);
    assert_eq!(summary["bridges"][0]["scans_intact"], 2);
}

#[test]
fn decode_follow_prints_scans_as_the_file_grows_and_stops_when_it_is_truncated() {
    let path = std::env::temp_dir().join(format!("scip2can-follow-{}.log", std::process::id()));
    let mut file = std::fs::File::create(&path).unwrap();
    let mut child = spawn(&["decode", "--follow", path.to_str().unwrap()]);
    let lines = line_reader(&mut child);
    let mut t = 1.0;
    for (seq, scan) in [(0x107, &INTACT[..]), (0x108, &TRUNCATED[..])] {
        for &f in scan {
            file.write_all(candump(t, f).as_bytes()).unwrap();
            file.flush().unwrap();
            t += 0.001;
            std::thread::sleep(Duration::from_millis(20));
        }
        let v = expect_scan(&lines, &mut child, seq);
        assert_eq!(v["completeness"], "intact");
    }
    // Still following: nothing ends it but a truncation (or Ctrl-C).
    std::thread::sleep(Duration::from_millis(300));
    assert!(child.try_wait().unwrap().is_none(), "decode stopped early");
    file.set_len(0).unwrap();
    let out = child.wait_with_output().expect("decode ends");
    let _ = std::fs::remove_file(&path);
    assert!(out.status.success());
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(stderr.contains("was truncated; stopping"), "{stderr}");
    assert!(stderr.contains("node 0: scans 2 intact"), "{stderr}");
}

#[test]
fn frames_of_another_protocol_on_the_same_ids_are_counted_and_reported_not_decoded() {
    // Another device's frames on node 0's identifiers: too short for a header A, a
    // 4-byte "trailer", a status page that does not exist (SPEC 5: rejected), and in
    // the middle of scan 0x0107 a 2-byte data frame (below SPEC 3.3's minimum of 3) and
    // a data frame of another sequence (an orphan, SPEC 7). None may change the scans
    // around them.
    let foreign: [(u16, &str); 5] = [
        (0x130, "01"),
        (0x160, "DEADBEEF"),
        (0x120, "7F00000000000000"),
        (0x150, "0101"),
        (0x150, "0030BC0A00FF3F12"),
    ];
    let mut log = String::new();
    let mut t = 1.0;
    let mut put = |f: (u16, &str), log: &mut String| {
        *log += &candump(t, f);
        t += 0.001;
    };
    for &f in &foreign[..2] {
        put(f, &mut log);
    }
    for (i, &f) in INTACT.iter().enumerate() {
        put(f, &mut log);
        if i == 2 {
            put(foreign[3], &mut log);
            put(foreign[4], &mut log);
        }
    }
    put(foreign[2], &mut log);
    for &f in &TRUNCATED {
        put(f, &mut log);
    }
    let mut child = spawn(&["decode", "--stats", "-"]);
    child
        .stdin
        .take()
        .unwrap()
        .write_all(log.as_bytes())
        .unwrap();
    let out = child.wait_with_output().expect("decode");
    assert!(out.status.success());
    let stdout = String::from_utf8(out.stdout).unwrap();
    let scans: Vec<Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(scans.len(), 2, "{stdout}");
    assert_eq!(scans[0]["seq"], 0x107);
    assert_eq!(scans[0]["completeness"], "intact");
    assert_eq!(
        scans[0]["distances"],
        serde_json::json!([2748, null, null, 291, null])
    );
    assert_eq!(scans[1]["seq"], 0x108);
    assert_eq!(scans[1]["completeness"], "intact");
    let stderr = String::from_utf8(out.stderr).unwrap();
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("warning: frame"))
        .collect();
    assert_eq!(warnings.len(), 4, "{stderr}");
    assert!(
        warnings[0].starts_with("warning: frame 130#01 at 1.000000 s"),
        "{stderr}"
    );
    assert!(warnings[0].contains("counted as corrupt"), "{stderr}");
    let summary: Value = serde_json::from_str(stderr.lines().last().unwrap()).unwrap();
    assert_eq!(summary["frames"], 14);
    assert_eq!(summary["frames_rejected"], 4);
    assert_eq!(summary["bridges"][0]["scans_intact"], 2);
    assert_eq!(summary["bridges"][0]["frames_orphaned"], 1);
}

/// An SLCAN adapter on a TCP socket for a bridge: answers its commands, keeps what it
/// transmits, and once `trigger` frames went by puts `inject` on the bus. Returns the
/// frames transmitted after the injection.
fn adapter(listener: TcpListener, trigger: usize, inject: Vec<(u16, Vec<u8>)>) -> Vec<Frame> {
    listener.set_nonblocking(true).unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut sock = loop {
        match listener.accept() {
            Ok((s, _)) => break s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => panic!("the bridge did not connect: {e}"),
        }
    };
    sock.set_nonblocking(false).unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let mut adapter = slcan::Adapter::new(*b"0100", *b"TEST", true);
    let mut lines = slcan::LineBuffer::new();
    let (mut sent, mut after) = (0usize, Vec::new());
    let mut injected = false;
    let mut buf = [0u8; 4096];
    'run: while Instant::now() < deadline {
        let n = match sock.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(_) => 0,
        };
        let mut input = &buf[..n];
        while !input.is_empty() {
            let (used, line) = lines.feed(input);
            input = &input[used..];
            if let Some(line) = line {
                let outcome = adapter.line(line);
                if let slcan::Outcome::Transmit(f, _) = outcome {
                    sent += 1;
                    if injected {
                        let fd = f.kind() != slcan::FrameKind::Data;
                        after.push(Frame::new(f.id(), f.data(), fd).unwrap());
                    }
                }
                let mut out = [0u8; slcan::LINE_MAX];
                let m = outcome.reply().emit(&mut out).unwrap();
                if sock.write_all(&out[..m]).is_err() {
                    break 'run;
                }
            }
        }
        if !injected && sent >= trigger {
            injected = true;
            for (id, data) in &inject {
                let f = slcan::Frame::new(
                    embedded_can::Id::Standard(embedded_can::StandardId::new(*id).unwrap()),
                    slcan::FrameKind::Data,
                    data,
                )
                .unwrap();
                let mut out = [0u8; slcan::LINE_MAX];
                let m = adapter.received(&f, 0, &mut out).expect("channel open");
                if sock.write_all(&out[..m]).is_err() {
                    break 'run;
                }
            }
        }
    }
    after
}

#[test]
fn another_protocol_on_the_bridge_ids_is_counted_and_the_bridge_keeps_streaming() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let can = format!("slcan:tcp://{}", listener.local_addr().unwrap());
    // Another device on node 0's identifiers (SPEC 3, 5: a 1-byte header A, a 4-byte
    // trailer, a status page that does not exist): each is rejected by a receiver.
    let inject = vec![
        (0x130, vec![0x01]),
        (0x160, vec![0xDE, 0xAD, 0xBE, 0xEF]),
        (0x120, vec![0x7F, 0, 0, 0, 0, 0, 0, 0]),
    ];
    let server = std::thread::spawn(move || adapter(listener, 500, inject));
    let mut child = spawn(&[
        "bridge",
        "sim:model=urg04lx,speed=4",
        "--encoding",
        "d12",
        "--can",
        &can,
        "--foxglove",
        "127.0.0.1:0",
        "--seconds",
        "8",
    ]);
    // Held to the end: its thread keeps reading the child's standard error.
    let (_errs, addr) = server_address(&mut child);
    let mut ws = connect(&addr);
    let status = advertised(&mut ws, "/scip2can/bridge");
    subscribe(&mut ws, 1, &status);
    let deadline = Instant::now() + Duration::from_secs(7);
    let mut rejected = 0;
    while Instant::now() < deadline && rejected < 3 {
        let v: Value = serde_json::from_slice(&message_data(&mut ws, 1)).expect("JSON");
        rejected = v["bus_frames_rejected"].as_u64().unwrap();
    }
    assert_eq!(rejected, 3);
    drop(ws);
    let after = server.join().expect("adapter");
    assert!(child.wait().expect("bridge ends").success());
    // The bridge went on streaming whole scans after the foreign frames.
    let mut dec: Box<can_wire::reassembly::Decoder<1440, 1>> = Box::new(
        can_wire::reassembly::Decoder::new(can_wire::IdWindow::DEFAULT),
    );
    let mut intact = 0;
    for f in &after {
        if let Ok(Some(can_wire::reassembly::Event::Scan { scan, .. })) = dec.push_frame(f) {
            assert_eq!(scan.header().point_count, 682);
            intact += usize::from(scan.is_intact());
        }
    }
    assert!(
        intact >= 20,
        "{intact} intact scans after the foreign frames"
    );
}

#[test]
fn decode_serves_a_live_log_to_a_foxglove_client() {
    let mut child = spawn(&["decode", "--foxglove", "127.0.0.1:0", "-"]);
    // Held to the end: its thread keeps reading the child's standard error.
    let (_errs, addr) = server_address(&mut child);
    let mut stdin = child.stdin.take().expect("stdin");
    // Its JSON lines are read (and dropped) so that a full pipe never stops it.
    let _lines = line_reader(&mut child);
    let mut ws = connect(&addr);
    let mut t = 1.0;
    let mut write = |scan: &[(u16, &str)], stdin: &mut std::process::ChildStdin| {
        for &f in scan {
            stdin.write_all(candump(t, f).as_bytes()).unwrap();
            t += 0.001;
        }
        stdin.flush().unwrap();
    };
    // The first scan makes the node's topic; the second is the one received.
    write(&INTACT, &mut stdin);
    let c = advertised(&mut ws, "/scip2can/node0/scan");
    subscribe(&mut ws, 2, &c);
    // Subscriptions take effect asynchronously: scans are written until one arrives
    // (0x0108 and 0x0107 in turn, each a new scan).
    ws.get_mut()
        .set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut next = [&TRUNCATED[..], &INTACT[..]].into_iter().cycle();
    let s = loop {
        assert!(Instant::now() < deadline, "no scan arrived");
        write(next.next().unwrap(), &mut stdin);
        match ws.read() {
            Ok(Message::Binary(b)) if b.first() == Some(&1) => break laser_scan(&b[13..]),
            // The server can take a subscription before it knows the channel it just
            // advertised (seen about one run in five): subscribe again.
            Ok(Message::Text(t)) if t.as_str().contains("Unknown channel") => {
                std::thread::sleep(Duration::from_millis(50));
                subscribe(&mut ws, 2, &c);
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => panic!("{e}"),
        }
    };
    // The golden scans (SPEC 3): points 1 step apart from step -2 of 1024; 0x0107 has
    // 5 (2748 mm, invalid, out of range, 291 mm, out of range), the truncated 0x0108
    // the first 4 of them.
    let step = std::f64::consts::TAU / 1024.0;
    let n = s.ranges.len();
    assert!(n == 4 || n == 5, "{n} points");
    assert!((s.start + 2.0 * step).abs() < 1e-6, "{}", s.start);
    assert!((s.end - (n as f64 - 3.0) * step).abs() < 1e-6, "{}", s.end);
    // Ranges are f32 metres (as in sensor_msgs/LaserScan), widened to the f64 of
    // foxglove.LaserScan.
    assert!((s.ranges[0] - 2.748).abs() < 1e-6, "{}", s.ranges[0]);
    assert!(s.ranges[1].is_nan());
    assert_eq!(s.ranges[2], f64::INFINITY);
    assert!((s.ranges[3] - 0.291).abs() < 1e-6, "{}", s.ranges[3]);
    if n == 5 {
        assert_eq!(s.ranges[4], f64::INFINITY);
    }
    drop(stdin);
    drop(ws);
    assert!(child.wait().expect("decode ends").success());
}
