//! Counters of the pipeline. All saturate at `u32::MAX` instead of wrapping.

/// What the pipeline has seen and done since it was created (or its counters cleared).
///
/// Every pushed point lands in exactly one of `points_ignored`, `sequence_errors`,
/// `points_outside_roi`, or is processed; every processed point reaches an output point
/// (possibly merged with others by angular decimation) unless its scan ends incomplete
/// while it waits in a filter window (`points_discarded`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stats {
    /// `begin_scan` calls.
    pub scans_begun: u32,
    /// Scans refused for an impossible geometry.
    pub scans_bad_geometry: u32,
    /// Scans skipped by temporal decimation.
    pub scans_skipped: u32,
    /// Scans published (their points processed).
    pub scans_published: u32,
    /// Published scans that ended complete.
    pub scans_complete: u32,
    /// Published scans that ended incomplete (declared not intact, short, out of
    /// sequence, or abandoned by the next `begin_scan`).
    pub scans_incomplete: u32,
    /// Points pushed, all of them.
    pub points_in: u32,
    /// Points pushed while no published scan was open (skipped scans cost only this).
    pub points_ignored: u32,
    /// Points whose step was not the next one of the scan's geometry (dropped, and the
    /// rest of the scan with them).
    pub sequence_errors: u32,
    /// Points outside the region of interest (dropped).
    pub points_outside_roi: u32,
    /// Points the sensor marked as error codes (made invalid).
    pub invalid_error_code: u32,
    /// Valid points outside the range window (made invalid).
    pub invalid_out_of_range: u32,
    /// Valid points below the intensity threshold (made invalid).
    pub invalid_low_intensity: u32,
    /// Valid points removed as speckles (made invalid).
    pub invalid_speckle: u32,
    /// Points that waited in a filter window when their scan ended incomplete.
    pub points_discarded: u32,
    /// Output points emitted.
    pub points_out: u32,
    /// Output points emitted without a range.
    pub points_out_invalid: u32,
}

/// `*c += 1`, saturating.
pub(crate) fn bump(c: &mut u32) {
    *c = c.saturating_add(1);
}

/// `*c += n`, saturating.
pub(crate) fn add(c: &mut u32, n: usize) {
    *c = c.saturating_add(u32::try_from(n).unwrap_or(u32::MAX));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_saturate() {
        let mut c = u32::MAX - 1;
        bump(&mut c);
        assert_eq!(c, u32::MAX);
        bump(&mut c);
        assert_eq!(c, u32::MAX);
        let mut d = 5;
        add(&mut d, 7);
        assert_eq!(d, 12);
        add(&mut d, usize::MAX);
        assert_eq!(d, u32::MAX);
    }
}
