//! FNV-1a (32 bit) over CAN frames: what the work benchmark prints, and what the host
//! (`scip2can icount`, which includes this file) computes over the same core's frames.

use embedded_can::Id;

/// FNV-1a (32 bit) over frames: per frame its raw identifier (4 bytes, little endian,
/// bit 31 set for an extended one), FD flag, length and data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHash(pub u32);

impl Default for FrameHash {
    fn default() -> Self {
        Self(0x811C_9DC5)
    }
}

impl FrameHash {
    /// Adds bytes.
    pub fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u32::from(b)).wrapping_mul(0x0100_0193);
        }
    }

    /// Adds one frame.
    pub fn frame(&mut self, frame: &can_wire::Frame) {
        let raw = match frame.id() {
            Id::Standard(id) => u32::from(id.as_raw()),
            Id::Extended(id) => id.as_raw() | 0x8000_0000,
        };
        self.bytes(&raw.to_le_bytes());
        let len = u8::try_from(frame.data().len()).unwrap_or(u8::MAX);
        self.bytes(&[u8::from(frame.is_fd()), len]);
        self.bytes(frame.data());
    }
}
