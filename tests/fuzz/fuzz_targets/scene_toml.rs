#![no_main]
//! Fuzz target: `scene_toml` (see `fuzz/targets.rs`).

#[path = "../targets.rs"]
mod targets;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = targets::load("scene_toml", data);
});
