//! Fault injection on the frames of a measurement stream, each fault logged.
//!
//! Faults hit measurement responses (M*/N* frames and G*/H* answers) only, at most one
//! byte fault per response, so that what a receiver must see is exact:
//!
//! - **bit flip**: one bit of one char of the timestamp or a data line (its sum char
//!   included). Bits 0–5 always change the line's sum (the sum is the byte total
//!   mod 64); bits 6 and 7 leave the sum alone but always make a value char invalid
//!   (outside `0x30..=0x6F`), so every flip is caught. Flips that would make a line end
//!   (`LF`, `CR`) or a multi-echo `&` are not drawn.
//! - **dropped byte** / **inserted byte**: in a data line; drawn so that the line's sum
//!   fails (dropping or inserting a byte ≡ 0 mod 64 would keep it).
//!
//! Each such fault is logged with the decoder error it must cause (`bad_sum` or
//! `bad_char`): exactly one error per damaged response. Besides these:
//! - **stall**: the response and everything after it are held back for a while;
//! - **hardware fault**: a frame carries a status `50`..`97` and no data instead of a
//!   scan; the stream goes on;
//! - **reboot**: after a given number of frames the sensor stops in the middle of a
//!   frame and boots again (URG-04LX comes back in SCIP 1.1, the clock restarts at 0).
//!
//! Rates are per response: the chance that one response gets that fault.
//!
//! **Line noise** ([`LineNoise`]) is the other model, and the realistic one: errors hit
//! every byte the sensor sends (echoes, statuses, payload, line ends) at given rates per
//! byte, as a noisy serial line does — bit flips, dropped bytes, inserted bytes and
//! bursts of garbled bytes — whether or not any check of the receiver can catch them.
//! Nothing is filtered and nothing is logged per event (only counted, see
//! [`LineNoiseStats`]): what the receiver makes of the damage is judged against the
//! sensor's ground truth ([`crate::session::ScanTruth`]).

use scip::checksum;

/// Which faults, how often.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FaultConfig {
    /// Chance per response of one flipped bit.
    pub flip: f64,
    /// Chance per response of one dropped byte.
    pub drop: f64,
    /// Chance per response of one inserted byte.
    pub insert: f64,
    /// Chance per response of a stall.
    pub stall: f64,
    /// Length of a stall, ms of sensor time.
    pub stall_ms: u64,
    /// Chance per stream frame of a hardware-fault status instead of a scan.
    pub hardware: f64,
    /// Reboot in the middle of this stream frame (0-based count of frames since boot).
    pub reboot_at_frame: Option<u64>,
    /// Seed of the fault draws (independent of the scene's noise).
    pub seed: u64,
    /// Line noise on every byte sent.
    pub line: LineNoise,
}

/// Errors of a noisy line, each a chance per byte sent.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LineNoise {
    /// One bit of the byte flipped.
    pub flip: f64,
    /// The byte lost.
    pub drop: f64,
    /// A random byte inserted before it.
    pub insert: f64,
    /// A burst starts at the byte: 2..=`burst_len` bytes each replaced by another,
    /// random byte.
    pub burst: f64,
    /// The longest burst, bytes (at least 2).
    pub burst_len: u8,
}

impl LineNoise {
    /// Every kind at `ber / 4` per byte: `ber` is the chance that a byte starts an error
    /// event. Bursts up to 8 bytes.
    pub fn uniform(ber: f64) -> Self {
        let r = ber / 4.0;
        Self {
            flip: r,
            drop: r,
            insert: r,
            burst: r,
            burst_len: 8,
        }
    }

    /// The chance per byte of any event.
    pub fn rate(&self) -> f64 {
        self.flip.max(0.0) + self.drop.max(0.0) + self.insert.max(0.0) + self.burst.max(0.0)
    }
}

/// What line noise did so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LineNoiseStats {
    /// Bytes that went through the line.
    pub bytes: u64,
    /// Bits flipped (one per event).
    pub flips: u64,
    /// Bytes dropped.
    pub drops: u64,
    /// Bytes inserted.
    pub inserts: u64,
    /// Bursts.
    pub bursts: u64,
}

