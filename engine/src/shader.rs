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

    /// SPIR-V bytes of `name` (e.g. `"frame/gbuffer.vert"`).
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

    /// Recompiles every shader of the library from `source_dir` (hot reload). All or nothing:
    /// on any compile error the library is unchanged and the error lists every failing file
    /// with its line and message. Returns the names whose SPIR-V changed.
    pub fn reload_all(&mut self) -> Result<Vec<String>> {
        let dir = self.source_dir.clone().ok_or_else(|| anyhow!("no shader source directory set"))?;
        let mut fresh = BTreeMap::new();
        let mut errors = Vec::new();
        for name in self.shaders.keys() {
            match crate::glsl_compile::compile_glsl_file(&dir.join(name), &dir.join("include")) {
                Ok(words) => {
                    fresh.insert(name.clone(), words.iter().flat_map(|w| w.to_le_bytes()).collect::<Vec<u8>>());
                }
                Err(e) => errors.push(e.to_string()),
            }
        }
        if !errors.is_empty() {
            return Err(anyhow!("{} shader(s) failed to compile:\n{}", errors.len(), errors.join("\n")));
        }
        let changed = fresh.iter().filter(|(k, v)| self.shaders.get(*k) != Some(*v)).map(|(k, _)| k.clone()).collect();
        self.shaders = fresh;
        Ok(changed)
    }

    /// Compiles a GLSL source string at run time (tests, tools).
    pub fn compile_source(name: &str, source: &str, include_dir: &Path) -> Result<Vec<u32>> {
        let kind = crate::glsl_compile::stage_for(Path::new(name)).ok_or_else(|| anyhow!("{name}: unknown stage"))?;
        crate::glsl_compile::compile_glsl_source(source, kind, Path::new(name), include_dir).map_err(|e| anyhow!(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "#version 450\nlayout(local_size_x = 1) in;\nvoid main() {}\n";

    fn library(dir: &Path) -> ShaderLibrary {
        std::fs::create_dir_all(dir.join("include")).unwrap();
        std::fs::write(dir.join("a.comp"), GOOD).unwrap();
        std::fs::write(dir.join("b.comp"), GOOD).unwrap();
        let table: [(&str, &[u8]); 2] = [("a.comp", &[1, 2, 3, 4]), ("b.comp", &[5, 6, 7, 8])];
        ShaderLibrary::from_embedded(&table, Some(dir.to_path_buf()))
    }

    #[test]
    fn reload_all_is_all_or_nothing_and_reports_every_error() {
        let dir = std::env::temp_dir().join(format!("penumbra-shader-reload-{}", std::process::id()));
        let mut lib = library(&dir);
        let changed = lib.reload_all().expect("valid sources");
        assert_eq!(changed, vec!["a.comp".to_string(), "b.comp".to_string()]);
        let a = lib.get("a.comp").unwrap().to_vec();
        assert_eq!(&a[..4], &0x0723_0203u32.to_le_bytes(), "SPIR-V magic");
        assert!(lib.reload_all().unwrap().is_empty(), "nothing changed on disk");

        std::fs::write(dir.join("a.comp"), "#version 450\nlayout(local_size_x = 1) in;\nvoid main() { oops; }\n")
            .unwrap();
        std::fs::write(dir.join("b.comp"), "#version 450\nvoid main() { also_bad(); }\n").unwrap();
        let err = lib.reload_all().expect_err("broken sources").to_string();
        assert!(err.contains("2 shader(s) failed"), "{err}");
        assert!(err.contains("a.comp:3") && err.contains("b.comp:2"), "{err}");
        assert_eq!(lib.get("a.comp").unwrap(), a.as_slice(), "library unchanged after a failed reload");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
