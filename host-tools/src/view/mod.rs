//! Scans as the messages ROS 2 and Foxglove users view: `sensor_msgs/msg/LaserScan`
//! (CDR, [`ros2`]), `foxglove.LaserScan` (protobuf, [`foxglove`]), status frames as
//! `diagnostic_msgs/msg/DiagnosticArray`, and the MCAP file of `decode --mcap`
//! ([`mcap`]).
//!
//! A decoded scan becomes a [`LaserScan`] (the fields both message types share) with
//! [`laser_scan`]; [`NodeInfo`] keeps what a bridge's status frames told about its
//! sensor (range limits, scan speed), which the scan header does not carry.
//!
//! **Geometry.** `angle_min` is the angle of point 0 and `angle_increment`
//! `2π · step_increment / ares` (SPEC 3.2: counter-clockwise seen from above, 0 = the
//! sensor's front, which is ROS's convention for a laser frame with x forward);
//! `angle_max` is the angle of the last point the scan lists. A scan whose header has
//! `ares` = 0 (geometry unknown) has no angles: it is not converted
//! ([`Skip::GeometryUnknown`]; `decode` still prints it as JSON).
//!
//! **Ranges** are metres (f32), invalid points as REP 117 says:
//!
//! | what the scan holds | range |
//! |---|---|
//! | a range of `d` mm | `d / 1000` |
//! | out of range (beyond what the encoding and unit express, or the sensor's over-range mark) | `+inf` |
//! | invalid (fixed-width code 0: no return or a sensor error code the encoding does not keep; a point the bridge's filters invalidated) | `NaN` |
//! | a sensor error code (lossless coding) meaning no echo / no object: URG-04LX class 0; UTM class (UTM, UXM, UST) 1 and 4; 65533 of the Ethernet models | `+inf` |
//! | a sensor error code meaning too near: UTM class 2 | `-inf` |
//! | any other sensor error code, or one of a sensor whose model is not known | `NaN` |
//! | a point that did not arrive (a lost frame) | `NaN` |
//!
//! Intensities (when the scan has the channel) are the 16-bit values of SPEC 4
//! (`4 × raw`, saturated), `NaN` for points that did not arrive; empty without the
//! channel.
//!
//! **Range limits**: `range_min`/`range_max` are the sensor's DMIN/DMAX from the
//! bridge's status page 4 once one was seen for that node, else what the scan's
//! encoding can express (one unit up to the largest range code).
//! **Timing**: `scan_time = 60 / scan_rpm` and `time_increment = scan_time ·
//! step_increment / ares` from status page 6, both 0 until one was seen.
//! **Time**: the header's timestamp (in the robot's clock with `time_master`), by
//! [`scan_stamp_ns`].
//!
//! Only scans whose points are the values sent are converted: intact and incomplete
//! ones (missing points are `NaN`); a scan with a CRC mismatch, a corrupt or an aborted
//! one is not ([`Skip::NotPublishable`]).

pub mod foxglove;
pub mod mcap;
pub mod ros2;

use can_wire::reassembly::Completeness;
use can_wire::{Distance, DistanceEncoding, ScanHeader, SensorModel, Status};

use crate::decode::DecodedScan;

/// The time of a scan in nanoseconds, received at `received_us` (the log time of the
/// frame that completed it): in the time master's clock (Unix time) when the header says
/// `time_master`, made whole from its low 32 bits of µs with the receive time
/// ([`crate::decode::json::robot_time_us`]); otherwise the header's timestamp as it is, µs
/// of the bridge's clock with `time_estimated`, ms (sensor or bridge time) without. The
/// one place where scan time is converted.
pub fn scan_stamp_ns(header: &ScanHeader, received_us: u64) -> u64 {
    let stamp = header.timestamp_ms;
    if header.time_master {
        crate::decode::json::robot_time_us(stamp, received_us).saturating_mul(1000)
    } else if header.time_estimated {
        u64::from(stamp) * 1000
    } else {
        u64::from(stamp) * 1_000_000
    }
}

/// What a bridge's status frames told about its sensor.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NodeInfo {
    /// Status page 4: model, DMIN and DMAX (mm).
    pub range: Option<(SensorModel, u16, u32)>,
    /// Status page 6: scanner speed, rpm (non-zero).
    pub scan_rpm: Option<u16>,
}

