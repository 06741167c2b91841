//! Boot parameters a host may leave in memory before the firmware starts: the sensor's
//! TCP address of the Ethernet binary, so that an emulation can point it at a simulator
//! on any port without rebuilding.
//!
//! QEMU writes them with its generic loader device, e.g. for 192.168.0.10:20000
//! (`0x4E20` = 20000, `0xC0A8000A` = 192.168.0.10, `0x53324345` = "S2CE"):
//!
//! ```text
//! -device loader,addr=0x21000000,data=0x00004E2053324345,data-len=8
//! -device loader,addr=0x21000008,data=0xC0A8000A,data-len=4
//! ```
//!
//! The words live at the start of the PSRAM (0x2100_0000), which the firmware does not
//! otherwise use (see `memory.x`); without the magic word the defaults hold.
//!
//! The one `unsafe` block here is a volatile read of that always-mapped RAM.

#![allow(unsafe_code)]

/// Where the block starts: the PSRAM of the AN385/AN386 images.
const BASE: usize = 0x2100_0000;

/// The first word when the block is there: "S2CE" in ASCII, little-endian.
pub const MAGIC: u32 = 0x5332_4345;

fn word(index: usize) -> u32 {
    // SAFETY: `BASE` is the PSRAM of this machine, always mapped, 4-byte aligned, and
    // not part of the program's memory (memory.x places nothing there): reading it has
    // no side effect and aliases nothing.
    unsafe { core::ptr::read_volatile((BASE + 4 * index) as *const u32) }
}

/// The sensor's address from the block, `(IPv4 as a big-endian u32, port)`: each
/// `None` where the block is absent or gives 0.
pub fn sensor() -> (Option<u32>, Option<u16>) {
    if word(0) != MAGIC {
        return (None, None);
    }
    let port = u16::try_from(word(1) & 0xFFFF).ok().filter(|&p| p != 0);
    let ip = Some(word(2)).filter(|&a| a != 0);
    (ip, port)
}
