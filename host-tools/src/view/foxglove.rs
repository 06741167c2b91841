//! A reassembled scan as a `foxglove.LaserScan` message.
//!
//! Ranges in metres at equally spaced angles from `start_angle` to `end_angle` (the
//! sensor's front is 0 rad, counter-clockwise, x forward), one per point the scan lists.
//! A point without a range (invalid, a sensor error code, or not received) is NaN; a
//! range beyond what the encoding expresses is +∞ (as `sensor_msgs/LaserScan` has it).
//! Intensities are given when the scan carries them (NaN where a point is missing).
//! With the geometry unknown (`ares` 0) both angles are NaN.

use can_wire::Distance;
use foxglove::schemas::{LaserScan, Timestamp};

use crate::decode::DecodedScan;

/// The range of a point, metres.
fn range_m(point: Option<can_wire::reassembly::Point>) -> f64 {
    match point.map(|p| p.distance) {
        Some(Distance::Mm(mm)) => f64::from(mm) / 1000.0,
        Some(Distance::OutOfRange) => f64::INFINITY,
        Some(Distance::Invalid | Distance::SensorError(_)) | None => f64::NAN,
    }
}

/// `scan` as a `foxglove.LaserScan` in `frame_id`, stamped `timestamp`.
pub fn laser_scan(scan: &DecodedScan, frame_id: &str, timestamp: Timestamp) -> LaserScan {
    let h = &scan.header;
    let n = scan.points.len();
    let last = u16::try_from(n.saturating_sub(1)).unwrap_or(u16::MAX);
    let intensities = if h.encoding.intensity.is_present() {
        scan.points
            .iter()
            .map(|p| p.and_then(|p| p.intensity).map_or(f64::NAN, f64::from))
            .collect()
    } else {
        Vec::new()
    };
    LaserScan {
        timestamp: Some(timestamp),
        frame_id: frame_id.to_owned(),
        pose: None,
        start_angle: f64::from(h.angle_rad(0)),
        end_angle: f64::from(h.angle_rad(last)),
        ranges: scan.points.iter().map(|&p| range_m(p)).collect(),
        intensities,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use can_wire::reassembly::{Completeness, Point};
    use can_wire::{DistanceEncoding, Encoding, Grouping, IntensityEncoding, ScanHeader};

    #[test]
    fn ranges_angles_and_intensities() {
        // 4 points, 2 steps apart from step -4 of 16 (a quarter turn right of the
        // front), D16 with I16: angles -π/2 .. -π/2 + 3·(2·2π/16) = π/4.
        let p = |distance, intensity| {
            Some(Point {
                distance,
                intensity: Some(intensity),
            })
        };
        let scan = DecodedScan {
            node: 3,
            time_us: 0,
            header: ScanHeader {
                seq: 1,
                timestamp_ms: 0,
                point_count: 4,
                encoding: Encoding {
                    distance: DistanceEncoding::D16,
                    intensity: IntensityEncoding::I16,
                    unit_exp: 0,
                },
                time_synced: false,
                grouping: Grouping::Single,
                step_increment: 2,
                first_step: -4,
                ares: 16,
            },
            completeness: Completeness::Intact,
            flags: None,
            points: vec![
                p(Distance::Mm(1500), 7),
                p(Distance::OutOfRange, 8),
                p(Distance::Invalid, 9),
                None,
            ],
        };
        let m = laser_scan(&scan, "laser", Timestamp::new(5, 6));
        assert_eq!(m.frame_id, "laser");
        assert_eq!(m.timestamp, Some(Timestamp::new(5, 6)));
        assert!((m.start_angle + std::f64::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((m.end_angle - std::f64::consts::FRAC_PI_4).abs() < 1e-6);
        assert_eq!(m.ranges.len(), 4);
        assert_eq!(m.ranges[0], 1.5);
        assert_eq!(m.ranges[1], f64::INFINITY);
        assert!(m.ranges[2].is_nan() && m.ranges[3].is_nan());
        assert_eq!(&m.intensities[..3], [7.0, 8.0, 9.0]);
        assert!(m.intensities[3].is_nan());
    }
}
