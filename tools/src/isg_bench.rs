//! `penumbra bench isg`: the ISG technique per pixel (`isg`) and per vertex (`isg-vertex`)
//! against the full reference and the SG-lighting reference (exact visibility), in one run.

use crate::bench::{run, BenchArgs};
use anyhow::{Context as _, Result};
use clap::Args;
use penumbra_passes::registry;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct IsgArgs {
    /// Scene file or glTF model; the built-in default scene when omitted.
    pub scene: Option<PathBuf>,
    /// Image size WxH.
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Scene frame K measured (time K / fps).
    #[arg(long, default_value_t = 30)]
    pub frame: u32,
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// GPU frames per mode after one warm-up frame (timings are medians over them).
    #[arg(long, default_value_t = 4)]
    pub frames: u32,
    /// Samples per pixel of the two CPU references.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// An ISG parameter KEY=VALUE for both modes (repeatable; keys of `IsgSettings::set`).
    #[arg(long = "param", value_name = "KEY=VALUE")]
    pub params: Vec<String>,
    /// Output directory: reference.exr, reference_sg.exr, isg.exr, isg-vertex.exr, diffs,
    /// bench.json.
    #[arg(long, default_value = "bench-isg-out")]
    pub out: PathBuf,
    /// Render ISG at N x N times the size and box-filter down before comparing (see
    /// `bench techniques --supersample`): separates the technique's error from the aliasing of
    /// sub-pixel highlights (shininess 1000) against the pixel-integrating reference.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=8))]
    pub supersample: u32,
    /// Skip the variants table (the paper's sigmoid fit and patch rule against the defaults,
    /// per-vertex refinement off): only the two modes with their defaults.
    #[arg(long)]
    pub no_variants: bool,
    /// Skip the paper's comparisons (isg against 30 and 1024 shadow maps as Figure 11, and
    /// against `mc` at equal error, over moving frames against the converged reference).
    #[arg(long)]
    pub no_paper: bool,
    /// Supersampling of the paper's comparisons (N x N points per pixel, box-filtered; the
    /// converged reference averages the same points): 2 as `bench matrix`, whose checked-in
    /// references it then reuses at 160x120; at 1 a shininess-1000 highlight aliases into every
    /// configuration's error alike.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub paper_supersample: u32,
    /// The `mc` sample counts per frame tried for the equal-error comparison (ascending).
    #[arg(long, default_value = "1,2,4,8,16,32,64,128,256", value_delimiter = ',')]
    pub mc_spp: Vec<u32>,
    /// Converged reference cache of the paper's comparisons (default: <temp>/penumbra-references,
    /// shared with `bench matrix`; the repository's checked-in references are copied in).
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

/// The alternatives `bench isg` measures against the defaults: (technique, parameters, what).
pub const VARIANTS: &[(&str, &[(&str, &str)], &str)] = &[
    ("isg", &[("isg_eval", "sigmoid")], "eq. 14's sigmoid fit instead of the table"),
    ("isg", &[("patch_rule", "paper")], "the paper's overlap rule instead of patch centres"),
    ("isg", &[("isg_eval", "sigmoid"), ("patch_rule", "paper")], "both: the paper's visibility integral"),
    ("isg-vertex", &[("pixel_refine", "1")], "no per-pixel refinement: the paper's pure per-vertex mode"),
    ("isg", &[("as_lobes", "1")], "Ashikhmin-Shirley as one Cook-Torrance lobe instead of the paper's seven"),
];

impl IsgArgs {
    /// The scene with the ISG parameters applied (a bad key or value is an error naming it).
    pub fn scene_with_params(&self, scene: &Scene) -> Result<Scene> {
        let mut scene = scene.clone();
        if !matches!(scene.technique.as_str(), "isg" | "isg-vertex") {
            scene.technique_params.clear();
        }
        for p in &self.params {
            let (k, v) = p.split_once('=').ok_or_else(|| anyhow::anyhow!("--param {p}: expected KEY=VALUE"))?;
            scene.technique_params.insert(k.trim().to_string(), v.trim().to_string());
        }
        let mut check = penumbra_passes::isg::IsgSettings::default();
        for (k, v) in &scene.technique_params {
            if k == "mode" {
                anyhow::bail!("--param mode: bench isg measures both modes");
            }
            check.set(k, v)?;
        }
        Ok(scene)
    }
}

/// RMSE over the mean radiance of `img` against `reference` (the matrix's `rmse_rel_mean`).
fn rmse_over_mean(reference: &Image, img: &Image) -> Result<f64> {
    Ok(compare(reference, "reference", img, "technique")?.rmse_rel_mean)
}

/// The [`VARIANTS`] table: each variant rendered as the defaults were (same frame, size,
/// supersampling, timed frames) and compared with the same two references; writes
/// `variants.json`.
fn variants(args: &IsgArgs, scene: &Scene, rows: &[serde_json::Value]) -> Result<()> {
    let (w, h) = penumbra_reference::cli::parse_size(&args.size)?;
    let t = args.frame as f32 / args.fps;
    let full = Image::read_exr(args.out.join("reference.exr"))?;
    let sg = Image::read_exr(args.out.join("reference_sg.exr"))?;
    println!();
    println!("| technique | variant | GPU ms/frame | RMSE / mean vs full reference | vs SG-lighting reference |");
    println!("|---|---|---|---|---|");
    let mut out = Vec::new();
    for name in ["isg", "isg-vertex"] {
        let Ok(img) = Image::read_exr(args.out.join(format!("{name}.exr"))) else { continue };
        let ms = rows.iter().find(|r| r["technique"] == name).and_then(|r| r["gpu_ms_per_frame"].as_f64());
        let (ef, es) = (rmse_over_mean(&full, &img)?, rmse_over_mean(&sg, &img)?);
        println!(
            "| {name} | defaults | {} | {:.2}% | {:.2}% |",
            ms.map_or("-".into(), |m| format!("{m:.2}")),
            100.0 * ef,
            100.0 * es
        );
        out.push(serde_json::json!({"technique": name, "variant": "defaults", "gpu_ms_per_frame": ms, "rmse_over_mean": ef, "rmse_over_mean_sg": es}));
    }
    for (name, params, what) in VARIANTS {
        let mut p = scene.technique_params.clone();
        for (k, v) in *params {
            p.insert(k.to_string(), v.to_string());
        }
        let label = params.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(" ");
        let m = crate::bench::measure_technique(scene, name, Some(p), w, h, args.supersample, t, args.frames)?;
        let file = format!("{name}_{}.exr", label.replace(['=', ' '], "_"));
        m.image.write_exr(args.out.join(&file))?;
        let (ef, es) = (rmse_over_mean(&full, &m.image)?, rmse_over_mean(&sg, &m.image)?);
        println!("| {name} | {label} ({what}) | {:.2} | {:.2}% | {:.2}% |", m.technique_ms, 100.0 * ef, 100.0 * es);
        out.push(serde_json::json!({"technique": name, "variant": label, "image": file, "gpu_ms_per_frame": m.technique_ms, "rmse_over_mean": ef, "rmse_over_mean_sg": es}));
    }
    std::fs::write(args.out.join("variants.json"), serde_json::to_string_pretty(&out)?)?;
    Ok(())
}

/// The configurations of the paper's comparisons: (technique, parameters, the paper's figure).
pub const PAPER_POINTS: &[(&str, &[(&str, &str)], &str)] = &[
    ("isg", &[], "Figure 11: 14.5 ms (per vertex, 400x400, GeForce GTX 580)"),
    ("isg-vertex", &[], ""),
    ("shadowmaps", &[("count", "30"), ("shading", "lights")], "Figure 11: 30 maps, 23.0 ms"),
    ("shadowmaps", &[("count", "1024"), ("shading", "lights")], "Figure 11: 1024 maps, 262 ms"),
    ("shadowmaps", &[], "the project's default (32 maps, ratio shading)"),
];

/// `mc`'s frame cost at `isg`'s error, from `mc`'s points `(spp, ms, error)` (ascending spp):
/// log-log interpolation between the two points that bracket the error. `Ok(ms)`: reached (with
/// the spp bracket); `Err(most accurate point)`: never reached.
pub fn equal_error_ms(mc: &[(u32, f64, f64)], error: f64) -> Result<(f64, u32, u32), (u32, f64, f64)> {
    let mut best = (0, 0.0, f64::INFINITY);
    for (i, &(spp, ms, e)) in mc.iter().enumerate() {
        if e < best.2 {
            best = (spp, ms, e);
        }
        if e <= error {
            let Some(&(spp0, ms0, e0)) = i.checked_sub(1).and_then(|j| mc.get(j)) else {
                return Ok((ms, spp, spp)); // the fewest samples tried already reach it
            };
            if !(e0 > e && e > 0.0 && ms0 > 0.0 && ms > 0.0) {
                return Ok((ms, spp0, spp));
            }
            let f = (error.ln() - e0.ln()) / (e.ln() - e0.ln());
            return Ok(((ms0.ln() + f * (ms.ln() - ms0.ln())).exp(), spp0, spp));
        }
    }
    Err(best)
}

/// The paper's comparisons on this scene, measured as `bench pareto` measures a point (a
/// matrix cell: two warm-up frames, three consecutive timed frames of the moving scene ending
/// at frame K, wall-clock ms with GPU and CPU beside it) against the converged reference of
/// `bench matrix` (`--paper-supersample`, 2: its 2 x 2 pixel grid): isg and isg-vertex, the
/// shadow-map baselines of Figure 11 and mc's sample counts, then isg against mc at equal error.
/// Writes `paper/pareto.{json,md,png}`.
fn paper_comparisons(args: &IsgArgs, scene: &Scene) -> Result<()> {
    use crate::pareto::{mark_front, Measure, Target};
    let (w, h) = penumbra_reference::cli::parse_size(&args.size)?;
    let (bytes, stem) = match &args.scene {
        Some(p) => (
            std::fs::read(p).with_context(|| format!("reading {}", p.display()))?,
            p.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default(),
        ),
        None => (b"built-in default scene".to_vec(), "default".to_string()),
    };
    let measure = Measure {
        frames: 3,
        warmup: 2,
        frame: args.frame,
        fps: args.fps,
        supersample: args.paper_supersample,
        reference_grid: 0,
        noise: 0.01,
        max_spp: 131072,
        cache: args.cache.clone().unwrap_or_else(|| std::env::temp_dir().join("penumbra-references")),
    };
    let ctx = penumbra_engine::Context::new(&penumbra_engine::ContextDesc::default())?;
    println!();
    println!(
        "The paper's comparisons on '{}' at {w}x{h}, frames {}..{} (moving), against the converged reference:",
        scene.name,
        args.frame.saturating_sub(4),
        args.frame
    );
    let target = Target::new(&ctx, scene, &bytes, &stem, (w, h), measure)?;
    let mut front = target.front();
    let params_of = |technique: &str, kv: &[(&str, &str)]| {
        let mut p: registry::Params =
            if technique == scene.technique { scene.technique_params.clone() } else { Default::default() };
        p.extend(kv.iter().map(|(k, v)| (k.to_string(), v.to_string())));
        p
    };
    let mut rows: Vec<(String, String, Option<crate::pareto::Point>)> = Vec::new();
    let measure_point = |front: &mut crate::pareto::Front,
                         technique: &str,
                         kv: &[(&str, &str)]|
     -> Result<Option<crate::pareto::Point>> {
        let p = params_of(technique, kv);
        eprint!("  {technique} {} ... ", crate::pareto::label(&p));
        Ok(match target.point(technique, &p)? {
            Ok(pt) => {
                eprintln!("{:.1} ms/frame, rmse/mean {:.4}", pt.frame_ms, pt.rmse_rel_mean);
                front.points.push(pt.clone());
                Some(pt)
            }
            Err(e) => {
                eprintln!("error: {e}");
                front.errors.push((technique.to_string(), p, e));
                None
            }
        })
    };
    for (technique, kv, paper) in PAPER_POINTS {
        if registry::refusal(technique, scene).is_some() {
            continue;
        }
        let pt = measure_point(&mut front, technique, kv)?;
        let label = if kv.is_empty() {
            "defaults".to_string()
        } else {
            kv.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(" ")
        };
        rows.push((format!("{technique} {label}"), paper.to_string(), pt));
    }
    let isg_error =
        rows.iter().find(|r| r.0 == "isg defaults").and_then(|r| r.2.as_ref()).map(|p| (p.rmse_rel_mean, p.frame_ms));
    let mut mc = Vec::new();
    let mut spps = args.mc_spp.clone();
    spps.sort_unstable();
    spps.dedup();
    for spp in spps.into_iter().filter(|s| (1..=16384).contains(s)) {
        let v = spp.to_string();
        let pt = measure_point(&mut front, "mc", &[("spp", &v)])?;
        if let Some(p) = &pt {
            mc.push((spp, p.frame_ms, p.rmse_rel_mean));
        }
        rows.push((format!("mc spp={spp}"), String::new(), pt));
        // the first point at or below isg's error brackets it
        if let (Some((e, _)), Some(p)) = (isg_error, mc.last()) {
            if p.2 <= e {
                break;
            }
        }
    }
    println!("| configuration | ms/frame (wall) | GPU ms | CPU ms | RMSE / mean | the paper |");
    println!("|---|---|---|---|---|---|");
    for (label, paper, pt) in &rows {
        match pt {
            Some(p) => println!(
                "| {label} | {:.1} | {:.1} | {:.1} | {:.4} | {paper} |",
                p.frame_ms, p.gpu_ms, p.cpu_ms, p.rmse_rel_mean
            ),
            None => println!("| {label} | error | | | | {paper} |"),
        }
    }
    if let Some((e, ms)) = isg_error {
        match equal_error_ms(&mc, e) {
            Ok((mc_ms, a, b)) => println!(
                "\nisg at RMSE / mean {e:.4}: mc reaches it at {mc_ms:.1} ms/frame (between spp {a} and {b}, log-log): isg is {:.2}x {} ({ms:.1} ms/frame)",
                if ms <= mc_ms { mc_ms / ms } else { ms / mc_ms },
                if ms <= mc_ms { "faster" } else { "slower" }
            ),
            Err((spp, mc_ms, best)) => println!(
                "\nisg at RMSE / mean {e:.4}: mc does not reach it by spp {spp} (RMSE / mean {best:.4} at {mc_ms:.1} ms/frame): isg is more than {:.2}x faster at equal error",
                mc_ms / ms
            ),
        }
    }
    mark_front(&mut front.points);
    let dir = args.out.join("paper");
    std::fs::create_dir_all(&dir)?;
    crate::pareto::write_outputs(&[front], &dir)
}

/// Runs `bench techniques --techniques isg,isg-vertex --sg-reference` and prints its results as
/// tables: per mode GPU ms per frame, speedup over the reference renderer, PSNR / relative RMSE
/// against both references; GPU ms per pass; the per-vertex interpolation error.
pub fn run_isg(args: &IsgArgs, scene: &Scene) -> Result<()> {
    let scene = args.scene_with_params(scene)?;
    let bench = BenchArgs {
        scene: args.scene.clone(),
        techniques: "isg,isg-vertex".into(),
        size: args.size.clone(),
        frame: args.frame,
        fps: args.fps,
        frames: args.frames,
        spp: args.spp,
        seed: args.seed,
        out: args.out.clone(),
        sg_reference: true,
        supersample: args.supersample,
        technique_params: Some(scene.technique_params.clone()),
    };
    run(&bench, &scene)?;
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(args.out.join("bench.json"))?)?;
    let rows = report["techniques"].as_array().cloned().unwrap_or_default();
    let f = |v: &serde_json::Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.2}"));
    let f4 = |v: &serde_json::Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.4}"));
    println!();
    println!(
        "ISG on '{}' at {}{}, t = {:.2} s; reference {} spp in {:.1} s",
        scene.name,
        args.size,
        if args.supersample > 1 {
            format!(" (GPU at {0}x{0} supersampling, box-filtered)", args.supersample)
        } else {
            String::new()
        },
        report["time_s"].as_f64().unwrap_or(0.0),
        args.spp,
        report["reference"]["seconds"].as_f64().unwrap_or(0.0)
    );
    println!("| mode | GPU ms/frame | speedup vs reference | PSNR / relRMSE vs full reference | PSNR / relRMSE vs SG-lighting reference |");
    println!("|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {}x | {} dB / {} | {} dB / {} |",
            r["technique"].as_str().unwrap_or("?"),
            f(&r["gpu_ms_per_frame"]),
            f(&r["speedup_vs_reference"]),
            f(&r["psnr_db"]),
            f4(&r["rel_rmse"]),
            f(&r["vs_sg_reference"]["psnr_db"]),
            f4(&r["vs_sg_reference"]["rel_rmse"]),
        );
    }
    let mut passes: Vec<String> = Vec::new();
    for r in &rows {
        for k in r["passes"].as_object().map(|o| o.keys().cloned().collect::<Vec<_>>()).unwrap_or_default() {
            if !passes.contains(&k) {
                passes.push(k);
            }
        }
    }
    println!();
    let names: Vec<&str> = rows.iter().map(|r| r["technique"].as_str().unwrap_or("?")).collect();
    println!("| GPU ms per pass (median) | {} |", names.join(" | "));
    println!("|---|{}", "---|".repeat(rows.len()));
    for p in &passes {
        println!("| {p} | {} |", rows.iter().map(|r| f(&r["passes"][p]["median_ms"])).collect::<Vec<_>>().join(" | "));
    }
    let read = |name: &str| Image::read_exr(args.out.join(format!("{name}.exr")));
    // The paper's "RMS error" (3.2% / 4.6% on its bunny scene): RMSE over the mean reference
    // radiance (its exact normalization is not given).
    println!();
    println!("| mode | RMSE / mean radiance vs full reference | vs SG-lighting reference |");
    println!("|---|---|---|");
    for name in ["isg", "isg-vertex"] {
        let Ok(img) = read(name) else { continue };
        let mut cells = Vec::new();
        for r in ["reference", "reference_sg"] {
            let Ok(reference) = read(r) else { continue };
            cells.push(format!("{:.2}%", 100.0 * rmse_over_mean(&reference, &img)?));
        }
        println!("| {name} | {} |", cells.join(" | "));
    }
    if !args.no_variants {
        variants(args, &scene, &rows)?;
    }
    if !args.no_paper {
        paper_comparisons(args, &scene)?;
    }
    if let (Ok(px), Ok(vx)) = (read("isg"), read("isg-vertex")) {
        let c = compare(&px, "per pixel", &vx, "per vertex")?;
        println!();
        println!(
            "per vertex vs per pixel (interpolation error): PSNR {} dB, relRMSE {:.4}, FLIP {:.4}",
            c.psnr_db.map_or("inf".into(), |p| format!("{p:.2}")),
            c.rel_rmse,
            c.flip_mean
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::equal_error_ms;

    #[test]
    fn equal_error_interpolates_mc_in_log_log() {
        // error halves per 4x samples, cost grows 4x
        let mc = [(1, 10.0, 0.4), (4, 40.0, 0.2), (16, 160.0, 0.1)];
        let (ms, a, b) = equal_error_ms(&mc, 0.2).unwrap();
        assert!((ms - 40.0).abs() < 1e-9 && (a, b) == (1, 4), "{ms} {a} {b}");
        // between 4 and 16 spp: error 0.1414 (log midpoint) costs 80 ms (log midpoint)
        let (ms, a, b) = equal_error_ms(&mc, 0.2f64.sqrt() * 0.1f64.sqrt()).unwrap();
        assert!((ms - 80.0).abs() < 1e-6 && (a, b) == (4, 16), "{ms}");
        // already reached by the fewest samples: that point's cost
        assert_eq!(equal_error_ms(&mc, 0.5).unwrap(), (10.0, 1, 1));
        // never reached: the most accurate point
        assert_eq!(equal_error_ms(&mc, 0.05).unwrap_err(), (16, 160.0, 0.1));
        assert!(equal_error_ms(&[], 0.1).is_err());
    }
}