impl NodeInfo {
    /// Takes in what a status frame tells.
    pub fn update(&mut self, status: &Status) {
        match *status {
            Status::SensorRange {
                model,
                dmin_mm,
                dmax_mm,
            } if dmax_mm > 0 => self.range = Some((model, dmin_mm, dmax_mm)),
            Status::SensorTiming { scan_rpm, .. } if scan_rpm > 0 => {
                self.scan_rpm = Some(scan_rpm);
            }
            _ => {}
        }
    }

    /// The sensor's model, when page 4 named one.
    pub fn model(&self) -> Option<SensorModel> {
        match self.range {
            Some((SensorModel::Unidentified | SensorModel::Unknown(_), _, _)) | None => None,
            Some((m, _, _)) => Some(m),
        }
    }
}

/// A laser scan as ROS 2 and Foxglove describe it (the fields both share).
#[derive(Debug, Clone, PartialEq)]
pub struct LaserScan {
    /// Time of the scan, ns ([`scan_stamp_ns`]).
    pub stamp_ns: u64,
    /// Coordinate frame.
    pub frame_id: String,
    /// Angle of the first point, rad.
    pub angle_min: f32,
    /// Angle of the last point, rad.
    pub angle_max: f32,
    /// Angle between points, rad.
    pub angle_increment: f32,
    /// Time between points, s (0 when unknown).
    pub time_increment: f32,
    /// Time between scans, s (0 when unknown).
    pub scan_time: f32,
    /// Smallest range, m.
    pub range_min: f32,
    /// Largest range, m.
    pub range_max: f32,
    /// Ranges, m, REP 117 (see the module docs).
    pub ranges: Vec<f32>,
    /// Intensities, empty without the channel.
    pub intensities: Vec<f32>,
}

/// Why a scan was not converted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Skip {
    /// `ares` = 0: the points have no angles.
    GeometryUnknown,
    /// A CRC mismatch, corrupt or aborted scan.
    NotPublishable(Completeness),
}

/// Sensor error codes by class (see the module docs): the REP 117 value of `code`.
fn error_code(code: u32, model: Option<SensorModel>) -> f32 {
    match (model, code) {
        (_, 65533) => f32::INFINITY,
        (Some(SensorModel::Urg04lx), 0) => f32::INFINITY,
        (Some(SensorModel::Urg04lx), _) | (None, _) => f32::NAN,
        (Some(_), 1 | 4) => f32::INFINITY,
        (Some(_), 2) => f32::NEG_INFINITY,
        (Some(_), _) => f32::NAN,
    }
}

/// The REP 117 range (m) of a point; `None` is a point that did not arrive.
pub fn range_m(distance: Option<Distance>, model: Option<SensorModel>) -> f32 {
    match distance {
        Some(Distance::Mm(mm)) => (f64::from(mm) / 1000.0) as f32,
        Some(Distance::OutOfRange) => f32::INFINITY,
        Some(Distance::SensorError(code)) => error_code(code, model),
        Some(Distance::Invalid) | None => f32::NAN,
    }
}

/// The ranges the scan's encoding can express, m.
fn encoding_limits(header: &ScanHeader) -> (f32, f32) {
    let e = &header.encoding;
    let unit = f64::from(e.unit_mm());
    let max_code = match e.distance {
        // Codes 128 ..= 2^20 - 1 are ranges (SPEC 4.2.1).
        DistanceEncoding::Lossless => f64::from((1u32 << 20) - 1 - 128),
        // Codes 1 ..= max - 1 are ranges (SPEC 4.1).
        d => f64::from(d.max_code()) - 1.0,
    };
    let min = match e.distance {
        DistanceEncoding::Lossless => 0.0,
        _ => unit,
    };
    ((min / 1000.0) as f32, (max_code * unit / 1000.0) as f32)
}

