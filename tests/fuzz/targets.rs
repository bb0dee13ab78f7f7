//! The loaders the fuzz targets drive, by name: shared by `tests/fuzz/fuzz_targets/*.rs` (cargo-fuzz,
//! nightly) and the corpus replay test `tools/tests/corpus.rs` (stable, every `cargo test`).
//! Each takes untrusted bytes and must end in `Ok` or an error, never a panic, an abort or an
//! unbounded allocation.

use std::path::Path;

/// Every target (its corpus: `tests/fuzz/corpus/<name>/`).
#[allow(dead_code)] // used by the replay test, not by the fuzz binaries
pub const TARGETS: &[&str] = &["scene_toml", "gltf", "exr", "hdr", "png", "spheres", "pvv", "psf", "psw"];

/// Loads `bytes` as target `name` (an unknown name is an error).
pub fn load(name: &str, bytes: &[u8]) -> Result<(), String> {
    use penumbra_scene::{Budget, Environment, Limits, LoadOptions, Texture};
    let path = Path::new("fuzz-input");
    let budget = Budget::new(Limits::default());
    let s = |e: penumbra_scene::SceneError| e.to_string();
    match name {
        "scene_toml" => {
            let text = std::str::from_utf8(bytes).map_err(|e| e.to_string())?;
            // relative files resolve under a directory that does not exist
            penumbra_scene::format::parse_toml_with(
                Path::new("/nonexistent-fuzz/s.toml"),
                text,
                &LoadOptions::default(),
                &budget,
            )
            .map(drop)
            .map_err(s)
        }
        "gltf" => penumbra_scene::gltf_load::load_bytes_with(path, bytes, Path::new("/nonexistent-fuzz"), &budget)
            .map(drop)
            .map_err(s),
        "exr" => Environment::from_exr_bytes_with(path, bytes, &budget).map(drop).map_err(s),
        "hdr" => Environment::from_hdr_bytes_with(path, bytes, &budget).map(drop).map_err(s),
        "png" => Texture::from_bytes_with(path, bytes, true, &budget).map(drop).map_err(s),
        "spheres" => {
            let text = std::str::from_utf8(bytes).map_err(|e| e.to_string())?;
            penumbra_math::sphereset::SphereSet::parse(text).map(drop).map_err(|e| e.to_string())
        }
        "pvv" => penumbra_math::vv::VvData::from_bytes(bytes, "fuzz-input").map(drop),
        "psf" => penumbra_math::shadow_field::ObjectField::from_bytes(bytes).map(drop),
        "psw" => penumbra_math::shadow_field::haar::HaarField::from_bytes(bytes).map(drop),
        other => Err(format!("unknown fuzz target '{other}'")),
    }
}
