//! `penumbra bench matrix`: every scene x every technique against a converged CPU reference.
//!
//! Per scene: a converged reference (`penumbra_reference::converge`, cached on disk), then each
//! technique rendered at the same size and frame with only its own parameters (a scene's
//! `[technique_params]` belong to the scene's own technique), compared with the reference, and
//! judged against its registered budget (`penumbra_passes::registry::REGISTRY`). Writes
//! `matrix.json` (shape documented in the README), `matrix.md` (the table) and `matrix.png` (the
//! contact sheet), and compares the failing cells with the checked-in known-failures list.

use anyhow::{bail, Context as _, Result};
use clap::Args;
use penumbra::engine::{Context, ContextDesc};
use penumbra::{RenderSettings, Renderer};
use penumbra_passes::registry::{self, Budget, TechniqueInfo, MIN_SHADOW_RECOVERED};
use penumbra_reference::cli::parse_size;
use penumbra_reference::converge::{load_or_render, ConvergeOptions};
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{Mode, ReferenceOptions};
use penumbra_scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// The repository root (scenes/, tests/matrix/), as built.
pub(crate) fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The repository's checked-in converged references (40x30 for the CI test, 160x120 for the
/// default size; `tests/matrix/references*/`).
pub(crate) fn checked_in_references() -> Vec<PathBuf> {
    let dir = repo_root().join("tests/matrix");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir() && p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("references")))
        .collect();
    dirs.sort();
    dirs
}

/// Copies a checked-in reference of exactly this scene file, size, frame and reference version
/// into `cache` when the cache lacks it, so that a fresh clone does not spend hours converging
/// references the repository already holds. `load_or_render` then checks it like any cached one.
pub(crate) fn seed_reference(
    cache: &Path,
    dirs: &[PathBuf],
    scene: &Scene,
    stem: &str,
    scene_bytes: &[u8],
    copts: &ConvergeOptions,
) {
    use penumbra_reference::converge::{cache_path, scene_cache_key};
    let key = scene_cache_key(scene, scene_bytes, copts);
    let dest = cache_path(cache, stem, copts, &key);
    if dest.exists() {
        return;
    }
    for dir in dirs {
        let same = |a: &Path, b: &Path| matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y);
        if same(dir, cache) {
            continue;
        }
        let src = cache_path(dir, stem, copts, &key);
        if src.exists() && src.with_extension("json").exists() {
            let copy = || -> std::io::Result<()> {
                std::fs::create_dir_all(cache)?;
                std::fs::copy(src.with_extension("json"), dest.with_extension("json"))?;
                std::fs::copy(&src, &dest)?;
                Ok(())
            };
            match copy() {
                Ok(()) => eprintln!("  reference seeded from {}", src.display()),
                Err(e) => eprintln!("  reference {}: not copied into {}: {e}", src.display(), cache.display()),
            }
            return;
        }
    }
}

#[derive(Args, Clone)]
pub struct MatrixArgs {
    /// The compute ray tracer's structure: `auto` (a host-built threaded BVH on a CPU device, the
    /// device-built kd-tree on a GPU), `kdtree` or `bvh`.
    #[arg(long, default_value = "auto", value_parser = crate::parse_tracer)]
    pub tracer: penumbra::engine::TracerStructure,
    /// Comma-separated scene files (.toml) or glTF models (.glb/.gltf). Default: every
    /// scenes/*.toml except example.toml, plus the models in scenes/assets/.
    #[arg(long)]
    pub scenes: Option<String>,
    /// Comma-separated techniques. Default: every registered technique.
    #[arg(long)]
    pub techniques: Option<String>,
    /// Image size WxH of the reference and of the compared images.
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Techniques render at N x N the size and are box-filtered down (the reference integrates
    /// each pixel's area; a technique point-samples it).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub supersample: u32,
    /// Target noise of the converged references, in the unit of rmse_rel_mean (RMSE over the
    /// mean radiance), estimated from two independent halves.
    #[arg(long, default_value_t = 0.01)]
    pub noise: f64,
    /// Most reference samples per pixel (the noise target may then be missed: reported).
    #[arg(long, default_value_t = 131072)]
    pub max_spp: u32,
    /// The compared frame K (scene time K / fps; the frame before it is K - 1).
    #[arg(long, default_value_t = 30)]
    pub frame: u32,
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// Frames rendered before timing starts (pipeline creation, first uploads, lavapipe's
    /// shader compilation): frames K - warmup - frames + 1 ...
    #[arg(long, default_value_t = 2)]
    pub warmup: u32,
    /// Timed frames, the last one is frame K (consecutive frames: moving objects move, so
    /// rebuilds and re-uploads are in the cost).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Output directory: matrix.json, matrix.md, matrix.png, images/<scene>/<technique>.exr.
    #[arg(long, default_value = "matrix-out")]
    pub out: PathBuf,
    /// Reference cache directory (default: <temp>/penumbra-references). A reference missing
    /// there is first looked up among the repository's checked-in ones (tests/matrix/references*/,
    /// same scene file, size, frame and version) and copied in.
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// The known-failures list (TOML, `[[cell]]` entries per size). Default:
    /// tests/matrix/known_failing.toml of the repository.
    #[arg(long)]
    pub known: Option<PathBuf>,
    /// Exit with status 1 when the run disagrees with the known-failures list (a failing cell
    /// not on it, or a listed cell that passes).
    #[arg(long)]
    pub check: bool,
    /// Replace this size's entries of the known-failures list with the run's failing cells.
    #[arg(long)]
    pub write_known: bool,
    /// Run every cell under the Vulkan validation layer with synchronization validation: a cell
    /// with validation errors fails, and the run exits with status 1 whatever the known-failures
    /// list says (a wrong barrier is a bug even when the image is right).
    #[arg(long)]
    pub validation: bool,
    /// A technique parameter for this run, TECHNIQUE.KEY=VALUE (repeatable; over the scene's
    /// `[technique_params]` where the scene names that technique), to measure a setting against
    /// the same references. Not with --write-known: the list is of the defaults.
    #[arg(long = "param", value_name = "TECHNIQUE.KEY=VALUE")]
    pub params: Vec<String>,
}

/// One cell of the matrix (the JSON shape other tools read).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Cell {
    pub scene: String,
    pub technique: String,
    /// "ok" | "refused" | "error"
    pub status: String,
    /// Why refused, the error, or why the cell fails (budget, shadows, what it ignored).
    pub reason: Option<String>,
    pub rmse_rel_mean: Option<f64>,
    pub rel_rmse: Option<f64>,
    pub shadow_recovered: Option<f64>,
    pub psnr: Option<f64>,
    pub flip: Option<f64>,
    pub gpu_ms: Option<f64>,
    pub cpu_ms: Option<f64>,
    pub frame_ms: Option<f64>,
    /// The rmse_rel_mean budget applied (null: not judged, the unshadowed baseline).
    pub budget: Option<f64>,
    /// Whether the cell passes (null: not judged: refused, or the baseline).
    pub pass: Option<bool>,
    /// With `--validation`: the validation layer's errors while the cell rendered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_errors: Option<usize>,
}

