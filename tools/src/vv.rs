//! `penumbra precompute vv MODEL`: vectorized visibility (per vertex) and the spherical-Voronoi
//! correspondence (per triangle) of a static scene or model, written to one `.pvv` file
//! (`penumbra_math::vv`), with sizes and times (the paper's Table 1 columns).

use anyhow::{anyhow, Result};
use clap::Args;
use penumbra_math::vv::{self, Stage, VvData, VvModel, VvParams};
use penumbra_scene::Scene;
use std::path::PathBuf;

#[derive(Args)]
pub struct VvArgs {
    /// Scene file (.toml) or glTF model (.glb/.gltf); every object is static geometry (objects
    /// with casts_shadow = false only receive).
    pub model: PathBuf,
    /// Output file (default: <model stem>.pvv in the current directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Visibility map resolution N (N x N Lambert equal-area cells per vertex hemisphere).
    #[arg(long, default_value_t = VvParams::default().resolution)]
    pub resolution: u32,
    /// Bisection steps refining each boundary crossing.
    #[arg(long, default_value_t = VvParams::default().refine_steps)]
    pub refine_steps: u32,
    /// Simplification tolerance of the boundary loops, degrees.
    #[arg(long, default_value_t = VvParams::default().tolerance_deg)]
    pub tolerance: f32,
    /// Longest boundary segment, degrees.
    #[arg(long, default_value_t = VvParams::default().max_segment_deg)]
    pub max_segment: f32,
    /// Largest angle between linked entities of a correspondence triple, degrees.
    #[arg(long, default_value_t = VvParams::default().max_link_deg)]
    pub max_link: f32,
    /// Receiver refinement, as the technique's `refine` parameter: edges longer than
    /// sqrt(scene area / refine) are split; 0 keeps the meshes as given.
    #[arg(long, default_value_t = penumbra_passes::vv::VvSettings::default().refine)]
    pub refine: u32,
    /// Seed of the correspondence (random triangle order, symbolic perturbation).
    #[arg(long, default_value_t = VvParams::default().seed)]
    pub seed: u64,
    /// Do not precompute: read this existing .pvv file, check it belongs to MODEL and print its
    /// contents' sizes.
    #[arg(long, value_name = "FILE")]
    pub check: Option<PathBuf>,
    /// Also compare with ray-traced visibility at this many random triangle interior points
    /// (eq. 19 blend of eq. 3 syntheses vs eq. 21 interpolation; 0 = skip).
    #[arg(long, default_value_t = 0)]
    pub evaluate: usize,
}

impl VvArgs {
    /// The parameters, validated (bad values are bad input).
    pub fn params(&self) -> std::result::Result<VvParams, String> {
        let p = VvParams {
            resolution: self.resolution,
            refine_steps: self.refine_steps,
            tolerance_deg: self.tolerance,
            max_segment_deg: self.max_segment,
            max_link_deg: self.max_link,
            seed: self.seed,
        };
        p.validate().map(|_| p)
    }
}

/// The static model of a scene as the `vv` technique shades it (`penumbra_passes::vv::scene_model`:
/// every object in world space, long edges refined). Moving or deforming objects are bad input.
pub fn scene_model(scene: &Scene, name: &str, refine: u32) -> std::result::Result<VvModel, String> {
    penumbra_passes::vv::scene_model(scene, refine).map(|g| g.model).map_err(|e| format!("{name}: {e:#}"))
}

fn bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::with_draw_target(Some(len), indicatif::ProgressDrawTarget::stderr());
    b.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{what} {{bar:40}} {{pos}}/{{len}} {{elapsed}} (eta {{eta}})"
        ))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    b
}

