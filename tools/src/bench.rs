//! `penumbra bench`: each technique against ground truth on the same scene, camera and frame,
//! and against each other in speed, in one run.

use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::{RenderSettings, Renderer};
use penumbra_reference::cli::parse_size;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::{compare, write_diff_png};
use penumbra_reference::render::{render as reference_render, Mode, ReferenceOptions};
use penumbra_scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct BenchArgs {
    /// Scene file or glTF model; the built-in default scene when omitted.
    pub scene: Option<PathBuf>,
    /// Comma-separated techniques to measure (the first is the speed baseline of the ratios).
    #[arg(long, default_value = "env")]
    pub techniques: String,
    /// Image size WxH.
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Scene frame K measured (time K / fps).
    #[arg(long, default_value_t = 0)]
    pub frame: u32,
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// GPU frames rendered per technique at that time after one warm-up frame (timings are
    /// medians over them; progressive techniques accumulate over them and the warm-up frame).
    #[arg(long, default_value_t = 8)]
    pub frames: u32,
    /// Samples per pixel of the CPU reference.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory: reference.exr, <technique>.exr, <technique>_diff.png, bench.json, tradeoff.png.
    #[arg(long, default_value = "bench-out")]
    pub out: PathBuf,
    /// Also compare against the reference with SG-approximated lighting and exact visibility
    /// (tells a technique's visibility error from its SG lighting error); reference_sg.exr.
    #[arg(long)]
    pub sg_reference: bool,
    /// Render the GPU techniques at N x N times the size and box-filter them down before comparing
    /// (the reference integrates each pixel's area with its jittered samples; a GPU technique
    /// point-samples pixel centres, so sub-pixel highlights and edges alias). GPU ms are those of
    /// the larger image.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=8))]
    pub supersample: u32,
    /// Parameters for every listed technique that takes parameters (set by `bench isg` for both
    /// isg modes); `None`: each technique gets the scene's `[technique_params]` only if it is the
    /// scene's own technique.
    #[arg(skip)]
    pub technique_params: Option<penumbra_passes::registry::Params>,
}

/// A frame's radiance as an image (alpha dropped).
pub(crate) fn hdr_image(f: &penumbra::FrameImages) -> Image {
    downsample(&f.hdr, f.width, f.height, 1)
}

/// Box-filters a `ss`-times larger RGBA readback down to `w` x `h` (`--supersample`).
pub(crate) fn downsample(hdr: &[[f32; 4]], w: u32, h: u32, ss: u32) -> Image {
    let gw = w * ss;
    Image::from_fn(w, h, |x, y| {
        let mut sum = [0.0f32; 3];
        for sy in 0..ss {
            for sx in 0..ss {
                let p = hdr[((y * ss + sy) * gw + x * ss + sx) as usize];
                for c in 0..3 {
                    sum[c] += p[c];
                }
            }
        }
        sum.map(|v| v / (ss * ss) as f32)
    })
}

/// GPU ms per frame of a renderer's technique: the sum of its passes' medians, uploads and
/// the readback excluded.
pub(crate) fn technique_gpu_ms(r: &Renderer) -> f64 {
    r.engine
        .profiler
        .gpu_stats()
        .iter()
        .filter(|(p, _)| !(p.ends_with("_upload") || p.as_str() == "readback"))
        .map(|(_, st)| st.median_ms)
        .sum()
}

/// One technique measured at one still frame: its image (box-filtered down from the
/// supersampled render), its passes' GPU statistics and its GPU ms per frame.
pub(crate) struct Measured {
    pub image: Image,
    pub passes: serde_json::Value,
    pub technique_ms: f64,
    pub device: String,
    pub driver: String,
}

/// Renders `name` (with `params`) at `width x height` times `supersample`, the still frame at
/// time `t`: one warm-up frame outside the statistics (its passes' first dispatches include
/// lavapipe's shader compilation, seconds for the larger technique shaders), then `frames` timed
/// frames. (`bench pareto`'s points are measured over moving frames: `pareto::Target::point`.)
#[allow(clippy::too_many_arguments)]
pub(crate) fn measure_technique(
    scene: &Scene,
    name: &str,
    params: Option<std::collections::BTreeMap<String, String>>,
    width: u32,
    height: u32,
    supersample: u32,
    t: f32,
    frames: u32,
) -> Result<Measured> {
    let ss = supersample.max(1);
    let settings = RenderSettings {
        width: width * ss,
        height: height * ss,
        technique: Some(name.to_string()),
        technique_params: params,
        ..Default::default()
    };
    let mut r = Renderer::new_headless(scene, settings, false)?;
    let frame = scene.at(t, Some(t));
    let mut images = r.render(&frame, None, true)?;
    images.extend(r.finish()?);
    r.engine.profiler.reset();
    for _ in 0..frames.max(1) {
        images.extend(r.render(&frame, None, true)?);
    }
    images.extend(r.finish()?);
    let last = images.last().context("no frame finished")?;
    Ok(Measured {
        image: downsample(&last.hdr, width, height, ss),
        passes: serde_json::to_value(r.engine.profiler.gpu_stats())?,
        technique_ms: technique_gpu_ms(&r),
        device: r.context().device_name.clone(),
        driver: r.context().driver_info(),
    })
}

