//! `penumbra tune SCENE --max-error E` and `--max-error E` on `render` and `view`: the cheapest
//! technique and parameters whose error against the converged reference (RMSE over the
//! reference's mean, the matrix's `rmse_rel_mean`) is at most E on this scene.
//!
//! The points are measured as `bench pareto` measures them (a matrix cell: warm-up frames, then
//! timed frames ending at frame K of the moving scene, against the converged CPU reference of
//! that frame and size), or read from a `pareto.json` it wrote (`--pareto`). The search:
//! 1. every technique that accepts the scene at its defaults;
//! 2. each technique's registered knobs one at a time (`bench pareto`'s configurations), except
//!    for techniques whose defaults cost more than [`PRUNE`] times the cheapest configuration
//!    already within E (a knob rarely buys that much; the skip is printed);
//! 3. when nothing is within E: the knobs' costlier values (`registry::Knob::finer`, mc's
//!    samples per pixel), in order, until one is.
//!
//! Measured points are cached per scene file, size, frame, device and build (the executable's size and time)
//! (`<cache>/points/<stem>-WxH-f<K>-<key>.json`), so `render --max-error` after `tune` does not
//! measure again. Nothing within E is an error that names the most accurate configuration seen.

use crate::pareto::{configurations, label, mark_front, Measure, Point, Target};
use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::engine::{Context, ContextDesc};
use penumbra_passes::registry::{self, Params};
use penumbra_reference::cli::parse_size;
use penumbra_reference::converge::fnv1a64;
use penumbra_scene::Scene;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A technique whose defaults cost more than this many times the cheapest configuration already
/// within the error is not swept further.
pub const PRUNE: f64 = 8.0;

/// The largest image `--max-error` measures at: bigger renders are measured at this width (the
/// render's aspect), and say so.
pub const MAX_TUNE_PIXELS: u32 = 160 * 120;

#[derive(Args, Clone)]
pub struct TuneArgs {
    /// Scene file (.toml) or glTF model.
    pub scene: PathBuf,
    /// The largest accepted error: RMSE over the reference's mean radiance (e.g. 0.2).
    #[arg(long)]
    pub max_error: f64,
    /// Image size WxH the errors are measured at.
    #[arg(long, default_value = "40x30")]
    pub size: String,
    /// Comma-separated techniques to choose from (default: every one that accepts the scene).
    #[arg(long)]
    pub techniques: Option<String>,
    /// Choose from this `bench pareto` output (pareto.json) instead of measuring.
    #[arg(long)]
    pub pareto: Option<PathBuf>,
    /// Store the choice in the scene file (`technique` and `[technique_params]`, with a comment
    /// giving the measured error and cost).
    #[arg(long)]
    pub write: bool,
    /// The compared frame K (scene time K / fps).
    #[arg(long, default_value_t = 30)]
    pub frame: u32,
    /// Timed frames per point.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Frames rendered before timing starts.
    #[arg(long, default_value_t = 1)]
    pub warmup: u32,
    /// Reference and point cache directory (default: <temp>/penumbra-references).
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

/// What a search needs besides the scene.
#[derive(Clone, Debug)]
pub struct TuneOptions {
    pub max_error: f64,
    pub size: (u32, u32),
    pub techniques: Option<String>,
    pub pareto: Option<PathBuf>,
    pub frame: u32,
    pub frames: u32,
    pub warmup: u32,
    pub cache: PathBuf,
}

impl TuneOptions {
    /// `--max-error` on `render`/`view` at `width` x `height`: measured at that size, or at most
    /// [`MAX_TUNE_PIXELS`] with the same aspect.
    pub fn for_render(max_error: f64, pareto: Option<PathBuf>, width: u32, height: u32) -> Self {
        TuneOptions {
            max_error,
            size: tune_size(width, height),
            techniques: None,
            pareto,
            frame: 30,
            frames: 1,
            warmup: 1,
            cache: default_cache(),
        }
    }
}

pub fn default_cache() -> PathBuf {
    std::env::temp_dir().join("penumbra-references")
}

/// The size `--max-error` measures a `width` x `height` render at.
pub fn tune_size(width: u32, height: u32) -> (u32, u32) {
    if width * height <= MAX_TUNE_PIXELS {
        return (width, height);
    }
    let s = (MAX_TUNE_PIXELS as f64 / (width as f64 * height as f64)).sqrt();
    (((width as f64 * s).round() as u32).max(1), ((height as f64 * s).round() as u32).max(1))
}

/// The chosen configuration.
#[derive(Clone, Debug)]
pub struct Choice {
    pub point: Point,
    pub size: (u32, u32),
    /// Where the numbers come from: "measured" or the pareto.json read.
    pub source: String,
    pub device: String,
    /// The frame the error was measured at.
    pub frame: u32,
}

impl Choice {
    /// The flags that select it on `render` and `view`.
    pub fn flags(&self) -> String {
        let mut s = format!("--technique {}", self.point.technique);
        for (k, v) in &self.point.params {
            s += &format!(" --param {k}={v}");
        }
        s
    }

