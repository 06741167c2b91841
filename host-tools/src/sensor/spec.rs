//! The `<sensor>` argument of the clients.
//!
//! - `tcp://host:port` — an Ethernet sensor or `scip2can sim` (port 10940 if left out);
//! - `sim:key=value,...` — a simulator inside this process, keys as the `sim` flags
//!   (`sim:model=urg04lx,seed=3,scene=wall:2000,speed=10`); `sim:` alone is a UTM-30LX;
//! - anything else — a serial device path, opened at `--baud` bit/s.

use anyhow::bail;

use crate::sim::SimOptions;

/// Where the sensor is.
#[derive(Debug, Clone)]
pub enum SensorSpec {
    /// `host:port` of a TCP sensor.
    Tcp(String),
    /// A serial device and the bit rate to open it at.
    Serial {
        /// Device path.
        path: String,
        /// Bit rate.
        baud: u32,
    },
    /// An in-process simulator.
    Sim(SimOptions),
}

impl SensorSpec {
    /// Parses a spec; `baud` is used for serial devices.
    pub fn parse(text: &str, baud: u32) -> anyhow::Result<Self> {
        if let Some(rest) = text.strip_prefix("tcp://") {
            let rest = rest.trim_end_matches('/');
            if rest.is_empty() {
                bail!("tcp:// needs a host");
            }
            let addr = if rest
                .rsplit_once(':')
                .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
            {
                rest.to_owned()
            } else {
                format!("{rest}:10940")
            };
            return Ok(Self::Tcp(addr));
        }
        if let Some(rest) = text.strip_prefix("sim:") {
            return Ok(Self::Sim(SimOptions::from_spec(rest)?));
        }
        if text.is_empty() || text.contains("://") {
            bail!("unknown sensor {text:?}: use tcp://host:port, sim:..., or a serial device path");
        }
        Ok(Self::Serial {
            path: text.to_owned(),
            baud,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_form() {
        assert!(
            matches!(SensorSpec::parse("tcp://10.0.0.2:10940", 0).unwrap(), SensorSpec::Tcp(a) if a == "10.0.0.2:10940")
        );
        assert!(
            matches!(SensorSpec::parse("tcp://lidar", 0).unwrap(), SensorSpec::Tcp(a) if a == "lidar:10940")
        );
        assert!(
            matches!(SensorSpec::parse("/dev/ttyACM0", 19200).unwrap(), SensorSpec::Serial { path, baud: 19200 } if path == "/dev/ttyACM0")
        );
        match SensorSpec::parse("sim:model=urg04lx,seed=4", 0).unwrap() {
            SensorSpec::Sim(o) => assert_eq!(o.seed, 4),
            other => panic!("{other:?}"),
        }
        assert!(SensorSpec::parse("sim:bogus=1", 0).is_err());
        assert!(SensorSpec::parse("udp://x", 0).is_err());
        assert!(SensorSpec::parse("tcp://", 0).is_err());
    }
}