impl FaultConfig {
    /// True when no fault can happen.
    pub fn is_none(&self) -> bool {
        self.flip <= 0.0
            && self.drop <= 0.0
            && self.insert <= 0.0
            && self.stall <= 0.0
            && self.hardware <= 0.0
            && self.reboot_at_frame.is_none()
            && self.line.rate() <= 0.0
    }
}

/// What was done.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// Bit `bit` of the byte at `column` of response line `line` was flipped.
    BitFlip {
        /// Line in the response (0 = echo).
        line: u16,
        /// Byte in the line.
        column: u16,
        /// Bit number 0..=7.
        bit: u8,
    },
    /// The byte `byte` at `column` of line `line` was left out.
    DroppedByte {
        /// Line in the response.
        line: u16,
        /// Byte in the line.
        column: u16,
        /// The byte dropped.
        byte: u8,
    },
    /// `byte` was inserted before `column` of line `line`.
    InsertedByte {
        /// Line in the response.
        line: u16,
        /// Byte in the line.
        column: u16,
        /// The byte inserted.
        byte: u8,
    },
    /// Output held back this long.
    Stall {
        /// ms of sensor time.
        ms: u64,
    },
    /// A frame with this status instead of a scan.
    HardwareFault {
        /// The status chars.
        status: [u8; 2],
    },
    /// The sensor rebooted after sending `sent` bytes of the frame.
    Reboot {
        /// Bytes of the frame sent before the reboot.
        sent: usize,
    },
}

/// One logged fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultRecord {
    /// Sensor time, µs since start.
    pub at_us: u64,
    /// Index of the response in the sensor's output (0 = first response since start).
    pub response: u64,
    /// Scan number of the frame hit (the scan clock's count).
    pub scan: u64,
    /// What was done.
    pub kind: FaultKind,
    /// The decoder error it must cause (`ErrorKind::name`), `None` when it causes none
    /// by itself (stall, hardware status) or none can be told in advance (reboot).
    pub detected_as: Option<&'static str>,
}

/// The injector: a seeded random source and the log.
#[derive(Debug, Clone)]
pub struct Faults {
    cfg: FaultConfig,
    rng: fastrand::Rng,
    log: Vec<FaultRecord>,
    /// Line noise draws apart from the others, so that they do not shift them.
    line_rng: fastrand::Rng,
    /// Bytes still clean before the next line-noise event.
    line_gap: u64,
    line_stats: LineNoiseStats,
}

/// Line ranges (start, end without LF) of a response's bytes.
fn lines(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for (i, &b) in bytes.iter().enumerate() {
        if b == b'\n' {
            out.push((start, i));
            start = i + 1;
        }
    }
    out
}

fn valid_value_char(c: u8) -> bool {
    (0x30..=0x6F).contains(&c)
}

/// The decoder error a damaged payload line (body + sum char) causes, `None` if it
/// would pass.
fn line_error(line: &[u8]) -> Option<&'static str> {
    let [body @ .., sum] = line else {
        return Some("bad_sum");
    };
    if checksum(body) != *sum {
        Some("bad_sum")
    } else if !body.iter().all(|&c| valid_value_char(c)) {
        Some("bad_char")
    } else {
        None
    }
}

impl Faults {
    /// An injector for `cfg`.
    pub fn new(cfg: FaultConfig) -> Self {
        let mut f = Self {
            cfg,
            rng: fastrand::Rng::with_seed(cfg.seed ^ 0xFA17_5EED),
            log: Vec::new(),
            line_rng: fastrand::Rng::with_seed(cfg.seed ^ 0x11AE_5EED),
            line_gap: 0,
            line_stats: LineNoiseStats::default(),
        };
        f.line_gap = f.draw_gap();
        f
    }

    /// Replaces the line noise from now on.
    pub fn set_line_noise(&mut self, noise: LineNoise) {
        self.cfg.line = noise;
        self.line_gap = self.draw_gap();
    }