    /// One line: what was chosen and why.
    pub fn describe(&self, max_error: f64) -> String {
        format!(
            "chose {} {} ({}): RMSE/mean {:.4} <= {max_error} at {}x{}, {:.1} ms per frame on {} ({})",
            self.point.technique,
            label(&self.point.params),
            self.flags(),
            self.point.rmse_rel_mean,
            self.size.0,
            self.size.1,
            self.point.frame_ms,
            self.device,
            self.source
        )
    }
}

/// The cheapest point whose error is at most `max_error` (ties: the more accurate).
pub fn cheapest_within(points: &[Point], max_error: f64) -> Option<&Point> {
    points
        .iter()
        .filter(|p| p.rmse_rel_mean.is_finite() && p.rmse_rel_mean <= max_error)
        .min_by(|a, b| a.frame_ms.total_cmp(&b.frame_ms).then(a.rmse_rel_mean.total_cmp(&b.rmse_rel_mean)))
}

fn most_accurate(points: &[Point]) -> Option<&Point> {
    points.iter().filter(|p| p.rmse_rel_mean.is_finite()).min_by(|a, b| a.rmse_rel_mean.total_cmp(&b.rmse_rel_mean))
}

fn nothing_within(scene: &Scene, max_error: f64, size: (u32, u32), points: &[Point]) -> anyhow::Error {
    let best = match most_accurate(points) {
        Some(p) => format!(
            "; the most accurate of the {} configurations measured is {} {} with RMSE/mean {:.4} ({:.1} ms per frame)",
            points.len(),
            p.technique,
            label(&p.params),
            p.rmse_rel_mean,
            p.frame_ms
        ),
        None => "; no configuration rendered".into(),
    };
    crate::bad(format!(
        "no technique reaches RMSE/mean <= {max_error} on '{}' at {}x{}{best}",
        scene.name, size.0, size.1
    ))
}

/// This executable's identity, its size and modification time: a point measured by another
/// build (a technique changed, e.g. mc's sample points in session 32) is measured again rather
/// than trusted.
fn build_id() -> String {
    std::env::current_exe()
        .and_then(std::fs::metadata)
        .map(|m| {
            let t = m.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).unwrap_or_default();
            format!("exe {} bytes {}.{:09}", m.len(), t.as_secs(), t.subsec_nanos())
        })
        .unwrap_or_else(|_| "exe unknown".into())
}

/// The cache of measured points of one scene file, size, frame, device and build.
struct PointCache {
    path: PathBuf,
    points: Vec<Point>,
}

impl PointCache {
    fn open(dir: &Path, stem: &str, bytes: &[u8], o: &TuneOptions, ctx: &Context) -> Self {
        let key = format!(
            "{} {} {}x{} f{} frames {} warmup {} {} {} {} pixel-grid references",
            env!("CARGO_PKG_VERSION"),
            build_id(),
            o.size.0,
            o.size.1,
            o.frame,
            o.frames,
            o.warmup,
            ctx.device_name,
            ctx.driver_info(),
            penumbra_reference::converge::REFERENCE_VERSION
        );
        let h = fnv1a64(key.as_bytes(), fnv1a64(bytes, 0xcbf2_9ce4_8422_2325));
        let stem = penumbra_reference::converge::cache_stem(stem);
        let path = dir.join("points").join(format!("{stem}-{}x{}-f{}-{h:016x}.json", o.size.0, o.size.1, o.frame));
        let points =
            std::fs::read_to_string(&path).ok().and_then(|t| serde_json::from_str(&t).ok()).unwrap_or_default();
        PointCache { path, points }
    }

