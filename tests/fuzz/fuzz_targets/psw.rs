#![no_main]
//! Fuzz target: `psw` (see `fuzz/targets.rs`).

#[path = "../targets.rs"]
mod targets;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = targets::load("psw", data);
});
