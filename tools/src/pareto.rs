//! `penumbra bench pareto`: the speed/accuracy trade of every technique on one scene. For each
//! technique that accepts the scene: its defaults, then each of its registered knobs
//! (`registry::TechniqueInfo::knobs`) at each of the knob's values, one knob at a time; each point
//! rendered as a matrix cell is (warm-up frames, then consecutive timed frames ending at frame K,
//! the scene moving, so rebuilds are in the cost) and compared with the converged, cached CPU
//! reference of that frame and size. The front is the set of points no other point beats on both
//! frame_ms and rmse_rel_mean. Writes `pareto.json` (one object per size), `pareto.md` and a
//! chart per size, error against log ms, each technique's points joined in order of cost
//! (`pareto.png` for the first size, `pareto_WxH.png` for every size).

use crate::matrix::{render_technique, MatrixArgs};
use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::engine::{Context, ContextDesc};
use penumbra_passes::registry::{self, Params};
use penumbra_reference::cli::parse_size;
use penumbra_reference::converge::{load_or_render, ConvergeOptions};
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

#[derive(Args, Clone)]
pub struct ParetoArgs {
    /// Scene file (.toml) or glTF model.
    pub scene: PathBuf,
    /// Comma-separated techniques. Default: every registered technique that accepts the scene.
    #[arg(long)]
    pub techniques: Option<String>,
    /// Image size WxH (reference and compared images).
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Comma-separated sizes W1xH1,...: the fronts at each (overrides --size).
    #[arg(long)]
    pub sizes: Option<String>,
    /// Timed frames per point (consecutive, the last one is frame K).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Frames rendered before timing starts.
    #[arg(long, default_value_t = 2)]
    pub warmup: u32,
    /// The compared frame K (scene time K / fps).
    #[arg(long, default_value_t = 30)]
    pub frame: u32,
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// Techniques render at N x N the size and are box-filtered down.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub supersample: u32,
    /// The reference's pixel grid: each reference pixel averages N x N point samples (default:
    /// the --supersample factor, so that reference and technique sample the same points). 2 with
    /// --supersample 1 times images rendered at the size itself against the anti-aliased
    /// references of `bench matrix`'s default (its --supersample 2), so that a front at 640x480
    /// reuses them without rendering techniques at 1280x960.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub reference_grid: Option<u32>,
    /// Target noise of the converged references (RMSE over the mean).
    #[arg(long, default_value_t = 0.01)]
    pub noise: f64,
    /// Most reference samples per pixel.
    #[arg(long, default_value_t = 131072)]
    pub max_spp: u32,
    /// Reference cache directory (default: <temp>/penumbra-references, shared with the matrix).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Output directory: pareto.json, pareto.md, pareto.png, pareto_WxH.png.
    #[arg(long, default_value = "pareto-out")]
    pub out: PathBuf,
    /// Measure nothing: re-draw the table and charts of this earlier pareto.json into --out.
    #[arg(long)]
    pub from: Option<PathBuf>,
}

/// One measured configuration.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Point {
    pub technique: String,
    /// The parameters away from the technique's defaults (empty: the defaults).
    pub params: Params,
    pub frame_ms: f64,
    pub gpu_ms: f64,
    pub cpu_ms: f64,
    pub rmse_rel_mean: f64,
    pub rel_rmse: f64,
    pub psnr: Option<f64>,
    pub flip: f64,
    pub on_front: bool,
}

/// The points of one size.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Front {
    pub scene: String,
    pub device: String,
    pub driver: String,
    pub size: [u32; 2],
    /// Points that failed to render: (technique, params, error).
    pub errors: Vec<(String, Params, String)>,
    pub points: Vec<Point>,
}

/// Marks the points no other point beats on both frame_ms and rmse_rel_mean (ties on both are
/// kept).
pub fn mark_front(points: &mut [Point]) {
    let dominated: Vec<bool> = points
        .iter()
        .map(|p| {
            points.iter().any(|q| {
                q.frame_ms <= p.frame_ms
                    && q.rmse_rel_mean <= p.rmse_rel_mean
                    && (q.frame_ms < p.frame_ms || q.rmse_rel_mean < p.rmse_rel_mean)
            })
        })
        .collect();
    for (p, d) in points.iter_mut().zip(dominated) {
        p.on_front = !d;
    }
}

/// The configurations of one technique: the defaults, then each knob value alone.
pub fn configurations(info: &registry::TechniqueInfo) -> Vec<Params> {
    let mut v = vec![Params::new()];
    for kn in info.knobs {
        for value in kn.values {
            v.push([(kn.key.to_string(), value.to_string())].into_iter().collect());
        }
    }
    v
}

pub fn label(p: &Params) -> String {
    if p.is_empty() {
        "defaults".into()
    } else {
        p.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(",")
    }
}