impl Cell {
    /// A cell with no measurement yet: status "ok", every number null, not judged.
    fn new(scene: &str, technique: &str) -> Self {
        Cell {
            scene: scene.into(),
            technique: technique.into(),
            status: "ok".into(),
            reason: None,
            rmse_rel_mean: None,
            rel_rmse: None,
            shadow_recovered: None,
            psnr: None,
            flip: None,
            gpu_ms: None,
            cpu_ms: None,
            frame_ms: None,
            budget: None,
            pass: None,
            validation_errors: None,
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RefEntry {
    pub scene: String,
    pub spp: u32,
    pub noise_rmse_rel_mean: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Matrix {
    pub device: String,
    pub driver: String,
    pub size: [u32; 2],
    pub references: Vec<RefEntry>,
    pub cells: Vec<Cell>,
}

/// An entry of the known-failures list.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct KnownCell {
    /// Image size WxH of the run the entry is for.
    pub size: String,
    pub scene: String,
    pub technique: String,
    /// The issue that will fix it.
    pub issue: u32,
    pub rmse_rel_mean: Option<f64>,
    pub shadow_recovered: Option<f64>,
    pub reason: String,
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct KnownList {
    #[serde(default)]
    pub cell: Vec<KnownCell>,
}

/// The issue expected to fix a failing cell of `technique` (see `issues list`): a scene that
/// does not load (glTF extensions) goes to the ecosystem issue, the rest to the technique's.
fn issue_for(technique: &str, reason: &str, medium: bool) -> u32 {
    if reason.contains("glTF") || reason.contains(".glb") || reason.contains(".gltf") {
        return 26;
    }
    if medium && technique == "mc" {
        return 21; // mc is unbiased on surfaces; in a medium the volumetric effect's error remains
    }
    match technique {
        "avs" => 18,
        "isg" | "isg-vertex" => 19,
        "shadow-fields" | "shadow-fields-fixed" | "shadow-fields-wavelet" => 20,
        "vv" => 22,
        "mc" | "shadowmaps" => 23,
        _ => 17,
    }
}

pub(crate) fn default_scenes() -> Result<Vec<PathBuf>> {
    let dir = repo_root().join("scenes");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml") && p.file_stem().is_some_and(|s| s != "example"))
        .collect();
    v.sort();
    let assets = dir.join("assets");
    if let Ok(rd) = std::fs::read_dir(&assets) {
        let mut m: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "glb" || e == "gltf"))
            .collect();
        m.sort();
        v.extend(m);
    }
    Ok(v)
}

/// What one technique's run on one scene produced.
pub(crate) struct Run {
    /// Where the set-up time went (printed).
    pub(crate) setup: String,
    pub(crate) image: Image,
    pub(crate) gpu_ms: f64,
    pub(crate) cpu_ms: f64,
    pub(crate) frame_ms: f64,
    pub(crate) spp: Option<u32>,
    pub(crate) ignored: Vec<String>,
}

/// The parameters `technique` is measured with, from those asked for: the reference samples the
/// rasterizer's pixel grid ([`converge_options`]), so `mc`, the reference's GPU twin, samples
/// the same points (`aa = false`) unless `params` say otherwise. `bench pareto` and `tune`
/// record these, so a configuration chosen from a front renders as it was measured.
pub(crate) fn measured_params(technique: &str, mut params: registry::Params) -> registry::Params {
    if technique == "mc" {
        params.entry("aa".into()).or_insert_with(|| "false".into());
    }
    params
}

/// Renders `name` on `scene` as a matrix cell does (warm-up frames, then timed consecutive
/// frames ending at frame K) with `params` (`None`: the renderer's rule, the scene's
/// `[technique_params]` for its own technique only).
pub(crate) fn render_technique(
    ctx: &Arc<Context>,
    scene: &Scene,
    name: &str,
    params: Option<registry::Params>,
    args: &MatrixArgs,
    w: u32,
    h: u32,
) -> Result<Run> {
    let ss = args.supersample.max(1);
    let s = scene.clone();
    let mut settings = RenderSettings {
        width: w * ss,
        height: h * ss,
        technique: Some(name.to_string()),
        technique_params: params,
        ..Default::default()
    };
    let (_, p) = penumbra::resolve_technique(&s, &settings)?;
    settings.technique_params = Some(measured_params(name, p));
    let t_create = Instant::now();
    let mut r = Renderer::new(ctx.clone(), &s, settings)?;
    let create_s = t_create.elapsed().as_secs_f64();
    let ignored = r.technique_limitations();
    let k = args.frame as i64;
    let first = k - (args.warmup + args.frames) as i64 + 1;
    let time = |f: i64| f.max(0) as f32 / args.fps;
    let frame_at = |f: i64| s.at(time(f), if f > 0 { Some(time(f - 1)) } else { None });
    let mut images = Vec::new();
    for f in first..first + args.warmup as i64 {
        images.extend(r.render(&frame_at(f), None, true)?);
    }
    images.extend(r.finish()?);
    let warmup_s = t_create.elapsed().as_secs_f64() - create_s;
    r.engine.profiler.reset();
    let start = Instant::now();
    let mut cpu = 0.0;
    for f in first + args.warmup as i64..=k {
        images.extend(r.render(&frame_at(f), None, true)?);
        cpu += r.technique_cpu_ms;
    }
    images.extend(r.finish()?);
    let frame_ms = start.elapsed().as_secs_f64() * 1e3 / args.frames as f64;
    let last = images.last().context("no frame finished")?;
    if last.hdr.len() != (w * ss * h * ss) as usize {
        bail!("frame read back {} pixels, expected {}", last.hdr.len(), w * ss * h * ss);
    }
    let gpu_ms = crate::bench::technique_gpu_ms(&r);
    Ok(Run {
        setup: format!("created in {create_s:.1} s, warm-up {warmup_s:.1} s"),
        image: crate::bench::downsample(&last.hdr, w, h, ss),
        gpu_ms,
        cpu_ms: cpu / args.frames as f64,
        frame_ms,
        spp: r.technique_samples_per_pixel(),
        ignored,
    })
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |x| format!("{x:.digits$}"))
}

/// The converged reference of `scene`'s frame `frame` at `w` x `h` that the matrix and `bench
/// pareto` compare with (exact mode, to `noise` RMSE over the mean or `max_spp`).
pub(crate) fn converge_options(
    scene: &Scene,
    w: u32,
    h: u32,
    ss: u32,
    frame: u32,
    fps: f32,
    noise: f64,
    max_spp: u32,
) -> ConvergeOptions {
    ConvergeOptions {
        base: ReferenceOptions {
            width: w,
            height: h,
            frame,
            time: None,
            fps,
            mode: Mode::Exact,
            progress: true,
            pixel_grid: ss.max(1),
            ..Default::default()
        },
        target_noise: noise,
        max_spp,
        progress: true,
        label: scene.name.clone(),
        ..Default::default()
    }
}

/// The run's `--param TECHNIQUE.KEY=VALUE` overrides as (technique, key, value), checked before
/// anything renders.
pub(crate) fn parse_overrides(overrides: &[String]) -> Result<Vec<(String, String, String)>> {
    overrides
        .iter()
        .map(|o| {
            let bad = || crate::bad(format!("--param {o}: expected TECHNIQUE.KEY=VALUE"));
            let (t, kv) = o.split_once('.').ok_or_else(bad)?;
            let (k, v) = kv.split_once('=').ok_or_else(bad)?;
            registry::check_name(t).map_err(|e| crate::bad(format!("--param {o}: {e}")))?;
            Ok((t.to_string(), k.trim().to_string(), v.trim().to_string()))
        })
        .collect()
}

/// The parameters of `technique` on `scene` with the run's overrides; `None` (the renderer's
/// rule) when none names the technique.
pub(crate) fn cell_params(
    scene: &Scene,
    technique: &str,
    overrides: &[(String, String, String)],
) -> Option<registry::Params> {
    let mut params: Option<registry::Params> = None;
    for (_, k, v) in overrides.iter().filter(|(t, _, _)| t == technique) {
        params
            .get_or_insert_with(|| {
                if scene.technique == technique {
                    scene.technique_params.clone()
                } else {
                    Default::default()
                }
            })
            .insert(k.clone(), v.clone());
    }
    params
}

pub fn run(args: &MatrixArgs) -> Result<()> {
    let (w, h) = parse_size(&args.size).map_err(crate::bad)?;
    if args.write_known && !args.params.is_empty() {
        return Err(crate::bad("--write-known with --param: the known-failures list is of the default parameters"));
    }
    let overrides = parse_overrides(&args.params)?;
    if !(args.noise.is_finite() && args.noise > 0.0) {
        return Err(crate::bad(format!("--noise {}: must be positive", args.noise)));
    }
    let techniques: Vec<&'static TechniqueInfo> = match &args.techniques {
        None => registry::REGISTRY.iter().collect(),
        Some(list) => {
            let mut v = Vec::new();
            for t in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                v.push(registry::info(t).ok_or_else(|| {
                    crate::bad(format!(
                        "--techniques: '{t}' is not a technique (known: {})",
                        registry::names().join(", ")
                    ))
                })?);
            }
            v
        }
    };
    let scenes: Vec<PathBuf> = match &args.scenes {
        None => default_scenes()?,
        Some(list) => list.split(',').map(str::trim).filter(|s| !s.is_empty()).map(PathBuf::from).collect(),
    };
    for p in &scenes {
        if !p.exists() {
            return Err(crate::bad(format!("{}: no such scene file", p.display())));
        }
    }
    let known_path = args.known.clone().unwrap_or_else(|| repo_root().join("tests/matrix/known_failing.toml"));
    let known: KnownList = match std::fs::read_to_string(&known_path) {
        Ok(t) => toml::from_str(&t).map_err(|e| crate::bad(format!("{}: {e}", known_path.display())))?,
        Err(_) if !args.check => KnownList::default(),
        Err(e) => return Err(crate::bad(format!("{}: {e}", known_path.display()))),
    };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let cache = args.cache.clone().unwrap_or_else(|| std::env::temp_dir().join("penumbra-references"));
    let seeds = checked_in_references();
    let ctx = Context::new(&ContextDesc { validation: args.validation, tracer: args.tracer, ..Default::default() })?;
    // (cell, first messages) of every cell with validation errors
    let mut invalid: Vec<(String, Vec<String>)> = Vec::new();
    let device = ctx.device_name.clone();
    let driver = ctx.driver_info();
    let mut matrix = Matrix { device, driver, size: [w, h], references: Vec::new(), cells: Vec::new() };
    let mut sheet: Vec<(String, Vec<(String, Option<Image>, String, Option<bool>)>)> = Vec::new();
    let mut medium_scenes: Vec<String> = Vec::new();
    let total = scenes.len();
    let started = Instant::now();
    for (si, path) in scenes.iter().enumerate() {
        let stem = path.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default();
        eprintln!("[{}/{total}] {} ({:.0} s so far)", si + 1, path.display(), started.elapsed().as_secs_f64());
        let scene = match Scene::load(path) {
            Ok(s) => s,
            Err(e) => {
                let reason = e.to_string();
                eprintln!("  scene does not load: {reason}");
                for t in &techniques {
                    matrix.cells.push(Cell {
                        status: "error".into(),
                        reason: Some(reason.clone()),
                        pass: Some(false),
                        ..Cell::new(&stem, t.name)
                    });
                }
                sheet.push((stem.clone(), vec![("scene does not load".into(), None, reason, Some(false))]));
                continue;
            }
        };
        if scene.medium.is_some() {
            medium_scenes.push(scene.name.clone());
        }
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let copts = converge_options(&scene, w, h, args.supersample, args.frame, args.fps, args.noise, args.max_spp);
        seed_reference(&cache, &seeds, &scene, &stem, &bytes, &copts);
        let reference = load_or_render(&scene, &bytes, &stem, &copts, Some(&cache))
            .with_context(|| format!("reference of {}", path.display()))?;
        eprintln!(
            "  reference: {} spp, noise {:.4}{}",
            reference.meta.spp,
            reference.meta.noise_rmse_rel_mean,
            if reference.cached { " (cached)" } else { "" }
        );
        let img_dir = args.out.join("images").join(&scene.name);
        std::fs::create_dir_all(&img_dir)?;
        reference.radiance.write_exr(img_dir.join("reference.exr"))?;
        matrix.references.push(RefEntry {
            scene: scene.name.clone(),
            spp: reference.meta.spp,
            noise_rmse_rel_mean: reference.meta.noise_rmse_rel_mean,
        });
        let ref_noise = reference.meta.noise_rmse_rel_mean;
        let mut tiles = vec![(
            "reference".to_string(),
            Some(reference.radiance.clone()),
            format!("{} spp, noise {:.3}", reference.meta.spp, ref_noise),
            None,
        )];
        // The unshadowed error, for shadow_recovered (rendered even when env is not listed).
        let mut env_err: Option<(f64, f64)> = None; // (rel_rmse, rmse_rel_mean)
        let mut order: Vec<&TechniqueInfo> = techniques.clone();
        if !order.iter().any(|t| t.name == "env") {
            order.insert(0, registry::info("env").expect("env is registered"));
        } else {
            order.sort_by_key(|t| t.name != "env");
        }
        for t in order {
            let listed = techniques.iter().any(|x| x.name == t.name);
            let mut cell = Cell::new(&scene.name, t.name);
            if let Some(why) = registry::refusal(t.name, &scene) {
                cell.status = "refused".into();
                cell.reason = Some(why);
            } else {
                let t0 = Instant::now();
                let errors_before = ctx.validation.error_count();
                let messages_before = ctx.validation.errors().len();
                let params = cell_params(&scene, t.name, &overrides);
                let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    render_technique(&ctx, &scene, t.name, params, args, w, h)
                }));
                match run {
                    Ok(Ok(run)) => {
                        let c = compare(&reference.radiance, "reference", &run.image, t.name)?;
                        run.image.write_exr(img_dir.join(format!("{}.exr", t.name)))?;
                        cell.rmse_rel_mean = Some(c.rmse_rel_mean);
                        cell.rel_rmse = Some(c.rel_rmse);
                        cell.psnr = c.psnr_db;
                        cell.flip = Some(c.flip_mean);
                        cell.gpu_ms = Some(run.gpu_ms);
                        cell.cpu_ms = Some(run.cpu_ms);
                        cell.frame_ms = Some(run.frame_ms);
                        if t.name == "env" {
                            env_err = Some((c.rel_rmse, c.rmse_rel_mean));
                        }
                        let mut fails = Vec::new();
                        cell.budget = match t.budget {
                            Budget::RmseRelMean { rmse_rel_mean, .. } => Some(rmse_rel_mean),
                            Budget::Unbiased { factor, .. } => run
                                .spp
                                .filter(|&s| s > 0)
                                .map(|s| factor * ref_noise * (reference.meta.spp as f64 / s as f64).sqrt()),
                            Budget::Baseline { .. } => None,
                        };
                        if let Some(b) = cell.budget {
                            if !(c.rmse_rel_mean <= b) {
                                fails.push(format!("rmse_rel_mean {:.4} > budget {:.4}", c.rmse_rel_mean, b));
                            }
                        } else if !matches!(t.budget, Budget::Baseline { .. }) {
                            fails.push("no samples per pixel reported: budget unknown".into());
                        }
                        if t.shadows {
                            if let Some((env_rel, env_rmm)) = env_err {
                                if env_rmm >= 3.0 * ref_noise && env_rel > 0.0 {
                                    let sr = 1.0 - c.rel_rmse / env_rel;
                                    cell.shadow_recovered = Some(sr);
                                    if !(sr >= MIN_SHADOW_RECOVERED) {
                                        fails.push(format!("shadow_recovered {sr:.3} < {MIN_SHADOW_RECOVERED}"));
                                    }
                                }
                            }
                        }
                        if c.non_finite_b > 0 {
                            // excluded from the metrics above, so they must fail the cell here
                            fails.push(format!("{} pixels are NaN or infinite", c.non_finite_b));
                        }
                        if !run.ignored.is_empty() {
                            fails.push(format!("ignores part of the scene: {}", run.ignored.join("; ")));
                        }
                        if args.validation {
                            let n = ctx.validation.error_count() - errors_before;
                            cell.validation_errors = Some(n);
                            if n > 0 {
                                fails.push(format!("{n} validation error(s)"));
                                let msgs: Vec<String> =
                                    ctx.validation.errors().into_iter().skip(messages_before).take(3).collect();
                                invalid.push((format!("{} x {}", scene.name, t.name), msgs));
                            }
                        }
                        if !matches!(t.budget, Budget::Baseline { .. }) {
                            cell.pass = Some(fails.is_empty());
                        }
                        if !fails.is_empty() {
                            cell.reason = Some(fails.join("; "));
                        }
                        eprintln!(
                            "  {:<20} rmse/mean {:>7.4}  relRMSE {:>7.4}  recovered {:>6}  {:>8.1} ms/frame ({:.0} s: {})  {}",
                            t.name,
                            c.rmse_rel_mean,
                            c.rel_rmse,
                            fmt_opt(cell.shadow_recovered, 3),
                            run.frame_ms,
                            t0.elapsed().as_secs_f64(),
                            run.setup,
                            match cell.pass {
                                Some(true) => "pass",
                                Some(false) => "FAIL",
                                None => "(not judged)",
                            }
                        );
                        if listed {
                            let label = match cell.pass {
                                Some(true) => "pass",
                                Some(false) => "FAIL",
                                None => "baseline",
                            };
                            tiles.push((
                                t.name.to_string(),
                                Some(run.image),
                                format!("{:.3} {label}", c.rmse_rel_mean),
                                cell.pass,
                            ));
                        }
                    }
                    Ok(Err(e)) => {
                        cell.status = "error".into();
                        cell.reason = Some(format!("{e:#}"));
                        cell.pass = Some(false);
                    }
                    Err(p) => {
                        let msg = p
                            .downcast_ref::<String>()
                            .cloned()
                            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
                        cell.status = "error".into();
                        cell.reason = Some(format!("panicked: {}", msg.unwrap_or_default()));
                        cell.pass = Some(false);
                    }
                }
            }
            if cell.status != "ok" {
                eprintln!("  {:<20} {}: {}", t.name, cell.status, cell.reason.as_deref().unwrap_or(""));
                if listed {
                    let label = if cell.status == "refused" { "refused" } else { "ERROR" };
                    tiles.push((t.name.to_string(), None, label.into(), cell.pass));
                }
            }
            if listed {
                matrix.cells.push(cell);
            }
        }
        sheet.push((scene.name.clone(), tiles));
    }
    let json = args.out.join("matrix.json");
    std::fs::write(&json, serde_json::to_string_pretty(&matrix)? + "\n")
        .with_context(|| format!("writing {}", json.display()))?;
    let md = args.out.join("matrix.md");
    std::fs::write(&md, table_md(&matrix, &techniques)).with_context(|| format!("writing {}", md.display()))?;
    let png = args.out.join("matrix.png");
    contact_sheet(&png, &sheet, w, h).with_context(|| format!("writing {}", png.display()))?;
    println!("wrote {}, {} and {}", json.display(), md.display(), png.display());
    let size = format!("{w}x{h}");
    let mismatches = check_known(&matrix, &known, &size);
    let failing = matrix.cells.iter().filter(|c| c.pass == Some(false)).count();
    let passing = matrix.cells.iter().filter(|c| c.pass == Some(true)).count();
    println!("{passing} cells pass, {failing} fail, {} not judged", matrix.cells.len() - passing - failing);
    for r in &matrix.references {
        if r.noise_rmse_rel_mean > args.noise {
            println!(
                "warning: reference of {} reached noise {:.4} only (target {}, {} spp)",
                r.scene, r.noise_rmse_rel_mean, args.noise, r.spp
            );
        }
    }
    if !invalid.is_empty() {
        println!("validation errors in {} cell(s):", invalid.len());
        for (cell, msgs) in &invalid {
            println!("  {cell}:");
            for m in msgs {
                println!("    {m}");
            }
        }
        bail!("the validation layer reported errors in {} cell(s)", invalid.len());
    }
    if args.write_known {
        // the file as it is now, not as it was when the run began: runs at other sizes may have
        // written it meanwhile (only this size's judged cells are replaced)
        let mut list = match std::fs::read_to_string(&known_path) {
            Ok(t) => toml::from_str(&t).map_err(|e| crate::bad(format!("{}: {e}", known_path.display())))?,
            Err(_) => known.clone(),
        };
        // Replace the entries of the cells this run judged; keep the others (other sizes, or
        // cells of scenes and techniques not run this time).
        list.cell.retain(|k| {
            k.size != size || !matrix.cells.iter().any(|c| c.scene == k.scene && c.technique == k.technique)
        });
        for c in matrix.cells.iter().filter(|c| c.pass == Some(false)) {
            list.cell.push(KnownCell {
                size: size.clone(),
                scene: c.scene.clone(),
                technique: c.technique.clone(),
                issue: issue_for(&c.technique, c.reason.as_deref().unwrap_or(""), medium_scenes.contains(&c.scene)),
                rmse_rel_mean: c.rmse_rel_mean.map(|v| (v * 1e4).round() / 1e4),
                shadow_recovered: c.shadow_recovered.map(|v| (v * 1e3).round() / 1e3),
                reason: c.reason.clone().unwrap_or_default(),
            });
        }
        // one order whatever was run: diffs of the list show what changed
        list.cell.sort_by(|a, b| (&a.size, &a.scene, &a.technique).cmp(&(&b.size, &b.scene, &b.technique)));
        let header = "# Known failing cells of the scene x technique accuracy matrix (`penumbra bench matrix`),\n\
# per image size: each with its measured numbers and the issue that will fix it. Written by\n\
# `penumbra bench matrix --write-known`; `tools/tests/matrix.rs` fails when a cell not listed\n\
# fails, and when a listed cell passes (remove it: the list only shrinks). Never loosen a budget\n\
# to shorten it.\n\n";
        std::fs::write(&known_path, format!("{header}{}", toml::to_string(&list)?))
            .with_context(|| format!("writing {}", known_path.display()))?;
        println!("wrote {} ({} entries for {size})", known_path.display(), failing);
    } else if mismatches.is_empty() {
        println!("the failing cells match {} ({size})", known_path.display());
    } else {
        println!("the run disagrees with {} ({size}):", known_path.display());
        for m in &mismatches {
            println!("  {m}");
        }
        if args.check {
            bail!("{} cell(s) disagree with the known-failures list", mismatches.len());
        }
    }
    Ok(())
}

