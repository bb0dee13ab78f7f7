#![no_main]
//! Fuzz target: `png` (see `fuzz/targets.rs`).

#[path = "../targets.rs"]
mod targets;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = targets::load("png", data);
});
