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

/// Compiles `files` on every core (one file per task; glslang is the slow part of a clean build),
/// results in the order of `files`.
pub fn compile_glsl_files(files: &[PathBuf], include_dir: &Path, loop_guard: bool) -> Vec<Result<Vec<u32>, String>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(files.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<(usize, Result<Vec<u32>, String>)> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(f) = files.get(i) else { break };
                        done.push((i, compile_glsl_file_with(f, include_dir, loop_guard)));
                    }
                    done
                })
            })
            .collect();
        workers.into_iter().filter_map(|w| w.join().ok()).flatten().collect()
    });
    let mut out: Vec<Result<Vec<u32>, String>> =
        files.iter().map(|f| Err(format!("{}: its compile thread panicked", f.display()))).collect();
    for (i, r) in results {
        out[i] = r;
    }
    out
}

/// Compiles one GLSL file to SPIR-V words. `#include "x.glsl"` is resolved relative to the
/// including file, then in `include_dir`. Errors carry `file:line: message` lines from glslang.
pub fn compile_glsl_file(path: &Path, include_dir: &Path) -> Result<Vec<u32>, String> {
    compile_glsl_file_with(path, include_dir, false)
}

/// [`compile_glsl_file`], with every loop counted when `loop_guard` ([`instrument_loops`]).
pub fn compile_glsl_file_with(path: &Path, include_dir: &Path, loop_guard: bool) -> Result<Vec<u32>, String> {
    let source = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let kind = stage_for(path).ok_or_else(|| format!("{}: unknown shader stage extension", path.display()))?;
    compile_glsl_source_with(&source, kind, path, include_dir, loop_guard)
}

/// Compiles GLSL source text; `path` names it in messages and anchors relative includes.
pub fn compile_glsl_source(
    source: &str,
    kind: shaderc::ShaderKind,
    path: &Path,
    include_dir: &Path,
) -> Result<Vec<u32>, String> {
    compile_glsl_source_with(source, kind, path, include_dir, false)
}

