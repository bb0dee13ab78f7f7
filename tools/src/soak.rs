//! `penumbra bench soak`: memory over time. Each technique in turn renders many frames of an
//! animated scene at a small size; host RSS, device memory held through the allocator and the
//! engine's pooled transients are sampled as it goes. After the warm-up frames both must stay
//! flat: a renderer that runs for hours may not grow (issue 25).

use anyhow::{Context as _, Result};
use clap::Args;
use penumbra::engine::{Context, ContextDesc};
use penumbra::{RenderSettings, Renderer};
use penumbra_passes::registry;
use penumbra_reference::cli::parse_size;
use penumbra_scene::Scene;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Clone)]
pub struct SoakArgs {
    /// Scene file (.toml) or glTF model (default: the built-in default scene).
    pub scene: Option<PathBuf>,
    /// Comma-separated techniques (default: every one that accepts the scene).
    #[arg(long)]
    pub techniques: Option<String>,
    /// Frames per technique (the scene's time loops over its first 10 s).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(2..))]
    pub frames: u32,
    /// Frames before the memory must be flat.
    #[arg(long, default_value_t = 100)]
    pub warmup: u32,
    #[arg(long, default_value = "32x24")]
    pub size: String,
    /// Largest accepted growth of host RSS after the warm-up (peak of the second half of the
    /// frames against the peak of the first), in MiB.
    #[arg(long, default_value_t = 16.0)]
    pub max_rss_growth_mib: f64,
    /// Output directory: soak.json.
    #[arg(long, default_value = "soak-out")]
    pub out: PathBuf,
}

/// Memory at one frame.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Sample {
    pub frame: u32,
    pub rss_bytes: u64,
    pub gpu_allocated_bytes: u64,
    pub gpu_allocations: usize,
    pub gpu_reserved_bytes: u64,
    pub pooled_transients: usize,
}

/// One technique's run.
#[derive(Clone, Debug, Serialize)]
pub struct Run {
    pub technique: String,
    pub frames: u32,
    pub ms_per_frame: f64,
    pub samples: Vec<Sample>,
    /// Host RSS growth after the warm-up: the peak over the second half of the remaining
    /// frames minus the peak over the first half, bytes.
    pub rss_growth_bytes: i64,
    /// The same for device memory allocated (flat: at most 2 % or 1 MiB).
    pub gpu_growth_bytes: i64,
    pub flat: bool,
}

/// Resident set size of this process (Linux `/proc/self/statm`; 0 elsewhere).
pub fn rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1).and_then(|p| p.parse::<u64>().ok()))
        .map_or(0, |pages| pages * 4096)
}

/// Renders `frames` frames of `scene` with `technique` at `w` x `h`, sampling memory every
/// `every` frames and at the warm-up frame and the last.
pub fn soak_one(
    ctx: &std::sync::Arc<Context>,
    scene: &Scene,
    technique: &str,
    frames: u32,
    warmup: u32,
    w: u32,
    h: u32,
    max_rss_growth: u64,
) -> Result<Run> {
    let settings = RenderSettings { width: w, height: h, technique: Some(technique.to_string()), ..Default::default() };
    let mut r = Renderer::new(ctx.clone(), scene, settings)?;
    let every = (frames / 50).max(1);
    let mut samples = Vec::new();
    let sample = |k: u32, r: &Renderer| {
        let (alloc, n, reserved) = r.context().memory_report();
        Sample {
            frame: k,
            rss_bytes: rss_bytes(),
            gpu_allocated_bytes: alloc,
            gpu_allocations: n,
            gpu_reserved_bytes: reserved,
            pooled_transients: r.engine.pooled(),
        }
    };
    let fps = 30.0;
    let start = Instant::now();
    let mut prev = None;
    for k in 0..frames {
        // loop the first 10 s of the animation (a scene's motion may end)
        let t = (k % 300) as f32 / fps;
        let frame = scene.at(t, prev);
        prev = Some(t);
        r.render(&frame, None, false)?;
        if k % every == 0 || k + 1 == frames || k == warmup {
            samples.push(sample(k, &r));
        }
    }
    r.finish()?;
    let ms = start.elapsed().as_secs_f64() * 1e3 / frames as f64;
    // Growth: the peak over the second half of the frames after the warm-up against the peak
    // over the first half (robust to the ups and downs of techniques whose buffers follow
    // the scene; a leak of any size per frame shows).
    let after: Vec<&Sample> = samples.iter().filter(|s| s.frame >= warmup.min(frames - 1)).collect();
    let mid = after.len() / 2;
    let peak = |v: &[&Sample], f: fn(&Sample) -> u64| v.iter().map(|s| f(s)).max().unwrap_or(0) as i64;
    let (first, second) = if mid == 0 { (&after[..], &after[..]) } else { after.split_at(mid) };
    let rss_growth = peak(second, |s| s.rss_bytes) - peak(first, |s| s.rss_bytes);
    let gpu_first = peak(first, |s| s.gpu_allocated_bytes);
    let gpu_growth = peak(second, |s| s.gpu_allocated_bytes) - gpu_first;
    let flat = rss_growth <= max_rss_growth as i64 && gpu_growth <= (gpu_first / 50).max(1 << 20);
    Ok(Run {
        technique: technique.to_string(),
        frames,
        ms_per_frame: ms,
        samples,
        rss_growth_bytes: rss_growth,
        gpu_growth_bytes: gpu_growth,
        flat,
    })
}

