//! Distance codes of the lossless encoding (SPEC 4.2): what each value of the distance
//! channel stands for. Unlike the fixed-width encodings, every sensor error code keeps
//! its identity.
//!
//! | code | meaning |
//! |---|---|
//! | 0..=99 | the sensor's error code of that value (SCIP: a distance below DMIN) |
//! | 100..=122 | reserved (a receiver rejects the segment) |
//! | 123 | invalid, no sensor code (set invalid by the bridge's filters) |
//! | 124 | out of range (a range too long for the unit, or an over-range mark such as 4095 of the 2-character encodings) |
//! | 125, 126, 127 | the sensor codes 65533, 65534, 65535 (Ethernet models) |
//! | 128.. | a range of `(code - 128) × 2^unit_exp` mm |

use super::MAX_VALUE;
use crate::encoding::Distance;
use crate::Error;

/// Codes at or above this are ranges.
pub const RANGE_BASE: u32 = 128;
/// Sensor error codes below this keep their value as their code.
pub const ERROR_CODES: u32 = 100;
/// Invalid without a sensor code.
pub const INVALID: u32 = 123;
/// Out of range.
pub const OUT_OF_RANGE: u32 = 124;
/// The code of sensor code 65533; 65534 and 65535 follow.
pub const HIGH_ERRORS: u32 = 125;
/// The first of the sensor's high error codes (Ethernet models: 65533..=65535).
pub const HIGH_ERROR_VALUE: u32 = 65533;

/// The code of a distance, ranges in units of `2^unit_exp` mm (rounded half up).
#[inline(always)]
pub const fn distance_code(d: Distance, unit_exp: u8) -> u32 {
    match d {
        Distance::Invalid => INVALID,
        Distance::OutOfRange => OUT_OF_RANGE,
        Distance::SensorError(v) => error_code(v),
        Distance::Mm(mm) => range_code(mm, unit_exp),
    }
}

/// Values at or above this are no sensor's (a SCIP field holds at most 24 bits): a run
/// writes one for a point that has no sensor value, which is coded [`INVALID`].
pub const NO_SENSOR_VALUE: u32 = 1 << 24;

/// The code of a sensor error value (anything the sensor sent that is no range).
#[inline(always)]
pub const fn error_code(v: u32) -> u32 {
    if v >= NO_SENSOR_VALUE {
        INVALID
    } else if v < ERROR_CODES {
        v
    } else if v >= HIGH_ERROR_VALUE && v <= HIGH_ERROR_VALUE + 2 {
        // v is HIGH_ERROR_VALUE..=HIGH_ERROR_VALUE + 2 here.
        HIGH_ERRORS.wrapping_add(v.wrapping_sub(HIGH_ERROR_VALUE))
    } else {
        OUT_OF_RANGE
    }
}

/// The code of a range of `mm` millimetres.
#[inline(always)]
pub const fn range_code(mm: u32, unit_exp: u8) -> u32 {
    let e = (unit_exp & 0xF) as u32;
    let q = mm.saturating_add((1u32 << e) >> 1) >> e;
    if q > MAX_VALUE - RANGE_BASE {
        OUT_OF_RANGE
    } else {
        RANGE_BASE.wrapping_add(q) // q <= MAX_VALUE - RANGE_BASE here
    }
}

/// Whether a code is a range.
#[inline(always)]
pub const fn is_range(code: u32) -> bool {
    code >= RANGE_BASE
}

/// The distance a code stands for; reserved codes and codes above [`MAX_VALUE`] are
/// errors.
pub const fn decode_distance(code: u32, unit_exp: u8) -> Result<Distance, Error> {
    if code > MAX_VALUE {
        return Err(Error::ReservedBits);
    }
    if code >= RANGE_BASE {
        let q = code.wrapping_sub(RANGE_BASE) as u64; // code >= RANGE_BASE here
        let mm = q << (unit_exp & 0xF);
        return Ok(if mm > u32::MAX as u64 {
            Distance::OutOfRange
        } else {
            Distance::Mm(mm as u32)
        });
    }
    match code {
        0..ERROR_CODES => Ok(Distance::SensorError(code)),
        INVALID => Ok(Distance::Invalid),
        OUT_OF_RANGE => Ok(Distance::OutOfRange),
        HIGH_ERRORS..RANGE_BASE => Ok(Distance::SensorError(
            // code is HIGH_ERRORS..RANGE_BASE here.
            HIGH_ERROR_VALUE.wrapping_add(code.wrapping_sub(HIGH_ERRORS)),
        )),
        _ => Err(Error::ReservedBits),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table of the SPEC, row by row.
    #[test]
    fn table_of_the_spec() {
        assert_eq!(distance_code(Distance::SensorError(0), 0), 0);
        assert_eq!(distance_code(Distance::SensorError(19), 0), 19);
        assert_eq!(distance_code(Distance::SensorError(99), 0), 99);
        assert_eq!(distance_code(Distance::Invalid, 0), 123);
        assert_eq!(distance_code(Distance::OutOfRange, 0), 124);
        assert_eq!(distance_code(Distance::SensorError(4095), 0), 124);
        assert_eq!(distance_code(Distance::SensorError(65533), 0), 125);
        assert_eq!(distance_code(Distance::SensorError(65534), 0), 126);
        assert_eq!(distance_code(Distance::SensorError(65535), 0), 127);
        assert_eq!(error_code(NO_SENSOR_VALUE), 123);
        assert_eq!(error_code(u32::MAX), 123);
        assert_eq!(distance_code(Distance::Mm(0), 0), 128);
        assert_eq!(distance_code(Distance::Mm(5600), 0), 5728);
        assert_eq!(distance_code(Distance::Mm(100_000), 0), 100_128);
        assert_eq!(distance_code(Distance::Mm(5601), 1), 128 + 2801); // half up
        assert_eq!(distance_code(Distance::Mm(u32::MAX), 0), 124);
        for code in 100..=122 {
            assert_eq!(decode_distance(code, 0), Err(Error::ReservedBits));
        }
        assert_eq!(decode_distance(1 << 20, 0), Err(Error::ReservedBits));
        assert_eq!(decode_distance(5728, 0), Ok(Distance::Mm(5600)));
        assert_eq!(decode_distance(128 + 2801, 1), Ok(Distance::Mm(5602)));
        assert_eq!(decode_distance(MAX_VALUE, 15), Ok(Distance::OutOfRange));
        for v in [0, 7, 99, 65533, 65534, 65535] {
            let c = distance_code(Distance::SensorError(v), 0);
            assert_eq!(decode_distance(c, 3), Ok(Distance::SensorError(v)));
        }
    }
}
