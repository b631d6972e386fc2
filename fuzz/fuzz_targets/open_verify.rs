//! Fuzzes `Container::from_bytes` and, when it accepts the input, `verify`: neither may panic,
//! whatever the bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(container) = treelod_format::Container::from_bytes(data) {
        let _ = treelod_format::verify(&container);
    }
});
