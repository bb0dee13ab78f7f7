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
    /// Compiled with every loop counted ([`ShaderLibrary::with_loop_guard`]).
    loop_guard: bool,
}

impl ShaderLibrary {
    pub fn from_embedded(table: &[(&str, &[u8])], source_dir: Option<PathBuf>) -> Self {
        ShaderLibrary {
            shaders: table.iter().map(|(k, v)| (k.to_string(), v.to_vec())).collect(),
            source_dir,
            loop_guard: false,
        }
    }

    /// The same shaders recompiled from `source_dir` with every loop counted (the loop guard:
    /// `glsl_compile::instrument_loops`): each invocation counts its loop iterations and reports
    /// the most, and whether it reached 32768 or 65535 (lavapipe 22.3's silent limit), into the
    /// guard buffer of a context created with `ContextDesc::loop_guard`
    /// ([`crate::Context::loop_guard_counts`]). For tests and `penumbra bench loop-guard`: slower
    /// shaders (and their pipelines slower to create), about 30 s of compiling on one core.
    pub fn with_loop_guard(&self) -> Result<ShaderLibrary> {
        let dir = self.source_dir.clone().ok_or_else(|| anyhow!("the loop guard needs the shader sources (glsl/)"))?;
        let shaders = self.compile_all(&dir, true)?;
        Ok(ShaderLibrary { shaders, source_dir: Some(dir), loop_guard: true })
    }

    /// The shader's slot in the loop guard's buffer (its index among the library's names), when
    /// the library counts loops.
    pub fn loop_guard_slot(&self, name: &str) -> Option<u32> {
        if !self.loop_guard {
            return None;
        }
        self.shaders.keys().position(|k| k == name).map(|i| i as u32)
    }

    /// Whether the library counts loops ([`ShaderLibrary::with_loop_guard`]).
    pub fn is_loop_guarded(&self) -> bool {
        self.loop_guard
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
        let words = crate::glsl_compile::compile_glsl_file_with(&dir.join(name), &dir.join("include"), self.loop_guard)
            .map_err(|e| anyhow!(e))?;
        self.shaders.insert(name.to_string(), words.iter().flat_map(|w| w.to_le_bytes()).collect());
        Ok(())
    }

    /// Recompiles every shader of the library from `source_dir` (hot reload). All or nothing:
    /// on any compile error the library is unchanged and the error lists every failing file
    /// with its line and message. Returns the names whose SPIR-V changed.
    pub fn reload_all(&mut self) -> Result<Vec<String>> {
        let dir = self.source_dir.clone().ok_or_else(|| anyhow!("no shader source directory set"))?;
        let fresh = self.compile_all(&dir, self.loop_guard)?;
        let changed = fresh.iter().filter(|(k, v)| self.shaders.get(*k) != Some(*v)).map(|(k, _)| k.clone()).collect();
        self.shaders = fresh;
        Ok(changed)
    }

    /// Every shader of the library compiled from `dir` on every core; all or nothing, the error
    /// listing every failing file with its line and message.
    fn compile_all(&self, dir: &Path, loop_guard: bool) -> Result<BTreeMap<String, Vec<u8>>> {
        let files: Vec<PathBuf> = self.shaders.keys().map(|n| dir.join(n)).collect();
        let compiled = crate::glsl_compile::compile_glsl_files(&files, &dir.join("include"), loop_guard);
        let mut shaders = BTreeMap::new();
        let mut errors = Vec::new();
        for (name, r) in self.shaders.keys().zip(compiled) {
            match r {
                Ok(words) => {
                    shaders.insert(name.clone(), words.iter().flat_map(|w| w.to_le_bytes()).collect());
                }
                Err(e) => errors.push(e),
            }
        }
        if !errors.is_empty() {
            return Err(anyhow!("{} shader(s) failed to compile:\n{}", errors.len(), errors.join("\n")));
        }
        Ok(shaders)
    }

