//! What goes into the pipeline and what comes out of it.

/// One value of a scan as the sensor gave it, already classified upstream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RawPoint {
    /// Sensor step of the value (the first step of its cluster).
    pub step: u16,
    /// Distance in mm, or the sensor's error code when `valid` is false.
    pub distance: u32,
    /// Intensity, when the scan carries intensities.
    pub intensity: Option<u32>,
    /// False when `distance` is an error code (below DMIN, over-range marker, ...).
    pub valid: bool,
}

/// One output point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Point {
    /// Sensor step of the point: its own step, or the first step of the group it stands
    /// for after angular decimation.
    pub step: u16,
    /// Range in mm; `None` for an invalid point. An error code is never a range.
    pub range_mm: Option<u32>,
    /// Intensity, when the scan carries intensities. Invalid points keep the intensity
    /// they were measured with (see the decimation modes for groups).
    pub intensity: Option<u32>,
}

impl Point {
    /// Whether the point has a range.
    pub fn is_valid(&self) -> bool {
        self.range_mm.is_some()
    }
}

/// Geometry and identity of one scan, given when it begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScanInfo {
    /// Scan sequence number (assigned by the caller; the pipeline only passes it on).
    pub seq: u32,
    /// Sensor timestamp of the scan, ms (used by rate-limited temporal decimation).
    pub timestamp_ms: u32,
    /// First step requested.
    pub first_step: u16,
    /// Last step requested.
    pub last_step: u16,
    /// Steps merged into one value by the sensor; 0 counts as 1, as on the sensors.
    pub cluster: u16,
}

impl ScanInfo {
    /// The cluster size in force (at least 1).
    pub fn cluster_size(&self) -> u16 {
        self.cluster.max(1)
    }

    /// Number of values the sensor sends: `ceil((last - first + 1) / cluster)`.
    /// `None` when `first_step > last_step`.
    pub fn point_count(&self) -> Option<usize> {
        let span = self.last_step.checked_sub(self.first_step)?;
        let count = u32::from(span.checked_div(self.cluster_size())?).saturating_add(1);
        usize::try_from(count).ok()
    }

    /// Step of the last value the sensor sends (`first + (count - 1) * cluster`).
    /// `None` when `first_step > last_step`.
    pub fn last_point_step(&self) -> Option<u16> {
        let span = self.last_step.checked_sub(self.first_step)?;
        let cluster = self.cluster_size();
        let whole = span.checked_div(cluster)?.checked_mul(cluster)?;
        self.first_step.checked_add(whole)
    }
}

/// Receives the pipeline's output points, in step order.
///
/// Any `FnMut(Point)` closure is a sink. A sink cannot refuse a point: size its queue for
/// the count `begin_scan` announces, or drop and count on its own side.
pub trait PointSink {
    /// Takes one output point.
    fn point(&mut self, p: Point);
}

impl<F: FnMut(Point)> PointSink for F {
    fn point(&mut self, p: Point) {
        self(p)
    }
}

/// The decision taken when a scan begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScanStart {
    /// The scan is published; an intact scan gives exactly `points` output points.
    Publish {
        /// Output points of the scan if it arrives intact.
        points: usize,
    },
    /// Temporal decimation skips this scan: its points are ignored at almost no cost and
    /// nothing is emitted for it.
    Skip,
    /// The geometry is impossible (`first_step > last_step`): the scan is ignored.
    BadGeometry,
}

/// How a scan ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScanEnd {
    /// Every announced point arrived in sequence and the caller called the scan intact:
    /// `points` (= the announced count) were emitted.
    Complete {
        /// Points emitted for the scan.
        points: usize,
    },
    /// The scan was cut short, out of sequence, or declared not intact. The points already
    /// emitted stay valid (each was fully determined by points that did arrive); the ones
    /// still waiting in the filter windows were dropped.
    Incomplete {
        /// Points emitted for the scan (fewer than announced, or all of them if only the
        /// end was bad).
        points: usize,
        /// Input points whose output was still pending and was dropped.
        discarded: usize,
    },
    /// No published scan was open (it was skipped, had a bad geometry, or never began).
    NotPublished,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(first: u16, last: u16, cluster: u16) -> ScanInfo {
        ScanInfo {
            seq: 0,
            timestamp_ms: 0,
            first_step: first,
            last_step: last,
            cluster,
        }
    }

    #[test]
    fn point_count_follows_the_scip_formula() {
        // ceil((725 - 44 + 1) / 1) = 682
        assert_eq!(scan(44, 725, 1).point_count(), Some(682));
        assert_eq!(scan(44, 725, 1).last_point_step(), Some(725));
        // ceil(11 / 3) = 4: steps 0, 3, 6, 9
        assert_eq!(scan(0, 10, 3).point_count(), Some(4));
        assert_eq!(scan(0, 10, 3).last_point_step(), Some(9));
        // cluster 0 behaves as 1
        assert_eq!(scan(0, 10, 0).point_count(), Some(11));
        assert_eq!(scan(0, 10, 0).last_point_step(), Some(10));
        assert_eq!(scan(7, 7, 99).point_count(), Some(1));
        assert_eq!(scan(7, 7, 99).last_point_step(), Some(7));
        assert_eq!(scan(0, u16::MAX, 1).point_count(), Some(65536));
        assert_eq!(scan(0, u16::MAX, 2).last_point_step(), Some(65534));
        assert_eq!(scan(8, 7, 1).point_count(), None);
        assert_eq!(scan(8, 7, 1).last_point_step(), None);
    }

    #[test]
    fn closures_are_sinks() {
        let mut got = 0u32;
        let mut sink = |p: Point| got += p.range_mm.unwrap_or(0);
        sink.point(Point {
            step: 1,
            range_mm: Some(5),
            intensity: None,
        });
        sink.point(Point {
            step: 2,
            range_mm: None,
            intensity: None,
        });
        assert_eq!(got, 5);
    }
}