    fn get(&self, technique: &str, params: &Params) -> Option<Point> {
        self.points.iter().find(|p| p.technique == technique && &p.params == params).cloned()
    }

    fn put(&mut self, p: &Point) {
        self.points.push(p.clone());
        let write = || -> Result<()> {
            if let Some(d) = self.path.parent() {
                std::fs::create_dir_all(d)?;
            }
            std::fs::write(&self.path, serde_json::to_string_pretty(&self.points)? + "\n")?;
            Ok(())
        };
        if let Err(e) = write() {
            eprintln!("tune cache {}: not written: {e:#}", self.path.display());
        }
    }
}

/// Chooses from a `bench pareto` output: the front at `o.size`.
fn from_pareto(file: &Path, scene: &Scene, o: &TuneOptions) -> Result<Choice> {
    let fronts = crate::pareto::read_fronts(file)?;
    let Some(f) = fronts.iter().find(|f| f.size == [o.size.0, o.size.1]) else {
        let sizes: Vec<String> = fronts.iter().map(|f| format!("{}x{}", f.size[0], f.size[1])).collect();
        return Err(crate::bad(format!(
            "{}: no front at {}x{} (it has {})",
            file.display(),
            o.size.0,
            o.size.1,
            if sizes.is_empty() { "none".into() } else { sizes.join(", ") }
        )));
    };
    if f.scene != scene.name {
        return Err(crate::bad(format!("{}: measured on scene '{}', not '{}'", file.display(), f.scene, scene.name)));
    }
    let allowed: Option<Vec<&str>> = o.techniques.as_deref().map(|l| l.split(',').map(str::trim).collect());
    let points: Vec<Point> = f
        .points
        .iter()
        .filter(|p| allowed.as_ref().is_none_or(|a| a.contains(&p.technique.as_str())))
        // a front measured before a technique refused the scene (shadow fields on deforming
        // casters since session 30) must not choose it
        .filter(|p| registry::refusal(&p.technique, scene).is_none())
        .cloned()
        .collect();
    let p = cheapest_within(&points, o.max_error).ok_or_else(|| nothing_within(scene, o.max_error, o.size, &points))?;
    Ok(Choice {
        point: p.clone(),
        size: o.size,
        source: format!("from {}", file.display()),
        device: f.device.clone(),
        frame: o.frame,
    })
}

