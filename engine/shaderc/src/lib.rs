//! `shaderc`, linked against the system's static archives. Use `penumbra_shaderc::shaderc`.
pub use shaderc;