    /// Line noise so far.
    pub fn line_stats(&self) -> &LineNoiseStats {
        &self.line_stats
    }

    /// Clean bytes before the next line-noise event: geometric with the total rate.
    fn draw_gap(&mut self) -> u64 {
        let p = self.cfg.line.rate();
        if p <= 0.0 {
            return u64::MAX;
        }
        if p >= 1.0 {
            return 0;
        }
        let u = 1.0 - self.line_rng.f64(); // (0, 1]
        (u.ln() / (1.0 - p).ln()).floor().min(u64::MAX as f64 / 2.0) as u64
    }

    /// Sends `bytes` through the noisy line: returns what arrives.
    pub fn line(&mut self, bytes: Vec<u8>) -> Vec<u8> {
        let n = self.cfg.line;
        self.line_stats.bytes += bytes.len() as u64;
        if n.rate() <= 0.0 || self.line_gap >= bytes.len() as u64 {
            self.line_gap = self.line_gap.saturating_sub(bytes.len() as u64);
            return bytes;
        }
        let mut out = Vec::with_capacity(bytes.len() + 8);
        let mut i = 0usize;
        while i < bytes.len() {
            let clean = usize::try_from(self.line_gap).unwrap_or(usize::MAX);
            let end = i.saturating_add(clean).min(bytes.len());
            out.extend_from_slice(bytes.get(i..end).unwrap_or(&[]));
            self.line_gap -= (end - i) as u64;
            i = end;
            let Some(&b) = bytes.get(i) else {
                break;
            };
            // An event at byte i: which kind, by weight.
            let x = self.line_rng.f64() * n.rate();
            if x < n.flip {
                out.push(b ^ (1 << self.line_rng.u8(0..8)));
                self.line_stats.flips += 1;
                i += 1;
            } else if x < n.flip + n.drop {
                self.line_stats.drops += 1;
                i += 1;
            } else if x < n.flip + n.drop + n.insert {
                out.push(self.line_rng.u8(..));
                self.line_stats.inserts += 1;
                // The byte itself comes next, with a gap of its own.
            } else {
                let len = usize::from(self.line_rng.u8(2..=n.burst_len.max(2)));
                for &c in bytes.get(i..(i + len).min(bytes.len())).unwrap_or(&[]) {
                    out.push(c ^ self.line_rng.u8(1..));
                }
                self.line_stats.bursts += 1;
                i = (i + len).min(bytes.len());
            }
            self.line_gap = self.draw_gap();
        }
        out
    }

    /// The configuration.
    pub fn config(&self) -> &FaultConfig {
        &self.cfg
    }