/// The cheapest configuration within `o.max_error` on `scene` (read from `path`, or the
/// built-in default scene when `None`).
pub fn tune(path: Option<&Path>, scene: &Scene, o: &TuneOptions) -> Result<Choice> {
    if !(o.max_error.is_finite() && o.max_error > 0.0) {
        return Err(crate::bad(format!("--max-error {}: expected a positive number", o.max_error)));
    }
    if let Some(file) = &o.pareto {
        return from_pareto(file, scene, o);
    }
    let (bytes, stem) = match path {
        Some(p) => (
            std::fs::read(p).with_context(|| format!("reading {}", p.display()))?,
            p.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default(),
        ),
        // The built-in scene has no file: its description stands for the bytes.
        None => (format!("{scene:?}").into_bytes(), "default".to_string()),
    };
    let techniques = crate::pareto::techniques_for(o.techniques.as_deref(), scene)?;
    let ctx = Context::new(&ContextDesc::default())?;
    let measure = Measure {
        frames: o.frames,
        warmup: o.warmup,
        frame: o.frame,
        fps: 30.0,
        supersample: 1,
        reference_grid: 0,
        noise: 0.01,
        max_spp: 131072,
        cache: o.cache.clone(),
    };
    let target = Target::new(&ctx, scene, &bytes, &stem, o.size, measure)?;
    let mut cache = PointCache::open(&o.cache, &stem, &bytes, o, &ctx);
    let started = Instant::now();
    let mut points: Vec<Point> = Vec::new();
    let mut refused: BTreeMap<&str, String> = BTreeMap::new();
    let mut measure_one = |t: &str, params: &Params, points: &mut Vec<Point>| -> Result<Option<Point>> {
        let params = &crate::matrix::measured_params(t, params.clone());
        eprint!("  {t} {} ({:.0} s so far) ... ", label(params), started.elapsed().as_secs_f64());
        let p = match cache.get(t, params) {
            Some(p) => {
                eprint!("(cached) ");
                p
            }
            None => match target.point(t, params)? {
                Ok(p) => {
                    cache.put(&p);
                    p
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    return Ok(None);
                }
            },
        };
        eprintln!("{:.1} ms/frame, RMSE/mean {:.4}", p.frame_ms, p.rmse_rel_mean);
        points.push(p.clone());
        Ok(Some(p))
    };
    eprintln!("tune: '{}' at {}x{}, frame {}, RMSE/mean <= {}", scene.name, o.size.0, o.size.1, o.frame, o.max_error);
    // 1. Every technique at its defaults.
    let mut defaults_ms: BTreeMap<&str, f64> = BTreeMap::new();
    for t in &techniques {
        if let Some(why) = registry::refusal(t.name, scene) {
            refused.insert(t.name, why.to_string());
            continue;
        }
        match measure_one(t.name, &Params::new(), &mut points)? {
            Some(p) => {
                defaults_ms.insert(t.name, p.frame_ms);
            }
            None => {
                refused.insert(t.name, "failed at its defaults".into());
            }
        }
    }
    // 2. Each knob value alone, unless the technique is far costlier than a point within E.
    for t in &techniques {
        let Some(&ms) = defaults_ms.get(t.name) else { continue };
        let configs = configurations(t);
        if let Some(best) = cheapest_within(&points, o.max_error) {
            if ms > PRUNE * best.frame_ms {
                eprintln!(
                    "  {}: its {} other configurations skipped (defaults {ms:.1} ms per frame, over {PRUNE} x the {:.1} ms of {} {})",
                    t.name,
                    configs.len() - 1,
                    best.frame_ms,
                    best.technique,
                    label(&best.params)
                );
                continue;
            }
        }
        for params in &configs[1..] {
            measure_one(t.name, params, &mut points)?;
        }
    }
    // 3. Nothing within E: the costlier knob values, in order, until one is.
    'finer: for t in &techniques {
        if !defaults_ms.contains_key(t.name) {
            continue;
        }
        for kn in t.knobs {
            for v in kn.finer {
                if cheapest_within(&points, o.max_error).is_some() {
                    break 'finer;
                }
                let params: Params = [(kn.key.to_string(), v.to_string())].into_iter().collect();
                measure_one(t.name, &params, &mut points)?;
            }
        }
    }
    for (t, why) in &refused {
        eprintln!("  {t}: not a candidate ({why})");
    }
    mark_front(&mut points);
    let p = cheapest_within(&points, o.max_error).ok_or_else(|| nothing_within(scene, o.max_error, o.size, &points))?;
    Ok(Choice {
        point: p.clone(),
        size: o.size,
        source: "measured".into(),
        device: ctx.device_name.clone(),
        frame: o.frame,
    })
}