/// Disagreements between the run's judged cells and the known-failures entries of `size`.
pub fn check_known(m: &Matrix, known: &KnownList, size: &str) -> Vec<String> {
    let mut v = Vec::new();
    for c in &m.cells {
        let Some(pass) = c.pass else { continue };
        let listed = known.cell.iter().any(|k| k.size == size && k.scene == c.scene && k.technique == c.technique);
        match (pass, listed) {
            (false, false) => v.push(format!(
                "{} x {}: fails and is not listed ({}; rmse_rel_mean {}, shadow_recovered {})",
                c.scene,
                c.technique,
                c.reason.as_deref().unwrap_or(""),
                fmt_opt(c.rmse_rel_mean, 4),
                fmt_opt(c.shadow_recovered, 3)
            )),
            (true, true) => v.push(format!(
                "{} x {}: listed as failing but passes (rmse_rel_mean {}, shadow_recovered {}): remove it from the list",
                c.scene,
                c.technique,
                fmt_opt(c.rmse_rel_mean, 4),
                fmt_opt(c.shadow_recovered, 3)
            )),
            _ => {}
        }
    }
    v
}

/// The table: one row per scene, per technique `rmse_rel_mean / shadow_recovered` and the verdict.
pub fn table_md(m: &Matrix, techniques: &[&TechniqueInfo]) -> String {
    let mut s = format!(
        "# Accuracy matrix, {}x{} ({}; {})\n\nEach cell: `rmse_rel_mean` / `shadow_recovered`, then pass, **FAIL**, refused or error. \
Budgets (rmse_rel_mean): {}. Shadow techniques also need shadow_recovered >= {MIN_SHADOW_RECOVERED}.\n\n",
        m.size[0],
        m.size[1],
        m.device,
        m.driver,
        techniques
            .iter()
            .map(|t| match t.budget {
                Budget::RmseRelMean { rmse_rel_mean, .. } => format!("{} {rmse_rel_mean}", t.name),
                Budget::Unbiased { factor, .. } => format!("{} {factor}x the reference estimator's noise at its spp", t.name),
                Budget::Baseline { .. } => format!("{} none (baseline)", t.name),
            })
            .collect::<Vec<_>>()
            .join(", ")
    );
    s += "| scene | ref spp / noise |";
    for t in techniques {
        s += &format!(" {} |", t.name);
    }
    s += "\n|---|---|";
    for _ in techniques {
        s += "---|";
    }
    s += "\n";
    let mut scenes: Vec<&str> = Vec::new();
    for c in &m.cells {
        if !scenes.contains(&c.scene.as_str()) {
            scenes.push(&c.scene);
        }
    }
    for sc in scenes {
        let r = m.references.iter().find(|r| r.scene == sc);
        s += &format!("| {sc} | {} |", r.map_or("-".into(), |r| format!("{} / {:.4}", r.spp, r.noise_rmse_rel_mean)));
        for t in techniques {
            let cell = m.cells.iter().find(|c| c.scene == sc && c.technique == t.name);
            s += &match cell {
                None => " |".into(),
                Some(c) if c.status == "refused" => " refused |".into(),
                Some(c) if c.status == "error" => " error |".into(),
                Some(c) => format!(
                    " {} / {} {} |",
                    fmt_opt(c.rmse_rel_mean, 3),
                    fmt_opt(c.shadow_recovered, 2),
                    match c.pass {
                        Some(true) => "pass",
                        Some(false) => "**FAIL**",
                        None => "",
                    }
                ),
            };
        }
        s += "\n";
    }
    s += "\nReasons of failing, refused and erroneous cells:\n\n";
    for c in m.cells.iter().filter(|c| c.pass == Some(false) || c.status != "ok") {
        s += &format!("- {} x {} ({}): {}\n", c.scene, c.technique, c.status, c.reason.as_deref().unwrap_or(""));
    }
    s
}

