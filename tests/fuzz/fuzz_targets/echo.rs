//! Fuzzes the echo parser: any bytes that parse as a request must encode back (as the
//! sensor echoes it) to the same bytes and parse again to the same request.
#![no_main]

use libfuzzer_sys::fuzz_target;
use scip::{Request, REQUEST_MAX};

fuzz_target!(|data: &[u8]| {
    let Ok(request) = Request::parse(data) else {
        return;
    };
    let mut out = [0u8; REQUEST_MAX];
    let n = request
        .encode_echo(&mut out)
        .expect("a parsed echo must encode");
    let (line, lf) = out[..n].split_at(n - 1);
    assert_eq!(lf, b"\n");
    // Byte for byte, except that an empty tag (`CMD;`) is written without its `;`.
    let exact = line == data || (data.strip_suffix(b";") == Some(line));
    assert!(exact, "echo {:?} re-encoded as {:?}", data, line);
    assert_eq!(Request::parse(line), Ok(request), "re-parse differs");
    // The validating encoder either refuses or writes the same line.
    let mut strict = [0u8; REQUEST_MAX];
    if let Ok(m) = request.encode(&mut strict) {
        assert_eq!(&strict[..m], &out[..n], "encode and encode_echo differ");
    }
});
