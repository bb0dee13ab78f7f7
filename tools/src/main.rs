//! `penumbra`: render scenes on the GPU, render ground truth on the CPU, compare images.
//!
//! Exit codes: 0 success; 1 a run-time failure (Vulkan, validation errors with --validate);
//! 2 bad input (scene/model/image files, arguments).

// The doc comments of the clap argument structs are the `--help` text, plain text rather than
// Markdown: `<technique>.exr` and a scene's `[medium]` table are meant literally there.
#![allow(rustdoc::invalid_html_tags, rustdoc::broken_intra_doc_links)]

use anyhow::{Context as _, Result};
use clap::{Args, Parser, Subcommand};
use penumbra::engine::dump;
use penumbra::{RenderSettings, Renderer};
use penumbra_reference::cli::{parse_size, CompareArgs, ReferenceArgs};
use penumbra_reference::image::write_png_rgb8;
use penumbra_scene::{Limits, LoadOptions, Scene, SceneError};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod avs_bench;
mod bench;
mod chrome_trace;
mod graph_html;
mod hsdt_bench;
mod isg_bench;
mod loop_guard;
mod matrix;
mod pareto;
mod plot;
mod renderdoc_capture;
mod soak;
mod spheres;
mod tune;
mod view;
mod vv;
mod vv_bench;

#[derive(Parser)]
#[command(name = "penumbra", version, about = "Vulkan rendering of dynamic scenes under all-frequency lighting", long_about = None)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    /// Host memory a scene may take to load (meshes, textures, environment map), in MiB,
    /// checked from file headers and glTF accessor counts before anything is allocated.
    #[arg(long, global = true, value_name = "MIB", default_value_t = 1024, value_parser = clap::value_parser!(u64).range(1..))]
    memory_budget: u64,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render frames of a scene on the GPU (the built-in default scene without SCENE).
    ///
    /// Writes DIR/frame_NNNN.exr (linear float radiance) and DIR/frame_NNNN.png (tone-mapped
    /// sRGB) per frame, DIR/graph.json, DIR/graph.dot and DIR/graph.txt (the last frame's
    /// compiled render graph: passes, culled passes and why, barriers, resources), DIR/graph.html
    /// (the same graph for a person: one self-contained page with the passes on a GPU timeline,
    /// resource lifetimes, barriers per pass and thumbnails of the last frame's images) and
    /// DIR/profile.json (per-pass GPU median/min/max ms from timestamps, CPU compile and record ms).
    Render(RenderArgs),
    /// Render CPU ground truth (Monte Carlo, exact visibility) of a scene frame.
    Reference(ReferenceArgs),
    /// Compare two EXR images (A is the reference): PSNR, RMSE, FLIP, difference image.
    Compare(CompareArgs),
    /// Benchmarks: accuracy against the CPU reference and speed ratios, in one run.
    #[command(subcommand)]
    Bench(BenchCmd),
    /// Offline precomputation for techniques.
    #[command(subcommand)]
    Precompute(PrecomputeCmd),
    /// Show a scene live in a window (Esc quits, Space pauses, Left/Right step while paused,
    /// T next technique, P screenshot, G frame-graph dump); `--frames N --screenshot FILE` for
    /// scripts (e.g. under xvfb-run).
    View(view::ViewArgs),
    /// List every registered technique and effect: summary, requirements, accuracy budget and
    /// parameters (key, default, accepted values), as scene files and --param take them.
    Techniques,
    /// The cheapest technique and parameters whose error (RMSE over the converged reference's
    /// mean) is at most --max-error on a scene: measured at --size as `bench pareto` measures
    /// (or read from its pareto.json with --pareto); prints the choice, its error and cost, and
    /// with --write stores it in the scene file. `render` and `view` take --max-error too.
    Tune(tune::TuneArgs),
    /// Approximate a closed mesh by N spheres (blockers of the ISG technique) and report the
    /// fraction of its volume they cover and the volume they put outside it.
    Spheres(spheres::SpheresArgs),
    /// Generated models: `asset walker` writes the procedural walking figure with a hat (the
    /// adaptive visibility sampling paper's third scene; `scenes/paper/walker.glb` is its output).
    #[command(subcommand)]
    Asset(AssetCmd),
}