/// A decoded scan as a [`LaserScan`] in `frame_id`, with what `info` knows about the
/// bridge's sensor.
pub fn laser_scan(scan: &DecodedScan, info: &NodeInfo, frame_id: &str) -> Result<LaserScan, Skip> {
    match scan.completeness {
        Completeness::Intact | Completeness::Incomplete { .. } => {}
        other => return Err(Skip::NotPublishable(other)),
    }
    let h = &scan.header;
    if h.ares == 0 {
        return Err(Skip::GeometryUnknown);
    }
    let last = u16::try_from(scan.points.len().saturating_sub(1)).unwrap_or(u16::MAX);
    let angle_min = h.angle_rad(0);
    let angle_max = h.angle_rad(last);
    let angle_increment =
        (std::f64::consts::TAU * f64::from(h.step_increment) / f64::from(h.ares)) as f32;
    let (scan_time, time_increment) = match info.scan_rpm {
        Some(rpm) => {
            let t = 60.0 / f64::from(rpm);
            (
                t as f32,
                (t * f64::from(h.step_increment) / f64::from(h.ares)) as f32,
            )
        }
        None => (0.0, 0.0),
    };
    let (range_min, range_max) = match info.range {
        Some((_, dmin, dmax)) => (
            (f64::from(dmin) / 1000.0) as f32,
            (f64::from(dmax) / 1000.0) as f32,
        ),
        None => encoding_limits(h),
    };
    let model = info.model();
    let ranges = scan
        .points
        .iter()
        .map(|p| range_m(p.map(|p| p.distance), model))
        .collect();
    let intensities = if h.encoding.intensity.is_present() {
        scan.points
            .iter()
            .map(|p| p.and_then(|p| p.intensity).map_or(f32::NAN, |v| v as f32))
            .collect()
    } else {
        Vec::new()
    };
    Ok(LaserScan {
        stamp_ns: scan_stamp_ns(h, scan.time_us),
        frame_id: frame_id.to_owned(),
        angle_min,
        angle_max,
        angle_increment,
        time_increment,
        scan_time,
        range_min,
        range_max,
        ranges,
        intensities,
    })
}

/// Fills `{node}` of a topic or frame template.
pub fn expand(template: &str, node: u8) -> String {
    template.replace("{node}", &node.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rep117_mapping() {
        let urg = Some(SensorModel::Urg04lx);
        let utm = Some(SensorModel::Utm30lx);
        assert_eq!(range_m(Some(Distance::Mm(1234)), None), 1.234);
        assert_eq!(range_m(Some(Distance::OutOfRange), None), f32::INFINITY);
        assert!(range_m(Some(Distance::Invalid), utm).is_nan());
        assert!(range_m(None, utm).is_nan());
        assert_eq!(range_m(Some(Distance::SensorError(0)), urg), f32::INFINITY);
        assert!(range_m(Some(Distance::SensorError(7)), urg).is_nan());
        assert_eq!(range_m(Some(Distance::SensorError(1)), utm), f32::INFINITY);
        assert_eq!(
            range_m(Some(Distance::SensorError(2)), utm),
            f32::NEG_INFINITY
        );
        assert!(range_m(Some(Distance::SensorError(3)), utm).is_nan());
        assert_eq!(range_m(Some(Distance::SensorError(4)), utm), f32::INFINITY);
        assert!(range_m(Some(Distance::SensorError(0)), None).is_nan());
        assert_eq!(
            range_m(Some(Distance::SensorError(65533)), None),
            f32::INFINITY
        );
    }

    #[test]
    fn stamps_by_time_base() {
        let mut h = ScanHeader {
            seq: 1,
            timestamp_ms: 2_475_464_640,
            point_count: 1,
            encoding: can_wire::Encoding::PLAIN_MM,
            time_synced: false,
            time_estimated: false,
            time_master: false,
            grouping: can_wire::Grouping::Single,
            step_increment: 1,
            first_step: 0,
            ares: 1024,
        };
        let received = 1_795_985_999_990_000; // Unix µs, 30 ms after the scan below
        assert_eq!(scan_stamp_ns(&h, received), 2_475_464_640_000_000);
        h.time_synced = true;
        h.time_estimated = true;
        assert_eq!(scan_stamp_ns(&h, received), 2_475_464_640_000);
        h.time_master = true;
        // 1 795 985 999 960 000 µs ≡ 2 475 464 640 (mod 2^32).
        assert_eq!(scan_stamp_ns(&h, received), 1_795_985_999_960_000_000);
    }
}
