//! Command-line glue for `penumbra reference` and `penumbra compare` (the binary owns scene
//! loading and the subcommand enum; these are the argument structs and the actions).

use crate::metrics::compare_files;
use crate::render::{render, Mode, ReferenceOptions};
use anyhow::{bail, Context as _};
use clap::Args;
use penumbra_scene::Scene;
use std::path::PathBuf;

/// `penumbra reference [SCENE] --frame K --spp N [--size WxH] --out DIR`
#[derive(Args, Clone, Debug)]
pub struct ReferenceArgs {
    /// Scene file (as for `render`); the built-in default scene when omitted.
    pub scene: Option<PathBuf>,
    /// Frame index K (scene time K / fps unless --time is given).
    #[arg(long, default_value_t = 0)]
    pub frame: u32,
    /// Scene time in seconds (overrides --frame / --fps).
    #[arg(long)]
    pub time: Option<f32>,
    /// Frames per second for --frame.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// Samples per pixel.
    #[arg(long, default_value_t = 256)]
    pub spp: u32,
    /// Image size WxH.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// Output directory (reference.exr, reference_stderr.exr, reference.json).
    #[arg(long, default_value = "reference-out")]
    pub out: PathBuf,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// What to evaluate.
    #[arg(long, value_enum, default_value_t = Mode::Exact)]
    pub mode: Mode,
    /// SG lobes fitted to the environment in --mode sg-lighting.
    #[arg(long, default_value_t = 16)]
    pub sg_lobes: u32,
    /// Primary rays through the centres of an N x N grid of sub-pixels (what a rasterizer sees
    /// at N x N supersampling; 1 = the pixel centre) instead of anywhere in the pixel (0).
    #[arg(long, default_value_t = 0)]
    pub pixel_grid: u32,
    /// Hide the progress bar (it is hidden anyway when stderr is not a terminal).
    #[arg(long)]
    pub no_progress: bool,
}

/// `penumbra compare A.exr B.exr [--json] [--diff OUT.png]` (A is the reference).
#[derive(Args, Clone, Debug)]
pub struct CompareArgs {
    /// Reference image (EXR).
    pub a: PathBuf,
    /// Test image (EXR).
    pub b: PathBuf,
    /// Print the comparison as JSON.
    #[arg(long)]
    pub json: bool,
    /// Write a false-colour difference image (PNG).
    #[arg(long)]
    pub diff: Option<PathBuf>,
}

/// Parse "WxH" (also "W*H" or "W,H").
pub fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let parts: Vec<&str> = s.trim().split(['x', 'X', '*', ',']).collect();
    if parts.len() != 2 {
        bail!("size '{s}' is not WxH (e.g. 320x240)");
    }
    let w: u32 = parts[0].trim().parse().with_context(|| format!("size '{s}': bad width"))?;
    let h: u32 = parts[1].trim().parse().with_context(|| format!("size '{s}': bad height"))?;
    if w == 0 || h == 0 {
        bail!("size '{s}' is empty");
    }
    Ok((w, h))
}

impl ReferenceArgs {
    pub fn options(&self) -> anyhow::Result<ReferenceOptions> {
        let (width, height) = parse_size(&self.size)?;
        let o = ReferenceOptions {
            width,
            height,
            spp: self.spp,
            frame: self.frame,
            time: self.time,
            fps: self.fps,
            seed: self.seed,
            mode: self.mode,
            sg_lobes: self.sg_lobes,
            progress: !self.no_progress,
            pixel_grid: self.pixel_grid,
        };
        crate::render::validate(&o)?;
        Ok(o)
    }
}

/// Render the reference of `scene` (already loaded by the caller) and write it to `args.out`.
pub fn run_reference(args: &ReferenceArgs, scene: &Scene) -> anyhow::Result<()> {
    let opts = args.options()?;
    let img = render(scene, &opts).with_context(|| format!("reference render of scene '{}'", scene.name))?;
    let s = img.write(&args.out)?;
    println!(
        "reference: scene '{}' frame {} (t = {:.4} s), {}x{}, {} spp, {} triangles, {:.2} s",
        s.scene, opts.frame, s.time_s, opts.width, opts.height, opts.spp, s.triangles, s.render_seconds
    );
    println!(
        "noise: relative standard error mean {:.3e}, median {:.3e}, max {:.3e} ({} pixels); mean absolute s.e. {:.3e}",
        s.noise.mean_rel_std_error,
        s.noise.median_rel_std_error,
        s.noise.max_rel_std_error,
        s.noise.pixels_measured,
        s.noise.mean_std_error
    );
    if let Some(e) = s.sg_fit_rel_l2 {
        println!("SG lighting: {} lobes, relative L2 fit error {e:.4}", opts.sg_lobes);
    }
    println!("wrote {} and {}", s.image.display(), s.std_error_image.display());
    Ok(())
}

/// Compare two EXR files and print the metrics (JSON with `--json`).
pub fn run_compare(args: &CompareArgs) -> anyhow::Result<()> {
    let c = compare_files(&args.a, &args.b, args.diff.as_deref())?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        println!("{}", c.summary());
        if let Some(d) = &args.diff {
            println!("diff:          {} (scale {:.6e} = top of the colour map)", d.display(), c.diff_scale);
        }
    }
    Ok(())
}