/// Stores `choice` in the scene file at `path`: `technique`, `[technique_params]` (replaced)
/// and a comment with the measured numbers above the technique line. Other lines are kept.
pub fn write_choice(path: &Path, choice: &Choice, max_error: f64) -> Result<()> {
    if path.extension().and_then(|e| e.to_str()) != Some("toml") {
        return Err(crate::bad(format!(
            "{}: --write stores the choice in a scene file (.toml); write a scene that names this model and tune that",
            path.display()
        )));
    }
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut doc: toml_edit::DocumentMut =
        text.parse().map_err(|e| crate::bad(format!("{}: not TOML: {e}", path.display())))?;
    doc.remove("technique");
    doc.remove("technique_params");
    doc.insert("technique", toml_edit::value(choice.point.technique.as_str()));
    if let Some(mut key) = doc.key_mut("technique") {
        key.leaf_decor_mut().set_prefix(format!(
            "\n# Chosen by `penumbra tune --max-error {max_error}`: RMSE/mean {:.4} at {}x{} (frame {}),\n# {:.1} ms per frame on {}.\n",
            choice.point.rmse_rel_mean, choice.size.0, choice.size.1, choice.frame, choice.point.frame_ms, choice.device
        ));
    }
    if !choice.point.params.is_empty() {
        let mut t = toml_edit::Table::new();
        for (k, v) in &choice.point.params {
            // Numbers stay numbers, the rest strings (the loader takes both).
            let item = match v.parse::<i64>() {
                Ok(i) => toml_edit::value(i),
                Err(_) => match v.parse::<f64>() {
                    Ok(f) => toml_edit::value(f),
                    Err(_) => toml_edit::value(v.as_str()),
                },
            };
            t.insert(k, item);
        }
        doc.insert("technique_params", toml_edit::Item::Table(t));
    }
    std::fs::write(path, doc.to_string()).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// `penumbra tune`.
pub fn run(args: &TuneArgs, limits: &penumbra_scene::Limits) -> Result<()> {
    let size = parse_size(&args.size).map_err(crate::bad)?;
    let scene = crate::load_scene(Some(&args.scene), limits)?;
    let o = TuneOptions {
        max_error: args.max_error,
        size,
        techniques: args.techniques.clone(),
        pareto: args.pareto.clone(),
        frame: args.frame,
        frames: args.frames,
        warmup: args.warmup,
        cache: args.cache.clone().unwrap_or_else(default_cache),
    };
    if args.write && args.scene.extension().and_then(|e| e.to_str()) != Some("toml") {
        return Err(crate::bad(format!("{}: --write needs a scene file (.toml)", args.scene.display())));
    }
    let choice = tune(Some(&args.scene), &scene, &o)?;
    println!("{}", choice.describe(args.max_error));
    if args.write {
        write_choice(&args.scene, &choice, args.max_error)?;
        println!("wrote the choice to {}", args.scene.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pareto::tests::pt;

    #[test]
    fn the_cheapest_point_within_the_error_is_chosen() {
        let p = vec![
            pt("env", 1.0, 0.5),
            pt("sm", 5.0, 0.15),
            pt("isg", 4.0, 0.19),
            pt("mc", 50.0, 0.04),
            pt("nan", 0.1, f64::NAN),
        ];
        assert_eq!(cheapest_within(&p, 0.2).unwrap().technique, "isg");
        assert_eq!(cheapest_within(&p, 0.16).unwrap().technique, "sm");
        assert_eq!(cheapest_within(&p, 0.05).unwrap().technique, "mc");
        assert!(cheapest_within(&p, 0.01).is_none());
        let e = nothing_within(&Scene::empty("s"), 0.01, (40, 30), &p).to_string();
        assert!(e.contains("mc") && e.contains("0.0400"), "{e}");
    }

    #[test]
    fn big_renders_are_tuned_at_a_small_size_of_the_same_aspect() {
        assert_eq!(tune_size(40, 30), (40, 30));
        assert_eq!(tune_size(160, 120), (160, 120));
        assert_eq!(tune_size(640, 480), (160, 120));
        let (w, h) = tune_size(1920, 1080);
        assert!(w * h <= MAX_TUNE_PIXELS + 200 && (w as f64 / h as f64 - 16.0 / 9.0).abs() < 0.02, "{w}x{h}");
    }

    #[test]
    fn the_choice_is_written_into_the_scene_file_keeping_the_rest() {
        let dir = std::env::temp_dir().join(format!("penumbra-tune-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.toml");
        std::fs::write(&path, "# my scene\nname = \"s\"\ntechnique = \"isg\"\n\n[technique_params]\nlobes = 8\n\n[camera]\neye = [0.0, 1.0, 2.0]\n").unwrap();
        let mut p = pt("mc", 12.0, 0.04);
        p.params.insert("spp".into(), "256".into());
        let c = Choice { point: p, size: (40, 30), source: "measured".into(), device: "dev".into(), frame: 30 };
        write_choice(&path, &c, 0.05).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let v: toml::Table = text.parse().unwrap();
        assert_eq!(v["technique"].as_str(), Some("mc"));
        assert_eq!(v["technique_params"]["spp"].as_integer(), Some(256));
        assert!(v["technique_params"].get("lobes").is_none(), "{text}");
        assert!(
            text.contains("# my scene") && text.contains("RMSE/mean 0.0400") && text.contains("[camera]"),
            "{text}"
        );
        assert!(write_choice(&dir.join("m.glb"), &c, 0.05).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
