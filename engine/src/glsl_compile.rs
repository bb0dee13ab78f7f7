//! GLSL -> SPIR-V compilation with shaderc, shared by the root `build.rs` (via `#[path]`) and the
//! engine's run-time recompilation (hot reload). Depends only on `penumbra_shaderc` and std.

use penumbra_shaderc::shaderc;
use std::path::{Path, PathBuf};

/// Shader stage from a file extension (`vert`, `frag`, `comp`, `tesc`, `tese`, `geom`).
pub fn stage_for(path: &Path) -> Option<shaderc::ShaderKind> {
    Some(match path.extension()?.to_str()? {
        "vert" => shaderc::ShaderKind::Vertex,
        "frag" => shaderc::ShaderKind::Fragment,
        "comp" => shaderc::ShaderKind::Compute,
        "tesc" => shaderc::ShaderKind::TessControl,
        "tese" => shaderc::ShaderKind::TessEvaluation,
        "geom" => shaderc::ShaderKind::Geometry,
        _ => return None,
    })
}

/// Compiles one GLSL file to SPIR-V words. `#include "x.glsl"` is resolved relative to the
/// including file, then in `include_dir`. Errors carry `file:line: message` lines from glslang.
pub fn compile_glsl_file(path: &Path, include_dir: &Path) -> Result<Vec<u32>, String> {
    let source = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let kind = stage_for(path).ok_or_else(|| format!("{}: unknown shader stage extension", path.display()))?;
    compile_glsl_source(&source, kind, path, include_dir)
}

/// Compiles GLSL source text; `path` names it in messages and anchors relative includes.
pub fn compile_glsl_source(
    source: &str,
    kind: shaderc::ShaderKind,
    path: &Path,
    include_dir: &Path,
) -> Result<Vec<u32>, String> {
    let compiler = shaderc::Compiler::new().map_err(|e| format!("shaderc unavailable: {e}"))?;
    let mut options = shaderc::CompileOptions::new().map_err(|e| format!("shaderc options: {e}"))?;
    options.set_target_env(shaderc::TargetEnv::Vulkan, shaderc::EnvVersion::Vulkan1_3 as u32);
    options.set_source_language(shaderc::SourceLanguage::GLSL);
    options.set_optimization_level(shaderc::OptimizationLevel::Performance);
    options.set_generate_debug_info();
    options.set_warnings_as_errors();
    let include_dir = include_dir.to_path_buf();
    options.set_include_callback(move |name, ty, from, _depth| {
        let mut tries: Vec<PathBuf> = Vec::new();
        if ty == shaderc::IncludeType::Relative {
            if let Some(parent) = Path::new(from).parent() {
                tries.push(parent.join(name));
            }
        }
        tries.push(include_dir.join(name));
        for p in &tries {
            if let Ok(content) = std::fs::read_to_string(p) {
                return Ok(shaderc::ResolvedInclude { resolved_name: p.display().to_string(), content });
            }
        }
        Err(format!("cannot find include \"{name}\" (looked in {tries:?})"))
    });
    let name = path.display().to_string();
    compiler
        .compile_into_spirv(source, kind, &name, "main", Some(&options))
        .map(|a| a.as_binary().to_vec())
        .map_err(|e| e.to_string())
}
