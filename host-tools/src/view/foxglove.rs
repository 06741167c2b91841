//! `foxglove.LaserScan`: the message type, schema and protobuf encoding of the foxglove
//! crate, filled from a [`LaserScan`].
//!
//! Foxglove places the points at equal angles from `start_angle` to `end_angle`
//! (both inclusive), which is what [`LaserScan::angle_min`] and
//! [`LaserScan::angle_max`] are; the pose is the identity (the points are in
//! `frame_id`). Ranges and intensities are the same values as in the ROS 2 message
//! (non-finite ranges are not drawn).

use foxglove::schemas::{Pose, Quaternion, Timestamp, Vector3};
use foxglove::{Encode, Schema};

use super::LaserScan;

/// The Foxglove message of a scan.
pub fn laser_scan(s: &LaserScan) -> foxglove::schemas::LaserScan {
    let sec = u32::try_from(s.stamp_ns / 1_000_000_000).unwrap_or(u32::MAX);
    let nsec = (s.stamp_ns % 1_000_000_000) as u32;
    foxglove::schemas::LaserScan {
        timestamp: Some(Timestamp::new(sec, nsec)),
        frame_id: s.frame_id.clone(),
        pose: Some(Pose {
            position: Some(Vector3 {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            }),
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        }),
        start_angle: f64::from(s.angle_min),
        end_angle: f64::from(s.angle_max),
        ranges: s.ranges.iter().map(|&r| f64::from(r)).collect(),
        intensities: s.intensities.iter().map(|&i| f64::from(i)).collect(),
    }
}

/// The schema of `foxglove.LaserScan` (protobuf file descriptor set).
pub fn laser_scan_schema() -> Schema {
    // The foxglove crate defines a schema for each of its message types.
    foxglove::schemas::LaserScan::get_schema()
        .unwrap_or_else(|| Schema::new("foxglove.LaserScan", "protobuf", Vec::<u8>::new()))
}

/// A scan's Foxglove message, encoded (protobuf).
pub fn laser_scan_bytes(s: &LaserScan) -> Vec<u8> {
    let msg = laser_scan(s);
    let mut buf = Vec::with_capacity(msg.encoded_len().unwrap_or(0));
    // Encoding into a growable Vec cannot run out of room.
    let _ = msg.encode(&mut buf);
    buf
}
