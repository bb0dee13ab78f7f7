//! The shader library: SPIR-V embedded at build time by the root `build.rs`, keyed by the path
//! under `glsl/`, with optional run-time recompilation from the sources (hot reload).

use anyhow::{anyhow, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Named SPIR-V blobs.
#[derive(Clone, Debug, Default)]
pub struct ShaderLibrary {
    shaders: BTreeMap<String, Vec<u8>>,
    /// Where `glsl/` lives, for [`ShaderLibrary::reload`].
    pub source_dir: Option<PathBuf>,
}

impl ShaderLibrary {
    pub fn from_embedded(table: &[(&str, &[u8])], source_dir: Option<PathBuf>) -> Self {
        ShaderLibrary { shaders: table.iter().map(|(k, v)| (k.to_string(), v.to_vec())).collect(), source_dir }
    }

    /// SPIR-V bytes of `name` (e.g. `"gbuffer.vert"`).
    pub fn get(&self, name: &str) -> Result<&[u8]> {
        self.shaders.get(name).map(|v| v.as_slice()).ok_or_else(|| {
            anyhow!(
                "shader '{name}' is not in the library (known: {})",
                self.shaders.keys().cloned().collect::<Vec<_>>().join(", ")
            )
        })
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.shaders.keys().map(|s| s.as_str())
    }

    /// Recompiles `name` from `source_dir` with the same options as the build, replacing the
    /// embedded SPIR-V. Errors name the file and line.
    pub fn reload(&mut self, name: &str) -> Result<()> {
        let dir = self.source_dir.clone().ok_or_else(|| anyhow!("no shader source directory set"))?;
        let words =
            crate::glsl_compile::compile_glsl_file(&dir.join(name), &dir.join("include")).map_err(|e| anyhow!(e))?;
        self.shaders.insert(name.to_string(), words.iter().flat_map(|w| w.to_le_bytes()).collect());
        Ok(())
    }

    /// Compiles a GLSL source string at run time (tests, tools).
    pub fn compile_source(name: &str, source: &str, include_dir: &Path) -> Result<Vec<u32>> {
        let kind = crate::glsl_compile::stage_for(Path::new(name)).ok_or_else(|| anyhow!("{name}: unknown stage"))?;
        crate::glsl_compile::compile_glsl_source(source, kind, Path::new(name), include_dir).map_err(|e| anyhow!(e))
    }
}
