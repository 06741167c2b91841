//! Response status codes: two opaque chars, with meanings given by a table.

use core::fmt;

/// The status of a response.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// A SCIP 2.x status: two chars (a valid sum char followed them).
    Scip2([u8; 2]),
    /// A lone SCIP 1.1 status char without a sum: the sensor speaks SCIP 1.1 and needs
    /// `SCIP2.0` to switch.
    Scip11(u8),
}

/// What a status means, for people and for the session state machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StatusKind {
    /// `00`: command accepted.
    Ok,
    /// `99`: a frame of a continuous stream.
    StreamFrame,
    /// `0M` (SCIP 2.2): a stream frame measured while the sensor is unstable.
    Unstable,
    /// Already in the requested state (`02` to `BM`, `03` to `SS`/`CR`/`TM2`, ...).
    AlreadyDone,
    /// A parameter was refused (`01`..`07`, `0A`..`0L`, `04` to `SS`/`CR`...).
    Refused,
    /// `10`: laser is off (G*), or denied (SCIP 2.2).
    LaserOff,
    /// `21`..`49`: measurement stopped to check an error.
    Stopped,
    /// `50`..`97`: hardware fault.
    HardwareFault,
    /// `98`: resumed after a fault.
    Resumed,
    /// A SCIP 1.1 status char.
    Scip11,
    /// Anything else.
    Other,
}

impl Status {
    /// `00`.
    pub const OK: Status = Status::Scip2(*b"00");
    /// `99`.
    pub const STREAM: Status = Status::Scip2(*b"99");

    /// The raw chars (one for SCIP 1.1).
    pub fn as_bytes(&self) -> &[u8] {
        match self {
            Status::Scip2(b) => b,
            Status::Scip11(b) => core::slice::from_ref(b),
        }
    }

    /// The status as text (`"00"`, `"99"`, `"0E"`, or one char for SCIP 1.1).
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(self.as_bytes()).unwrap_or("??")
    }

    /// True for statuses after which measurement data follows: `00`, `99`, `0M`.
    pub fn carries_data(&self) -> bool {
        matches!(
            self,
            Status::Scip2([b'0', b'0'] | [b'9', b'9'] | [b'0', b'M'])
        )
    }

    /// The meaning of the status for a command of code `command` (two letters, e.g. `b"BM"`).
    pub fn kind(&self, command: &[u8]) -> StatusKind {
        let code = match self {
            Status::Scip11(_) => return StatusKind::Scip11,
            Status::Scip2(code) => code,
        };
        match code {
            b"00" => StatusKind::Ok,
            b"99" => StatusKind::StreamFrame,
            b"0M" => StatusKind::Unstable,
            b"98" => StatusKind::Resumed,
            b"10" => StatusKind::LaserOff,
            b"02" if command == b"BM" || command == b"TM" => StatusKind::AlreadyDone,
            b"03" if matches!(command, b"SS" | b"CR" | b"TM") => StatusKind::AlreadyDone,
            [b'0', _] => StatusKind::Refused,
            // Two digits: at most 99, never wraps.
            [d1 @ b'2'..=b'9', d2 @ b'0'..=b'9'] => match d1
                .wrapping_sub(b'0')
                .wrapping_mul(10)
                .wrapping_add(d2.wrapping_sub(b'0'))
            {
                21..=49 => StatusKind::Stopped,
                50..=97 => StatusKind::HardwareFault,
                _ => StatusKind::Other,
            },
            _ => StatusKind::Other,
        }
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds() {
        assert_eq!(Status::OK.kind(b"VV"), StatusKind::Ok);
        assert_eq!(Status::STREAM.kind(b"MD"), StatusKind::StreamFrame);
        assert_eq!(Status::Scip2(*b"02").kind(b"BM"), StatusKind::AlreadyDone);
        assert_eq!(Status::Scip2(*b"03").kind(b"CR"), StatusKind::AlreadyDone);
        assert_eq!(Status::Scip2(*b"04").kind(b"CR"), StatusKind::Refused);
        assert_eq!(Status::Scip2(*b"0E").kind(b"XX"), StatusKind::Refused);
        assert_eq!(Status::Scip2(*b"10").kind(b"GD"), StatusKind::LaserOff);
        assert_eq!(Status::Scip2(*b"21").kind(b"MD"), StatusKind::Stopped);
        assert_eq!(Status::Scip2(*b"50").kind(b"MD"), StatusKind::HardwareFault);
        assert_eq!(Status::Scip2(*b"97").kind(b"MD"), StatusKind::HardwareFault);
        assert_eq!(Status::Scip2(*b"98").kind(b"MD"), StatusKind::Resumed);
        assert_eq!(Status::Scip2(*b"0M").kind(b"MD"), StatusKind::Unstable);
        assert_eq!(Status::Scip11(b'E').kind(b"VV"), StatusKind::Scip11);
        assert_eq!(Status::Scip11(b'E').as_str(), "E");
        assert!(Status::Scip2(*b"0M").carries_data());
        assert!(!Status::Scip2(*b"02").carries_data());
    }
}
