//! Session settings and their validation.

use core::fmt;

use scip::{Command, Request, ScanMode, ScanRequest};

/// What the session is asked to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SessionConfig {
    /// The stream to run: a continuous request (M*/N*); `count` 0 streams until stopped.
    pub scan: ScanRequest,
    /// Replace `scan.start`/`scan.end` by the sensor's AMIN/AMAX once PP is decoded, so
    /// one configuration streams the full range of any model.
    pub full_range: bool,
    /// Bit rate to raise the UART to with `SS` after identification (serial links only).
    pub bit_rate: Option<u32>,
    /// The UART's bit rate at power-up, restored after a reset (`RS` resets the sensor's).
    pub initial_bit_rate: u32,
    /// Time a command's answer may take, in ms.
    pub response_timeout_ms: u32,
    /// Silence in a stream that counts as lost, in ms; 0 derives it from the scan period
    /// learned from PP (8 periods × (skip + 1), plus 500 ms: see
    /// [`super::Session::silence_limit_ms`]).
    pub silence_timeout_ms: u32,
    /// First back-off before re-initialising after a failure, in ms.
    pub backoff_min_ms: u32,
    /// Longest back-off, in ms (the back-off doubles up to this).
    pub backoff_max_ms: u32,
    /// Times a command is sent again after a timeout or a damaged answer before the
    /// session recovers the sensor.
    pub max_retries: u8,
}

impl Default for SessionConfig {
    /// Full-range distance stream (AMIN..AMAX from PP; 0..=1080 until then), at the
    /// UART's power-up rate of 115200 bit/s, 1 s answer timeout, 100 ms .. 5 s back-off.
    fn default() -> Self {
        Self {
            scan: ScanRequest::distance(ScanMode::Continuous, 0, 1080),
            full_range: true,
            bit_rate: None,
            initial_bit_rate: 115_200,
            response_timeout_ms: 1000,
            silence_timeout_ms: 0,
            backoff_min_ms: 100,
            backoff_max_ms: 5000,
            max_retries: 2,
        }
    }
}

/// Why a session configuration is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SessionError {
    /// The scan request is a single-scan (G*/H*) one; the bridge streams.
    NotContinuous,
    /// The scan request would be refused by the encoder (bad steps, cluster, ...).
    BadScanRequest(scip::EncodeError),
    /// The `SS` bit rate is not one of [`scip::BIT_RATES`].
    BadBitRate,
    /// A timeout or back-off of 0 ms, or a back-off minimum above its maximum.
    BadTiming,
}

impl fmt::Display for SessionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NotContinuous => f.write_str("the scan request must be continuous (M*/N*)"),
            Self::BadScanRequest(e) => write!(f, "bad scan request: {e}"),
            Self::BadBitRate => f.write_str("bit rate not supported by SS"),
            Self::BadTiming => f.write_str("timeouts and back-off must be non-zero, min <= max"),
        }
    }
}

impl SessionConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SessionError> {
        if self.scan.mode != ScanMode::Continuous {
            return Err(SessionError::NotContinuous);
        }
        Request::new(Command::Scan(self.scan))
            .encode(&mut [0u8; scip::REQUEST_MAX])
            .map_err(SessionError::BadScanRequest)?;
        if let Some(rate) = self.bit_rate {
            if !scip::BIT_RATES.contains(&rate) {
                return Err(SessionError::BadBitRate);
            }
        }
        if self.response_timeout_ms == 0
            || self.backoff_min_ms == 0
            || self.backoff_min_ms > self.backoff_max_ms
        {
            return Err(SessionError::BadTiming);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation() {
        assert_eq!(SessionConfig::default().validate(), Ok(()));
        let mut c = SessionConfig::default();
        c.scan.mode = ScanMode::Single;
        assert_eq!(c.validate(), Err(SessionError::NotContinuous));
        let mut c = SessionConfig::default();
        c.scan.cluster = 0;
        assert_eq!(
            c.validate(),
            Err(SessionError::BadScanRequest(scip::EncodeError::BadCluster))
        );
        let c = SessionConfig {
            bit_rate: Some(9600),
            ..SessionConfig::default()
        };
        assert_eq!(c.validate(), Err(SessionError::BadBitRate));
        let c = SessionConfig {
            backoff_min_ms: 10_000,
            ..SessionConfig::default()
        };
        assert_eq!(c.validate(), Err(SessionError::BadTiming));
    }
}
