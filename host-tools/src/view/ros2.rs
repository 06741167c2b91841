//! ROS 2 messages in CDR: `sensor_msgs/msg/LaserScan` and
//! `diagnostic_msgs/msg/DiagnosticArray`, with their `ros2msg` schema texts (the message
//! definition followed by every message it uses, each after a line of 80 `=` and
//! `MSG: package/Type`, as ROS 2 bags store them).
//!
//! The serialisation is the little-endian XCDR1 that ROS 2's middleware writes: the
//! 4-byte encapsulation header `00 01 00 00`, then the fields in order, each primitive
//! aligned to its size counted from after the header; a string is a u32 length that
//! counts its terminating NUL, the bytes and the NUL; a sequence is a u32 count and
//! its elements. Two messages need only these few rules, so they are written here
//! rather than through a serialisation framework.

use can_wire::{BridgeState, Status};
use serde_json::Value;

use super::LaserScan;

/// The schema name of the scans.
pub const LASER_SCAN: &str = "sensor_msgs/msg/LaserScan";
/// The schema name of the diagnostics.
pub const DIAGNOSTIC_ARRAY: &str = "diagnostic_msgs/msg/DiagnosticArray";

const SEPARATOR: &str =
    "================================================================================\n";

const HEADER_DEFS: &str = "MSG: std_msgs/Header\n\
builtin_interfaces/Time stamp\n\
string frame_id\n";

const TIME_DEFS: &str = "MSG: builtin_interfaces/Time\n\
int32 sec\n\
uint32 nanosec\n";

/// The `ros2msg` schema of [`LASER_SCAN`].
pub fn laser_scan_schema() -> String {
    let own = "std_msgs/Header header\n\
float32 angle_min\n\
float32 angle_max\n\
float32 angle_increment\n\
float32 time_increment\n\
float32 scan_time\n\
float32 range_min\n\
float32 range_max\n\
float32[] ranges\n\
float32[] intensities\n";
    [own, SEPARATOR, HEADER_DEFS, SEPARATOR, TIME_DEFS].concat()
}

/// The `ros2msg` schema of [`DIAGNOSTIC_ARRAY`].
pub fn diagnostic_array_schema() -> String {
    let own = "std_msgs/Header header\n\
diagnostic_msgs/DiagnosticStatus[] status\n";
    let status = "MSG: diagnostic_msgs/DiagnosticStatus\n\
byte OK=0\n\
byte WARN=1\n\
byte ERROR=2\n\
byte STALE=3\n\
byte level\n\
string name\n\
string message\n\
string hardware_id\n\
diagnostic_msgs/KeyValue[] values\n";
    let kv = "MSG: diagnostic_msgs/KeyValue\n\
string key\n\
string value\n";
    [
        own,
        SEPARATOR,
        HEADER_DEFS,
        SEPARATOR,
        TIME_DEFS,
        SEPARATOR,
        status,
        SEPARATOR,
        kv,
    ]
    .concat()
}

/// A little-endian CDR buffer.
struct Cdr(Vec<u8>);