/// Writes a bench's JSON report to `path` and says so: the device and driver that measured it
/// (`None`: nothing was measured), the scene and image size, then `body`'s fields.
pub(crate) fn write_report(
    path: &std::path::Path,
    device: Option<(String, String)>,
    scene: &str,
    size: [u32; 2],
    body: serde_json::Value,
) -> Result<()> {
    let (device, driver) = device.unwrap_or_default();
    let mut report = serde_json::json!({"device": device, "driver": driver, "scene": scene, "size": size});
    if let (Some(r), serde_json::Value::Object(b)) = (report.as_object_mut(), body) {
        r.extend(b);
    }
    std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")?;
    println!("wrote {}", path.display());
    Ok(())
}

/// Renders the CPU reference of `scene` with `opts` into `out/reference.exr` and says so.
pub(crate) fn reference_into(
    scene: &Scene,
    opts: &ReferenceOptions,
    out: &std::path::Path,
) -> Result<penumbra_reference::render::ReferenceImage> {
    let reference = reference_render(scene, opts).context("reference render")?;
    reference.radiance.write_exr(out.join("reference.exr"))?;
    println!(
        "reference: {} spp in {:.2} s, mean relative standard error {:.2e}",
        opts.spp, reference.render_seconds, reference.noise.mean_rel_std_error
    );
    Ok(reference)
}

pub fn run(args: &BenchArgs, scene: &Scene) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let t = args.frame as f32 / args.fps;
    let opts = ReferenceOptions {
        width,
        height,
        spp: args.spp,
        frame: args.frame,
        time: Some(t),
        fps: args.fps,
        seed: args.seed,
        mode: Mode::Exact,
        progress: true,
        ..Default::default()
    };
    let reference = reference_into(scene, &opts, &args.out)?;
    let sg_reference = if args.sg_reference {
        let r = reference_render(scene, &ReferenceOptions { mode: Mode::SgLighting, ..opts.clone() })
            .context("SG-lighting reference render")?;
        r.radiance.write_exr(args.out.join("reference_sg.exr"))?;
        println!(
            "SG-lighting reference: {} spp in {:.2} s, env SG fit rel. L2 {}",
            args.spp,
            r.render_seconds,
            r.sg_fit_rel_l2.map_or("-".into(), |e| format!("{e:.3}"))
        );
        Some(r)
    } else {
        None
    };
    let mut rows = Vec::new();
    let mut baseline_ms = None;
    let mut device: Option<(String, String)> = None;
    for name in args.techniques.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let technique_params = args
            .technique_params
            .clone()
            .filter(|_| penumbra_passes::registry::info(name).is_some_and(|i| i.takes_params()));
        let m = measure_technique(scene, name, technique_params, width, height, args.supersample, t, args.frames)?;
        device.get_or_insert_with(|| (m.device.clone(), m.driver.clone()));
        let (img, stats, technique_ms) = (m.image, m.passes, m.technique_ms);
        img.write_exr(args.out.join(format!("{name}.exr")))?;
        let c = compare(&reference.radiance, "reference", &img, name)?;
        write_diff_png(&reference.radiance, &img, &args.out.join(format!("{name}_diff.png")))?;
        let base = *baseline_ms.get_or_insert(technique_ms);
        let vs_sg = match &sg_reference {
            Some(sg) => Some(compare(&sg.radiance, "reference_sg", &img, name)?),
            None => None,
        };
        rows.push(serde_json::json!({
            "vs_sg_reference": vs_sg.as_ref().map(|c| serde_json::json!({"psnr_db": c.psnr_db, "rel_rmse": c.rel_rmse, "flip_mean": c.flip_mean})),
            "technique": name,
            "gpu_ms_per_frame": technique_ms,
            "speed_ratio_vs_first": technique_ms / base,
            "speedup_vs_reference": reference.render_seconds * 1e3 / technique_ms,
            "psnr_db": c.psnr_db,
            "rel_rmse": c.rel_rmse,
            "flip_mean": c.flip_mean,
            "passes": stats,
        }));
        println!(
            "{name:<14} {technique_ms:>9.2} ms/frame  x{:<6.2} ({:.0}x faster than the reference)  PSNR {:>6}  relRMSE {:.4}  FLIP {:.4}",
            technique_ms / base,
            reference.render_seconds * 1e3 / technique_ms,
            c.psnr_db.map_or("inf".into(), |p| format!("{p:.2}")),
            c.rel_rmse,
            c.flip_mean
        );
        if let Some(c) = &vs_sg {
            println!(
                "{:<14} vs the SG-lighting reference: PSNR {:>6}  relRMSE {:.4}  FLIP {:.4}",
                "",
                c.psnr_db.map_or("inf".into(), |p| format!("{p:.2}")),
                c.rel_rmse,
                c.flip_mean
            );
        }
    }
    let body = serde_json::json!({
        "supersample": args.supersample.max(1),
        "time_s": t,
        "reference": {"spp": args.spp, "seconds": reference.render_seconds, "noise": reference.noise},
        "techniques": rows,
    });
    write_report(&args.out.join("bench.json"), device, &scene.name, [width, height], body)?;
    // The speed/accuracy trade as a picture: one point per technique.
    let series: Vec<crate::plot::Series> = rows
        .iter()
        .map(|r| {
            let name = r["technique"].as_str().unwrap_or("?").to_string();
            let point = (r["gpu_ms_per_frame"].as_f64().unwrap_or(f64::NAN), r["psnr_db"].as_f64().unwrap_or(f64::NAN));
            crate::plot::Series { name: name.clone(), points: vec![point], labels: vec![format!(" {name}")] }
        })
        .collect();
    let chart = crate::plot::Chart::new(
        format!("{}: error against time ({}x{}, {}-spp reference)", scene.name, width, height, args.spp),
        "GPU ms per frame (median, lavapipe)",
        "PSNR vs reference (dB)",
    )
    .log(true, false)
    .legend(false);
    match crate::plot::write_chart(&args.out.join("tradeoff.png"), &chart, &series) {
        Ok(()) => println!("wrote {}", args.out.join("tradeoff.png").display()),
        // e.g. every technique matched the reference exactly (infinite PSNR): nothing to plot
        Err(e) => println!("no chart: {e:#}"),
    }
    Ok(())
}

