//! The GPU tracer, through both structures (the device-built kd-tree and the host-built threaded
//! BVH), against an `obvhs` CPU BVH on the same rays (lavapipe): every built-in scene plus the
//! bunny glTF, incoherent random rays, coherent camera rays and secondary rays off surfaces;
//! any-hit agreement >= 99.99%, closest-hit distance within 1e-4 relative.

mod common;
use common::{root, shaders};
use glam::Vec3;
use penumbra_engine::{Context, ContextDesc, Engine};
use penumbra_passes::kdtree::{ray_epsilon, world_triangles, KdTreeBuilder, Structure};
use penumbra_passes::trace::{CpuBvh, Ray, Tracer};
use penumbra_passes::trace_bench::{camera_rays, random_rays, run_gpu, surface_rays};
use penumbra_scene::Scene;
use std::path::PathBuf;

fn scene_paths() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(root().join("scenes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v.push(root().join("scenes/assets/bunny.glb"));
    v
}

#[derive(Default)]
struct Tally {
    any_total: usize,
    any_diff: usize,
    closest_total: usize,
    closest_hitmiss_diff: usize,
    both_hit: usize,
    dist_bad: usize,
    max_rel: f64,
    diffs: Vec<String>,
}

#[test]
fn kdtree_tracer_agrees_with_obvhs_on_every_scene() {
    tracer_agrees_with_obvhs_on_every_scene(Structure::KdTree, None);
}

#[test]
fn bvh_tracer_agrees_with_obvhs_on_every_scene() {
    tracer_agrees_with_obvhs_on_every_scene(Structure::Bvh, None);
}

/// The threaded BVH in one depth-first order: a node buffer too small for its six orders (4
/// nodes per triangle) keeps the first alone.
#[test]
fn bvh_tracer_in_one_order_agrees_with_obvhs_on_every_scene() {
    tracer_agrees_with_obvhs_on_every_scene(Structure::Bvh, Some(4));
}

fn tracer_agrees_with_obvhs_on_every_scene(structure: Structure, nodes_per_triangle: Option<u32>) {
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let mut builder = KdTreeBuilder::new(&ctx, &lib).unwrap();
    builder.params.structure = structure;
    if let Some(n) = nodes_per_triangle {
        builder.params.nodes_per_triangle = n;
    }
    let tracer = Tracer::new(&ctx, &lib).unwrap();
    let mut all = Tally::default();
    let mut one_order_scenes = 0;
    for path in scene_paths() {
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // A mid-animation frame: moved and deformed geometry where the scene has it.
        let frame = scene.at(0.5, Some(0.5 - 1.0 / 30.0));
        let tris = world_triangles(&scene, &frame).unwrap();
        let cpu = CpuBvh::new(&tris);
        let extent = tris.iter().flatten().fold(1.0f32, |m, v| m.max(v.abs().max_element()));
        let cam = camera_rays(&frame.camera, 48, 36);
        let surf = surface_rays(&cpu, &tris, &cam, ray_epsilon(extent), 3);
        let rnd_inf = random_rays(&tris, 2048, 1, false);
        let rnd_fin = random_rays(&tris, 2048, 2, true);
        let mut cam_fin = cam.clone();
        for (i, r) in cam_fin.iter_mut().enumerate() {
            r.tmax = 0.5 + 0.1 * (i % 97) as f32;
        }
        let sets: Vec<(Vec<Ray>, Vec<Ray>)> = vec![
            (rnd_fin, rnd_inf.clone()),
            (cam_fin, cam.clone()),
            (surf.clone(), surf.clone()),
            (rnd_inf, Vec::new()),
        ];
        let run = run_gpu(&mut engine, &mut builder, &tracer, &tris, &sets).unwrap();
        let s = run.stats;
        assert_eq!(s.structure, structure);
        if structure == Structure::Bvh && s.triangles > 0 {
            // seven orders when the node buffer holds them (2 uvec4 per node each, 3 per leaf triangle)
            let cap = s.triangles as u64 * builder.params.nodes_per_triangle as u64 + 8192;
            let seven = 14 * s.nodes as u64 + 3 * s.leaf_refs as u64 <= cap;
            assert_eq!(s.bvh_orders, if seven { 7 } else { 1 }, "{name}");
            one_order_scenes += (s.bvh_orders == 1) as usize;
        }
        println!(
            "{name}: {} tris, {} nodes, {} leaves ({} empty), {} leaf refs ({:.2}/tri), depth {}, {:.2} MB used, {:.2} MB allocated, overflow {}",
            s.triangles,
            s.nodes,
            s.leaves,
            s.empty_leaves,
            s.leaf_refs,
            s.leaf_refs as f64 / s.triangles.max(1) as f64,
            s.depth,
            s.bytes_used as f64 / 1e6,
            s.bytes_allocated as f64 / 1e6,
            s.overflow
        );
        let build_ms: f64 = run.gpu_ms.iter().filter(|(n, _)| n.starts_with("kdtree_")).map(|(_, ms)| ms).sum();
        println!(
            "{name}: build {build_ms:.1} ms on the device, {:.1} ms recording (a BVH: its host build)",
            run.record_ms
        );
        assert_eq!(s.triangles as usize, tris.len());
        assert!(s.leaves > 0 && s.nodes >= s.leaves && s.leaf_refs as usize >= tris.len(), "{name}: {s:?}");
        let mut t = Tally::default();
        for (si, ((any, closest), (gany, gclosest))) in sets.iter().zip(&run.hits).enumerate() {
            assert_eq!(gany.len(), any.len());
            assert_eq!(gclosest.len(), closest.len());
            for (i, (r, g)) in any.iter().zip(gany).enumerate() {
                let c = cpu.occluded(r);
                t.any_total += 1;
                if c != g.is_some() {
                    t.any_diff += 1;
                    t.diffs.push(format!("{name} set {si} ray {i}: any-hit cpu {c} gpu {g:?} ({r:?})"));
                }
            }
            for (i, (r, g)) in closest.iter().zip(gclosest).enumerate() {
                let c = cpu.closest(r);
                t.closest_total += 1;
                match (c, g) {
                    (Some((tc, _)), Some(h)) => {
                        t.both_hit += 1;
                        let rel = ((h.t - tc).abs() / tc.abs().max(1e-6)) as f64;
                        t.max_rel = t.max_rel.max(rel);
                        if rel > 1e-4 {
                            t.dist_bad += 1;
                            t.diffs
                                .push(format!("{name} set {si} ray {i}: closest cpu {tc} gpu {} (rel {rel:.2e})", h.t));
                        }
                    }
                    (None, None) => {}
                    _ => {
                        t.closest_hitmiss_diff += 1;
                        t.diffs.push(format!("{name} set {si} ray {i}: closest cpu {c:?} gpu {g:?} ({r:?})"));
                    }
                }
            }
        }
        println!(
            "{name}: any-hit {}/{} differ, closest {}/{} hit/miss differ, {} of {} both-hit beyond 1e-4 (max rel {:.2e})",
            t.any_diff, t.any_total, t.closest_hitmiss_diff, t.closest_total, t.dist_bad, t.both_hit, t.max_rel
        );
        all.any_total += t.any_total;
        all.any_diff += t.any_diff;
        all.closest_total += t.closest_total;
        all.closest_hitmiss_diff += t.closest_hitmiss_diff;
        all.both_hit += t.both_hit;
        all.dist_bad += t.dist_bad;
        all.max_rel = all.max_rel.max(t.max_rel);
        all.diffs.extend(t.diffs);
    }
    for d in &all.diffs {
        println!("difference: {d}");
    }
    let any_agree = 1.0 - all.any_diff as f64 / all.any_total as f64;
    let closest_agree = 1.0 - (all.closest_hitmiss_diff + all.dist_bad) as f64 / all.closest_total as f64;
    println!(
        "total: any-hit agreement {:.5}% of {}, closest-hit agreement {:.5}% of {} ({} both hit, max rel distance error {:.2e})",
        100.0 * any_agree,
        all.any_total,
        100.0 * closest_agree,
        all.closest_total,
        all.both_hit,
        all.max_rel
    );
    assert!(all.any_total > 50_000 && all.both_hit > 10_000);
    if structure == Structure::Bvh {
        assert_eq!(one_order_scenes > 0, nodes_per_triangle.is_some(), "scenes in one order: {one_order_scenes}");
    }
    assert!(any_agree >= 0.9999, "any-hit agreement {any_agree}");
    assert!(closest_agree >= 0.9999, "closest-hit agreement {closest_agree}");
    let errors = ctx.validation.error_count();
    assert_eq!(errors, 0, "validation errors: {:?}", ctx.validation.errors());
    let _ = Vec3::ZERO;
}

/// `bench_trace` runs in one go and reports plausible numbers (small sizes here; the table in the
/// issue note comes from `penumbra bench trace SCENE` or `cargo test ... bench_table -- --ignored`).
#[test]
fn bench_trace_reports_build_and_ray_rates() {
    let ctx = Context::new(&ContextDesc::default()).expect("context");
    let lib = shaders();
    let scene = Scene::load(root().join("scenes/assets/bunny.glb")).unwrap();
    let r = penumbra_passes::trace_bench::bench_trace(&ctx, &lib, &scene, 64, 48, 4096).unwrap();
    println!("{r}");
    assert!(r.triangles > 1000 && r.stats.leaves > 0 && r.build_ms > 0.0);
    // coherent, incoherent and shadow rays
    assert_eq!(r.rows.len(), 3);
    assert!(r.rows[2].name.starts_with("shadow") && r.rows[2].rays > 0, "{:?}", r.rows[2]);
    for row in &r.rows {
        assert!(row.gpu_mrays > 0.0 && row.cpu_mrays > 0.0 && row.gpu_mrays.is_finite(), "{row:?}");
        assert!(row.bvh_mrays > 0.0 && row.bvh_mrays.is_finite(), "{row:?}");
    }
    assert!(
        r.bvh_stats.structure == Structure::Bvh && r.bvh_stats.leaves > 0 && r.bvh_stats.nodes >= r.bvh_stats.leaves
    );
}

/// The bench table over every scene (slow; run with `--ignored`).
#[test]
#[ignore]
fn bench_table() {
    let ctx = Context::new(&ContextDesc::default()).expect("context");
    let lib = shaders();
    let only = std::env::var("BENCH_SCENE").ok();
    for path in scene_paths() {
        if only.as_ref().is_some_and(|o| !path.to_string_lossy().contains(o.as_str())) {
            continue;
        }
        let scene = Scene::load(&path).unwrap();
        let r = penumbra_passes::trace_bench::bench_trace(&ctx, &lib, &scene, 320, 240, 76800).unwrap();
        println!("== {}\n{r}", path.file_name().unwrap().to_string_lossy());
    }
}

/// `KdTreeBuilder::add` rebuilds when objects moved or deformed and keeps the tree of static
/// geometry; the rebuilt tree traces the new triangle positions.
#[test]
fn tree_rebuilds_only_when_geometry_changes() {
    use penumbra_engine::Graph;
    use penumbra_passes::trace::{add_copy_to_readback, decode_hits, upload_rays, TraceMode, HIT_BYTES};
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let tracer = Tracer::new(&ctx, &lib).unwrap();
    for ((file, dynamic), structure) in [("falling.toml", true), ("hat_on_cloth.toml", true), ("chess.toml", false)]
        .into_iter()
        .flat_map(|c| [(c, Structure::KdTree), (c, Structure::Bvh)])
    {
        let scene = Scene::load(root().join("scenes").join(file)).unwrap();
        let mut engine = Engine::new(ctx.clone(), 2).unwrap();
        let mut builder = KdTreeBuilder::new(&ctx, &lib).unwrap();
        builder.params.structure = structure;
        let mut prev = None;
        for k in 0..3 {
            let t = 0.4 + k as f32 / 30.0;
            let frame = scene.at(t, prev);
            prev = Some(t);
            let mut g = Graph::new();
            let tree =
                builder.add_frame(&mut penumbra_engine::FrameStore::new(&mut engine), &mut g, &scene, &frame).unwrap();
            let built = g.passes().iter().any(|p| p.name == "kdtree_upload");
            assert_eq!(built, tree.built_this_frame);
            let expect = k == 0 || (dynamic && (frame.any_moved() || frame.any_deformed()));
            assert_eq!(built, expect, "{file} {structure:?} frame {k}: built {built}");
            let tris = world_triangles(&scene, &frame).unwrap();
            let cpu = CpuBvh::new(&tris);
            let rays = camera_rays(&frame.camera, 32, 24);
            let rb = upload_rays(&mut g, "rays", &rays);
            let hits = tracer.add_trace(&mut g, &tree, rb, TraceMode::ClosestHit);
            add_copy_to_readback(&mut g, hits, "hits", rays.len() as u64 * HIT_BYTES);
            engine.submit(g).unwrap();
            let out = engine.drain().unwrap().pop().unwrap();
            let gpu = decode_hits(&out.readbacks["hits"]);
            let mut bad = 0;
            for (r, h) in rays.iter().zip(&gpu) {
                match (cpu.closest(r), h) {
                    (Some((tc, _)), Some(h)) if ((h.t - tc).abs() / tc.max(1e-6)) <= 1e-4 => {}
                    (None, None) => {}
                    _ => bad += 1,
                }
            }
            assert!(bad <= 1, "{file} {structure:?} frame {k}: {bad} of {} camera rays disagree", rays.len());
        }
        if dynamic {
            assert!(scene.at(0.5, Some(0.45)).any_moved() || scene.at(0.5, Some(0.45)).any_deformed());
        }
    }
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

/// Degenerate inputs: no triangles (every ray misses), and rays with a zero, NaN or infinite
/// direction, NaN origin or an empty interval (misses, no hang), next to valid ones.
#[test]
fn degenerate_inputs_are_misses() {
    let ctx = Context::new(&ContextDesc::default()).expect("context");
    let lib = shaders();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let tracer = Tracer::new(&ctx, &lib).unwrap();
    for structure in [Structure::KdTree, Structure::Bvh] {
        let mut builder = KdTreeBuilder::new(&ctx, &lib).unwrap();
        builder.params.structure = structure;
        degenerate_inputs(&mut engine, &mut builder, &tracer);
    }
}

fn degenerate_inputs(engine: &mut Engine, builder: &mut KdTreeBuilder, tracer: &Tracer) {
    let o = Vec3::new(0.0, 0.0, -5.0);
    let valid = Ray::new(o, Vec3::Z, 0.0, f32::MAX);
    let bad = vec![
        valid,
        Ray::new(o, Vec3::ZERO, 0.0, f32::MAX),
        Ray::new(o, Vec3::new(f32::NAN, 0.0, 1.0), 0.0, f32::MAX),
        Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::Z, 0.0, f32::MAX),
        Ray::new(o, Vec3::new(f32::INFINITY, 0.0, 1.0), 0.0, f32::MAX),
        Ray::new(o, Vec3::Z, 10.0, 1.0),
        Ray::new(o, Vec3::Z, 0.0, 4.0),
    ];
    // empty scene
    let run = run_gpu(engine, builder, tracer, &[], &[(bad.clone(), bad.clone())]).unwrap();
    assert_eq!(run.stats.triangles, 0);
    assert!(run.hits[0].0.iter().chain(&run.hits[0].1).all(|h| h.is_none()), "{:?}", run.hits);
    // one triangle across the z = 0 plane
    let tri = [[Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)]];
    let run = run_gpu(engine, builder, tracer, &tri, &[(bad.clone(), bad.clone())]).unwrap();
    for (mode, hits) in [("any", &run.hits[0].0), ("closest", &run.hits[0].1)] {
        assert!(hits[0].is_some_and(|h| (h.t - 5.0).abs() < 1e-5), "{mode}: valid ray {:?}", hits[0]);
        assert!(hits[1..].iter().all(|h| h.is_none()), "{mode}: {hits:?}");
    }
}