/// [`compile_glsl_source`], with every loop counted when `loop_guard` ([`instrument_loops`]).
pub fn compile_glsl_source_with(
    source: &str,
    kind: shaderc::ShaderKind,
    path: &Path,
    include_dir: &Path,
    loop_guard: bool,
) -> Result<Vec<u32>, String> {
    let instrumented;
    let source = if loop_guard {
        instrumented = instrument_loops(source, true).map_err(|e| format!("{}: {e}", path.display()))?;
        instrumented.as_str()
    } else {
        source
    };
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
                let content = if loop_guard {
                    instrument_loops(&content, false).map_err(|e| format!("{}: {e}", p.display()))?
                } else {
                    content
                };
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

/// The loop guard's specialization constants (`glsl_compile` instruments with them): the guard
/// buffer's device address (low and high words) and the shader's slot in it.
pub const LOOP_GUARD_CONSTANT_IDS: [u32; 3] = [200, 201, 202];

/// Words per shader slot in the loop guard's buffer: the most loop iterations one invocation ran,
/// the invocations that reached [`LOOP_GUARD_NEAR`], those that reached [`LOOP_GUARD_LIMIT`], and 1
/// once any invocation of the shader returned.
pub const LOOP_GUARD_SLOT_WORDS: usize = 4;
/// Iterations counted as "near" the limit.
pub const LOOP_GUARD_NEAR: u32 = 32768;
/// lavapipe's (Mesa 22.3) per-invocation loop limit.
pub const LOOP_GUARD_LIMIT: u32 = 65535;

/// GLSL declarations of the guard, inserted after a shader's `#version` line.
fn loop_guard_preamble() -> String {
    let [lo, hi, slot] = LOOP_GUARD_CONSTANT_IDS;
    format!(
        r#"#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
layout(buffer_reference, std430, buffer_reference_align = 4) buffer PenumbraLoopGuard {{ uint penumbra_slots[]; }};
layout(constant_id = {lo}) const uint PENUMBRA_GUARD_LO = 0u;
layout(constant_id = {hi}) const uint PENUMBRA_GUARD_HI = 0u;
layout(constant_id = {slot}) const uint PENUMBRA_GUARD_SLOT = 0u;
uint penumbra_loop_ticks = 0u;
void penumbra_loop_report() {{
    if (PENUMBRA_GUARD_LO == 0u && PENUMBRA_GUARD_HI == 0u) return;
    PenumbraLoopGuard g = PenumbraLoopGuard(uvec2(PENUMBRA_GUARD_LO, PENUMBRA_GUARD_HI));
    uint base = PENUMBRA_GUARD_SLOT * {words}u;
    if (penumbra_loop_ticks > g.penumbra_slots[base]) atomicMax(g.penumbra_slots[base], penumbra_loop_ticks);
    if (penumbra_loop_ticks >= {near}u) atomicAdd(g.penumbra_slots[base + 1u], 1u);
    if (penumbra_loop_ticks >= {limit}u) atomicAdd(g.penumbra_slots[base + 2u], 1u);
    if (g.penumbra_slots[base + 3u] == 0u) g.penumbra_slots[base + 3u] = 1u;
}}
// one add per iteration (a report inside every loop made llvmpipe's compile of the larger
// shaders take minutes): the count is reported when main returns
bool penumbra_loop_tick() {{
    penumbra_loop_ticks++;
    return true;
}}
#define main penumbra_guarded_main
"#,
        words = LOOP_GUARD_SLOT_WORDS,
        near = LOOP_GUARD_NEAR,
        limit = LOOP_GUARD_LIMIT,
    )
}

/// Counts every loop iteration of a shader: each `for` loop's increment gains
/// `penumbra_loop_tick()` (run once per completed iteration, `continue` included) and each `while`
/// condition (`while` and `do`-`while` loops) becomes `(cond) && penumbra_loop_tick()`. Source
/// loops are counted whether or not the compiler unrolls them, so the count bounds what a driver
/// counts. Comments and preprocessor lines are left alone; line numbers are kept. `top`: the
/// compiled file itself (not an include): the guard's declarations go after its `#version` line,
/// its `main` is renamed and a new `main` reports the count when it returns.
pub fn instrument_loops(source: &str, top: bool) -> Result<String, String> {
    let b = source.as_bytes();
    let mut out = String::with_capacity(source.len() + 256);
    let mut i = 0;
    let mut copied = 0;
    let mut line_start = true;
    let mut version_end = None;
    while i < b.len() {
        let c = b[i];
        if c == b'\n' {
            line_start = true;
            i += 1;
            continue;
        }
        if c.is_ascii_whitespace() {
            i += 1;
            continue;
        }
        if line_start && c == b'#' {
            // a preprocessor line (with continuations)
            let start = i;
            while i < b.len() && !(b[i] == b'\n' && b[i - 1] != b'\\') {
                i += 1;
            }
            if version_end.is_none() && source[start..i].trim_start_matches('#').trim_start().starts_with("version") {
                version_end = Some(i);
            }
            continue;
        }
        line_start = false;
        if c == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
            continue;
        }
        if c == b'/' && b.get(i + 1) == Some(&b'*') {
            i += 2;
            while i + 1 < b.len() && !(b[i] == b'*' && b[i + 1] == b'/') {
                i += 1;
            }
            i += 2;
            continue;
        }
        if c.is_ascii_alphabetic() || c == b'_' {
            let start = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            let word = &source[start..i];
            if word == "discard" || word == "terminateInvocation" {
                // the count is reported when main returns: an invocation that ends otherwise
                // would go uncounted
                return Err(format!(
                    "'{word}' at byte {start}: the loop guard cannot count a shader that ends invocations early"
                ));
            }
            if word != "for" && word != "while" {
                continue;
            }
            let mut j = i;
            while j < b.len() && b[j].is_ascii_whitespace() {
                j += 1;
            }
            if b.get(j) != Some(&b'(') {
                continue;
            }
            let open = j;
            let mut depth = 0i32;
            let mut semis = Vec::new();
            let close = loop {
                let Some(&ch) = b.get(j) else {
                    return Err(format!("'{word}' at byte {start}: unbalanced parentheses"));
                };
                match ch {
                    b'(' | b'[' | b'{' => depth += 1,
                    b')' | b']' | b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            break j;
                        }
                    }
                    b';' if depth == 1 => semis.push(j),
                    _ => {}
                }
                j += 1;
            };
            out.push_str(&source[copied..open + 1]);
            if word == "for" {
                let [_, second] = semis[..] else {
                    return Err(format!("'for' at byte {start}: expected two ';' in its header"));
                };
                out.push_str(&source[open + 1..second + 1]);
                let incr = source[second + 1..close].trim();
                if incr.is_empty() {
                    out.push_str(" penumbra_loop_tick()");
                } else {
                    out.push_str(" penumbra_loop_tick(), ");
                    out.push_str(&source[second + 1..close]);
                }
            } else {
                out.push('(');
                out.push_str(&source[open + 1..close]);
                out.push_str(") && penumbra_loop_tick()");
            }
            out.push(')');
            copied = close + 1;
            i = close + 1;
            continue;
        }
        i += 1;
    }
    out.push_str(&source[copied..]);
    if !top {
        return Ok(out);
    }
    let end = version_end.ok_or("no #version line")?;
    let version_line = source[..end].lines().count();
    // `end` is unchanged in `out`: nothing before the #version line is rewritten
    let mut s = String::with_capacity(out.len() + 1200);
    s.push_str(&out[..end]);
    s.push('\n');
    s.push_str(&loop_guard_preamble());
    // GLSL >= 330: `#line n` numbers the next line n; that line is the rest of the #version line
    s.push_str(&format!("#line {version_line}\n"));
    s.push_str(&out[end..]);
    s.push_str("\n#undef main\nvoid main() { penumbra_guarded_main(); penumbra_loop_report(); }\n");
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instrumenting_counts_every_loop_and_keeps_lines() {
        let src = "#version 460\n#extension GL_GOOGLE_include_directive : require\n// for (x) while (y)\n\
                   #define N 4 /* for (;;) */\nvoid f() {\n  for (int i = 0; i < N; i++) g(i);\n  \
                   for (;;) { break; }\n  while (a(b(c)) > 0) { d(); }\n  do { e(); } while (h);\n  \
                   for (int k = 0; k < 3;) k += 1;\n  uint forward = 0u; /* while (z) */\n}\nvoid main() { f(); }\n";
        let inc = instrument_loops(src, false).unwrap();
        assert_eq!(inc.lines().count(), src.lines().count());
        assert!(inc.contains("for (int i = 0; i < N; penumbra_loop_tick(),  i++) g(i);"), "{inc}");
        assert!(inc.contains("for (;; penumbra_loop_tick()) { break; }"), "{inc}");
        assert!(inc.contains("while ((a(b(c)) > 0) && penumbra_loop_tick())"), "{inc}");
        assert!(inc.contains("} while ((h) && penumbra_loop_tick());"), "{inc}");
        assert!(inc.contains("for (int k = 0; k < 3; penumbra_loop_tick())"), "{inc}");
        assert!(inc.contains("// for (x) while (y)") && inc.contains("/* for (;;) */") && inc.contains("forward"));
        assert_eq!(inc.matches("penumbra_loop_tick").count(), 5, "{inc}");
        let top = instrument_loops(src, true).unwrap();
        assert!(top.starts_with("#version 460\n#extension GL_EXT_buffer_reference"), "{top}");
        assert!(top.contains("#define main penumbra_guarded_main") && top.ends_with("penumbra_loop_report(); }\n"));
        assert!(instrument_loops("void f() { while (a(b) { }", false).is_err(), "unbalanced");
        assert!(instrument_loops("void f() { for (int i = 0) { } }", false).is_err(), "a for without two semicolons");
        assert!(instrument_loops("void f() { }", true).is_err(), "no #version line");
        assert!(instrument_loops("void f() { if (x) discard; }", false).unwrap_err().contains("discard"));
    }

    #[test]
    fn an_instrumented_shader_compiles_and_errors_keep_their_line() {
        let dir = std::env::temp_dir();
        let ok = "#version 460\nlayout(local_size_x = 1) in;\nlayout(set = 0, binding = 0) buffer B { uint x[]; };\n\
                  void main() {\n  uint s = 0u;\n  for (uint i = 0u; i < x[0]; ++i) s += i;\n  \
                  while (s > 3u) s /= 2u;\n  if (s == 7u) return;\n  x[1] = s;\n}\n";
        let kind = shaderc::ShaderKind::Compute;
        compile_glsl_source_with(ok, kind, Path::new("ok.comp"), &dir, true).expect("instrumented source compiles");
        let bad = ok.replace("x[1] = s;", "x[1] = undefined_name;");
        let err = compile_glsl_source_with(&bad, kind, Path::new("bad.comp"), &dir, true).unwrap_err();
        assert!(err.contains("bad.comp:9"), "the error's line is the source's: {err}");
    }
}
