//! Status / heartbeat frames (SPEC section 5): 8 bytes, multiplexed by the page in byte 0.

use crate::error::check_len;
use crate::header::{byte, le16, le32, put};
use crate::Error;

/// Length of a status frame.
pub const STATUS_LEN: usize = 8;
/// Largest load value (0.5 % units): 100 %.
pub const MAX_LOAD: u8 = 200;
/// The protocol version this crate implements.
pub const PROTOCOL_VERSION: u8 = 3;

mod field {
    use core::ops::Range;
    pub const PAGE: usize = 0;
    // page 0
    pub const STATE: usize = 1;
    pub const CPU_LOAD: usize = 2;
    pub const BUS_LOAD: usize = 3;
    pub const UPTIME: Range<usize> = 4..8;
    // pages 1, 2, 5, 6: u16 words
    pub const W1: Range<usize> = 1..3;
    pub const W2: Range<usize> = 3..5;
    pub const W3: Range<usize> = 5..7;
    pub const LAST: usize = 7;
    // page 3
    pub const PROTOCOL: usize = 1;
    pub const MAJOR: usize = 2;
    pub const MINOR: usize = 3;
    pub const PATCH: usize = 4;
    pub const BUILD: Range<usize> = 5..8;
    // page 4
    pub const MODEL: usize = 1;
    pub const DMIN: Range<usize> = 2..4;
    pub const DMAX: Range<usize> = 4..7;
}

macro_rules! code_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $var:ident = $val:expr,)* }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub enum $name {
            $($(#[$vm])* $var,)*
            /// A code this version does not know.
            Unknown(u8),
        }
        impl From<u8> for $name {
            fn from(v: u8) -> Self {
                match v { $($val => $name::$var,)* other => $name::Unknown(other) }
            }
        }
        impl From<$name> for u8 {
            fn from(v: $name) -> u8 {
                match v { $($name::$var => $val,)* $name::Unknown(other) => other }
            }
        }
    };
}

code_enum! {
    /// The bridge's state.
    BridgeState {
        /// Starting up.
        Booting = 0,
        /// Looking for the sensor.
        Detecting = 1,
        /// Configuring the sensor.
        Configuring = 2,
        /// Publishing scans.
        Streaming = 3,
        /// Sensor ready, not streaming.
        Idle = 4,
        /// Recovering the sensor after an error.
        Recovering = 5,
        /// Gave up; needs attention.
        Fault = 6,
    }
}

code_enum! {
    /// The bridge's CAN error state.
    BusState {
        /// Error active.
        ErrorActive = 0,
        /// Error passive.
        ErrorPassive = 1,
        /// Bus off.
        BusOff = 2,
    }
}

code_enum! {
    /// The sensor model.
    SensorModel {
        /// Not identified.
        Unidentified = 0,
        /// URG-04LX (-UG01).
        Urg04lx = 1,
        /// UTM-30LX (-EW).
        Utm30lx = 2,
        /// UXM-30LX-E.
        Uxm30lxE = 3,
        /// UST-10LX.
        Ust10lx = 4,
        /// UST-20LX.
        Ust20lx = 5,
    }
}

