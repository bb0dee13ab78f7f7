//! The CPU side of the tracer's tests and benchmark: the same triangles in an `obvhs` CWBVH
//! ([`CpuBvh`]), ray sets (coherent camera rays, incoherent random rays, secondary rays off surfaces), and
//! [`bench_trace`] (build time and memory of the kd-tree and of the threaded BVH, GPU rays/s
//! through each vs `obvhs` on all CPU cores for coherent, incoherent and shadow rays).

use crate::kdtree::{parse_stats, KdStats, KdTreeBuilder, Structure};
use crate::trace::{add_copy_to_readback, decode_hits, upload_rays, CpuBvh, Hit, Ray, TraceMode, Tracer, HIT_BYTES};
use anyhow::{anyhow, Result};
use glam::Vec3;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Context, Engine, Graph};
use penumbra_scene::{Camera, Frame, Scene};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// Small deterministic generator (PCG32).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E3779B97F4A7C15) ^ 0xDA3E39CB94B95BDB)
    }
    pub fn next_u32(&mut self) -> u32 {
        let old = self.0;
        self.0 = old.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let xs = (((old >> 18) ^ old) >> 27) as u32;
        xs.rotate_right((old >> 59) as u32)
    }
    pub fn f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 / (1u32 << 24) as f32
    }
    pub fn sphere(&mut self) -> Vec3 {
        let z = 1.0 - 2.0 * self.f32();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * self.f32();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

/// Incoherent rays: origins uniform in the (1.2x) scene box, uniform directions, `tmax` infinite
/// (`finite`: uniform in (0, diagonal)).
pub fn random_rays(tris: &[[Vec3; 3]], n: usize, seed: u64, finite: bool) -> Vec<Ray> {
    let (lo, hi) = crate::kdtree::bounds(tris);
    let c = 0.5 * (lo + hi);
    let e = 0.6 * (hi - lo);
    let diag = (hi - lo).length().max(1e-3);
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let o = c + e * Vec3::new(2.0 * rng.f32() - 1.0, 2.0 * rng.f32() - 1.0, 2.0 * rng.f32() - 1.0);
            let d = rng.sphere();
            let tmax = if finite { diag * rng.f32() } else { f32::MAX };
            Ray::new(o, d, 0.0, tmax)
        })
        .collect()
}

/// Coherent rays: the camera's primary rays through a `w` x `h` grid (pixel centres).
pub fn camera_rays(cam: &Camera, w: u32, h: u32) -> Vec<Ray> {
    let fwd = (cam.target - cam.eye).normalize_or(Vec3::NEG_Z);
    let right = fwd.cross(cam.up).normalize_or(Vec3::X);
    let up = right.cross(fwd);
    let th = (cam.fov_y_deg.to_radians() * 0.5).tan();
    let aspect = w as f32 / h.max(1) as f32;
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let u = (x as f32 + 0.5) / w as f32 * 2.0 - 1.0;
            let v = 1.0 - (y as f32 + 0.5) / h as f32 * 2.0;
            let d = (fwd + right * (u * th * aspect) + up * (v * th)).normalize();
            out.push(Ray::new(cam.eye, d, 0.0, f32::MAX));
        }
    }
    out
}

/// Secondary rays starting on surfaces: from the CPU closest hits of `primary`, offset by
/// `eps` along the geometric normal turned to the incoming side, in random directions of that
/// hemisphere (the self-intersection policy of [`crate::kdtree::ray_epsilon`]).
pub fn surface_rays(bvh: &CpuBvh, tris: &[[Vec3; 3]], primary: &[Ray], eps: f32, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    let mut out = Vec::new();
    for r in primary {
        let Some((t, tri)) = bvh.closest(r) else { continue };
        let [p0, p1, p2] = tris[tri as usize];
        let d = Vec3::from(r.dir);
        let mut ng = (p1 - p0).cross(p2 - p0).normalize();
        if ng.dot(d) > 0.0 {
            ng = -ng;
        }
        let p = Vec3::from(r.origin) + d * t + ng * eps;
        let mut w = rng.sphere();
        if w.dot(ng) < 0.0 {
            w = -w;
        }
        out.push(Ray::new(p, w, 0.0, f32::MAX));
    }
    out
}

