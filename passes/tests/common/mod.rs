//! Helpers of the passes' integration tests: the repository root, and the shaders as the build
//! compiled them (the `penumbra` crate's embedded SPIR-V, from the root `build.rs`), so the tests
//! run the same code the renderer does and compile no GLSL at run time.
#![allow(dead_code)]

use penumbra_engine::shader::ShaderLibrary;
use std::path::{Path, PathBuf};

/// The repository root (scenes/, glsl/).
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// The build's shader library.
pub fn shaders() -> ShaderLibrary {
    penumbra::shader_library()
}
