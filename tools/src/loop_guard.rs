//! `penumbra bench loop-guard`: every scene with every technique that accepts it, rendered with
//! shaders whose loops are counted (`ShaderLibrary::with_loop_guard`), so that no shader comes
//! near lavapipe 22.3's silent per-invocation loop limit (65535 iterations in total) unseen. Per
//! shader: the most loop iterations one invocation ran, where, and how many invocations reached
//! 32768 and 65535. Exit 1 when an invocation reached the limit or a cell failed to render.

use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::engine::glsl_compile::{LOOP_GUARD_LIMIT, LOOP_GUARD_NEAR};
use penumbra::engine::{Context, ContextDesc};
use penumbra::{RenderSettings, Renderer};
use penumbra_passes::registry;
use penumbra_reference::cli::parse_size;
use penumbra_scene::Scene;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

/// The kernel that measures the driver's limit by running past it (not judged).
const LOOP_PROBE: &str = "tests/loop_probe.comp";

#[derive(Args, Clone)]
pub struct LoopGuardArgs {
    /// The compute ray tracer's structure: `auto` (a host-built threaded BVH on a CPU device, the
    /// device-built kd-tree on a GPU), `kdtree` or `bvh`.
    #[arg(long, default_value = "auto", value_parser = crate::parse_tracer)]
    pub tracer: penumbra::engine::TracerStructure,
    /// Comma-separated scene files (default: every built-in scene, as `bench matrix`).
    #[arg(long)]
    pub scenes: Option<String>,
    /// Comma-separated techniques (default: every registered one; each scene's refusals skipped).
    #[arg(long)]
    pub techniques: Option<String>,
    /// A technique parameter for this run, `TECHNIQUE.KEY=VALUE` (repeatable), e.g.
    /// `avs.integration=adf` to guard a non-default mode (the known list is of the defaults: a
    /// cell over the limit fails the run unless listed).
    #[arg(long = "param")]
    pub params: Vec<String>,
    #[arg(long, default_value = "32x24")]
    pub size: String,
    /// Frames per cell (moving: the scene's animation at 30 fps), so that temporal paths and
    /// rebuilds run.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Vulkan validation with synchronization validation (slower).
    #[arg(long)]
    pub validation: bool,
    /// The checked-in list of cells known to reach the limit (default
    /// `tests/loop_guard/known_over_limit.toml`): a cell that reaches it and is not listed, or
    /// is listed and no longer reaches it, fails the run.
    #[arg(long)]
    pub known: Option<PathBuf>,
    /// Output directory: loop_guard.json and loop_guard.md.
    #[arg(long, default_value = "loop-guard-out")]
    pub out: PathBuf,
}

/// One shader's counts over the whole run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ShaderCounts {
    pub shader: String,
    /// Cells (scene, technique) in which an invocation of the shader ran.
    pub cells: u32,
    /// The most loop iterations one invocation ran (every loop of the invocation together).
    pub max_iterations: u32,
    /// The cell of that maximum, `scene/technique`.
    pub max_at: String,
    /// Invocations that reached 32768 iterations, summed over the cells.
    pub near: u64,
    /// Invocations that reached 65535 (truncated on Mesa 22.3's lavapipe).
    pub at_limit: u64,
}

/// One cell of the run.
#[derive(Clone, Debug, Serialize)]
pub struct CellRun {
    pub scene: String,
    pub technique: String,
    /// "ok", "refused: ...", or "error: ...".
    pub status: String,
    pub seconds: f64,
    /// The shaders whose loops ran in this cell: (shader, most iterations, invocations >= 32768,
    /// invocations >= 65535).
    pub shaders: Vec<(String, u32, u32, u32)>,
}

/// A cell known to reach the limit (`tests/loop_guard/known_over_limit.toml`).
#[derive(Clone, Debug, serde::Deserialize, Serialize)]
pub struct KnownOver {
    pub shader: String,
    pub scene: String,
    pub technique: String,
    /// The most iterations measured when it was listed.
    pub max_iterations: u32,
    /// Why, and what would fix it.
    pub why: String,
}

#[derive(Clone, Debug, Default, serde::Deserialize)]
struct KnownList {
    /// The size the list was measured at (`WxH`): only a run at it judges listed cells stale.
    #[serde(default)]
    size: Option<String>,
    #[serde(default)]
    over: Vec<KnownOver>,
}

