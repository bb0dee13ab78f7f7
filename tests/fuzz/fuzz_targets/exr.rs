#![no_main]
//! Fuzz target: `exr` (see `fuzz/targets.rs`).

#[path = "../targets.rs"]
mod targets;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = targets::load("exr", data);
});