impl Cdr {
    fn new() -> Self {
        Cdr(vec![0x00, 0x01, 0x00, 0x00])
    }

    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }

    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn i32(&mut self, v: i32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn f32(&mut self, v: f32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }

    fn len(&mut self, n: usize) {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    fn string(&mut self, s: &str) {
        self.len(s.len() + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }

    fn f32s(&mut self, v: &[f32]) {
        self.len(v.len());
        for &x in v {
            self.f32(x);
        }
    }

    /// `std_msgs/Header`: the stamp (seconds saturate at `i32::MAX`) and the frame.
    fn header(&mut self, stamp_ns: u64, frame_id: &str) {
        let sec = i32::try_from(stamp_ns / 1_000_000_000).unwrap_or(i32::MAX);
        self.i32(sec);
        self.u32((stamp_ns % 1_000_000_000) as u32);
        self.string(frame_id);
    }
}

/// A scan as a CDR `sensor_msgs/msg/LaserScan`.
pub fn laser_scan_cdr(s: &LaserScan) -> Vec<u8> {
    let mut c = Cdr::new();
    c.header(s.stamp_ns, &s.frame_id);
    for v in [
        s.angle_min,
        s.angle_max,
        s.angle_increment,
        s.time_increment,
        s.scan_time,
        s.range_min,
        s.range_max,
    ] {
        c.f32(v);
    }
    c.f32s(&s.ranges);
    c.f32s(&s.intensities);
    c.0
}

/// `diagnostic_msgs/DiagnosticStatus` levels.
const OK: u8 = 0;
const WARN: u8 = 1;
const ERROR: u8 = 2;

/// A status frame as one `diagnostic_msgs/DiagnosticStatus`.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostic {
    /// OK 0, WARN 1, ERROR 2.
    pub level: u8,
    /// `scip2can node N`.
    pub name: String,
    /// The page's name (`heartbeat`, `sensor_range` ...), with the state for heartbeats.
    pub message: String,
    /// `scip2can node N`.
    pub hardware_id: String,
    /// The page's fields as text (the fields of `decode`'s JSON).
    pub values: Vec<(String, String)>,
}

/// The diagnostic of a status frame of bridge `node`: a heartbeat in state fault is an
/// error, one recovering a warning, a bus-off bus page an error; the rest is OK.
pub fn diagnostic(node: u8, status: &Status) -> Diagnostic {
    let fields = crate::decode::json::status(status);
    let map = fields.as_object().cloned().unwrap_or_default();
    let page = map
        .get("page")
        .and_then(Value::as_str)
        .unwrap_or("status")
        .to_owned();
    let level = match *status {
        Status::Heartbeat {
            state: BridgeState::Fault,
            ..
        } => ERROR,
        Status::Heartbeat {
            state: BridgeState::Recovering,
            ..
        } => WARN,
        Status::BusCounters { error_state, .. } if u8::from(error_state) == 2 => ERROR,
        _ => OK,
    };
    let message = match *status {
        Status::Heartbeat { state, .. } => format!("{page}: {state:?}"),
        _ => page,
    };
    let values = map
        .into_iter()
        .filter(|(k, _)| k != "page")
        .map(|(k, v)| {
            let text = match v {
                Value::String(s) => s,
                other => other.to_string(),
            };
            (k, text)
        })
        .collect();
    let name = format!("scip2can node {node}");
    Diagnostic {
        level,
        hardware_id: name.clone(),
        name,
        message,
        values,
    }
}

/// One diagnostic as a CDR `diagnostic_msgs/msg/DiagnosticArray` stamped `stamp_ns`.
pub fn diagnostic_array_cdr(stamp_ns: u64, d: &Diagnostic) -> Vec<u8> {
    let mut c = Cdr::new();
    c.header(stamp_ns, "");
    c.len(1);
    c.u8(d.level);
    c.string(&d.name);
    c.string(&d.message);
    c.string(&d.hardware_id);
    c.len(d.values.len());
    for (k, v) in &d.values {
        c.string(k);
        c.string(v);
    }
    c.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes written from the CDR rules by hand (not by the code under test).
    #[test]
    fn laser_scan_golden_bytes() {
        let s = LaserScan {
            stamp_ns: 3_000_000_005,
            frame_id: "ab".into(),
            angle_min: 1.0,
            angle_max: 2.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            scan_time: 0.0,
            range_min: 0.0,
            range_max: 4.0,
            ranges: vec![1.5],
            intensities: vec![],
        };
        let mut want: Vec<u8> = vec![0, 1, 0, 0, 3, 0, 0, 0, 5, 0, 0, 0];
        // "ab": length 3 with the NUL, then one pad byte to the next float.
        want.extend([3, 0, 0, 0, b'a', b'b', 0, 0]);
        for f in [1.0f32, 2.0, 0.5, 0.0, 0.0, 0.0, 4.0] {
            want.extend(f.to_le_bytes());
        }
        want.extend([1, 0, 0, 0]);
        want.extend(1.5f32.to_le_bytes());
        want.extend([0, 0, 0, 0]);
        assert_eq!(laser_scan_cdr(&s), want);
    }

    #[test]
    fn schema_has_dependencies_in_ros2_bag_form() {
        let s = laser_scan_schema();
        assert!(s.starts_with("std_msgs/Header header\nfloat32 angle_min\n"));
        assert!(s.contains(&format!(
            "\n{}MSG: std_msgs/Header\n",
            "=".repeat(80) + "\n"
        )));
        assert!(s.ends_with("MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"));
    }
}