    /// Compiles a GLSL source string at run time (tests, tools).
    pub fn compile_source(name: &str, source: &str, include_dir: &Path) -> Result<Vec<u32>> {
        let kind = crate::glsl_compile::stage_for(Path::new(name)).ok_or_else(|| anyhow!("{name}: unknown stage"))?;
        crate::glsl_compile::compile_glsl_source(source, kind, Path::new(name), include_dir).map_err(|e| anyhow!(e))
    }
}

/// The loop guard's specialization constants for one shader stage, `(constant_id, value)`: the
/// guard buffer's address (low and high words) and the shader's slot. Pipelines built from a
/// loop-guarded library set them on every stage, through [`Specialization`].
struct LoopGuardSpec {
    constants: [(u32, u32); 3],
}

impl LoopGuardSpec {
    /// `None` for an ordinary library; an error when the library counts loops but the context
    /// has no guard buffer (`ContextDesc::loop_guard`).
    fn for_shader(ctx: &crate::Context, shaders: &ShaderLibrary, name: &str) -> Result<Option<LoopGuardSpec>> {
        let Some(slot) = shaders.loop_guard_slot(name) else { return Ok(None) };
        let address = ctx.loop_guard_address().ok_or_else(|| {
            anyhow!("'{name}' counts its loops (a loop-guarded library) but the context has no loop guard buffer")
        })?;
        if slot as usize >= ctx.loop_guard_slots() {
            return Err(anyhow!("loop guard: '{name}' has slot {slot}, the buffer {}", ctx.loop_guard_slots()));
        }
        let [lo, hi, sl] = crate::glsl_compile::LOOP_GUARD_CONSTANT_IDS;
        Ok(Some(LoopGuardSpec { constants: [(lo, address as u32), (hi, (address >> 32) as u32), (sl, slot)] }))
    }
}

/// The specialization constants of one shader stage: the caller's `(constant_id, value)` pairs
/// (mode switches that would otherwise leave every mode's code in the pipeline: lavapipe compiles
/// all of it at the first dispatch) and, from a loop-guarded library, the loop guard's (the guard
/// buffer's address and the shader's slot, ids [`crate::glsl_compile::LOOP_GUARD_CONSTANT_IDS`]).
pub struct Specialization {
    /// The values, 4 bytes each in the device's (the host's) byte order.
    data: Vec<u8>,
    entries: Vec<ash::vk::SpecializationMapEntry>,
}

impl Specialization {
    /// `None` without constants on an ordinary library; an error where a constant takes one of
    /// the loop guard's ids ([`crate::glsl_compile::LOOP_GUARD_CONSTANT_IDS`]), is given twice, or
    /// where the library counts loops and the context has no guard buffer
    /// (`ContextDesc::loop_guard`).
    pub fn for_shader(
        ctx: &crate::Context,
        shaders: &ShaderLibrary,
        name: &str,
        constants: &[(u32, u32)],
    ) -> Result<Option<Specialization>> {
        let reserved = crate::glsl_compile::LOOP_GUARD_CONSTANT_IDS;
        for (i, (id, _)) in constants.iter().enumerate() {
            if reserved.contains(id) {
                return Err(anyhow!("'{name}': specialization constant id {id} is the loop guard's ({reserved:?})"));
            }
            if constants[..i].iter().any(|(other, _)| other == id) {
                return Err(anyhow!("'{name}': specialization constant id {id} given twice"));
            }
        }
        let guard = LoopGuardSpec::for_shader(ctx, shaders, name)?;
        if guard.is_none() && constants.is_empty() {
            return Ok(None);
        }
        let all: Vec<(u32, u32)> = constants.iter().chain(guard.iter().flat_map(|g| &g.constants)).copied().collect();
        let data = all.iter().flat_map(|(_, v)| v.to_ne_bytes()).collect();
        let entries = all
            .iter()
            .enumerate()
            .map(|(i, &(constant_id, _))| ash::vk::SpecializationMapEntry {
                constant_id,
                offset: 4 * i as u32,
                size: 4,
            })
            .collect();
        Ok(Some(Specialization { data, entries }))
    }

    /// The specialization info (borrows `self`).
    pub fn info(&self) -> ash::vk::SpecializationInfo<'_> {
        ash::vk::SpecializationInfo::default().map_entries(&self.entries).data(&self.data)
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