/// The scale that maps `img`'s mean luminance to 0.18 (middle grey) before the display curve.
fn exposure_key(img: &Image) -> f32 {
    let n = img.pixels.len().max(1) as f64;
    let mean: f64 = img
        .pixels
        .iter()
        .map(|p| (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) as f64)
        .filter(|v| v.is_finite())
        .sum::<f64>()
        / n;
    if mean > 0.0 {
        (0.18 / mean) as f32
    } else {
        1.0
    }
}

/// Display encoding of the contact sheet: `x * key`, Reinhard `x / (1 + x)` (so neither
/// highlights nor bright floors clip), sRGB, 8 bits.
fn display_rgb8(img: &Image, key: f32) -> Vec<u8> {
    img.pixels
        .iter()
        .flat_map(|p| {
            p.map(|c| {
                let x = if c.is_finite() { (c * key).max(0.0) } else { 0.0 };
                (penumbra_reference::metrics::srgb_encode(x / (1.0 + x)) * 255.0 + 0.5) as u8
            })
        })
        .collect()
}

/// The contact sheet: one row per scene, the reference then each technique, each tile labelled
/// with its technique, rmse_rel_mean and verdict (red frame: fails).
pub(crate) fn contact_sheet(
    path: &Path,
    rows: &[(String, Vec<(String, Option<Image>, String, Option<bool>)>)],
    w: u32,
    h: u32,
) -> Result<()> {
    use plotters::prelude::*;
    crate::plot::register_font()?;
    let label_h = 30u32;
    let row_label_w = 120u32;
    let pad = 4u32;
    let cols = rows.iter().map(|r| r.1.len()).max().unwrap_or(1) as u32;
    let tile_w = w.max(150);
    let scale = tile_w as f32 / w as f32;
    let tile_h = (h as f32 * scale).round() as u32;
    let width = row_label_w + cols * (tile_w + pad) + pad;
    let height = rows.len().max(1) as u32 * (tile_h + label_h + pad) + pad;
    let mut buf = vec![40u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        root.fill(&RGBColor(40, 40, 40))?;
        let font = |size: f64, c: RGBColor| (crate::plot::FAMILY, size).into_font().color(&c);
        for (ri, (scene, tiles)) in rows.iter().enumerate() {
            let y0 = (pad + ri as u32 * (tile_h + label_h + pad)) as i32;
            // One exposure per row, from the reference (the first tile), so tiles compare.
            let key = tiles.first().and_then(|t| t.1.as_ref()).map_or(1.0, exposure_key);
            root.draw(&Text::new(scene.clone(), (4, y0 + tile_h as i32 / 2), font(14.0, RGBColor(230, 230, 230))))?;
            for (ci, (name, img, label, pass)) in tiles.iter().enumerate() {
                let x0 = (row_label_w + pad + ci as u32 * (tile_w + pad)) as i32;
                if let Some(img) = img {
                    let rgb = display_rgb8(img, key);
                    for ty in 0..tile_h {
                        for tx in 0..tile_w {
                            let sx = ((tx as f32 / scale) as u32).min(w - 1);
                            let sy = ((ty as f32 / scale) as u32).min(h - 1);
                            let i = ((sy * w + sx) * 3) as usize;
                            root.draw_pixel(
                                (x0 + tx as i32, y0 + ty as i32),
                                &RGBColor(rgb[i], rgb[i + 1], rgb[i + 2]),
                            )?;
                        }
                    }
                } else {
                    root.draw(&Rectangle::new(
                        [(x0, y0), (x0 + tile_w as i32, y0 + tile_h as i32)],
                        RGBColor(70, 70, 70).filled(),
                    ))?;
                }
                let colour = match pass {
                    Some(true) => RGBColor(80, 200, 80),
                    Some(false) => RGBColor(230, 60, 60),
                    None => RGBColor(150, 150, 150),
                };
                root.draw(&Rectangle::new(
                    [(x0, y0), (x0 + tile_w as i32 - 1, y0 + tile_h as i32 - 1)],
                    colour.stroke_width(2),
                ))?;
                root.draw(&Text::new(
                    name.clone(),
                    (x0 + 2, y0 + tile_h as i32 + 2),
                    font(12.0, RGBColor(235, 235, 235)),
                ))?;
                root.draw(&Text::new(label.clone(), (x0 + 2, y0 + tile_h as i32 + 15), font(12.0, colour)))?;
            }
        }
        root.present()?;
    }
    penumbra_reference::image::write_png_rgb8(path, width, height, &buf)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(scene: &str, technique: &str, pass: Option<bool>) -> Cell {
        Cell {
            scene: scene.into(),
            technique: technique.into(),
            status: "ok".into(),
            reason: pass.filter(|p| !p).map(|_| "rmse_rel_mean 0.3 > budget 0.1".into()),
            rmse_rel_mean: Some(0.3),
            rel_rmse: Some(0.2),
            shadow_recovered: Some(0.1),
            psnr: Some(20.0),
            flip: Some(0.1),
            gpu_ms: Some(1.0),
            cpu_ms: Some(0.1),
            frame_ms: Some(2.0),
            budget: Some(0.1),
            pass,
            validation_errors: None,
        }
    }

    fn known(size: &str, scene: &str, technique: &str) -> KnownCell {
        KnownCell {
            size: size.into(),
            scene: scene.into(),
            technique: technique.into(),
            issue: 18,
            rmse_rel_mean: Some(0.3),
            shadow_recovered: Some(0.1),
            reason: String::new(),
        }
    }

    #[test]
    fn checked_in_references_match_their_scenes_and_seed_the_cache() {
        // Every checked-in converged reference must belong to today's scene file (its key hashes
        // the file): a stale one would be silently re-rendered for hours on a fresh clone. Each is
        // seeded into an empty cache and then loads from it without rendering.
        let cache = std::env::temp_dir().join(format!("penumbra-seeded-references-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&cache);
        let dirs = checked_in_references();
        assert!(dirs.len() >= 2, "checked-in reference folders: {dirs:?}");
        let mut checked = 0;
        for dir in &dirs {
            for e in std::fs::read_dir(dir).unwrap().flatten() {
                let p = e.path();
                if p.extension().is_none_or(|x| x != "json") {
                    continue;
                }
                let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
                let file = p.file_name().unwrap().to_string_lossy().to_string();
                // `{stem}-{w}x{h}-f{frame}-{hash}.json`; a stem may hold dashes (bunny-draco).
                let stem = file.rsplitn(4, '-').last().unwrap().to_string();
                let scene_path = [
                    repo_root().join(format!("scenes/{stem}.toml")),
                    repo_root().join(format!("scenes/assets/{stem}.glb")),
                    repo_root().join(format!("scenes/assets/{stem}.gltf")),
                ]
                .into_iter()
                .find(|p| p.exists())
                .unwrap_or_else(|| panic!("{}: no scene file named {stem}", p.display()));
                let scene = Scene::load(&scene_path).unwrap();
                let bytes = std::fs::read(&scene_path).unwrap();
                let (w, h) = (meta["width"].as_u64().unwrap() as u32, meta["height"].as_u64().unwrap() as u32);
                let frame = meta["frame"].as_u64().unwrap() as u32;
                let seeded = cache.join(&file);
                assert!(!seeded.exists());
                // the key does not say the supersampling: the CI size uses 1, the default 2
                let copts = [2, 1]
                    .into_iter()
                    .map(|ss| converge_options(&scene, w, h, ss, frame, 30.0, 0.01, 131072))
                    .find(|c| {
                        seed_reference(&cache, &dirs, &scene, &stem, &bytes, c);
                        seeded.exists()
                    })
                    .unwrap_or_else(|| converge_options(&scene, w, h, 2, frame, 30.0, 0.01, 131072));
                assert!(
                    seeded.exists() && seeded.with_extension("exr").exists(),
                    "{} is stale: it does not belong to today's {} (render it again with `penumbra bench matrix --cache {}`)",
                    p.display(),
                    scene_path.display(),
                    dir.display()
                );
                let c = load_or_render(&scene, &bytes, &stem, &copts, Some(&cache)).unwrap();
                assert!(c.cached, "{file}: seeded but rendered again");
                checked += 1;
            }
        }
        assert!(checked >= 40, "{checked} checked-in references");
        let _ = std::fs::remove_dir_all(&cache);
    }

    #[test]
    fn known_failures_must_match_both_ways() {
        let m = Matrix {
            device: "d".into(),
            driver: "v".into(),
            size: [40, 30],
            references: vec![],
            cells: vec![cell("a", "avs", Some(false)), cell("a", "isg", Some(true)), cell("a", "env", None)],
        };
        // Listed failure: agrees.
        let list = KnownList { cell: vec![known("40x30", "a", "avs")] };
        assert!(check_known(&m, &list, "40x30").is_empty());
        // The same entry for another size does not count: the failure is unexpected.
        let other = KnownList { cell: vec![known("160x120", "a", "avs")] };
        let v = check_known(&m, &other, "40x30");
        assert_eq!(v.len(), 1);
        assert!(v[0].contains("fails and is not listed"), "{v:?}");
        // A listed cell that passes must be removed.
        let stale = KnownList { cell: vec![known("40x30", "a", "avs"), known("40x30", "a", "isg")] };
        let v = check_known(&m, &stale, "40x30");
        assert_eq!(v.len(), 1);
        assert!(v[0].contains("passes") && v[0].contains("isg"), "{v:?}");
        // Cells not judged (the baseline) never disagree.
        let base = KnownList { cell: vec![known("40x30", "a", "avs"), known("40x30", "a", "env")] };
        assert!(check_known(&m, &base, "40x30").is_empty());
        // The list round-trips through TOML.
        let text = toml::to_string(&stale).unwrap();
        let back: KnownList = toml::from_str(&text).unwrap();
        assert_eq!(back.cell.len(), 2);
        // The table names every cell's verdict.
        let md = table_md(
            &m,
            &[registry::info("env").unwrap(), registry::info("avs").unwrap(), registry::info("isg").unwrap()],
        );
        assert!(md.contains("**FAIL**") && md.contains("pass") && md.contains("| a |"), "{md}");
    }
}