/// How the points of a front are measured (shared by `bench pareto` and `penumbra tune`).
#[derive(Clone, Debug)]
pub struct Measure {
    pub frames: u32,
    pub warmup: u32,
    pub frame: u32,
    pub fps: f32,
    pub supersample: u32,
    /// The reference's pixel grid (0: the supersample factor).
    pub reference_grid: u32,
    pub noise: f64,
    pub max_spp: u32,
    /// The reference cache directory.
    pub cache: PathBuf,
}

impl Measure {
    /// The converged reference's options at `w` x `h`: its pixel grid is `reference_grid`, else
    /// the supersample factor.
    pub(crate) fn reference_options(&self, scene: &Scene, w: u32, h: u32) -> ConvergeOptions {
        crate::matrix::converge_options(
            scene,
            w,
            h,
            if self.reference_grid > 0 { self.reference_grid } else { self.supersample },
            self.frame,
            self.fps,
            self.noise,
            self.max_spp,
        )
    }

    fn matrix_args(&self, w: u32, h: u32) -> MatrixArgs {
        MatrixArgs {
            scenes: None,
            techniques: None,
            size: format!("{w}x{h}"),
            supersample: self.supersample,
            noise: self.noise,
            max_spp: self.max_spp,
            frame: self.frame,
            fps: self.fps,
            warmup: self.warmup,
            frames: self.frames,
            out: PathBuf::from("."),
            cache: None,
            known: None,
            check: false,
            write_known: false,
            validation: false,
            params: Vec::new(),
            tracer: Default::default(),
        }
    }
}

/// A scene file and its converged reference at one size: what points are compared with.
pub struct Target<'a> {
    pub scene: &'a Scene,
    pub ctx: &'a Arc<Context>,
    pub reference: Image,
    pub size: (u32, u32),
    pub measure: Measure,
}

impl<'a> Target<'a> {
    /// Loads (or renders and caches) the converged reference of `scene` (read from a file holding
    /// `bytes`, named `stem`) at `size`.
    pub fn new(
        ctx: &'a Arc<Context>,
        scene: &'a Scene,
        bytes: &[u8],
        stem: &str,
        size: (u32, u32),
        measure: Measure,
    ) -> Result<Self> {
        let (w, h) = size;
        let copts = measure.reference_options(scene, w, h);
        // a fresh clone converges nothing the repository holds (tests/matrix/references*)
        crate::matrix::seed_reference(
            &measure.cache,
            &crate::matrix::checked_in_references(),
            scene,
            stem,
            bytes,
            &copts,
        );
        let reference = load_or_render(scene, bytes, stem, &copts, Some(&measure.cache))
            .with_context(|| format!("reference of {} at {w}x{h}", scene.name))?;
        eprintln!("{w}x{h}: reference {} spp, noise {:.4}", reference.meta.spp, reference.meta.noise_rmse_rel_mean);
        Ok(Target { scene, ctx, reference: reference.radiance, size, measure })
    }

    /// Renders one configuration as a matrix cell is rendered and compares it with the
    /// reference. Errors and panics of the technique come back as `Err(message)`.
    pub fn point(&self, technique: &str, params: &Params) -> Result<std::result::Result<Point, String>> {
        let (w, h) = self.size;
        let margs = self.measure.matrix_args(w, h);
        let params = &crate::matrix::measured_params(technique, params.clone());
        let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            render_technique(self.ctx, self.scene, technique, Some(params.clone()), &margs, w, h)
        }));
        let run = match run {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => return Ok(Err(format!("{e:#}"))),
            Err(_) => return Ok(Err("panicked".into())),
        };
        let c = compare(&self.reference, "reference", &run.image, technique)?;
        Ok(Ok(Point {
            technique: technique.to_string(),
            params: params.clone(),
            frame_ms: run.frame_ms,
            gpu_ms: run.gpu_ms,
            cpu_ms: run.cpu_ms,
            rmse_rel_mean: c.rmse_rel_mean,
            rel_rmse: c.rel_rmse,
            psnr: c.psnr_db,
            flip: c.flip_mean,
            on_front: false,
        }))
    }

    /// An empty front of this target.
    pub fn front(&self) -> Front {
        Front {
            scene: self.scene.name.clone(),
            device: self.ctx.device_name.clone(),
            driver: self.ctx.driver_info(),
            size: [self.size.0, self.size.1],
            errors: Vec::new(),
            points: Vec::new(),
        }
    }
}

/// The sizes of `--size` or `--sizes`.
pub fn parse_sizes(list: &str) -> Result<Vec<(u32, u32)>> {
    let sizes: Vec<(u32, u32)> = list
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| parse_size(s).map_err(crate::bad))
        .collect::<Result<_>>()?;
    if sizes.is_empty() {
        return Err(crate::bad("--sizes: no size given"));
    }
    Ok(sizes)
}