/// One status frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// Page 0.
    Heartbeat {
        /// State.
        state: BridgeState,
        /// CPU load, 0.5 % units (0..=200).
        cpu_load: u8,
        /// CAN bus load, 0.5 % units (0..=200).
        bus_load: u8,
        /// Seconds since boot.
        uptime_s: u32,
    },
    /// Page 1 (wrapping counters).
    SensorCounters {
        /// Sensor lines whose sum failed.
        sum_errors: u16,
        /// Times the SCIP decoder resynchronised.
        resyncs: u16,
        /// Whole scans dropped (budget, queue, errors).
        dropped_scans: u16,
        /// Sensor recoveries (QT/RS/re-init).
        recoveries: u8,
    },
    /// Page 2 (wrapping counters).
    BusCounters {
        /// CAN bus errors.
        bus_errors: u16,
        /// Bus-off events.
        bus_off_events: u16,
        /// Frames dropped from a full transmit queue.
        tx_overflows: u16,
        /// Current CAN error state.
        error_state: BusState,
    },
    /// Page 3.
    Firmware {
        /// Wire protocol version.
        protocol: u8,
        /// Firmware major version.
        major: u8,
        /// Firmware minor version.
        minor: u8,
        /// Firmware patch version.
        patch: u8,
        /// Build id, 24 bits.
        build: u32,
    },
    /// Page 4.
    SensorRange {
        /// Model.
        model: SensorModel,
        /// Smallest valid range, mm.
        dmin_mm: u16,
        /// Largest range, mm (24 bits).
        dmax_mm: u32,
    },
    /// Page 5.
    SensorSteps {
        /// Steps per revolution.
        ares: u16,
        /// First measurable step.
        amin: u16,
        /// Last measurable step.
        amax: u16,
    },
    /// Page 6.
    SensorTiming {
        /// Front step.
        afrt: u16,
        /// Scanner speed, rpm.
        scan_rpm: u16,
    },
    /// Page 7: the time sync (SPEC 9), sent after each FOLLOW-UP.
    TimeSync {
        /// The bridge follows a time master (a mapping holds).
        synced: bool,
        /// Mean prediction error of the accepted samples, µs (saturating).
        error_us: u16,
        /// The FOLLOW-UP's reception time in the master's clock, µs modulo 2^32 (0 when
        /// not synced).
        master_time: u32,
    },
}

fn le24(data: &[u8], r: core::ops::Range<usize>) -> u32 {
    match data.get(r) {
        Some([a, b, c]) => u32::from_le_bytes([*a, *b, *c, 0]),
        _ => 0,
    }
}

fn zero(data: &[u8], r: core::ops::Range<usize>) -> Result<(), Error> {
    if data.get(r).is_some_and(|s| s.iter().all(|b| *b == 0)) {
        Ok(())
    } else {
        Err(Error::ReservedBits)
    }
}

fn load(data: &[u8], at: usize) -> Result<u8, Error> {
    let v = byte(data, at);
    if v > MAX_LOAD {
        return Err(Error::OutOfRange { offset: at as u8 });
    }
    Ok(v)
}

impl Status {
    /// Parse and validate status bytes.
    pub fn parse(data: &[u8]) -> Result<Status, Error> {
        check_len(data, STATUS_LEN)?;
        let w1 = le16(data, field::W1);
        let w2 = le16(data, field::W2);
        let w3 = le16(data, field::W3);
        Ok(match byte(data, field::PAGE) {
            0 => Status::Heartbeat {
                state: byte(data, field::STATE).into(),
                cpu_load: load(data, field::CPU_LOAD)?,
                bus_load: load(data, field::BUS_LOAD)?,
                uptime_s: le32(data, field::UPTIME),
            },
            1 => Status::SensorCounters {
                sum_errors: w1,
                resyncs: w2,
                dropped_scans: w3,
                recoveries: byte(data, field::LAST),
            },
            2 => Status::BusCounters {
                bus_errors: w1,
                bus_off_events: w2,
                tx_overflows: w3,
                error_state: byte(data, field::LAST).into(),
            },
            3 => Status::Firmware {
                protocol: byte(data, field::PROTOCOL),
                major: byte(data, field::MAJOR),
                minor: byte(data, field::MINOR),
                patch: byte(data, field::PATCH),
                build: le24(data, field::BUILD),
            },
            4 => {
                zero(data, field::LAST..STATUS_LEN)?;
                Status::SensorRange {
                    model: byte(data, field::MODEL).into(),
                    dmin_mm: le16(data, field::DMIN),
                    dmax_mm: le24(data, field::DMAX),
                }
            }
            5 => {
                zero(data, field::LAST..STATUS_LEN)?;
                Status::SensorSteps {
                    ares: w1,
                    amin: w2,
                    amax: w3,
                }
            }
            6 => {
                zero(data, field::W3.start..STATUS_LEN)?;
                Status::SensorTiming {
                    afrt: w1,
                    scan_rpm: w2,
                }
            }
            7 => Status::TimeSync {
                synced: match byte(data, field::STATE) {
                    0 => false,
                    1 => true,
                    _ => {
                        return Err(Error::OutOfRange {
                            offset: field::STATE as u8,
                        })
                    }
                },
                error_us: le16(data, 2..4),
                master_time: le32(data, field::UPTIME),
            },
            page => return Err(Error::UnknownPage(page)),
        })
    }