/// The device's per-invocation loop limit (README, "lavapipe's loop limit"): one invocation runs
/// a loop of 100 000 iterations, then a second of 16. Mesa 22.3's llvmpipe stops after 65535
/// iterations in total (the first loop comes up short and the second runs at most once); a driver
/// without the limit runs both in full. Either way the answer is one of those two, and short
/// loops always run in full.
#[test]
fn the_devices_loop_limit_is_known() {
    use penumbra_passes::kernels::loop_probe::{loop_limit, run_loops, LoopCounts};
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let short = run_loops(&mut engine, &lib, 1000, 1000).unwrap();
    assert_eq!(short, LoopCounts { first: 1000, second: 1000 });
    let limit = loop_limit(&mut engine, &lib, 100_000).unwrap();
    let driver = ctx.driver_info();
    println!("{} ({driver}): loop limit {limit:?}", ctx.device_name);
    if let Some(n) = limit {
        assert!((65_000..=65_536).contains(&n), "{driver}: loop limit {n}: neither none nor gallivm's 65535");
        let c = run_loops(&mut engine, &lib, 100_000, 16).unwrap();
        assert!(c.second <= 1, "{driver}: the limit is shared by the invocation's loops: {c:?}");
    }
    if driver.contains("Mesa 22.") {
        assert!(limit.is_some(), "{driver}: Mesa 22's llvmpipe has the limit");
    }
    assert_eq!(ctx.validation.error_count(), 0, "{:?}", ctx.validation.errors());
}
