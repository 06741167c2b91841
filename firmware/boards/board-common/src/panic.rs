//! The STM32 boards' panic handler (feature `panic-handler`): the panic's location and, when
//! it is a plain string, its message, logged through defmt; then a `HardFault` (`udf`), which
//! `probe-rs run` reports with a backtrace and a non-zero exit, as `panic-probe` did.
//!
//! It never formats: a message with arguments (`index out of bounds: the len is {} ...`) is
//! logged as its location only. Formatting it through `core::fmt`, as `panic-probe`'s
//! `print-defmt` does, linked about 3 KB of `core::fmt` machinery (padding, integer display,
//! `Debug` of every type some `unwrap` could print) into images that have 96 KiB of flash.
//! The location names the failing line, which is what the message would have explained.
//!
//! `defmt::panic!` and `defmt::unwrap!` log their own message first and then end here too,
//! through defmt's panic handler (below), without a second line.
//!
//! `udf` escalates to `HardFault` while `UsageFault` is disabled, its reset state, which
//! neither the boards nor embassy change.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

/// Logs the panic once (a panic while logging goes straight to the fault), then faults.
#[panic_handler]
fn panic(info: &PanicInfo<'_>) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    if !PANICKED.swap(true, Ordering::Relaxed) {
        let message = info
            .message()
            .as_str()
            .unwrap_or("(message with arguments)");
        match info.location() {
            Some(at) => defmt::error!(
                "panicked at {=str}:{=u32}:{=u32}: {=str}",
                at.file(),
                at.line(),
                at.column(),
                message
            ),
            None => defmt::error!("panicked: {=str}", message),
        }
    }
    cortex_m::asm::udf()
}

/// The end of `defmt::panic!` and `defmt::unwrap!`, which have logged their message.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::interrupt::disable();
    cortex_m::asm::udf()
}