/// Shadow rays: from the CPU closest hits of `primary` (offset by `eps` along the geometric
/// normal turned to the incoming side) towards the distant light direction `to_light`, as a
/// shadow-map or ray-traced-shadow pass casts them (any hit, unbounded).
pub fn shadow_rays(bvh: &CpuBvh, tris: &[[Vec3; 3]], primary: &[Ray], to_light: Vec3, eps: f32) -> Vec<Ray> {
    let l = to_light.normalize_or(Vec3::Y);
    let mut out = Vec::new();
    for r in primary {
        let Some((t, tri)) = bvh.closest(r) else { continue };
        let [p0, p1, p2] = tris[tri as usize];
        let d = Vec3::from(r.dir);
        let mut ng = (p1 - p0).cross(p2 - p0).normalize_or(Vec3::Y);
        if ng.dot(d) > 0.0 {
            ng = -ng;
        }
        out.push(Ray::new(Vec3::from(r.origin) + d * t + ng * eps, l, 0.0, f32::MAX));
    }
    out
}

/// Hits of one ray set: (any-hit, closest-hit).
pub type SetHits = (Vec<Option<Hit>>, Vec<Option<Hit>>);

/// Result of [`run_gpu`]: build statistics, per ray set its hits, per pass its GPU time.
pub struct GpuTraceRun {
    pub stats: KdStats,
    pub hits: Vec<SetHits>,
    pub gpu_ms: Vec<(String, f64)>,
    /// Host time to add the structure to the graph (a threaded BVH's build included), ms.
    pub record_ms: f64,
}

/// Builds the tree of `tris` and traces every (any-hit rays, closest-hit rays) set, in one graph.
pub fn run_gpu(
    engine: &mut Engine,
    builder: &mut KdTreeBuilder,
    tracer: &Tracer,
    tris: &[[Vec3; 3]],
    sets: &[(Vec<Ray>, Vec<Ray>)],
) -> Result<GpuTraceRun> {
    let mut g = Graph::new();
    let t0 = Instant::now();
    let mut tree = builder.add_triangles(&mut penumbra_engine::FrameStore::new(engine), &mut g, tris, true)?;
    let record_ms = t0.elapsed().as_secs_f64() * 1e3;
    let stats_rb = KdTreeBuilder::add_stats_readback(&mut g, &mut tree, "kdtree_stats");
    let _ = stats_rb;
    for (i, (any, closest)) in sets.iter().enumerate() {
        for (mode, rays, tag) in [(TraceMode::AnyHit, any, "any"), (TraceMode::ClosestHit, closest, "closest")] {
            if rays.is_empty() {
                continue;
            }
            let rb = upload_rays(&mut g, &format!("rays_{tag}_{i}"), rays);
            let hits = tracer.add_trace(&mut g, &tree, rb, mode);
            add_copy_to_readback(&mut g, hits, &format!("hits_{tag}_{i}"), rays.len() as u64 * HIT_BYTES);
        }
    }
    engine.submit(g)?;
    let mut outs = engine.drain()?;
    let out = outs.pop().ok_or_else(|| anyhow!("no frame output"))?;
    let stats = parse_stats(out.readbacks.get("kdtree_stats").ok_or_else(|| anyhow!("no stats"))?, builder.last_bytes)
        .ok_or_else(|| anyhow!("short stats"))?;
    let mut hits = Vec::new();
    for (i, (any, closest)) in sets.iter().enumerate() {
        let get = |tag: &str, n: usize| -> Vec<Option<Hit>> {
            if n == 0 {
                return Vec::new();
            }
            out.readbacks.get(&format!("hits_{tag}_{i}")).map(|b| decode_hits(b)).unwrap_or_default()
        };
        hits.push((get("any", any.len()), get("closest", closest.len())));
    }
    Ok(GpuTraceRun { stats, hits, gpu_ms: out.gpu_ms, record_ms })
}