#[derive(Subcommand)]
enum AssetCmd {
    /// A skinned figure (17.3k vertices, 14 joints, four materials) with a rigid hat on its
    /// head joint, and one looping animation, `walk`: 8 s, once around a circle of radius 1.2 m
    /// about the origin, a stride a second.
    Walker {
        /// Where to write the .glb.
        #[arg(long, default_value = "scenes/paper/walker.glb")]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum BenchCmd {
    /// Adaptive visibility sampling (`avs`): the paper's Table 1 columns per scene (the three
    /// paper scenes without SCENE), error against the reference, the MC baseline at the same time
    /// and to the same error, adaptive vs brute-force visibility maps at r = 64/128/256, and an
    /// E_v,max x r sweep.
    Avs(avs_bench::AvsArgs),
    /// The scene x technique accuracy matrix: every scene (default: scenes/*.toml and the models
    /// in scenes/assets) with every registered technique against a converged, cached CPU
    /// reference; rmse_rel_mean, rel_rmse, shadow_recovered, PSNR, FLIP and frame cost per cell,
    /// judged by each technique's registered budget; writes matrix.json, matrix.md and the
    /// contact sheet matrix.png, and compares the failing cells with the known-failures list.
    Matrix(matrix::MatrixArgs),
    /// Techniques against the CPU reference (PSNR, relative RMSE, FLIP) and against each other
    /// (GPU ms per frame and ratios), on the same scene, camera and frame; writes bench.json.
    Techniques(bench::BenchArgs),
    /// The speed/accuracy trade on one scene: every technique that accepts it at its defaults
    /// and at each value of each registered knob (one at a time), each point timed over moving
    /// frames after warm-up (wall clock, GPU and CPU ms) and compared with the converged
    /// reference; marks the front (ms against RMSE over the mean) and writes pareto.json,
    /// pareto.md and log-log charts (pareto.png, pareto_WxH.png); --sizes repeats it per size.
    Pareto(pareto::ParetoArgs),
    /// Memory over time: each technique renders --frames frames of an animated scene (the
    /// built-in default scene without SCENE) at a small size; host RSS and device memory are
    /// sampled and must stay flat after --warmup frames (exit 1 when they grow); writes soak.json.
    Soak(soak::SoakArgs),
    /// The loop guard: every scene with every technique that accepts it, rendered with shaders
    /// whose loops are counted; per shader the most loop iterations one invocation ran (lavapipe
    /// in Mesa 22.3 silently ends an invocation's loops at 65535 in total) and where; exit 1
    /// when an invocation reached the limit; writes loop_guard.json and loop_guard.md.
    LoopGuard(loop_guard::LoopGuardArgs),
    /// Volumetric shadows: the temporal method against the full baseline on the same frames
    /// (GPU ms per pass, speedup, marched fraction, image difference, missed pixels).
    Volumetric(bench::VolumetricArgs),
    /// The compute kd-tree tracer against obvhs on the CPU (all cores): build ms, memory, and
    /// million rays/s for coherent and incoherent visibility rays, in one run.
    Trace(bench::TraceArgs),
    /// Shadow fields: per-shell resolutions after adaptation, data size fixed vs adaptive,
    /// per-vertex error adaptive vs fixed and GPU vs CPU, ms per frame GPU vs CPU path.
    /// Then the image errors of the variants (adaptive/fixed, pixel/vertex mode, windows, with and
    /// without source radiance fields) against the CPU reference at --size (skip: --no-images).
    ShadowFields(bench::ShadowFieldsArgs),
    /// Vectorized visibility: the previous method (eq. 19, three evaluations) against the
    /// interpolated one (eq. 21) under dynamic tessellation for zeta = 1..4 and per fragment:
    /// ms per frame, ratio, PSNR against the reference, triangles after tessellation, precompute.
    Vv(vv_bench::VvArgs),
    /// ISG shadows per pixel and per vertex against the full and the SG-lighting references:
    /// GPU ms per pass and per frame, PSNR/relative RMSE, speedup over the reference renderer,
    /// per-vertex interpolation error.
    Isg(isg_bench::IsgArgs),
    /// Hemispherical distance transform (issue 8): t_S per point and per 1000 points on the GPU
    /// against the CPU, GPU fp16 and the HSDT against the exact brute-force transform, and the two
    /// SSDF lighting integrals against brute-force integration (errors per sharpness, us per lobe).
    Hsdt(hsdt_bench::HsdtArgs),
}

#[derive(Subcommand)]
enum PrecomputeCmd {
    /// Object occlusion fields of every mesh of a scene or model (fixed and adaptive shells,
    /// 8-bit SH coefficients), one file per object and variant: OUT/<mesh>.{fixed,adaptive}.psf.
    ShadowField(bench::ShadowFieldArgs),
    /// Vectorized visibility per vertex and the spherical-Voronoi correspondence per triangle
    /// of a static scene or model (issue 9), one file: OUT (default <model stem>.pvv); sizes and
    /// times; `--check FILE` validates an existing file against the model.
    Vv(vv::VvArgs),
}

#[derive(Args)]
struct RenderArgs {
    /// Scene file (.toml) or a bare glTF model (.glb/.gltf); the built-in default scene when omitted.
    scene: Option<PathBuf>,
    /// Number of frames; frame k is the scene at time k / fps.
    #[arg(long, default_value_t = 1)]
    frames: u32,
    /// Frames per second of scene time.
    #[arg(long, default_value_t = 30.0)]
    fps: f32,
    /// Image size WxH.
    #[arg(long, default_value = "640x480")]
    size: String,
    /// Output directory.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Enable the Khronos validation layer with synchronization validation; exit 1 (printing the
    /// count and the messages) if it reported any error.
    #[arg(long)]
    validate: bool,
    /// Also print the compiled graph of the last frame as text.
    #[arg(long)]
    dump_graph: bool,
    /// Also print the per-pass GPU timing table and draw it as DIR/profile.png (bars, recording order).
    #[arg(long)]
    profile: bool,
    /// Also write every intermediate image (G-buffer, HDR) of every frame to DIR/passes/ as EXR.
    #[arg(long)]
    dump_passes: bool,
    /// Also write a Chrome trace event file (opens in Perfetto and chrome://tracing): every
    /// frame's CPU spans (graph build, technique, compile, record, submit, waits) and its
    /// passes' GPU intervals, on their own tracks.
    #[arg(long, value_name = "FILE.json")]
    trace: Option<PathBuf>,
    /// Capture frame N (0-based) with RenderDoc's in-application API and print the capture's
    /// path. penumbra must run under RenderDoc (`renderdoccmd capture -w penumbra render ...
    /// --renderdoc-capture N`, or launched from qrenderdoc); without it: exit 2, saying so.
    #[arg(long, value_name = "N")]
    renderdoc_capture: Option<u32>,
    #[command(flatten)]
    o: SceneOverrides,
}

/// What `render` and `view` override in a scene, and how they present it.
#[derive(Args)]
pub struct SceneOverrides {
    /// Exposure applied before tone mapping.
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// Use the Vulkan device whose name contains this.
    #[arg(long)]
    pub device: Option<String>,
    /// The compute ray tracer's structure: `auto` (a threaded BVH built on the host on a CPU
    /// device such as lavapipe, where its walk is 2-3x faster; the kd-tree built on the device
    /// on a GPU), `kdtree` or `bvh`. Images agree; only the time differs.
    #[arg(long, default_value = "auto", value_parser = parse_tracer)]
    pub tracer: penumbra::engine::TracerStructure,
    /// Override the scene's technique (`auto`, `env`, `isg`, `avs`, ...: the README's technique table).
    #[arg(long)]
    pub technique: Option<String>,
    /// Volumetric method for scenes with a medium: temporal (default) or full.
    #[arg(long)]
    pub volumetric: Option<String>,
    /// A technique parameter KEY=VALUE (repeatable; overrides the scene's [technique_params]).
    /// The keys depend on the technique; an unknown key is an error that lists the known ones.
    #[arg(long = "param", value_name = "KEY=VALUE")]
    pub params: Vec<String>,
    /// Choose the technique: the cheapest whose error (RMSE over the converged reference's mean)
    /// is at most E on this scene, measured at the render size (at most 160x120, same aspect) as
    /// `penumbra tune` measures, cached; an error when nothing reaches E.
    #[arg(long, value_name = "E", conflicts_with_all = ["technique", "params"])]
    pub max_error: Option<f64>,
    /// With --max-error: choose from this `bench pareto` output instead of measuring.
    #[arg(long, value_name = "PARETO_JSON", requires = "max_error")]
    pub pareto: Option<PathBuf>,
}

/// `--tracer auto|kdtree|bvh`.
pub fn parse_tracer(s: &str) -> std::result::Result<penumbra::engine::TracerStructure, String> {
    penumbra::engine::TracerStructure::parse(s).ok_or_else(|| format!("unknown tracer '{s}' (auto, kdtree, bvh)"))
}

/// `--max-error`: replaces the scene's technique and parameters with the tuned choice.
fn apply_max_error(
    mut scene: Scene,
    path: Option<&Path>,
    o: &SceneOverrides,
    width: u32,
    height: u32,
) -> Result<Scene> {
    let Some(e) = o.max_error else { return Ok(scene) };
    let opts = tune::TuneOptions::for_render(e, o.pareto.clone(), width, height);
    if opts.size != (width, height) {
        eprintln!(
            "note: --max-error measures errors at {}x{} (renders above 160x120 are measured smaller)",
            opts.size.0, opts.size.1
        );
    }
    let choice = tune::tune(path, &scene, &opts)?;
    eprintln!("note: --max-error {e}: {}", choice.describe(e));
    scene.technique = choice.point.technique.clone();
    scene.technique_params = choice.point.params.clone();
    Ok(scene)
}

/// An error caused by the user's input: exit code 2.
#[derive(Debug)]
struct BadInput(String);
impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for BadInput {}

pub(crate) fn bad(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(BadInput(e.to_string()))
}

fn load_scene(path: Option<&Path>, limits: &Limits) -> Result<Scene> {
    let scene = match path {
        None => Scene::default_scene(),
        Some(p) => {
            let opts = LoadOptions { limits: *limits, ..Default::default() };
            Scene::load_with(p, &opts).map_err(|e: SceneError| bad(e))?
        }
    };
    // The scene crate keeps the technique as written; the registry decides what exists.
    if let (Err(e), Some(p)) = (penumbra_passes::registry::check_name(&scene.technique), path) {
        return Err(bad(format!("{}: {e}", p.display())));
    }
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    Ok(scene)
}

/// Applies `--technique`, `--param` and `--volumetric` to a loaded scene (bad values: exit 2).
fn apply_overrides(
    mut scene: Scene,
    technique: &Option<String>,
    params: &[String],
    volumetric: &Option<String>,
) -> Result<Scene> {
    if let Some(t) = technique {
        penumbra_passes::registry::check_name(t).map_err(|e| bad(format!("--technique {t}: {e}")))?;
    }
    if let Some(v) = volumetric {
        penumbra_passes::volumetric::VolumetricMethod::parse(v).map_err(|e| bad(format!("--volumetric: {e}")))?;
    }
    if let Some(t) = technique {
        if *t != scene.technique && !scene.technique_params.is_empty() {
            eprintln!("note: the scene's [technique_params] belong to '{}' and are not used by '{t}'", scene.technique);
            scene.technique_params.clear();
        }
        scene.technique = t.clone();
    }
    for p in params {
        let (k, v) = p.split_once('=').ok_or_else(|| bad(format!("--param {p}: expected KEY=VALUE")))?;
        scene.technique_params.insert(k.trim().to_string(), v.trim().to_string());
    }
    Ok(scene)
}

/// A renderer for `scene` (its errors keep their kind: see [`exit_code`]).
fn new_renderer(
    ctx: std::sync::Arc<penumbra::engine::Context>,
    scene: &Scene,
    settings: RenderSettings,
) -> Result<Renderer> {
    Ok(Renderer::new(ctx, scene, settings)?)
}

/// The exit code of a failed command: 2 bad input (the user's to fix: a scene file, a flag, a
/// technique name or parameter), 3 out of memory, 4 the device was lost, 1 anything else
/// (including validation errors and images that fail a check).
fn exit_code(e: &anyhow::Error) -> u8 {
    if e.downcast_ref::<BadInput>().is_some() {
        return 2;
    }
    match e.downcast_ref::<penumbra::Error>().map(penumbra::Error::kind) {
        Some(penumbra::ErrorKind::BadInput) => 2,
        Some(penumbra::ErrorKind::OutOfMemory) => 3,
        Some(penumbra::ErrorKind::DeviceLost) => 4,
        _ => 1,
    }
}

/// Prints the validation layer's counts; an error when it reported any (exit 1).
fn report_validation(log: &penumbra::engine::ValidationLog) -> Result<()> {
    let n = log.error_count();
    println!("validation: {n} error(s), {} warning(s)", log.warning_count());
    if n > 0 {
        for m in log.errors() {
            println!("  {m}");
        }
        anyhow::bail!("the validation layer reported {n} error(s)");
    }
    Ok(())
}

fn write_frame(out: &Path, index: u32, img: &penumbra::FrameImages) -> Result<()> {
    let exr = out.join(format!("frame_{index:04}.exr"));
    bench::hdr_image(img).write_exr(&exr).with_context(|| format!("writing {}", exr.display()))?;
    let png = out.join(format!("frame_{index:04}.png"));
    let rgb: Vec<u8> = img.ldr.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
    write_png_rgb8(&png, img.width, img.height, &rgb).with_context(|| format!("writing {}", png.display()))?;
    if !img.dumps.is_empty() {
        let dir = out.join("passes");
        std::fs::create_dir_all(&dir)?;
        for (name, texels) in &img.dumps {
            let path = dir.join(format!("frame_{index:04}_{name}.exr"));
            bench::downsample(texels, img.width, img.height, 1)
                .write_exr(&path)
                .with_context(|| format!("writing {}", path.display()))?;
        }
    }
    Ok(())
}

fn render(args: &RenderArgs, limits: &Limits) -> Result<()> {
    let (width, height) = parse_size(&args.size).map_err(bad)?;
    if args.frames == 0 {
        return Err(bad("--frames must be at least 1"));
    }
    if !(args.fps.is_finite() && args.fps > 0.0) {
        return Err(bad("--fps must be a positive number"));
    }
    let mut capture =
        args.renderdoc_capture.map(|n| renderdoc_capture::FrameCapture::new(n, args.frames)).transpose()?;
    let scene = load_scene(args.scene.as_deref(), limits)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let settings = RenderSettings {
        width,
        height,
        tonemap: penumbra_passes::tonemap::TonemapParams { exposure: args.o.exposure },
        technique: args.o.technique.clone(),
        dump_passes: args.dump_passes,
        effects: penumbra_passes::effect::EffectOverrides { volumetric: args.o.volumetric.clone() },
        ..Default::default()
    };
    let scene = apply_overrides(scene, &args.o.technique, &args.o.params, &args.o.volumetric)?;
    let scene = apply_max_error(scene, args.scene.as_deref(), &args.o, width, height)?;
    let ctx = penumbra::engine::Context::new(&penumbra::engine::ContextDesc {
        validation: args.validate,
        device_name: args.o.device.clone(),
        tracer: args.o.tracer,
        ..Default::default()
    })?;
    let mut r = new_renderer(ctx, &scene, settings)?;
    for l in r.notes() {
        eprintln!("note: {l}");
    }
    if r.repaired_env_texels() > 0 {
        eprintln!("warning: {} environment texels were NaN/Inf/negative and were set to 0", r.repaired_env_texels());
    }
    println!(
        "penumbra: scene '{}' ({} objects, {} vertices, {} triangles) at {width}x{height} on {}",
        scene.name,
        scene.objects.len(),
        r.scene_gpu().vertex_count,
        r.scene_gpu().triangle_count,
        r.context().device_name
    );
    let mut written = 0;
    let mut timelines = Vec::new();
    // the last frame's images, for graph.html's thumbnails
    let mut last = None;
    let mut prev_t = None;
    // A progress bar on terminals only (hidden in CI and pipes).
    let bar =
        indicatif::ProgressBar::with_draw_target(Some(args.frames as u64), indicatif::ProgressDrawTarget::stderr());
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames, {elapsed} (eta {eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    if args.frames < 2 {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    for k in 0..args.frames {
        bar.inc(1);
        let t = k as f32 / args.fps;
        let frame = scene.at(t, prev_t);
        prev_t = Some(t);
        let done = match capture.as_mut() {
            Some(c) => c.around(k, || Ok(r.render(&frame, None, true)?))?,
            None => r.render(&frame, None, true)?,
        };
        for img in done {
            write_frame(&args.out, img.frame as u32, &img)?;
            timelines.push((img.frame, img.timeline.clone()));
            last = Some(img);
            written += 1;
        }
    }
    for img in r.finish()? {
        write_frame(&args.out, img.frame as u32, &img)?;
        timelines.push((img.frame, img.timeline.clone()));
        last = Some(img);
        written += 1;
    }
    if let Some(path) = &args.trace {
        chrome_trace::write(path, &timelines)?;
        println!("wrote the trace {} (open it in ui.perfetto.dev or chrome://tracing)", path.display());
    }
    bar.finish_and_clear();
    let graph = r.last_graph.as_ref().context("no frame was compiled")?;
    let timings = r.engine.profiler.gpu_stats();
    let json = dump::to_json(graph, Some(&timings));
    std::fs::write(args.out.join("graph.json"), serde_json::to_string_pretty(&json)? + "\n")?;
    std::fs::write(args.out.join("graph.dot"), dump::to_dot(graph))?;
    let thumbs = last.as_ref().map(graph_html::thumbnails).unwrap_or_default();
    let title = format!(
        "{}: frame graph of frame {} ({}, {width}x{height})",
        scene.name,
        last.as_ref().map_or(0, |l| l.frame),
        r.technique_name()
    );
    std::fs::write(
        args.out.join("graph.html"),
        penumbra::engine::dump_html::to_html(graph, Some(&timings), &title, &thumbs),
    )?;
    let text = dump::to_text(graph, Some(&timings));
    std::fs::write(args.out.join("graph.txt"), &text)?;
    let mut profile = r.engine.profiler.to_json();
    profile["device"] = serde_json::json!(r.context().device_name);
    profile["driver"] = serde_json::json!(r.context().driver_info());
    profile["size"] = serde_json::json!([width, height]);
    profile["scene"] = serde_json::json!(scene.name);
    std::fs::write(args.out.join("profile.json"), serde_json::to_string_pretty(&profile)? + "\n")?;
    println!(
        "wrote {written} frame(s), graph.json, graph.dot, graph.txt, graph.html and profile.json to {}",
        args.out.display()
    );
    if args.dump_graph {
        print!("{text}");
    }
    if args.profile {
        print!("{}", r.engine.profiler.table());
        // The same medians as a picture, passes in recording order.
        let bars: Vec<(String, f64)> = profile["passes"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|p| {
                        (
                            p["pass"].as_str().unwrap_or("?").to_string(),
                            p["gpu_ms"]["median_ms"].as_f64().unwrap_or(f64::NAN),
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
        let title = format!(
            "{}: GPU ms per pass (median over the frames that ran it), {}",
            scene.name,
            r.context().device_name
        );
        let path = args.out.join("profile.png");
        match plot::write_bars(&path, &title, "ms", &bars) {
            Ok(()) => println!("wrote {}", path.display()),
            Err(e) => println!("no profile chart: {e:#}"),
        }
    }
    if args.validate {
        let log = r.context().validation.clone();
        drop(r);
        report_validation(&log)?;
    }
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    let limits = Limits::with_memory_mib(cli.memory_budget);
    match cli.cmd {
        Cmd::Render(a) => render(&a, &limits),
        Cmd::Asset(AssetCmd::Walker { out }) => {
            let bytes = penumbra_scene::walker::walker_glb();
            std::fs::write(&out, &bytes).map_err(|e| bad(format!("{}: cannot write: {e}", out.display())))?;
            println!(
                "wrote {} ({} bytes, {} vertices, animation 'walk' of {} s)",
                out.display(),
                bytes.len(),
                penumbra_scene::walker::vertex_count(),
                penumbra_scene::walker::WALK_DURATION
            );
            Ok(())
        }
        Cmd::Techniques => {
            print!("{}", penumbra_passes::registry::describe());
            Ok(())
        }
        Cmd::View(a) => view::view(&a, &limits),
        Cmd::Tune(a) => tune::run(&a, &limits),
        Cmd::Reference(a) => {
            let scene = load_scene(a.scene.as_deref(), &limits)?;
            a.options().map_err(bad)?;
            penumbra_reference::cli::run_reference(&a, &scene)
        }
        Cmd::Bench(BenchCmd::Volumetric(a)) => {
            parse_size(&a.size).map_err(bad)?;
            let scene = load_scene(Some(&a.scene), &limits)?;
            if scene.medium.is_none() {
                return Err(bad(format!("{}: the scene has no [medium]", a.scene.display())));
            }
            bench::run_volumetric(&a, &scene)
        }
        Cmd::Bench(BenchCmd::Avs(a)) => {
            parse_size(&a.size).map_err(bad)?;
            let mut params = std::collections::BTreeMap::new();
            for p in &a.params {
                let (k, v) = p.split_once('=').ok_or_else(|| bad(format!("--param '{p}': expected KEY=VALUE")))?;
                params.insert(k.trim().to_string(), v.trim().to_string());
            }
            penumbra_passes::avs::AvsSettings::from_params(&params).map_err(bad)?;
            avs_bench::run(&a, |p| load_scene(Some(p), &limits))
        }
        Cmd::Bench(BenchCmd::Trace(a)) => {
            parse_size(&a.size).map_err(bad)?;
            let scene = load_scene(a.scene.as_deref(), &limits)?;
            bench::run_trace(&a, &scene)
        }
        Cmd::Bench(BenchCmd::Hsdt(a)) => {
            a.resolutions().map_err(bad)?;
            hsdt_bench::run(&a)
        }
        Cmd::Bench(BenchCmd::Vv(a)) => {
            parse_size(&a.size).map_err(bad)?;
            let scene = load_scene(Some(&a.scene), &limits)?;
            vv_bench::run(&a, &scene)
        }
        Cmd::Bench(BenchCmd::ShadowFields(a)) => {
            a.params.check().map_err(bad)?;
            let scene = load_scene(a.scene.as_deref(), &limits)?;
            bench::run_shadow_fields(&a, &scene)
        }
        Cmd::Precompute(PrecomputeCmd::Vv(a)) => {
            let scene = load_scene(Some(&a.model), &limits)?;
            vv::run(&a, &scene)?.map_err(bad)
        }
        Cmd::Precompute(PrecomputeCmd::ShadowField(a)) => {
            a.params.check().map_err(bad)?;
            let scene = load_scene(Some(&a.model), &limits)?;
            bench::run_precompute_shadow_field(&a, &scene)
        }
        Cmd::Bench(BenchCmd::Isg(a)) => {
            parse_size(&a.size).map_err(bad)?;
            let scene = load_scene(a.scene.as_deref(), &limits)?;
            a.scene_with_params(&scene).map_err(bad)?;
            isg_bench::run_isg(&a, &scene)
        }
        Cmd::Bench(BenchCmd::Matrix(a)) => matrix::run(&a),
        Cmd::Bench(BenchCmd::Pareto(a)) => pareto::run(&a),
        Cmd::Bench(BenchCmd::LoopGuard(a)) => loop_guard::run(&a),
        Cmd::Bench(BenchCmd::Soak(a)) => {
            let scene = load_scene(a.scene.as_deref(), &limits)?;
            soak::run(&a, &scene)
        }
        Cmd::Bench(BenchCmd::Techniques(a)) => {
            parse_size(&a.size).map_err(bad)?;
            for t in a.techniques.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                penumbra_passes::registry::lookup(t).map_err(bad)?;
            }
            let scene = load_scene(a.scene.as_deref(), &limits)?;
            bench::run(&a, &scene)
        }
        Cmd::Spheres(a) => {
            let scene = load_scene(Some(&a.mesh), &limits)?;
            // Every failure here is about the input mesh or arguments.
            spheres::run(&a, &scene).map_err(|e| bad(format!("{e:#}")))
        }
        Cmd::Compare(a) => {
            for p in [&a.a, &a.b] {
                if !p.exists() {
                    return Err(bad(format!("{}: no such file", p.display())));
                }
            }
            penumbra_reference::cli::run_compare(&a).map_err(|e| {
                // Image decoding problems are bad input.
                if format!("{e:#}").contains(".exr") {
                    bad(format!("{e:#}"))
                } else {
                    e
                }
            })
        }
    }
}

fn main() -> ExitCode {
    // The Vulkan loader warns on every start when XDG_RUNTIME_DIR is unset (containers, CI).
    // The binary owns its environment; the library never changes the host's.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        let dir = std::env::temp_dir().join("penumbra-xdg");
        if std::fs::create_dir_all(&dir).is_ok() {
            std::env::set_var("XDG_RUNTIME_DIR", &dir);
        }
    }
    // The libraries' messages (warnings, reference and precompute progress, validation
    // errors) come through `tracing`: printed on stderr, `RUST_LOG` filters them. Default:
    // penumbra's own crates at info (targets starting with "penumbra"), nothing from the
    // dependencies (winit's X11 chatter); e.g. RUST_LOG=warn, RUST_LOG=penumbra::vulkan=off.
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("penumbra=info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .without_time()
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(exit_code(&e))
        }
    }
}