/// The techniques of `--techniques` (default: every registered one that accepts the scene).
pub fn techniques_for(list: Option<&str>, scene: &Scene) -> Result<Vec<&'static registry::TechniqueInfo>> {
    match list {
        None => Ok(registry::REGISTRY.iter().filter(|t| registry::refusal(t.name, scene).is_none()).collect()),
        Some(list) => list
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(|t| registry::lookup(t).map_err(crate::bad))
            .collect(),
    }
}

/// Reads a `pareto.json` this command wrote (a missing or malformed file is bad input).
pub fn read_fronts(path: &std::path::Path) -> Result<Vec<Front>> {
    let text = std::fs::read_to_string(path).map_err(|e| crate::bad(format!("reading {}: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| crate::bad(format!("{}: not a pareto.json: {e}", path.display())))
}

pub fn run(args: &ParetoArgs) -> Result<()> {
    if let Some(from) = &args.from {
        // Re-draw from an earlier run: nothing is measured.
        let fronts = read_fronts(from)?;
        std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
        return write_outputs(&fronts, &args.out);
    }
    let sizes = parse_sizes(args.sizes.as_deref().unwrap_or(&args.size))?;
    let scene = Scene::load(&args.scene).map_err(crate::bad)?;
    let techniques = techniques_for(args.techniques.as_deref(), &scene)?;
    let bytes = std::fs::read(&args.scene).with_context(|| format!("reading {}", args.scene.display()))?;
    let stem = args.scene.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default();
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let measure = Measure {
        frames: args.frames,
        warmup: args.warmup,
        frame: args.frame,
        fps: args.fps,
        supersample: args.supersample,
        reference_grid: args.reference_grid.unwrap_or(0),
        noise: args.noise,
        max_spp: args.max_spp,
        cache: args.cache.clone().unwrap_or_else(|| std::env::temp_dir().join("penumbra-references")),
    };
    let ctx = Context::new(&ContextDesc::default())?;
    let started = Instant::now();
    let mut fronts = Vec::new();
    for &size in &sizes {
        let target = Target::new(&ctx, &scene, &bytes, &stem, size, measure.clone())?;
        let mut front = target.front();
        let total: usize = techniques.iter().map(|t| configurations(t).len()).sum();
        let mut done = 0;
        for t in &techniques {
            for params in configurations(t) {
                done += 1;
                eprint!(
                    "  [{done}/{total}] {} {} ({:.0} s so far) ... ",
                    t.name,
                    label(&params),
                    started.elapsed().as_secs_f64()
                );
                match target.point(t.name, &params)? {
                    Ok(p) => {
                        eprintln!("{:.1} ms/frame, rmse/mean {:.4}", p.frame_ms, p.rmse_rel_mean);
                        front.points.push(p);
                    }
                    Err(e) => {
                        eprintln!("error: {e}");
                        front.errors.push((t.name.to_string(), params, e));
                    }
                }
            }
        }
        mark_front(&mut front.points);
        fronts.push(front);
    }
    write_outputs(&fronts, &args.out)
}

/// Writes `pareto.json`, `pareto.md` and the charts of `fronts` into `out` (series in registry
/// order).
pub fn write_outputs(fronts: &[Front], out: &std::path::Path) -> Result<()> {
    let techniques: Vec<&registry::TechniqueInfo> = registry::REGISTRY
        .iter()
        .filter(|t| fronts.iter().any(|f| f.points.iter().any(|p| p.technique == t.name)))
        .collect();
    let json = out.join("pareto.json");
    std::fs::write(&json, serde_json::to_string_pretty(fronts)? + "\n")
        .with_context(|| format!("writing {}", json.display()))?;
    let md = out.join("pareto.md");
    std::fs::write(&md, table_md(fronts)).with_context(|| format!("writing {}", md.display()))?;
    for (i, f) in fronts.iter().enumerate() {
        let chart = crate::plot::Chart::new(
            format!("{} {}x{}: error against cost (front: *)", f.scene, f.size[0], f.size[1]),
            "ms per frame (wall clock)",
            "RMSE / reference mean",
        )
        .log(true, true);
        let series: Vec<crate::plot::Series> = techniques
            .iter()
            .filter_map(|t| {
                let mut pts: Vec<&Point> = f.points.iter().filter(|p| p.technique == t.name).collect();
                pts.sort_by(|a, b| a.frame_ms.total_cmp(&b.frame_ms));
                (!pts.is_empty()).then(|| crate::plot::Series {
                    name: t.name.to_string(),
                    points: pts.iter().map(|p| (p.frame_ms, p.rmse_rel_mean)).collect(),
                    labels: pts.iter().map(|p| if p.on_front { "*".to_string() } else { String::new() }).collect(),
                })
            })
            .collect();
        let mut paths = vec![out.join(format!("pareto_{}x{}.png", f.size[0], f.size[1]))];
        if i == 0 {
            paths.push(out.join("pareto.png"));
        }
        for p in paths {
            match crate::plot::write_chart(&p, &chart, &series) {
                Ok(()) => {}
                Err(e) => eprintln!("no chart {}: {e:#}", p.display()),
            }
        }
    }
    print!("{}", table_md(fronts));
    println!("wrote {}, {} and the charts", json.display(), md.display());
    Ok(())
}

/// The points of every size as Markdown tables (front points marked).
pub fn table_md(fronts: &[Front]) -> String {
    let mut s = String::new();
    for f in fronts {
        s += &format!("## {} at {}x{} ({}, {})\n\n", f.scene, f.size[0], f.size[1], f.device, f.driver);
        s += "| technique | parameters | ms/frame | GPU ms | CPU ms | rmse/mean | relRMSE | FLIP | front |\n|---|---|---|---|---|---|---|---|---|\n";
        let mut pts: Vec<&Point> = f.points.iter().collect();
        pts.sort_by(|a, b| a.frame_ms.total_cmp(&b.frame_ms));
        for p in pts {
            s += &format!(
                "| {} | {} | {:.1} | {:.1} | {:.1} | {:.4} | {:.4} | {:.4} | {} |\n",
                p.technique,
                label(&p.params),
                p.frame_ms,
                p.gpu_ms,
                p.cpu_ms,
                p.rmse_rel_mean,
                p.rel_rmse,
                p.flip,
                if p.on_front { "*" } else { "" }
            );
        }
        for (t, p, e) in &f.errors {
            s += &format!("| {t} | {} | error: {} | | | | | | |\n", label(p), e.replace('|', "/").replace('\n', " "));
        }
        s += "\n";
    }
    s
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A point of technique `t` at its defaults costing `ms` with error `err` (tests of the
    /// front and of `tune`).
    pub(crate) fn pt(t: &str, ms: f64, err: f64) -> Point {
        Point {
            technique: t.into(),
            params: Params::new(),
            frame_ms: ms,
            gpu_ms: 0.0,
            cpu_ms: 0.0,
            rmse_rel_mean: err,
            rel_rmse: err,
            psnr: None,
            flip: 0.0,
            on_front: false,
        }
    }

    /// `--reference-grid 2` with `--supersample 1` looks up the reference `bench matrix` renders
    /// by default (its --supersample 2): the same cache key; without it the grid follows the
    /// supersample factor (a different reference).
    #[test]
    fn the_reference_grid_selects_the_matrix_default_reference() {
        use penumbra_reference::converge::scene_cache_key;
        let scene = Scene::default_scene();
        let m = |ss, grid| Measure {
            frames: 3,
            warmup: 2,
            frame: 30,
            fps: 30.0,
            supersample: ss,
            reference_grid: grid,
            noise: 0.01,
            max_spp: 131072,
            cache: PathBuf::from("."),
        };
        let matrix = crate::matrix::converge_options(&scene, 64, 48, 2, 30, 30.0, 0.01, 131072);
        let key = |o: &ConvergeOptions| scene_cache_key(&scene, b"scene", o);
        assert_eq!(key(&m(1, 2).reference_options(&scene, 64, 48)), key(&matrix));
        assert_eq!(key(&m(2, 0).reference_options(&scene, 64, 48)), key(&matrix));
        assert_ne!(key(&m(1, 0).reference_options(&scene, 64, 48)), key(&matrix));
    }

    #[test]
    fn the_front_keeps_the_undominated_points() {
        let mut p =
            vec![pt("a", 1.0, 0.5), pt("b", 2.0, 0.2), pt("c", 3.0, 0.3), pt("d", 10.0, 0.05), pt("e", 2.0, 0.2)];
        mark_front(&mut p);
        let on: Vec<bool> = p.iter().map(|p| p.on_front).collect();
        // c is beaten by b on both; b and its twin e are both kept
        assert_eq!(on, vec![true, true, false, true, true]);
    }

    #[test]
    fn configurations_are_the_defaults_then_one_knob_at_a_time() {
        let sm = registry::info("shadowmaps").unwrap();
        let c = configurations(sm);
        assert!(c[0].is_empty());
        assert_eq!(c.len(), 1 + sm.knobs.iter().map(|k| k.values.len()).sum::<usize>());
        assert!(c[1..].iter().all(|p| p.len() == 1));
        // every registered technique but env has at least two knob values: three points or more
        for t in registry::REGISTRY.iter().filter(|t| t.name != "env") {
            assert!(configurations(t).len() >= 3, "{}", t.name);
        }
    }
}