/// One line of the benchmark.
#[derive(Clone, Debug)]
pub struct BenchRow {
    pub name: String,
    pub rays: usize,
    /// Million rays per second through the kd-tree (GPU pass time from timestamps).
    pub gpu_mrays: f64,
    /// Million rays per second through the threaded BVH ([`Structure::Bvh`]) on the device.
    pub bvh_mrays: f64,
    /// Million rays per second through `obvhs` on all CPU cores (rayon).
    pub cpu_mrays: f64,
}

/// Result of [`bench_trace`].
#[derive(Clone, Debug)]
pub struct BenchReport {
    pub triangles: usize,
    pub stats: KdStats,
    /// GPU time of the build passes (upload, init, levels), ms.
    pub build_ms: f64,
    /// The threaded BVH: its statistics, its host build (and recording) time and the device
    /// time of its upload, ms.
    pub bvh_stats: KdStats,
    pub bvh_build_ms: f64,
    pub bvh_upload_ms: f64,
    /// The structure the device's techniques trace (`KdTreeBuilder::new`'s choice).
    pub default_structure: Structure,
    /// `obvhs` CWBVH build on the CPU, ms.
    pub cpu_build_ms: f64,
    pub rows: Vec<BenchRow>,
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = &self.stats;
        writeln!(
            f,
            "kd-tree: {} triangles, build {:.2} ms (GPU), {} nodes, {} leaves ({} empty), {} leaf refs, depth {}, {:.2} MB used / {:.2} MB allocated{}",
            self.triangles,
            self.build_ms,
            s.nodes,
            s.leaves,
            s.empty_leaves,
            s.leaf_refs,
            s.depth,
            s.bytes_used as f64 / 1e6,
            s.bytes_allocated as f64 / 1e6,
            if s.overflow != 0 { " (storage overflow: some leaves are large)" } else { "" }
        )?;
        let b = &self.bvh_stats;
        writeln!(
            f,
            "threaded BVH: build {:.2} ms (host) + upload {:.2} ms (device), {} nodes, {} leaves, depth {}, {:.2} MB used",
            self.bvh_build_ms,
            self.bvh_upload_ms,
            b.nodes,
            b.leaves,
            b.depth,
            b.bytes_used as f64 / 1e6
        )?;
        writeln!(f, "obvhs CWBVH build (CPU): {:.2} ms", self.cpu_build_ms)?;
        writeln!(f, "the device's techniques trace the {:?} (any-hit rays, Mrays/s):", self.default_structure)?;
        writeln!(
            f,
            "{:<32} {:>9} {:>10} {:>10} {:>14} {:>9} {:>9}",
            "rays (visibility)", "count", "kd-tree", "BVH", "obvhs (CPU)", "kd ratio", "BVH ratio"
        )?;
        for r in &self.rows {
            writeln!(
                f,
                "{:<32} {:>9} {:>10.3} {:>10.3} {:>14.3} {:>9.2} {:>9.2}",
                r.name,
                r.rays,
                r.gpu_mrays,
                r.bvh_mrays,
                r.cpu_mrays,
                r.gpu_mrays / r.cpu_mrays.max(1e-12),
                r.bvh_mrays / r.cpu_mrays.max(1e-12)
            )?;
        }
        Ok(())
    }
}

