//! `penumbra bench shadow-fields SCENE`: per-shell resolutions after adaptation (occlusion and
//! source radiance fields), data size fixed vs adaptive, per-vertex radiance error of adaptive
//! vs fixed and of the GPU path vs the CPU path, negative-lobe statistics, and ms of the CPU and
//! GPU paths on the same (culled) vertex set; the CLI adds the image errors of the technique's
//! variants against the reference renderer.

use super::{
    cpu_shade_points, gpu_shade_points, instance_frames, light_frames, vertex_points, FieldReport, SceneFields,
    SfOptions, ShadowFieldsTechnique,
};
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Context, Engine};
use penumbra_scene::Scene;
use std::fmt;
use std::sync::Arc;

/// Benchmark options.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    pub sf: SfOptions,
    /// Scene time of the measured frame (seconds).
    pub time: f32,
    /// Cull vertices outside the view (at this aspect ratio) or facing away, as the paper does
    /// on the CPU; `None` shades every vertex.
    pub cull: Option<f32>,
    /// Timed repetitions (the median is reported).
    pub repeats: usize,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions { sf: SfOptions::default(), time: 0.5, cull: Some(4.0 / 3.0), repeats: 3 }
    }
}

/// Benchmark results.
#[derive(Clone, Debug)]
pub struct BenchReport {
    pub scene: String,
    pub fields: Vec<FieldReport>,
    /// Source radiance fields of the local lights.
    pub lights: Vec<FieldReport>,
    /// Coefficient bytes over all meshes.
    pub fixed_bytes: usize,
    pub adaptive_bytes: usize,
    pub vertices: usize,
    /// Median ms per frame of the per-vertex radiance: CPU path (all cores), GPU `sf_points`
    /// pass (timestamps), adaptive fields.
    pub cpu_ms: f64,
    pub gpu_ms: f64,
    /// Relative RMS of adaptive vs fixed per-vertex radiance (CPU path).
    pub adaptive_vs_fixed_rel_rmse: f64,
    /// GPU vs CPU (adaptive): relative RMS and max abs difference of per-vertex radiance.
    pub gpu_vs_cpu_rel_rmse: f64,
    pub gpu_vs_cpu_max_abs: f64,
    /// Fraction of vertices whose unclamped radiance had a negative channel (triple-product
    /// ringing), and the most negative value relative to the mean radiance.
    pub negative_fraction: f64,
    pub most_negative_rel: f64,
    /// Precompute seconds over all meshes (0 for cached fields).
    pub precompute_seconds: f64,
}

/// Relative RMS difference `sqrt(sum |a-b|^2 / sum |b|^2)` over rgb triples.
pub fn rel_rmse(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            num += (x[c] - y[c]).powi(2);
            den += y[c].powi(2);
        }
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Runs the benchmark on `scene` at `opts.time`.
pub fn bench(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, opts: &BenchOptions) -> Result<BenchReport> {
    let fields = Arc::new(SceneFields::build(scene, &opts.sf)?);
    let tech = ShadowFieldsTechnique::with_fields(ctx, shaders, scene, fields.clone(), true)?;
    let frame = scene.at(opts.time, None);
    let points = vertex_points(scene, &frame, &fields, opts.cull);
    let ia = instance_frames(scene, &frame, &fields, true, opts.sf.srf);
    let ifx = instance_frames(scene, &frame, &fields, false, opts.sf.srf);
    let srf = opts.sf.srf;
    let la = light_frames(&frame, &fields, true, srf);
    let lfx = light_frames(&frame, &fields, false, srf);
    let window = opts.sf.window;
    let mut cpu_times = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..opts.repeats.max(1) {
        let t = std::time::Instant::now();
        cpu = cpu_shade_points(&points, &ia, &la, &tech.light, &tech.tensor, window);
        cpu_times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let fixed = cpu_shade_points(&points, &ifx, &lfx, &tech.light, &tech.tensor, window);
    let mut engine = Engine::new(ctx.clone(), 1)?;
    // Warm-up: lavapipe compiles the pipeline at its first dispatch.
    let mut gpu = gpu_shade_points(&mut engine, &tech, &frame, &points)?.0;
    let mut gpu_times = Vec::new();
    for _ in 0..opts.repeats.max(1) {
        let (g, ms) = gpu_shade_points(&mut engine, &tech, &frame, &points)?;
        gpu = g;
        gpu_times.push(ms);
    }
    let c3: Vec<[f64; 3]> = cpu.iter().map(|(c, _)| c.to_array()).collect();
    let f3: Vec<[f64; 3]> = fixed.iter().map(|(c, _)| c.to_array()).collect();
    let g3: Vec<[f64; 3]> = gpu.iter().map(|g| [g[0] as f64, g[1] as f64, g[2] as f64]).collect();
    let max_abs = c3.iter().zip(&g3).flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs())).fold(0.0, f64::max);
    let mean = c3.iter().map(|c| (c[0] + c[1] + c[2]) / 3.0).sum::<f64>() / c3.len().max(1) as f64;
    let neg = cpu.iter().filter(|(_, m)| *m < 0.0).count();
    let most_neg = cpu.iter().map(|(_, m)| *m).fold(0.0, f64::min);
    Ok(BenchReport {
        scene: scene.name.clone(),
        fixed_bytes: fields.reports.iter().filter(|r| r.shared_with.is_none()).map(|r| r.fixed_bytes).sum(),
        adaptive_bytes: fields.reports.iter().filter(|r| r.shared_with.is_none()).map(|r| r.adaptive_bytes).sum(),
        precompute_seconds: fields.reports.iter().map(|r| r.seconds).sum(),
        fields: fields.reports.clone(),
        lights: fields.light_reports.clone(),
        vertices: points.len(),
        cpu_ms: median(cpu_times),
        gpu_ms: median(gpu_times),
        adaptive_vs_fixed_rel_rmse: rel_rmse(&c3, &f3),
        gpu_vs_cpu_rel_rmse: rel_rmse(&g3, &c3),
        gpu_vs_cpu_max_abs: max_abs,
        negative_fraction: neg as f64 / cpu.len().max(1) as f64,
        most_negative_rel: if mean > 0.0 { most_neg / mean } else { most_neg },
    })
}