fn mib(b: i64) -> f64 {
    b as f64 / (1u64 << 20) as f64
}

pub fn run(args: &SoakArgs, scene: &Scene) -> Result<()> {
    let (w, h) = parse_size(&args.size).map_err(crate::bad)?;
    if args.warmup >= args.frames {
        return Err(crate::bad("--warmup must be less than --frames"));
    }
    let techniques = crate::pareto::techniques_for(args.techniques.as_deref(), scene)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let ctx = Context::new(&ContextDesc::default())?;
    let max_growth = (args.max_rss_growth_mib * (1u64 << 20) as f64) as u64;
    let mut runs = Vec::new();
    println!("soak: '{}' at {w}x{h}, {} frames per technique, flat after frame {} (RSS within {} MiB, device memory not growing)", scene.name, args.frames, args.warmup, args.max_rss_growth_mib);
    println!(
        "{:<20} {:>9} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10} {:>6}",
        "technique",
        "ms/frame",
        "RSS@warm MiB",
        "RSS@end MiB",
        "GPU@warm MiB",
        "GPU@end MiB",
        "RSS grew",
        "GPU grew",
        "flat"
    );
    for t in &techniques {
        if let Some(why) = registry::refusal(t.name, scene) {
            println!("{:<20} refused: {why}", t.name);
            continue;
        }
        let run = soak_one(&ctx, scene, t.name, args.frames, args.warmup, w, h, max_growth)
            .with_context(|| format!("soak of {}", t.name))?;
        let warm = run.samples.iter().find(|s| s.frame >= args.warmup).copied().unwrap_or(run.samples[0]);
        let last = *run.samples.last().unwrap();
        println!(
            "{:<20} {:>9.1} {:>12.1} {:>12.1} {:>12.2} {:>12.2} {:>10.2} {:>10.2} {:>6}",
            t.name,
            run.ms_per_frame,
            mib(warm.rss_bytes as i64),
            mib(last.rss_bytes as i64),
            mib(warm.gpu_allocated_bytes as i64),
            mib(last.gpu_allocated_bytes as i64),
            mib(run.rss_growth_bytes),
            mib(run.gpu_growth_bytes),
            if run.flat { "yes" } else { "NO" }
        );
        runs.push(run);
    }
    let json = serde_json::json!({
        "scene": scene.name,
        "device": ctx.device_name,
        "driver": ctx.driver_info(),
        "size": [w, h],
        "frames": args.frames,
        "warmup": args.warmup,
        "runs": runs,
    });
    let path = args.out.join("soak.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    let grown: Vec<&str> = runs.iter().filter(|r| !r.flat).map(|r| r.technique.as_str()).collect();
    if !grown.is_empty() {
        anyhow::bail!("memory grew after the warm-up under: {}", grown.join(", "));
    }
    Ok(())
}