    /// The page number.
    pub fn page(&self) -> u8 {
        match self {
            Status::Heartbeat { .. } => 0,
            Status::SensorCounters { .. } => 1,
            Status::BusCounters { .. } => 2,
            Status::Firmware { .. } => 3,
            Status::SensorRange { .. } => 4,
            Status::SensorSteps { .. } => 5,
            Status::SensorTiming { .. } => 6,
            Status::TimeSync { .. } => 7,
        }
    }

    /// The frame bytes (validates loads ≤ 200 and 24-bit fields).
    pub fn emit(&self) -> Result<[u8; STATUS_LEN], Error> {
        let mut b = [0u8; STATUS_LEN];
        b[field::PAGE] = self.page();
        let words = |b: &mut [u8; STATUS_LEN], w1: u16, w2: u16, w3: u16| {
            put(b, field::W1, &w1.to_le_bytes());
            put(b, field::W2, &w2.to_le_bytes());
            put(b, field::W3, &w3.to_le_bytes());
        };
        match *self {
            Status::Heartbeat {
                state,
                cpu_load,
                bus_load,
                uptime_s,
            } => {
                if cpu_load > MAX_LOAD {
                    return Err(Error::OutOfRange {
                        offset: field::CPU_LOAD as u8,
                    });
                }
                if bus_load > MAX_LOAD {
                    return Err(Error::OutOfRange {
                        offset: field::BUS_LOAD as u8,
                    });
                }
                b[field::STATE] = state.into();
                b[field::CPU_LOAD] = cpu_load;
                b[field::BUS_LOAD] = bus_load;
                put(&mut b, field::UPTIME, &uptime_s.to_le_bytes());
            }
            Status::SensorCounters {
                sum_errors,
                resyncs,
                dropped_scans,
                recoveries,
            } => {
                words(&mut b, sum_errors, resyncs, dropped_scans);
                b[field::LAST] = recoveries;
            }
            Status::BusCounters {
                bus_errors,
                bus_off_events,
                tx_overflows,
                error_state,
            } => {
                words(&mut b, bus_errors, bus_off_events, tx_overflows);
                b[field::LAST] = error_state.into();
            }
            Status::Firmware {
                protocol,
                major,
                minor,
                patch,
                build,
            } => {
                if build > 0xFF_FFFF {
                    return Err(Error::OutOfRange {
                        offset: field::BUILD.start as u8,
                    });
                }
                b[field::PROTOCOL] = protocol;
                b[field::MAJOR] = major;
                b[field::MINOR] = minor;
                b[field::PATCH] = patch;
                put(&mut b, field::BUILD, &build.to_le_bytes()[..3]);
            }
            Status::SensorRange {
                model,
                dmin_mm,
                dmax_mm,
            } => {
                if dmax_mm > 0xFF_FFFF {
                    return Err(Error::OutOfRange {
                        offset: field::DMAX.start as u8,
                    });
                }
                b[field::MODEL] = model.into();
                put(&mut b, field::DMIN, &dmin_mm.to_le_bytes());
                put(&mut b, field::DMAX, &dmax_mm.to_le_bytes()[..3]);
            }
            Status::SensorSteps { ares, amin, amax } => words(&mut b, ares, amin, amax),
            Status::SensorTiming { afrt, scan_rpm } => {
                put(&mut b, field::W1, &afrt.to_le_bytes());
                put(&mut b, field::W2, &scan_rpm.to_le_bytes());
            }
            Status::TimeSync {
                synced,
                error_us,
                master_time,
            } => {
                b[field::STATE] = u8::from(synced);
                put(&mut b, 2..4, &error_us.to_le_bytes());
                put(&mut b, field::UPTIME, &master_time.to_le_bytes());
            }
        }
        Ok(b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn golden() -> Vec<(Status, [u8; 8])> {
        vec![
            (
                Status::Heartbeat {
                    state: BridgeState::Streaming,
                    cpu_load: 90,
                    bus_load: 47,
                    uptime_s: 0x0001_0203,
                },
                [0, 3, 90, 47, 0x03, 0x02, 0x01, 0x00],
            ),
            (
                Status::SensorCounters {
                    sum_errors: 0x0102,
                    resyncs: 3,
                    dropped_scans: 0xFFFF,
                    recoveries: 9,
                },
                [1, 0x02, 0x01, 3, 0, 0xFF, 0xFF, 9],
            ),
            (
                Status::BusCounters {
                    bus_errors: 5,
                    bus_off_events: 1,
                    tx_overflows: 0x1234,
                    error_state: BusState::ErrorPassive,
                },
                [2, 5, 0, 1, 0, 0x34, 0x12, 1],
            ),
            (
                Status::Firmware {
                    protocol: 1,
                    major: 0,
                    minor: 3,
                    patch: 7,
                    build: 0x0033_7830,
                },
                [3, 1, 0, 3, 7, 0x30, 0x78, 0x33],
            ),
            (
                Status::SensorRange {
                    model: SensorModel::Utm30lx,
                    dmin_mm: 23,
                    dmax_mm: 60000,
                },
                [4, 2, 23, 0, 0x60, 0xEA, 0x00, 0],
            ),
            (
                Status::SensorSteps {
                    ares: 1440,
                    amin: 0,
                    amax: 1080,
                },
                [5, 0xA0, 0x05, 0, 0, 0x38, 0x04, 0],
            ),
            (
                Status::SensorTiming {
                    afrt: 540,
                    scan_rpm: 2400,
                },
                [6, 0x1C, 0x02, 0x60, 0x09, 0, 0, 0],
            ),
            (
                // SPEC 9 / 5 page 7: synced, 300 µs, master time 0xDEAD_BEEF.
                Status::TimeSync {
                    synced: true,
                    error_us: 300,
                    master_time: 0xDEAD_BEEF,
                },
                [7, 1, 0x2C, 0x01, 0xEF, 0xBE, 0xAD, 0xDE],
            ),
        ]
    }

    #[test]
    fn golden_round_trip() {
        for (s, bytes) in golden() {
            assert_eq!(s.emit(), Ok(bytes), "{s:?}");
            assert_eq!(Status::parse(&bytes), Ok(s), "{s:?}");
        }
    }

    #[test]
    fn every_bad_length() {
        for (_, bytes) in golden() {
            let mut long = [0u8; 65];
            long[..8].copy_from_slice(&bytes);
            for len in (0..=64).filter(|l| *l != 8) {
                assert_eq!(
                    Status::parse(&long[..len]),
                    Err(Error::BadLength {
                        expected: 8,
                        actual: len as u8
                    })
                );
            }
        }
    }

    #[test]
    fn rejects() {
        assert_eq!(
            Status::parse(&[8, 0, 0, 0, 0, 0, 0, 0]),
            Err(Error::UnknownPage(8))
        );
        assert_eq!(
            Status::parse(&[7, 2, 0, 0, 0, 0, 0, 0]),
            Err(Error::OutOfRange { offset: 1 })
        );
        assert_eq!(
            Status::parse(&[0, 3, 201, 0, 0, 0, 0, 0]),
            Err(Error::OutOfRange { offset: 2 })
        );
        assert_eq!(
            Status::parse(&[0, 3, 0, 255, 0, 0, 0, 0]),
            Err(Error::OutOfRange { offset: 3 })
        );
        assert_eq!(
            Status::parse(&[4, 2, 23, 0, 0, 0, 0, 1]),
            Err(Error::ReservedBits)
        );
        assert_eq!(
            Status::parse(&[5, 2, 23, 0, 0, 0, 0, 1]),
            Err(Error::ReservedBits)
        );
        assert_eq!(
            Status::parse(&[6, 2, 23, 0, 0, 1, 0, 0]),
            Err(Error::ReservedBits)
        );
        let hb = Status::Heartbeat {
            state: BridgeState::Unknown(77),
            cpu_load: 201,
            bus_load: 0,
            uptime_s: 0,
        };
        assert_eq!(hb.emit(), Err(Error::OutOfRange { offset: 2 }));
        let fw = Status::Firmware {
            protocol: 1,
            major: 0,
            minor: 0,
            patch: 0,
            build: 0x100_0000,
        };
        assert_eq!(fw.emit(), Err(Error::OutOfRange { offset: 5 }));
        // Unknown states survive a round trip.
        let hb = Status::parse(&[0, 77, 0, 0, 0, 0, 0, 0]).unwrap();
        assert!(matches!(
            hb,
            Status::Heartbeat {
                state: BridgeState::Unknown(77),
                ..
            }
        ));
    }
}