impl fmt::Display for BenchReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "shadow fields: {}", self.scene)?;
        writeln!(
            f,
            "{:<20} {:>7} {:>7} {:>10} {:>10} {:>8}  per-shell R (innermost first)",
            "mesh", "verts", "tris", "fixed KB", "adapt KB", "precomp s"
        )?;
        for r in self.fields.iter().chain(&self.lights) {
            if let Some(first) = r.shared_with {
                writeln!(f, "{:<20} {:>7} {:>7}  (shares the field of mesh {first})", r.mesh, r.vertices, r.triangles)?;
                continue;
            }
            let res: Vec<String> = r.resolutions.iter().map(|x| x.to_string()).collect();
            writeln!(
                f,
                "{:<20} {:>7} {:>7} {:>10.1} {:>10.1} {:>8.2}  {}",
                r.mesh,
                r.vertices,
                r.triangles,
                r.fixed_bytes as f64 / 1024.0,
                r.adaptive_bytes as f64 / 1024.0,
                r.seconds,
                res.join(" ")
            )?;
        }
        let red = if self.fixed_bytes > 0 {
            100.0 * (1.0 - self.adaptive_bytes as f64 / self.fixed_bytes as f64)
        } else {
            0.0
        };
        writeln!(
            f,
            "total OOF: fixed {:.1} KB, adaptive {:.1} KB ({red:.0}% smaller)",
            self.fixed_bytes as f64 / 1024.0,
            self.adaptive_bytes as f64 / 1024.0
        )?;
        if !self.lights.is_empty() {
            let (lf, la): (usize, usize) =
                (self.lights.iter().map(|r| r.fixed_bytes).sum(), self.lights.iter().map(|r| r.adaptive_bytes).sum());
            writeln!(
                f,
                "total SRF: fixed {:.1} KB, adaptive {:.1} KB ({:.0}% smaller)",
                lf as f64 / 1024.0,
                la as f64 / 1024.0,
                100.0 * (1.0 - la as f64 / lf.max(1) as f64)
            )?;
        }
        writeln!(f, "vertices shaded: {}", self.vertices)?;
        writeln!(
            f,
            "per-vertex radiance: adaptive vs fixed relRMSE {:.4}; GPU vs CPU relRMSE {:.2e}, max abs {:.2e}",
            self.adaptive_vs_fixed_rel_rmse, self.gpu_vs_cpu_rel_rmse, self.gpu_vs_cpu_max_abs
        )?;
        writeln!(
            f,
            "negative lobes: {:.2}% of vertices clamped, most negative {:.3} x mean",
            100.0 * self.negative_fraction,
            self.most_negative_rel
        )?;
        let ratio = if self.gpu_ms > 0.0 { self.cpu_ms / self.gpu_ms } else { 0.0 };
        writeln!(f, "ms per frame: CPU {:.2}, GPU {:.2} ({ratio:.1}x)", self.cpu_ms, self.gpu_ms)
    }
}
