//! ARM semihosting (`BKPT 0xAB`), the few calls of the lockstep co-simulation: files on
//! the host opened, read and written by QEMU (`-semihosting-config
//! enable=on,target=native`). A call is one instruction to the guest: virtual time does
//! not move while the host answers. Without a semihosting host the call faults.

#![allow(unsafe_code)]

/// `SYS_OPEN`.
const OPEN: u32 = 0x01;
/// `SYS_WRITE`.
const WRITE: u32 = 0x05;
/// `SYS_READ`.
const READ: u32 = 0x06;

/// `SYS_OPEN`'s modes (ISO C `fopen`'s, in the order semihosting numbers them).
pub const MODE_READ: u32 = 1; // "rb"
/// Write, binary (`"wb"`).
pub const MODE_WRITE: u32 = 5;

fn call(op: u32, args: &[u32]) -> i32 {
    let result: i32;
    // SAFETY: the semihosting call reads the argument block `args` points to (and the
    // buffers it names, which the callers' borrows keep alive and, for reads, writable)
    // and returns in r0; it touches no other guest state.
    unsafe {
        core::arch::asm!(
            "bkpt 0xAB",
            inout("r0") op => result,
            in("r1") args.as_ptr(),
            options(nostack),
        );
    }
    result
}

/// Opens the host file `path` (NUL-terminated) in `mode`; its handle.
pub fn open(path: &core::ffi::CStr, mode: u32) -> Option<u32> {
    let len = path.to_bytes().len() as u32;
    let handle = call(OPEN, &[path.as_ptr() as u32, mode, len]);
    u32::try_from(handle).ok()
}

/// Writes all of `bytes`; false if the host took fewer.
pub fn write(handle: u32, bytes: &[u8]) -> bool {
    call(WRITE, &[handle, bytes.as_ptr() as u32, bytes.len() as u32]) == 0
}

/// Fills `buf` (a pipe gives what it has: calls again for the rest); false at the end
/// of the file or on an error.
pub fn read_exact(handle: u32, buf: &mut [u8]) -> bool {
    let mut at = 0;
    while let Some(rest) = buf.get_mut(at..).filter(|r| !r.is_empty()) {
        let left = call(READ, &[handle, rest.as_mut_ptr() as u32, rest.len() as u32]);
        let Ok(left) = usize::try_from(left) else {
            return false;
        };
        let got = rest.len().saturating_sub(left);
        if got == 0 {
            return false;
        }
        at += got;
    }
    true
}