pub fn run(args: &LoopGuardArgs) -> Result<()> {
    let (w, h) = parse_size(&args.size).map_err(crate::bad)?;
    let overrides = crate::matrix::parse_overrides(&args.params)?;
    let techniques: Vec<&'static registry::TechniqueInfo> = match &args.techniques {
        None => registry::REGISTRY.iter().collect(),
        Some(list) => list
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(|t| registry::lookup(t).map_err(crate::bad))
            .collect::<Result<_>>()?,
    };
    let scenes: Vec<PathBuf> = match &args.scenes {
        None => crate::matrix::default_scenes()?,
        Some(list) => list.split(',').map(str::trim).filter(|s| !s.is_empty()).map(PathBuf::from).collect(),
    };
    for p in &scenes {
        if !p.exists() {
            return Err(crate::bad(format!("{}: no such scene file", p.display())));
        }
    }
    let known_path =
        args.known.clone().unwrap_or_else(|| crate::matrix::repo_root().join("tests/loop_guard/known_over_limit.toml"));
    let known: KnownList = match std::fs::read_to_string(&known_path) {
        Ok(t) => toml::from_str(&t).map_err(|e| crate::bad(format!("{}: {e}", known_path.display())))?,
        Err(e) if args.known.is_some() => return Err(crate::bad(format!("{}: {e}", known_path.display()))),
        Err(_) => KnownList::default(),
    };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let started = Instant::now();
    let shaders = penumbra::shader_library().with_loop_guard()?;
    eprintln!("loop guard: shaders compiled with counted loops in {:.1} s", started.elapsed().as_secs_f64());
    let ctx = Context::new(&ContextDesc {
        validation: args.validation,
        loop_guard: true,
        tracer: args.tracer,
        ..Default::default()
    })?;
    // the driver's own limit (loop_probe): where it truncates, the counts stop where it ended the
    // loops, so a listed cell cannot be judged stale
    let driver_limit = {
        let mut engine = penumbra::engine::Engine::new(ctx.clone(), 1)?;
        penumbra_passes::kernels::loop_probe::loop_limit(&mut engine, &penumbra::shader_library(), 100_000)?
    };
    if let Some(n) = driver_limit {
        eprintln!(
            "loop guard: this driver ends an invocation's loops after {n} iterations: counts of truncated invocations stop there"
        );
    }
    let names: Vec<String> = shaders.names().map(str::to_string).collect();
    let mut counts: Vec<ShaderCounts> =
        names.iter().map(|n| ShaderCounts { shader: n.clone(), ..Default::default() }).collect();
    let mut cells = Vec::new();
    let total = scenes.len() * techniques.len();
    let bar = indicatif::ProgressBar::with_draw_target(Some(total as u64), indicatif::ProgressDrawTarget::stderr());
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} cells, {elapsed} (eta {eta}) {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    for (si, path) in scenes.iter().enumerate() {
        let scene = Scene::load(path).map_err(|e| crate::bad(format!("{}: {e}", path.display())))?;
        if bar.is_hidden() {
            // logs and CI: a line per scene instead of the bar
            eprintln!(
                "[{}/{}] {} ({:.0} s so far)",
                si + 1,
                scenes.len(),
                path.display(),
                started.elapsed().as_secs_f64()
            );
        }
        for t in &techniques {
            bar.inc(1);
            bar.set_message(format!("{} / {}", scene.name, t.name));
            let cell_start = Instant::now();
            let mut in_cell = Vec::new();
            let status = match registry::refusal(t.name, &scene) {
                Some(why) => format!("refused: {why}"),
                None => {
                    ctx.reset_loop_guard();
                    match render_cell(&ctx, &shaders, &scene, t.name, &overrides, w, h, args.frames) {
                        Ok(()) => {
                            let at = format!("{}/{}", scene.name, t.name);
                            let slots = ctx.loop_guard_counts().context("the context has no loop guard")?;
                            for (c, s) in counts.iter_mut().zip(&slots) {
                                let [max, near, limit, ran] = *s;
                                // the driver's loop probe (isg runs it when created) loops past
                                // the limit by design
                                if (ran == 0 && max == 0) || c.shader == LOOP_PROBE {
                                    continue;
                                }
                                c.cells += 1;
                                if max > c.max_iterations {
                                    c.max_iterations = max;
                                    c.max_at = at.clone();
                                }
                                c.near += near as u64;
                                c.at_limit += limit as u64;
                                if max > 0 {
                                    in_cell.push((c.shader.clone(), max, near, limit));
                                }
                            }
                            "ok".to_string()
                        }
                        Err(e) => format!("error: {e:#}"),
                    }
                }
            };
            if status.starts_with("error") {
                bar.println(format!("{} / {}: {status}", scene.name, t.name));
            }
            cells.push(CellRun {
                scene: scene.name.clone(),
                technique: t.name.to_string(),
                status,
                seconds: cell_start.elapsed().as_secs_f64(),
                shaders: in_cell,
            });
        }
    }
    bar.finish_and_clear();
    let rendered = cells.iter().filter(|c| c.status == "ok").count();
    let errors: Vec<&CellRun> = cells.iter().filter(|c| c.status.starts_with("error")).collect();
    let md = table_md(&counts, &ctx.driver_info(), driver_limit, w, h, args.frames, rendered);
    print!("{md}");
    let json = serde_json::json!({
        "device": ctx.device_name,
        "driver": ctx.driver_info(),
        "size": [w, h],
        "frames": args.frames,
        "params": args.params,
        "driver_loop_limit": driver_limit,
        "near": LOOP_GUARD_NEAR,
        "limit": LOOP_GUARD_LIMIT,
        "shaders": counts,
        "cells": cells,
        "seconds": started.elapsed().as_secs_f64(),
    });
    let path = args.out.join("loop_guard.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    std::fs::write(args.out.join("loop_guard.md"), &md)?;
    println!("wrote {} and loop_guard.md ({:.0} s)", path.display(), started.elapsed().as_secs_f64());
    let v = ctx.validation.error_count();
    if v > 0 {
        anyhow::bail!("{v} validation error(s): {:?}", ctx.validation.errors().iter().take(3).collect::<Vec<_>>());
    }
    if !errors.is_empty() {
        anyhow::bail!(
            "{} cell(s) failed to render: {}",
            errors.len(),
            errors.iter().map(|c| format!("{}/{}", c.scene, c.technique)).collect::<Vec<_>>().join(", ")
        );
    }
    let same_size = known.size.as_deref().and_then(|s| parse_size(s).ok()) == Some((w, h));
    // the list is of the defaults: a run with --param judges no listed cell stale
    let problems = check_known(&cells, &known.over, same_size && driver_limit.is_none() && args.params.is_empty());
    if !problems.is_empty() {
        anyhow::bail!(
            "the loop limit ({LOOP_GUARD_LIMIT}) against {}:\n  {}",
            known_path.display(),
            problems.join("\n  ")
        );
    }
    let listed: Vec<String> = cells
        .iter()
        .filter(|c| known.over.iter().any(|k| k.scene == c.scene && k.technique == c.technique))
        .map(|c| format!("{}/{}", c.scene, c.technique))
        .collect();
    if !listed.is_empty() {
        println!("known to reach the limit (listed in {}): {}", known_path.display(), listed.join(", "));
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn render_cell(
    ctx: &std::sync::Arc<Context>,
    shaders: &penumbra::engine::shader::ShaderLibrary,
    scene: &Scene,
    technique: &str,
    overrides: &[(String, String, String)],
    w: u32,
    h: u32,
    frames: u32,
) -> Result<()> {
    let settings = RenderSettings {
        width: w,
        height: h,
        technique: Some(technique.to_string()),
        technique_params: crate::matrix::cell_params(scene, technique, overrides),
        ..Default::default()
    };
    let mut r = Renderer::new_with_shaders(ctx.clone(), scene, settings, shaders)?;
    let mut prev = None;
    for k in 0..frames {
        let t = k as f32 / 30.0;
        r.render(&scene.at(t, prev), None, false)?;
        prev = Some(t);
    }
    r.finish()?;
    Ok(())
}

/// Every cell that reached the limit without being listed, and (`judge_stale`: a run at the list's
/// size) every listed cell that ran and no longer reaches it (the list is kept true both ways, as
/// the matrix's known failures are).
pub fn check_known(cells: &[CellRun], known: &[KnownOver], judge_stale: bool) -> Vec<String> {
    let mut problems = Vec::new();
    for c in cells {
        for (shader, max, _, limit) in &c.shaders {
            let listed = known.iter().any(|k| &k.shader == shader && k.scene == c.scene && k.technique == c.technique);
            if *limit > 0 && !listed {
                problems.push(format!(
                    "{shader} on {}/{}: {limit} invocation(s) reached the limit (most: {max} iterations), not listed",
                    c.scene, c.technique
                ));
            }
        }
    }
    for k in known.iter().filter(|_| judge_stale) {
        let Some(c) = cells.iter().find(|c| c.scene == k.scene && c.technique == k.technique && c.status == "ok")
        else {
            continue;
        };
        if !c.shaders.iter().any(|(s, _, _, limit)| s == &k.shader && *limit > 0) {
            problems.push(format!(
                "{} on {}/{} no longer reaches the limit (listed at {} iterations): remove it from the list",
                k.shader, k.scene, k.technique, k.max_iterations
            ));
        }
    }
    problems
}

/// The per-shader table (README, "lavapipe's loop limit").
fn table_md(
    counts: &[ShaderCounts],
    driver: &str,
    limit: Option<u32>,
    w: u32,
    h: u32,
    frames: u32,
    cells: usize,
) -> String {
    let limit = match limit {
        Some(n) => {
            format!("ends an invocation's loops after {n} iterations (counts of truncated invocations stop there)")
        }
        None => "has no loop limit".to_string(),
    };
    let mut s = format!(
        "Loop guard, {driver} ({limit}), {w}x{h}, {frames} frame(s) per cell, {cells} cells rendered.\n\
         Iterations per invocation (all of its loops, as written in GLSL); Mesa 22.3 truncates at {LOOP_GUARD_LIMIT}, Mesa 25 has no limit.\n\n\
         | shader | cells | most iterations | at (scene/technique) | invocations >= {LOOP_GUARD_NEAR} | >= {LOOP_GUARD_LIMIT} | verdict |\n\
         |---|---|---|---|---|---|---|\n"
    );
    let mut by_dir: BTreeMap<&str, Vec<&ShaderCounts>> = BTreeMap::new();
    for c in counts {
        by_dir.entry(c.shader.split('/').next().unwrap_or("")).or_default().push(c);
    }
    let mut idle = Vec::new();
    for c in by_dir.values().flatten() {
        if c.cells == 0 {
            if c.shader != LOOP_PROBE {
                idle.push(c.shader.as_str());
            }
            continue;
        }
        // llvmpipe counts a loop's iterations per SIMD group (any lane active), so an
        // invocation with half the limit can be cut short (Mesa 22.3 cut isg's at about 33000)
        let verdict = if c.at_limit > 0 {
            "over the limit"
        } else if c.near > 0 {
            "at risk"
        } else {
            "within"
        };
        s.push_str(&format!(
            "| `{}` | {} | {} | {} | {} | {} | {verdict} |\n",
            c.shader,
            c.cells,
            c.max_iterations,
            if c.max_iterations > 0 { c.max_at.as_str() } else { "-" },
            c.near,
            c.at_limit
        ));
    }
    if !idle.is_empty() {
        s.push_str(&format!("\nNot run by any cell: {}.\n", idle.join(", ")));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(scene: &str, technique: &str, shaders: &[(&str, u32, u32)]) -> CellRun {
        CellRun {
            scene: scene.into(),
            technique: technique.into(),
            status: "ok".into(),
            seconds: 0.0,
            shaders: shaders.iter().map(|(s, max, limit)| (s.to_string(), *max, 0, *limit)).collect(),
        }
    }

    fn known(shader: &str, scene: &str, technique: &str) -> KnownOver {
        KnownOver {
            shader: shader.into(),
            scene: scene.into(),
            technique: technique.into(),
            max_iterations: 70000,
            why: String::new(),
        }
    }

    #[test]
    fn the_known_list_must_match_both_ways() {
        let cells = [cell("a", "isg", &[("isg/isg_shade.comp", 70000, 3)]), cell("b", "isg", &[("x.comp", 10, 0)])];
        let listed = [known("isg/isg_shade.comp", "a", "isg")];
        assert!(check_known(&cells, &listed, true).is_empty());
        let p = check_known(&cells, &[], false);
        assert!(p.len() == 1 && p[0].contains("not listed"), "{p:?}");
        let stale = [known("isg/isg_shade.comp", "a", "isg"), known("x.comp", "b", "isg")];
        let p = check_known(&cells, &stale, true);
        assert!(p.len() == 1 && p[0].contains("no longer reaches"), "{p:?}");
        assert!(check_known(&cells, &stale, false).is_empty(), "another size does not judge staleness");
        // a listed cell the run did not render is not judged
        assert!(check_known(&cells[..1], &stale, true).is_empty());
    }
}
