//! penumbra
include!(concat!(env!("OUT_DIR"), "/shaders.rs"));