#[derive(Args)]
pub struct VolumetricArgs {
    /// A scene with a [medium].
    pub scene: PathBuf,
    /// Frames rendered by both methods.
    #[arg(long, default_value_t = 12)]
    pub frames: u32,
    #[arg(long, default_value = "160x120")]
    pub size: String,
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// Time of the first frame (seconds).
    #[arg(long, default_value_t = 0.0)]
    pub start: f32,
    /// The temporal method recomputes every pixel every n frames: the thesis's "reused frame
    /// number" + 1 (Fig. 5.1; the thesis uses 3, so 4).
    #[arg(long, default_value_t = 4)]
    pub reuse_frames: u32,
    /// Samples per view ray.
    #[arg(long, default_value_t = 48)]
    pub samples: u32,
    /// Both methods march whole view rays (no shadow-volume intervals, no airlight); by default
    /// both run Wyman and Ramsey's hybrid, the thesis's baseline.
    #[arg(long)]
    pub plain: bool,
    /// Also draw the per-frame GPU ms of both methods as a chart (PNG); with --sweep, the
    /// frame rate against the reused frame number (the thesis's Fig. 5.2).
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Also run the temporal method with each of these refresh periods (comma-separated, e.g.
    /// 1,2,3,4,6,8; the reused frame number is the period - 1) and tabulate its whole-frame
    /// cost against the full method's (the thesis's Fig. 5.2).
    #[arg(long, value_delimiter = ',')]
    pub sweep: Vec<u32>,
    /// Write the report (per frame, totals, sweep) as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

fn vol_report_json(r: &penumbra_passes::volumetric::bench::VolBenchReport) -> serde_json::Value {
    let frames: Vec<serde_json::Value> = r
        .frames
        .iter()
        .map(|f| {
            serde_json::json!({
                "frame": f.frame, "time": f.time, "temporal_mode": f.temporal_mode,
                "vol_temporal_ms": f.temporal_total_ms, "vol_full_ms": f.full_total_ms,
                "frame_temporal_ms": f.temporal_frame_ms, "frame_full_ms": f.full_frame_ms,
                "temporal_pass_ms": f.temporal_ms, "full_pass_ms": f.full_ms,
                "marched_fraction": f.marched_fraction, "mean_abs": f.mean_abs, "max_abs": f.max_abs,
                "psnr_db": if f.psnr.is_finite() { serde_json::json!(f.psnr) } else { serde_json::Value::Null },
                "changed_pixels": f.changed_pixels, "missed_pixels": f.missed_pixels,
            })
        })
        .collect();
    serde_json::json!({
        "scene": r.scene, "width": r.width, "height": r.height,
        "vol_speedup": r.speedup, "frame_speedup": r.frame_speedup,
        "frame_temporal_ms": r.temporal_frame_ms, "frame_full_ms": r.full_frame_ms,
        "mean_marched_fraction": r.mean_marched_fraction, "missed_pixels": r.missed_pixels,
        "masked_march_ratio": r.masked_march_ratio, "masked_fraction": r.masked_fraction,
        "temporal_pass_ms": r.temporal_pass_ms, "full_pass_ms": r.full_pass_ms,
        "notes": r.notes, "frames": frames,
    })
}

pub fn run_volumetric(args: &VolumetricArgs, scene: &Scene) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    let ctx = penumbra::engine::Context::new(&Default::default())?;
    println!("device: {} ({})", ctx.device_name, ctx.driver_info());
    let opts = penumbra_passes::volumetric::bench::VolBenchOptions {
        width,
        height,
        frames: args.frames.max(1),
        fps: args.fps,
        start_time: args.start,
        reuse_frames: args.reuse_frames.max(1),
        samples: args.samples.max(1),
        hybrid: !args.plain,
        ..Default::default()
    };
    let report = penumbra_passes::volumetric::bench::bench_volumetric(&ctx, &penumbra::shader_library(), scene, &opts)?;
    print!("{}", report.table());
    // The reuse sweep (Fig. 5.2): whole-frame ms of the temporal method per refresh period.
    let mut sweep = Vec::new();
    for &n in &args.sweep {
        let o = penumbra_passes::volumetric::bench::VolBenchOptions { reuse_frames: n.max(1), ..opts.clone() };
        let r = penumbra_passes::volumetric::bench::bench_volumetric(&ctx, &penumbra::shader_library(), scene, &o)?;
        sweep.push((n.max(1), r));
    }
    if !sweep.is_empty() {
        println!("reuse sweep ({} frames each, whole-frame GPU ms):", opts.frames);
        println!("period  reused_number  temporal_ms  full_ms  speedup  vol_temporal_ms  vol_full_ms  vol_speedup  fps_temporal  marched  missed");
        for (n, r) in &sweep {
            println!(
                "{n:6}  {:13}  {:11.3}  {:7.3}  {:7.2}  {:15.3}  {:11.3}  {:11.2}  {:12.2}  {:7.3}  {:6}",
                n - 1,
                r.temporal_frame_ms,
                r.full_frame_ms,
                r.frame_speedup,
                r.temporal_vol_ms,
                r.full_vol_ms,
                r.speedup,
                1000.0 / r.temporal_frame_ms.max(1e-9),
                r.mean_marched_fraction,
                r.missed_pixels
            );
        }
    }
    if let Some(path) = &args.json {
        let mut v = vol_report_json(&report);
        v["reuse_frames"] = serde_json::json!(opts.reuse_frames);
        v["device"] = serde_json::json!(ctx.device_name);
        v["sweep"] = serde_json::Value::Array(
            sweep
                .iter()
                .map(|(n, r)| {
                    serde_json::json!({
                        "reuse_frames": n, "reused_frame_number": n - 1,
                        "frame_temporal_ms": r.temporal_frame_ms, "frame_full_ms": r.full_frame_ms,
                        "frame_speedup": r.frame_speedup, "mean_marched_fraction": r.mean_marched_fraction,
                        "vol_temporal_ms": r.temporal_vol_ms, "vol_full_ms": r.full_vol_ms, "vol_speedup": r.speedup,
                        "missed_pixels": r.missed_pixels,
                    })
                })
                .collect(),
        );
        std::fs::write(path, serde_json::to_string_pretty(&v)?)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let (Some(path), false) = (&args.chart, sweep.is_empty()) {
        let series = [
            crate::plot::Series {
                name: "temporal reuse".into(),
                points: sweep.iter().map(|(n, r)| ((n - 1) as f64, 1000.0 / r.temporal_frame_ms.max(1e-9))).collect(),
                labels: vec![],
            },
            crate::plot::Series {
                name: "full (every pixel)".into(),
                points: sweep.iter().map(|(n, r)| ((n - 1) as f64, 1000.0 / r.full_frame_ms.max(1e-9))).collect(),
                labels: vec![],
            },
        ];
        let chart = crate::plot::Chart::new(
            format!("{}: frame rate against the reused frame number, {width}x{height}", report.scene),
            "reused frame number (refresh period - 1)",
            "frames per second (whole-frame GPU time)",
        );
        crate::plot::write_chart(path, &chart, &series)?;
        println!("wrote {}", path.display());
    } else if let Some(path) = &args.chart {
        let line =
            |name: &str, ms: &dyn Fn(&penumbra_passes::volumetric::bench::VolBenchFrame) -> f64| crate::plot::Series {
                name: name.into(),
                points: report.frames.iter().map(|f| (f.frame as f64, ms(f))).collect(),
                labels: vec![],
            };
        let series = [
            line("temporal (masked re-march)", &|f| f.temporal_total_ms),
            line("full (every pixel)", &|f| f.full_total_ms),
        ];
        let chart = crate::plot::Chart::new(
            format!("{}: volumetric GPU ms per frame, {width}x{height} (overall {:.2}x)", report.scene, report.speedup),
            "frame",
            "GPU ms of the vol_* passes",
        );
        crate::plot::write_chart(path, &chart, &series)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[derive(Args)]
pub struct TraceArgs {
    /// Scene file or glTF model; the built-in default scene when omitted.
    pub scene: Option<PathBuf>,
    /// Camera rays WxH (coherent set; secondary rays leave the hit points).
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Number of incoherent (random) rays.
    #[arg(long, default_value_t = 20000)]
    pub incoherent: usize,
}

pub fn run_trace(args: &TraceArgs, scene: &Scene) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    let ctx = penumbra::engine::Context::new(&Default::default())?;
    println!("device: {} ({})", ctx.device_name, ctx.driver_info());
    let report = penumbra_passes::trace_bench::bench_trace(
        &ctx,
        &penumbra::shader_library(),
        scene,
        width,
        height,
        args.incoherent,
    )?;
    println!("{report}");
    Ok(())
}

/// Shadow-field precompute parameters shared by `bench shadow-fields` and `precompute`.
#[derive(Args, Clone)]
pub struct FieldParams {
    /// Concentric shells C.
    #[arg(long, default_value_t = 32)]
    pub shells: usize,
    /// Initial polar resolution R (R x R samples per shell; paper 64).
    #[arg(long, default_value_t = 32)]
    pub resolution: usize,
    /// Occlusion map resolution per sample (map_res x 2 map_res directions).
    #[arg(long, default_value_t = 32)]
    pub map_res: usize,
    /// Adaptive threshold of eq. 1.
    #[arg(long, default_value_t = 0.010)]
    pub threshold: f64,
}

impl FieldParams {
    /// Rejects values the technique would reject (same ranges as its `[technique_params]`).
    pub fn check(&self) -> Result<()> {
        let mut o = penumbra_passes::shadow_fields::SfOptions::default();
        for (k, v) in self.technique_params() {
            o.set(k, &v)?;
        }
        Ok(())
    }

    /// These parameters as the technique's `[technique_params]` keys and values.
    fn technique_params(&self) -> [(&'static str, String); 4] {
        [
            ("shells", self.shells.to_string()),
            ("resolution", self.resolution.to_string()),
            ("map_res", self.map_res.to_string()),
            ("threshold", self.threshold.to_string()),
        ]
    }

    fn options(&self) -> penumbra_passes::shadow_fields::SfOptions {
        let mut o = penumbra_passes::shadow_fields::SfOptions::default();
        o.params.shells = self.shells.max(1);
        o.params.resolution = self.resolution.max(1);
        o.params.map_res = self.map_res.max(2);
        o.params.threshold = self.threshold;
        o.progress = true;
        o
    }
}

#[derive(Args)]
pub struct ShadowFieldsArgs {
    /// Scene file or glTF model; the built-in default scene when omitted.
    pub scene: Option<PathBuf>,
    #[command(flatten)]
    pub params: FieldParams,
    /// Scene time of the measured frame (seconds).
    #[arg(long, default_value_t = 0.5)]
    pub time: f32,
    /// Timed repetitions (median reported).
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// Image size WxH of the image comparison against the CPU reference.
    #[arg(long, default_value = "128x96")]
    pub size: String,
    /// Samples per pixel of the CPU reference.
    #[arg(long, default_value_t = 32)]
    pub spp: u32,
    /// Skip the image comparison (reference render and technique variants).
    #[arg(long)]
    pub no_images: bool,
    /// Also the all-frequency (Haar, largest 5% kept) fields' sizes fixed vs adaptive and
    /// per-shell resolutions, with cube faces of this resolution (a power of two, 2..=64) and
    /// the initial R of `--resolution` (the paper: 64, with 64 x 64 maps, about `--haar 32`; one
    /// object's raw maps, `shells x R^2 x 6 n^2` floats, must fit in 8 GiB: 3 GiB there).
    #[arg(long)]
    pub haar: Option<usize>,
    /// Also draw the image comparison as a chart (PNG): PSNR against GPU ms per variant.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// The paper's Figure 8: the fixed fields against the adaptive ones at each of these
    /// thresholds (comma-separated, e.g. 0.02,0.01,0.005), rendered per vertex at --size with
    /// the differences scaled 15 times, beside each threshold's adaptive size (runs without
    /// --no-images too; needs no reference).
    #[arg(long, value_delimiter = ',')]
    pub thresholds: Vec<f64>,
    /// Output directory of the threshold sweep: sf_thresholds.json, sf_thresholds.png.
    #[arg(long, default_value = "bench-sf-thresholds")]
    pub sweep_out: PathBuf,
}

/// `scene` rendered with `technique` at `w x h` and `time` (three frames of the same time, the
/// last kept): its HDR image and GPU ms per frame.
fn render_still(scene: &Scene, technique: &str, (w, h): (u32, u32), time: f32) -> Result<(Image, f64)> {
    let settings = RenderSettings::with_technique(w, h, technique, &scene.technique_params);
    let mut r = Renderer::new_headless(scene, settings, false)?;
    let frame = scene.at(time, Some(time));
    let mut out = Vec::new();
    for _ in 0..3 {
        out.extend(r.render(&frame, None, true)?);
    }
    out.extend(r.finish()?);
    let img = crate::bench::hdr_image(out.last().context("no frame finished")?);
    Ok((img, technique_gpu_ms(&r)))
}

/// The threshold sweep of the paper's Figure 8 (`--thresholds`): per threshold the adaptive
/// fields' size and their per-vertex image against the fixed fields' (relative RMSE, PSNR), the
/// images and their differences x 15 in a contact sheet, and JSON; the paper's path (every light
/// through the fields: `light_shadows = fields`, `key_lights = 0`).
fn threshold_sweep(args: &ShadowFieldsArgs, scene: &Scene) -> Result<()> {
    use penumbra_passes::shadow_fields::SceneFields;
    let size = parse_size(&args.size)?;
    std::fs::create_dir_all(&args.sweep_out).with_context(|| format!("creating {}", args.sweep_out.display()))?;
    let with = |threshold: f64| {
        let mut s = scene.clone();
        s.technique_params = args.params.technique_params().into_iter().map(|(k, v)| (k.to_string(), v)).collect();
        s.technique_params.insert("threshold".into(), threshold.to_string());
        // per vertex, on the paper's path: every light through the fields (traced shadows and
        // key lights would hide the fields' differences)
        for (k, v) in [("mode", "vertex"), ("light_shadows", "fields"), ("key_lights", "0")] {
            s.technique_params.insert(k.into(), v.into());
        }
        s
    };
    let bytes = |threshold: f64| -> Result<(usize, usize)> {
        let mut o = args.params.options();
        o.params.threshold = threshold;
        let f = SceneFields::build(scene, &o)?;
        let unique = f.reports.iter().filter(|r| r.shared_with.is_none());
        Ok(unique.fold((0, 0), |(a, b), r| (a + r.fixed_bytes, b + r.adaptive_bytes)))
    };
    let (fixed, _) = render_still(&with(args.params.threshold), "shadow-fields-fixed", size, args.time)?;
    let (fixed_bytes, _) = bytes(args.params.threshold)?;
    println!(
        "threshold sweep (the paper's Figure 8), per vertex at {}x{}, t = {} s: fixed fields {:.1} KB",
        size.0,
        size.1,
        args.time,
        fixed_bytes as f64 / 1024.0
    );
    println!("{:>10} {:>12} {:>9} {:>16} {:>11}", "threshold", "adaptive KB", "smaller", "relRMSE vs fixed", "PSNR dB");
    let mut top =
        vec![("fixed".to_string(), Some(fixed.clone()), format!("{:.0} KB", fixed_bytes as f64 / 1024.0), None)];
    let mut bottom = vec![("fixed".to_string(), Some(fixed.clone()), String::new(), None)];
    let mut rows = Vec::new();
    for &t in &args.thresholds {
        let (img, _) = render_still(&with(t), "shadow-fields", size, args.time)?;
        let (_, adaptive_bytes) = bytes(t)?;
        let c = compare(&fixed, "fixed", &img, "adaptive")?;
        let smaller = 1.0 - adaptive_bytes as f64 / fixed_bytes.max(1) as f64;
        let psnr = c.psnr_db.map_or("inf".into(), |p| format!("{p:.2}"));
        println!(
            "{t:>10} {:>12.1} {:>8.0}% {:>16.4} {psnr:>11}",
            adaptive_bytes as f64 / 1024.0,
            100.0 * smaller,
            c.rel_rmse
        );
        let mut diff = img.clone();
        for (d, f) in diff.pixels.iter_mut().zip(&fixed.pixels) {
            for k in 0..3 {
                d[k] = 15.0 * (d[k] - f[k]).abs();
            }
        }
        let label = format!("{:.0} KB, {:.4}", adaptive_bytes as f64 / 1024.0, c.rel_rmse);
        top.push((format!("threshold {t}"), Some(img), label, None));
        bottom.push((format!("|diff| x 15, {t}"), Some(diff), String::new(), None));
        rows.push(serde_json::json!({
            "threshold": t,
            "adaptive_bytes": adaptive_bytes,
            "smaller": smaller,
            "rel_rmse_vs_fixed": c.rel_rmse,
            "psnr_db_vs_fixed": c.psnr_db,
        }));
    }
    let json = serde_json::json!({
        "scene": scene.name,
        "size": [size.0, size.1],
        "time_s": args.time,
        "shells": args.params.shells,
        "resolution": args.params.resolution,
        "map_res": args.params.map_res,
        "fixed_bytes": fixed_bytes,
        "thresholds": rows,
    });
    let jp = args.sweep_out.join("sf_thresholds.json");
    std::fs::write(&jp, serde_json::to_string_pretty(&json)?).with_context(|| format!("writing {}", jp.display()))?;
    let png = args.sweep_out.join("sf_thresholds.png");
    let sheet = [("adaptive".to_string(), top), ("differences".to_string(), bottom)];
    crate::matrix::contact_sheet(&png, &sheet, size.0, size.1)?;
    println!("wrote {} and {}", jp.display(), png.display());
    Ok(())
}

/// The variants of the image comparison: (label, technique, `[technique_params]`).
fn sf_variants(has_lights: bool) -> Vec<(&'static str, &'static str, Vec<(&'static str, &'static str)>)> {
    let mut v = vec![
        ("env (unshadowed)", "env", vec![]),
        ("adaptive pixel", "shadow-fields", vec![("mode", "pixel")]),
        ("fixed pixel", "shadow-fields-fixed", vec![("mode", "pixel")]),
        ("adaptive vertex", "shadow-fields", vec![("mode", "vertex")]),
        ("fixed vertex", "shadow-fields-fixed", vec![("mode", "vertex")]),
        ("adaptive px hanning", "shadow-fields", vec![("mode", "pixel"), ("window", "hanning")]),
        ("adaptive px lanczos", "shadow-fields", vec![("mode", "pixel"), ("window", "lanczos")]),
        ("adaptive vx hanning", "shadow-fields", vec![("mode", "vertex"), ("window", "hanning")]),
    ];
    if has_lights {
        v.push(("adaptive px no SRF", "shadow-fields", vec![("mode", "pixel"), ("srf", "false")]));
        v.push(("adaptive vx no SRF", "shadow-fields", vec![("mode", "vertex"), ("srf", "false")]));
    }
    v
}

pub fn run_shadow_fields(args: &ShadowFieldsArgs, scene: &Scene) -> Result<()> {
    let ctx = penumbra::engine::Context::new(&Default::default())?;
    println!("device: {} ({})", ctx.device_name, ctx.driver_info());
    let opts = penumbra_passes::shadow_fields::bench::BenchOptions {
        sf: args.params.options(),
        time: args.time,
        repeats: args.repeats.max(1),
        ..Default::default()
    };
    // the all-frequency fields' initial R, checked before the low-frequency bench's minutes
    let r0 = args.params.resolution.max(1);
    if let Some(n) = args.haar {
        if !(2..=64).contains(&n) || !n.is_power_of_two() {
            return Err(crate::bad(format!("--haar {n}: the cube face resolution must be a power of two in 2..=64")));
        }
        let raw_bytes = args.params.shells as f64 * (r0 * r0) as f64 * (6 * n * n) as f64 * 4.0;
        if raw_bytes > 8.0 * (1u64 << 30) as f64 {
            return Err(crate::bad(format!(
                "--haar {n} at R = {r0} with {} shells: {:.1} GiB of raw maps per object (at most 8)",
                args.params.shells,
                raw_bytes / (1u64 << 30) as f64
            )));
        }
    }
    let report = penumbra_passes::shadow_fields::bench::bench(&ctx, &penumbra::shader_library(), scene, &opts)?;
    println!("{report}");
    if let Some(n) = args.haar {
        use penumbra_math::shadow_field::haar::{raw_maps, CubeTable, HaarField};
        let table = CubeTable::new(n);
        println!(
            "all frequency (Haar, 5% kept, 6x{0}x{0} cube maps, R = {r0}, {1} shells):",
            table.n, args.params.shells
        );
        let (mut tf, mut ta) = (0usize, 0usize);
        for (mi, m) in scene.meshes.iter().enumerate() {
            if m.indices.len() < 3 || report.fields.get(mi).is_some_and(|r| r.shared_with.is_some()) {
                continue; // empty, or identical to an earlier mesh (shares its field)
            }
            let t0 = std::time::Instant::now();
            let (c, vr, maps) = raw_maps(&m.positions, &m.indices, args.params.shells, r0, &table);
            let f = HaarField::build(c, vr, &maps, r0, &table, 0.05, false, args.params.threshold);
            let a = HaarField::build(c, vr, &maps, r0, &table, 0.05, true, args.params.threshold);
            let res: Vec<String> = a.resolutions().iter().map(|x| x.to_string()).collect();
            println!(
                "{:<20} fixed {:>8.1} KB  adaptive {:>8.1} KB ({:.0}% smaller, {:.1} s)  {}",
                m.name,
                f.bytes() as f64 / 1024.0,
                a.bytes() as f64 / 1024.0,
                100.0 * (1.0 - a.bytes() as f64 / f.bytes().max(1) as f64),
                t0.elapsed().as_secs_f64(),
                res.join(" ")
            );
            tf += f.bytes();
            ta += a.bytes();
        }
        println!(
            "total all-frequency: fixed {:.1} KB, adaptive {:.1} KB ({:.0}% smaller)",
            tf as f64 / 1024.0,
            ta as f64 / 1024.0,
            100.0 * (1.0 - ta as f64 / tf.max(1) as f64)
        );
    }
    if !args.thresholds.is_empty() {
        threshold_sweep(args, scene)?;
    }
    if args.no_images {
        return Ok(());
    }
    // Image errors against the CPU reference (exact mode) of the same frame, every variant
    // rendered through the renderer (fields from the precompute cache the bench just filled).
    let (width, height) = parse_size(&args.size)?;
    let ropts = ReferenceOptions {
        width,
        height,
        spp: args.spp,
        time: Some(args.time),
        mode: Mode::Exact,
        progress: true,
        ..Default::default()
    };
    let reference = reference_render(scene, &ropts).context("reference render")?;
    println!(
        "image errors at {width}x{height}, t = {} s, against the CPU reference ({} spp, {:.1} s, noise {:.2e}):",
        args.time, args.spp, reference.render_seconds, reference.noise.mean_rel_std_error
    );
    println!("{:<22} {:>8} {:>9} {:>8} {:>11}", "variant", "PSNR dB", "relRMSE", "FLIP", "GPU ms");
    let mut images = Vec::new();
    let mut points = Vec::new();
    for (label, technique, params) in sf_variants(!scene.lights.is_empty()) {
        let mut s = scene.clone();
        s.technique_params = params.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        if technique != "env" {
            s.technique_params.extend(args.params.technique_params().map(|(k, v)| (k.to_string(), v)));
        }
        let (img, ms) =
            render_still(&s, technique, (width, height), args.time).with_context(|| format!("variant {label}"))?;
        let c = compare(&reference.radiance, "reference", &img, label)?;
        println!(
            "{label:<22} {:>8} {:>9.4} {:>8.4} {ms:>11.2}",
            c.psnr_db.map_or("inf".into(), |p| format!("{p:.2}")),
            c.rel_rmse,
            c.flip_mean
        );
        images.push((label, img));
        points.push((label, ms, c.psnr_db.unwrap_or(f64::NAN)));
    }
    if let Some(path) = &args.chart {
        let series: Vec<crate::plot::Series> = points
            .iter()
            .map(|&(l, ms, db)| crate::plot::Series { name: l.into(), points: vec![(ms, db)], labels: vec![] })
            .collect();
        // variants cluster: colours and a legend, not point labels
        let chart = crate::plot::Chart::new(
            format!("{}: shadow-field variants at {width}x{height}, t = {} s", scene.name, args.time),
            "GPU ms per frame (median of 3, lavapipe)",
            format!("PSNR vs reference, {} spp (dB)", args.spp),
        )
        .log(true, false);
        crate::plot::write_chart(path, &chart, &series)?;
        println!("wrote {}", path.display());
    }
    for mode in ["pixel", "vertex"] {
        let find = |kind: &str| images.iter().find(|(l, _)| *l == format!("{kind} {mode}"));
        if let (Some(a), Some(f)) = (find("adaptive"), find("fixed")) {
            let c = compare(&f.1, "fixed", &a.1, "adaptive")?;
            println!(
                "adaptive vs fixed ({mode}): PSNR {}  relRMSE {:.4}  FLIP {:.4}",
                c.psnr_db.map_or("inf".into(), |p| format!("{p:.2}")),
                c.rel_rmse,
                c.flip_mean
            );
        }
    }
    Ok(())
}

#[derive(Args)]
pub struct ShadowFieldArgs {
    /// Scene file or glTF model.
    pub model: PathBuf,
    #[command(flatten)]
    pub params: FieldParams,
    /// Output directory.
    #[arg(long, default_value = "shadow-fields")]
    pub out: PathBuf,
}

pub fn run_precompute_shadow_field(args: &ShadowFieldArgs, scene: &Scene) -> Result<()> {
    let (reports, paths) = penumbra_passes::shadow_fields::precompute_files(scene, &args.params.options(), &args.out)?;
    for r in &reports {
        println!(
            "{}: {} vertices, coefficients {} KB fixed -> {} KB adaptive ({:.0}% smaller), shells R = {:?}",
            r.mesh,
            r.vertices,
            r.fixed_bytes / 1024,
            r.adaptive_bytes / 1024,
            100.0 * (1.0 - r.adaptive_bytes as f64 / r.fixed_bytes.max(1) as f64),
            r.resolutions
        );
    }
    for p in &paths {
        println!("wrote {}", p.display());
    }
    Ok(())
}