/// Prints the Table-1 style summary of `d`.
pub fn report(model_name: &str, d: &VvData) {
    let mb = |b: usize| b as f64 / 1e6;
    let s = &d.stats;
    println!("{model_name}: {} vertices, {} triangles", d.vertex_count, d.triangle_count);
    println!(
        "  vectorized visibility: {} sequences, {} points ({:.1} per vertex), {:.3} MB, {:.2} s",
        d.vis.sequence_count(),
        d.vis.vertex_points,
        d.vis.vertex_points as f64 / d.vertex_count.max(1) as f64,
        mb(s.visibility_bytes),
        s.visibility_seconds
    );
    println!(
        "  correspondence: {} loops, {} triples ({:.1} per triangle; {} from RGB tripoints, {} propagated, {} relaxed, {} routing jumps through a pole), {} virtual points, {:.3} MB, {:.2} s",
        d.corr.loop_offsets.len().saturating_sub(1),
        d.corr.triples.len(),
        d.corr.triples.len() as f64 / d.triangle_count.max(1) as f64,
        s.voronoi_triples,
        s.propagated_triples,
        s.relaxed_triples,
        s.pole_triples,
        d.vis.points.len() - d.vis.vertex_points as usize,
        mb(s.triple_bytes),
        s.correspondence_seconds
    );
}

/// Prints how many triangles' eq. 21 interpolation disagrees with eq. 19's blend
/// (`penumbra_math::vv::interpolation_disagreement`), by threshold.
pub fn report_disagreement(model: &VvModel, d: &VvData) {
    let dis = vv::interpolation_disagreement(model, &d.vis, &d.corr);
    let count = |t: f32| dis.iter().filter(|&&x| x > t).count();
    println!(
        "  eq. 21 vs eq. 19 (occluded solid angle at 4 interior points): {} / {} / {} / {} of {} triangles differ by more than 0.05 / 0.1 / 0.25 / 0.5 sr",
        count(0.05),
        count(0.1),
        count(0.25),
        count(0.5),
        dis.len()
    );
}

/// Runs the subcommand; `Err(String)` is bad input (exit 2), `anyhow` errors are run-time.
pub fn run(args: &VvArgs, scene: &Scene) -> Result<std::result::Result<(), String>> {
    let name = args.model.display().to_string();
    let params = match args.params() {
        Ok(p) => p,
        Err(e) => return Ok(Err(e)),
    };
    let model = match scene_model(scene, &name, args.refine) {
        Ok(m) => m,
        Err(e) => return Ok(Err(e)),
    };
    if let Some(file) = &args.check {
        let d = match VvData::read_for(file, &model) {
            Ok(d) => d,
            Err(e) => return Ok(Err(e)),
        };
        report(&name, &d);
        report_disagreement(&model, &d);
        print_evaluation(args, &model, &d);
        println!(
            "{}: valid for {name} (format version {}, resolution {}, seed {})",
            file.display(),
            vv::FORMAT_VERSION,
            d.params.resolution,
            d.params.seed
        );
        return Ok(Ok(()));
    }
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from(format!("{}.pvv", args.model.file_stem().map_or("model".into(), |s| s.to_string_lossy())))
    });
    let bars = [
        bar(Stage::Visibility.total(&model), "visibility    "),
        bar(Stage::Correspondence.total(&model), "correspondence"),
    ];
    let d = vv::compute(&model, &params, &|stage, n| bars[(stage == Stage::Correspondence) as usize].inc(n))
        .map_err(|e| anyhow!("{name}: {e}"))?;
    bars.iter().for_each(|b| b.finish_and_clear());
    d.write(&out).map_err(|e| anyhow!(e))?;
    report(&name, &d);
    report_disagreement(&model, &d);
    print_evaluation(args, &model, &d);
    println!("wrote {} ({:.3} MB)", out.display(), std::fs::metadata(&out).map(|m| m.len()).unwrap_or(0) as f64 / 1e6);
    Ok(Ok(()))
}

fn print_evaluation(args: &VvArgs, model: &VvModel, d: &VvData) {
    if args.evaluate == 0 {
        return;
    }
    let e = vv::evaluate(model, d, args.evaluate, 48, d.params.seed);
    println!(
        "  vs ray tracing at {} occluded interior points (48x48 directions): eq. 19 blend {:.4}, eq. 21 {:.4} agreeing; eq. 21 at the vertices |dOmega| median {:.4} p95 {:.4} max {:.4} sr",
        e.points, e.agreement_eq19, e.agreement_eq21, e.vertex_error[0], e.vertex_error[1], e.vertex_error[2]
    );
    println!(
        "  eq. 21 at the triangles' own vertices: {} of {} triangles have a corner off by > 0.1 sr, {} by > 1 sr, {} by > 3 sr",
        e.triangles_over[0], e.triangles, e.triangles_over[1], e.triangles_over[2]
    );
}