    /// Every fault so far.
    pub fn log(&self) -> &[FaultRecord] {
        &self.log
    }

    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.f64() < p
    }

    /// A hardware-fault status for this frame, or `None`.
    pub fn hardware_fault(&mut self, at_us: u64, response: u64, scan: u64) -> Option<[u8; 2]> {
        if !self.chance(self.cfg.hardware) {
            return None;
        }
        let code = self.rng.u8(50..=97);
        let status = [b'0' + code / 10, b'0' + code % 10];
        self.log.push(FaultRecord {
            at_us,
            response,
            scan,
            kind: FaultKind::HardwareFault { status },
            detected_as: None,
        });
        Some(status)
    }

    /// A stall before this response, in µs, or 0.
    pub fn stall(&mut self, at_us: u64, response: u64, scan: u64) -> u64 {
        if !self.chance(self.cfg.stall) {
            return 0;
        }
        let ms = self.cfg.stall_ms;
        self.log.push(FaultRecord {
            at_us,
            response,
            scan,
            kind: FaultKind::Stall { ms },
            detected_as: None,
        });
        ms * 1000
    }

    /// True when frame number `frame` is the one to reboot in; logs the reboot and
    /// returns how many bytes of the frame go out first.
    pub fn reboot(
        &mut self,
        frame: u64,
        len: usize,
        at_us: u64,
        response: u64,
        scan: u64,
    ) -> Option<usize> {
        if self.cfg.reboot_at_frame != Some(frame) {
            return None;
        }
        let sent = self.rng.usize(1..len.max(2));
        self.log.push(FaultRecord {
            at_us,
            response,
            scan,
            kind: FaultKind::Reboot { sent },
            detected_as: None,
        });
        Some(sent)
    }

    /// Damages a measurement response in place (at most one byte fault), logging it.
    pub fn damage(&mut self, bytes: &mut Vec<u8>, at_us: u64, response: u64, scan: u64) {
        let kind = if self.chance(self.cfg.flip) {
            0
        } else if self.chance(self.cfg.drop) {
            1
        } else if self.chance(self.cfg.insert) {
            2
        } else {
            return;
        };
        let ls = lines(bytes);
        // Payload lines: timestamp (2) and data lines (3..), not the final empty line.
        let payload: Vec<(usize, (usize, usize))> = ls
            .iter()
            .copied()
            .enumerate()
            .filter(|&(i, (s, e))| i >= 2 && e > s)
            .collect();
        let data: Vec<_> = payload
            .iter()
            .copied()
            .filter(|&(i, (s, e))| i >= 3 && e - s >= 3)
            .collect();
        for _ in 0..64 {
            let attempt = match kind {
                0 => self.try_flip(bytes, &payload),
                1 => self.try_drop(bytes, &data),
                _ => self.try_insert(bytes, &data),
            };
            if let Some((new, kind, detected)) = attempt {
                *bytes = new;
                self.log.push(FaultRecord {
                    at_us,
                    response,
                    scan,
                    kind,
                    detected_as: Some(detected),
                });
                return;
            }
        }
    }

    fn pick(&mut self, lines: &[(usize, (usize, usize))]) -> Option<(usize, usize, usize)> {
        let &(i, (s, e)) = lines.get(self.rng.usize(0..lines.len().max(1)))?;
        Some((i, s, e))
    }

    fn try_flip(
        &mut self,
        bytes: &[u8],
        lines: &[(usize, (usize, usize))],
    ) -> Option<(Vec<u8>, FaultKind, &'static str)> {
        let (i, s, e) = self.pick(lines)?;
        let col = self.rng.usize(0..e - s);
        let bit = self.rng.u8(0..8);
        let mut line = bytes.get(s..e)?.to_vec();
        let c = line.get_mut(col)?;
        *c ^= 1 << bit;
        if matches!(*c, b'\n' | b'\r' | b'&') {
            return None;
        }
        let detected = line_error(&line)?;
        let mut new = bytes.to_vec();
        new.splice(s..e, line);
        let kind = FaultKind::BitFlip {
            line: i as u16,
            column: col as u16,
            bit,
        };
        Some((new, kind, detected))
    }

    fn try_drop(
        &mut self,
        bytes: &[u8],
        lines: &[(usize, (usize, usize))],
    ) -> Option<(Vec<u8>, FaultKind, &'static str)> {
        let (i, s, e) = self.pick(lines)?;
        // A data char (not the sum).
        let col = self.rng.usize(0..e - s - 1);
        let mut line = bytes.get(s..e)?.to_vec();
        let byte = line.remove(col);
        let detected = line_error(&line).filter(|&d| d == "bad_sum")?;
        let mut new = bytes.to_vec();
        new.splice(s..e, line);
        let kind = FaultKind::DroppedByte {
            line: i as u16,
            column: col as u16,
            byte,
        };
        Some((new, kind, detected))
    }

    fn try_insert(
        &mut self,
        bytes: &[u8],
        lines: &[(usize, (usize, usize))],
    ) -> Option<(Vec<u8>, FaultKind, &'static str)> {
        let (i, s, e) = self.pick(lines)?;
        let col = self.rng.usize(0..e - s);
        let byte = self.rng.u8(0x30..=0x6F);
        let mut line = bytes.get(s..e)?.to_vec();
        line.insert(col, byte);
        let detected = line_error(&line).filter(|&d| d == "bad_sum")?;
        let mut new = bytes.to_vec();
        new.splice(s..e, line);
        let kind = FaultKind::InsertedByte {
            line: i as u16,
            column: col as u16,
            byte,
        };
        Some((new, kind, detected))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAME: &[u8] =
        b"GD0000001000;GD00000999\n00P\nG]\\VF\n06306J06_07407607106i06i06i075070n\n\n";

    #[test]
    fn every_flip_is_caught_by_sum_or_char() {
        // Exhaustive over the payload bytes of a real response: flips of bits 0..=5
        // break the sum, flips of bits 6 and 7 break a value char.
        let ls = lines(FRAME);
        for &(s, e) in &ls[2..4] {
            for col in 0..e - s {
                for bit in 0..8u8 {
                    let mut line = FRAME[s..e].to_vec();
                    line[col] ^= 1 << bit;
                    if matches!(line[col], b'\n' | b'\r' | b'&') {
                        continue;
                    }
                    let is_sum = col == e - s - 1;
                    let want = if bit < 6 || is_sum {
                        "bad_sum"
                    } else {
                        "bad_char"
                    };
                    assert_eq!(line_error(&line), Some(want), "col {col} bit {bit}");
                }
            }
        }
    }

    #[test]
    fn damage_logs_one_fault_per_response() {
        let mut f = Faults::new(FaultConfig {
            flip: 0.4,
            drop: 0.4,
            insert: 1.0,
            seed: 3,
            ..Default::default()
        });
        for r in 0..200 {
            let mut bytes = FRAME.to_vec();
            f.damage(&mut bytes, 0, r, r);
            assert_ne!(bytes, FRAME);
            // Echo and status untouched.
            assert!(bytes.starts_with(b"GD0000001000;GD00000999\n00P\n"));
        }
        assert_eq!(f.log().len(), 200);
        let kinds = |k: fn(&FaultKind) -> bool| f.log().iter().filter(|r| k(&r.kind)).count();
        assert!(kinds(|k| matches!(k, FaultKind::BitFlip { .. })) > 50);
        assert!(kinds(|k| matches!(k, FaultKind::DroppedByte { .. })) > 20);
        assert!(kinds(|k| matches!(k, FaultKind::InsertedByte { .. })) > 20);
    }

    #[test]
    fn no_rates_no_faults() {
        let mut f = Faults::new(FaultConfig::default());
        let mut bytes = FRAME.to_vec();
        f.damage(&mut bytes, 0, 0, 0);
        assert_eq!(bytes, FRAME);
        assert_eq!(f.hardware_fault(0, 0, 0), None);
        assert_eq!(f.stall(0, 0, 0), 0);
        assert!(f.log().is_empty());
        assert!(FaultConfig::default().is_none());
    }

    #[test]
    fn line_noise_hits_every_kind_of_byte_at_its_rate() {
        let mut f = Faults::new(FaultConfig {
            line: LineNoise::uniform(0.01),
            seed: 9,
            ..Default::default()
        });
        let clean: Vec<u8> = FRAME.repeat(2000);
        let mut damaged_lf = 0;
        let mut got = Vec::new();
        for chunk in clean.chunks(FRAME.len()) {
            let out = f.line(chunk.to_vec());
            damaged_lf += usize::from(out.iter().filter(|&&b| b == b'\n').count() != 5);
            got.extend(out);
        }
        let st = *f.line_stats();
        assert_eq!(st.bytes, clean.len() as u64);
        // 0.25 % each of 142 000 bytes: about 355 events of each kind.
        for n in [st.flips, st.drops, st.inserts, st.bursts] {
            assert!((280..430).contains(&n), "{st:?}");
        }
        assert_eq!(
            got.len() as i64 - clean.len() as i64,
            st.inserts as i64 - st.drops as i64
        );
        // Line ends are hit like any byte (nothing is filtered).
        assert!(damaged_lf > 50, "{damaged_lf}");
        // No noise: the bytes pass untouched.
        let mut quiet = Faults::new(FaultConfig::default());
        assert_eq!(quiet.line(FRAME.to_vec()), FRAME);
    }
}