/// `penumbra bench trace SCENE`: builds the kd-tree of the scene's first frame on the device and
/// the threaded BVH on the host, traces coherent (camera, `w` x `h`), incoherent (random) and
/// shadow (from the camera rays' hit points towards one distant light) visibility rays through
/// each on the GPU (best of three runs) and the same rays through `obvhs` on all CPU cores (best
/// of three), in one run. GPU times come from the engine's timestamps.
pub fn bench_trace(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    w: u32,
    h: u32,
    incoherent: usize,
) -> Result<BenchReport> {
    let frame: Frame = scene.at(0.0, None);
    let tris = crate::kdtree::world_triangles(scene, &frame)?;
    let mut engine = Engine::new(ctx.clone(), 1)?;
    engine.timestamps = true;
    let mut builder = KdTreeBuilder::new(ctx, shaders)?;
    let default_structure = builder.params.structure;
    builder.params.structure = Structure::KdTree;
    let mut bvh_builder = KdTreeBuilder::new(ctx, shaders)?;
    bvh_builder.params.structure = Structure::Bvh;
    let tracer = Tracer::new(ctx, shaders)?;
    let coherent = camera_rays(&frame.camera, w, h);
    let random = random_rays(&tris, incoherent, 7, true);
    let t0 = Instant::now();
    let cpu = CpuBvh::new(&tris);
    let cpu_build_ms = t0.elapsed().as_secs_f64() * 1e3;
    let (lo, hi) = crate::kdtree::bounds(&tris);
    let eps = crate::kdtree::ray_epsilon((hi - lo).max_element());
    let shadow = shadow_rays(&cpu, &tris, &coherent, Vec3::new(0.4, 1.0, 0.3), eps);
    let sets = [(coherent.clone(), Vec::new()), (random.clone(), Vec::new()), (shadow.clone(), Vec::new())];
    let trace_ms = |run: &GpuTraceRun| -> Result<Vec<f64>> {
        let ms: Vec<f64> = run.gpu_ms.iter().filter(|(n, _)| n.starts_with("trace_any:")).map(|(_, ms)| *ms).collect();
        if ms.len() != 3 {
            return Err(anyhow!("missing trace timestamps ({:?})", run.gpu_ms));
        }
        Ok(ms)
    };
    // Per structure: a warm-up run (pipelines, allocations), then the best of three (as the
    // CPU's below: the device shares the 2 cores' noise).
    let mut measure = |builder: &mut KdTreeBuilder| -> Result<(GpuTraceRun, Vec<f64>)> {
        run_gpu(&mut engine, builder, &tracer, &tris, &sets[..1])?;
        let mut best: Option<(GpuTraceRun, Vec<f64>)> = None;
        for _ in 0..3 {
            let run = run_gpu(&mut engine, builder, &tracer, &tris, &sets)?;
            let ms = trace_ms(&run)?;
            best = Some(match best {
                None => (run, ms),
                Some((r, b)) => {
                    let m = b.iter().zip(&ms).map(|(x, y)| x.min(*y)).collect();
                    (r, m)
                }
            });
        }
        best.ok_or_else(|| anyhow!("no run"))
    };
    let (run, kd_ms) = measure(&mut builder)?;
    let (bvh_run, bvh_ms) = measure(&mut bvh_builder)?;
    let build_ms: f64 = run.gpu_ms.iter().filter(|(n, _)| n.starts_with("kdtree_")).map(|(_, ms)| ms).sum();
    let bvh_upload_ms: f64 = bvh_run.gpu_ms.iter().filter(|(n, _)| n.starts_with("kdtree_")).map(|(_, ms)| ms).sum();
    let mut rows = Vec::new();
    for (((name, rays), ms), bvh_ms) in [
        ("coherent (camera)", &coherent),
        ("incoherent (random)", &random),
        ("shadow (hit points to a light)", &shadow),
    ]
    .into_iter()
    .zip(kd_ms)
    .zip(bvh_ms)
    {
        // Warm-up (thread pool, caches), then the best of three.
        let mut hits: usize = rays.par_iter().map(|r| cpu.occluded(r) as usize).sum();
        let mut cpu_s = f64::INFINITY;
        for _ in 0..3 {
            let t0 = Instant::now();
            hits += rays.par_iter().map(|r| cpu.occluded(r) as usize).sum::<usize>();
            cpu_s = cpu_s.min(t0.elapsed().as_secs_f64());
        }
        std::hint::black_box(hits);
        rows.push(BenchRow {
            name: name.to_string(),
            rays: rays.len(),
            gpu_mrays: rays.len() as f64 / (ms.max(1e-6) * 1e-3) / 1e6,
            bvh_mrays: rays.len() as f64 / (bvh_ms.max(1e-6) * 1e-3) / 1e6,
            cpu_mrays: rays.len() as f64 / cpu_s.max(1e-9) / 1e6,
        });
    }
    Ok(BenchReport {
        triangles: tris.len(),
        stats: run.stats,
        build_ms,
        bvh_stats: bvh_run.stats,
        bvh_build_ms: bvh_run.record_ms,
        bvh_upload_ms,
        default_structure,
        cpu_build_ms,
        rows,
    })
}
