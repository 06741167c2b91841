//! Fuzzes the control-frame parser: any bytes either fail with a typed error (and get a
//! rejection answer) or parse to a valid request that emits back and parses the same.
#![no_main]

use can_wire::{Answer, Control};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    match Control::parse(data) {
        Err(e) => {
            let answer = Answer::reject(data, &e);
            assert_eq!(Answer::parse(&answer.emit()), Ok(answer));
        }
        Ok(control) => {
            control
                .command
                .validate()
                .expect("a parsed request is valid");
            let mut buf = [0u8; 8];
            let n = control.emit(&mut buf).expect("a parsed request emits");
            assert_eq!(Control::parse(&buf[..n]), Ok(control), "round trip");
        }
    }
});
