//! Shadow fields on the Vulkan device (lavapipe): the GPU per-vertex path agrees with the CPU
//! path, validation stays clean, and the benchmark runs.

mod common;
use common::{root, shaders};
use penumbra_engine::{Context, ContextDesc, Engine};
use penumbra_math::shadow_field::{InstanceFrame, Params, Window};
use penumbra_passes::shadow_fields::bench::{bench, BenchOptions};
use penumbra_passes::shadow_fields::{
    cpu_shade_points, gpu_shade_points, instance_frames, light_frames, vertex_points, SceneFields, SfOptions,
    ShadowFieldsTechnique,
};
use penumbra_scene::Scene;
use std::sync::Arc;

/// Largest channel difference between the CPU path's radiance and the GPU's.
fn max_abs_diff(cpu: &[(glam::DVec3, f64)], gpu: &[[f32; 4]]) -> f64 {
    cpu.iter().zip(gpu).flat_map(|(c, g)| (0..3).map(move |k| (c.0[k] - g[k] as f64).abs())).fold(0.0f64, f64::max)
}

fn small_options() -> SfOptions {
    SfOptions {
        params: Params { shells: 8, resolution: 16, map_res: 8, threshold: 0.010, min_resolution: 1 },
        adaptive: true,
        cache_dir: None,
        progress: false,
        ..Default::default()
    }
}

#[test]
fn shadow_fields_gpu_matches_cpu_and_is_validation_clean() {
    let scene = Scene::load(root().join("scenes/sf_spheres.toml")).expect("scene");
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let opts = small_options();
    let fields = Arc::new(SceneFields::build(&scene, &opts).unwrap());
    for r in &fields.reports {
        println!(
            "{}: {} verts, R {:?}, fixed {} B, adaptive {} B, {:.2} s",
            r.mesh, r.vertices, r.resolutions, r.fixed_bytes, r.adaptive_bytes, r.seconds
        );
    }
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    for adaptive in [true, false] {
        let tech = ShadowFieldsTechnique::with_fields(&ctx, &lib, &scene, fields.clone(), adaptive).unwrap();
        for t in [0.0f32, 1.3] {
            let frame = scene.at(t, None);
            let points = vertex_points(&scene, &frame, &fields, None);
            let insts = instance_frames(&scene, &frame, &fields, adaptive, true);
            let cpu = cpu_shade_points(&points, &insts, &[], &tech.light, &tech.tensor, Window::None);
            let (gpu, ms) = gpu_shade_points(&mut engine, &tech, &frame, &points).unwrap();
            assert_eq!(gpu.len(), points.len());
            // The shadows matter: without occluders the radiance differs at many vertices.
            let lone: Vec<InstanceFrame> = insts.iter().map(|i| InstanceFrame { field: None, ..*i }).collect();
            let unshadowed = cpu_shade_points(&points, &lone, &[], &tech.light, &tech.tensor, Window::None);
            let shadowed = cpu
                .iter()
                .zip(&unshadowed)
                .filter(|(a, b)| (a.0 - b.0).length() > 1e-3 * b.0.length().max(1e-3))
                .count();
            let peak = cpu.iter().map(|c| c.0.max_element()).fold(0.0f64, f64::max);
            let mut worst = 0.0f64;
            for (c, g) in cpu.iter().zip(&gpu) {
                for (ck, gk) in c.0.to_array().into_iter().zip(g) {
                    worst = worst.max((ck - *gk as f64).abs());
                }
                assert!(g.iter().all(|x| x.is_finite()));
            }
            println!(
                "adaptive {adaptive} t {t}: {} vertices, {shadowed} shadowed by other objects, GPU vs CPU max abs {worst:.2e} (peak {peak:.3}), GPU {ms:.2} ms",
                points.len()
            );
            assert!(shadowed > points.len() / 20, "too few vertices in shadow ({shadowed})");
            // Same dequantized data, arithmetic in f32 (GPU) vs f64 (CPU): f32 rounding of the
            // transforms, angles and triple products (measured ~1e-4 of the peak). The bound,
            // 1e-3 of the peak, is half the quantization error the paths share (half a step
            // is 1/510 = 2e-3 of a coefficient's per-shell range).
            assert!(worst <= 1e-3 * peak + 1e-6, "GPU vs CPU {worst} (peak {peak})");
        }
    }
    drop(engine);
    // One file per object and variant, read back identical.
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("sf_files_{}", std::process::id()));
    let (reports, paths) = penumbra_passes::shadow_fields::precompute_files(&scene, &opts, &dir).unwrap();
    assert_eq!(paths.len(), 2 * scene.meshes.len());
    assert_eq!(reports.len(), scene.meshes.len());
    for (i, p) in paths.iter().enumerate() {
        let f = penumbra_math::shadow_field::ObjectField::from_bytes(&std::fs::read(p).unwrap()).unwrap();
        let (fx, ad) = &fields.fields[i / 2];
        assert_eq!(&f, if i % 2 == 0 { fx.as_ref() } else { ad.as_ref() }, "{}", p.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
    let report =
        bench(&ctx, &lib, &scene, &BenchOptions { sf: opts, time: 0.7, cull: Some(4.0 / 3.0), repeats: 1 }).unwrap();
    println!("{report}");
    assert!(report.adaptive_bytes < report.fixed_bytes);
    assert!(report.vertices > 0 && report.gpu_vs_cpu_rel_rmse < 1e-3);
    assert!(report.negative_fraction >= 0.0 && report.negative_fraction <= 1.0);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:#?}", ctx.validation.errors());
}

/// The benchmark table of the issue note on the built-in rigid scenes (slow: full precompute
/// with the technique's defaults, or `SF_BENCH_R` / `SF_BENCH_MAP` overrides). Run with
/// `cargo test -p penumbra-passes --test shadow_fields_gpu -- --ignored --nocapture`.
#[test]
#[ignore]
fn shadow_fields_bench_builtin_scenes() {
    let ctx = Context::new(&ContextDesc { validation: false, ..Default::default() }).expect("context");
    let lib = shaders();
    let mut sf = SfOptions { progress: true, ..Default::default() };
    if let Some(r) = std::env::var("SF_BENCH_R").ok().and_then(|v| v.parse().ok()) {
        sf.params.resolution = r;
    }
    if let Some(m) = std::env::var("SF_BENCH_MAP").ok().and_then(|v| v.parse().ok()) {
        sf.params.map_res = m;
    }
    for name in ["sf_statues.toml", "sf_bowling.toml", "falling.toml", "sf_lamps.toml"] {
        let scene = Scene::load(root().join("scenes").join(name)).expect("scene");
        let report =
            bench(&ctx, &lib, &scene, &BenchOptions { sf: sf.clone(), time: 0.7, cull: Some(4.0 / 3.0), repeats: 3 })
                .unwrap();
        println!("{report}");
        assert!(report.adaptive_bytes <= report.fixed_bytes);
    }
}

/// Local lights through their source radiance fields and windowed visibility: the GPU path
/// (sf_points.comp) agrees with the CPU path (Fig. 3 with lights), validation clean.
#[test]
fn shadow_fields_gpu_lights_and_window_match_cpu() {
    let scene = Scene::load(root().join("scenes/sf_lamps.toml")).expect("scene");
    assert_eq!(scene.lights.len(), 3);
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let fields = Arc::new(SceneFields::build(&scene, &small_options()).unwrap());
    for r in &fields.light_reports {
        println!("{}: SRF R {:?}, fixed {} B, adaptive {} B", r.mesh, r.resolutions, r.fixed_bytes, r.adaptive_bytes);
        assert!(r.adaptive_bytes <= r.fixed_bytes);
    }
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let frame = scene.at(0.9, None);
    let points = vertex_points(&scene, &frame, &fields, Some(4.0 / 3.0));
    assert!(points.len() > 100);
    for window in [Window::None, Window::Hanning] {
        let mut tech = ShadowFieldsTechnique::with_fields(&ctx, &lib, &scene, fields.clone(), true).unwrap();
        tech.window = window;
        let insts = instance_frames(&scene, &frame, &fields, true, true);
        let lights = light_frames(&frame, &fields, true, true);
        let cpu = cpu_shade_points(&points, &insts, &lights, &tech.light, &tech.tensor, window);
        let (gpu, _) = gpu_shade_points(&mut engine, &tech, &frame, &points).unwrap();
        let env_only = cpu_shade_points(&points, &insts, &[], &tech.light, &tech.tensor, window);
        // the lights matter, and their light is shadowed by the objects
        let lit = cpu.iter().zip(&env_only).filter(|(a, b)| a.0.length() > 1.2 * b.0.length()).count();
        let lone: Vec<InstanceFrame> = insts.iter().map(|i| InstanceFrame { field: None, ..*i }).collect();
        let open = cpu_shade_points(&points, &lone, &lights, &tech.light, &tech.tensor, window);
        let shadowed = cpu.iter().zip(&open).filter(|(a, b)| a.0.length() < 0.8 * b.0.length()).count();
        // the SRF against the analytic radiance (no fields): quantization and interpolation
        let analytic = cpu_shade_points(
            &points,
            &insts,
            &light_frames(&frame, &fields, true, false),
            &tech.light,
            &tech.tensor,
            window,
        );
        let peak = cpu.iter().map(|c| c.0.max_element()).fold(0.0f64, f64::max);
        let worst = max_abs_diff(&cpu, &gpu);
        let (mut num, mut den) = (0.0, 0.0);
        for (a, b) in cpu.iter().zip(&analytic) {
            num += (a.0 - b.0).length_squared();
            den += b.0.length_squared();
        }
        println!(
            "{window:?}: {} vertices, {lit} lit mostly by the lamps, {shadowed} shadowed, GPU vs CPU max abs {worst:.2e} (peak {peak:.3}), SRF vs analytic lights relRMSE {:.4}",
            points.len(),
            (num / den).sqrt()
        );
        assert!(lit > points.len() / 10 && shadowed > points.len() / 50, "lit {lit}, shadowed {shadowed}");
        assert!(worst <= 1e-3 * peak + 1e-6, "GPU vs CPU {worst} (peak {peak})");
        assert!((num / den).sqrt() < 0.05, "SRF vs analytic relRMSE {}", (num / den).sqrt());
    }
    drop(engine);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:#?}", ctx.validation.errors());
}

/// A real emitter (sf_pendant: a sphere light in a swinging lamp shade, its fixture): the GPU
/// path agrees with the CPU path (the light's frame follows the shade, its field extrapolated
/// beyond the last shell, the shade sorted after its light); the bulb's source radiance field
/// lets its light out of the shade's opening and holds the shade's shadow elsewhere, which the
/// shade's own occlusion field (order 4, ending at its outermost shell) does not.
#[test]
fn shadow_fields_srf_of_a_light_in_its_shade() {
    let scene = Scene::load(root().join("scenes/sf_pendant.toml")).expect("scene");
    let k = scene.lights[0].fixture.expect("the bulb has a fixture");
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let fields = Arc::new(SceneFields::build(&scene, &small_options()).unwrap());
    let r = &fields.light_reports[0];
    println!(
        "{}: {} rays, SRF R {:?}, fixed {} B, adaptive {} B",
        r.mesh, r.rays, r.resolutions, r.fixed_bytes, r.adaptive_bytes
    );
    assert!(r.mesh.contains("'shade'") && r.rays > 0 && r.adaptive_bytes <= r.fixed_bytes);
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let window = Window::None;
    for t in [0.0, 0.9] {
        let frame = scene.at(t, None);
        let points = vertex_points(&scene, &frame, &fields, Some(4.0 / 3.0));
        let tech = ShadowFieldsTechnique::with_fields(&ctx, &lib, &scene, fields.clone(), true).unwrap();
        let insts = instance_frames(&scene, &frame, &fields, true, true);
        let lights = light_frames(&frame, &fields, true, true);
        let cpu = cpu_shade_points(&points, &insts, &lights, &tech.light, &tech.tensor, window);
        let (gpu, _) = gpu_shade_points(&mut engine, &tech, &frame, &points).unwrap();
        let peak = cpu.iter().map(|c| c.0.max_element()).fold(0.0f64, f64::max);
        let worst = max_abs_diff(&cpu, &gpu);
        assert!(worst <= 1e-3 * peak + 1e-6, "t = {t}: GPU vs CPU {worst} (peak {peak})");

        // Points that see the bulb's centre past the shade (a ray against its triangles) get
        // most of the open bulb's light, the others little of it.
        let shade = &scene.meshes[scene.objects[k].mesh];
        let w = frame.instances[k].world;
        let tris: Vec<glam::Vec3> = shade.positions.iter().map(|p| w.transform_point3(*p)).collect();
        let rays = penumbra_math::shadow_field::RayCaster::new(&tris, &shade.indices);
        let bulb = frame.lights[0].position.as_dvec3();
        let none = [[0.0; 3]; 16];
        let plain = instance_frames(&scene, &frame, &fields, true, false);
        let no_shade: Vec<InstanceFrame> = plain
            .iter()
            .enumerate()
            .map(|(i, f)| if i == k { InstanceFrame { field: None, ..*f } } else { *f })
            .collect();
        let lit = |insts: &[InstanceFrame], srf: bool| {
            cpu_shade_points(&points, insts, &light_frames(&frame, &fields, true, srf), &none, &tech.tensor, window)
        };
        let (srf, open, oof) = (lit(&insts, true), lit(&no_shade, false), lit(&plain, false));
        let (mut seen, mut hidden) = ([0.0; 3], [0.0; 3]);
        let (mut n_seen, mut n_hidden) = (0, 0);
        for (i, p) in points.iter().enumerate() {
            if p.inst == k || open[i].0.length() < 1e-4 {
                continue;
            }
            let d = bulb - p.pos;
            let behind = rays.occluded(p.pos, d.normalize(), d.length() * 0.999);
            let (acc, n) = if behind { (&mut hidden, &mut n_hidden) } else { (&mut seen, &mut n_seen) };
            acc[0] += srf[i].0.length();
            acc[1] += open[i].0.length();
            acc[2] += oof[i].0.length();
            *n += 1;
        }
        println!(
            "t = {t}: GPU vs CPU max abs {worst:.2e} (peak {peak:.3}); {n_seen} points see the bulb (SRF {:.3} of open, the shade's OOF {:.3}), {n_hidden} behind the shade ({:.3}, {:.3})",
            seen[0] / seen[1],
            seen[2] / seen[1],
            hidden[0] / hidden[1],
            hidden[2] / hidden[1]
        );
        assert!(n_seen > 20 && n_hidden > 20, "{n_seen} / {n_hidden} points");
        assert!(seen[0] > 0.6 * seen[1], "the light out of the shade: {} of open", seen[0] / seen[1]);
        assert!(hidden[0] < 0.25 * hidden[1], "the shade's shadow: {} of open", hidden[0] / hidden[1]);
    }
    drop(engine);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:#?}", ctx.validation.errors());
}

/// The all-frequency variant's precompute is cached per mesh and parameter set: a second build
/// of the same scene loads every field and self-visibility map (no ray casting) and gets the same
/// data; other parameters miss; a corrupt cache file is recomputed, not trusted.
#[test]
fn wavelet_fields_are_cached_per_mesh_and_parameters() {
    use penumbra_passes::shadow_fields::wavelet::{SfwOptions, WaveletFields};
    let scene = Scene::load(root().join("scenes/sf_spheres.toml")).expect("scene");
    let dir = std::env::temp_dir().join(format!("penumbra-sfw-cache-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let opts = SfwOptions { shells: 4, resolution: 4, cube: 4, cache_dir: Some(dir.clone()), ..Default::default() };
    let first = WaveletFields::build(&scene, &opts).unwrap();
    let built: Vec<_> = first.reports.iter().filter(|r| r.adaptive_bytes > 0).collect();
    assert!(!built.is_empty() && built.iter().all(|r| !r.cached), "{:?}", first.reports);
    let files = std::fs::read_dir(&dir).unwrap().count();
    assert!(files >= 2, "{files} cache files");
    let second = WaveletFields::build(&scene, &opts).unwrap();
    assert!(second.reports.iter().filter(|r| r.adaptive_bytes > 0).all(|r| r.cached), "{:?}", second.reports);
    let same = |a: &WaveletFields, b: &WaveletFields| {
        a.fields.len() == b.fields.len()
            && a.fields.iter().zip(&b.fields).all(|(x, y)| match (x, y) {
                (Some(x), Some(y)) => x.to_bytes() == y.to_bytes(),
                (None, None) => true,
                _ => false,
            })
            && a.self_maps == b.self_maps
            && a.reports.iter().zip(&b.reports).all(|(x, y)| x.fixed_bytes == y.fixed_bytes)
    };
    assert!(same(&first, &second));
    // another parameter set misses
    let other = WaveletFields::build(&scene, &SfwOptions { keep: 0.1, ..opts.clone() }).unwrap();
    assert!(other.reports.iter().filter(|r| r.adaptive_bytes > 0).all(|r| !r.cached));
    // corrupt every file: the next build recomputes the same data
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        let mut b = std::fs::read(&p).unwrap();
        b.truncate(b.len() / 2);
        std::fs::write(&p, b).unwrap();
    }
    let third = WaveletFields::build(&scene, &opts).unwrap();
    assert!(third.reports.iter().filter(|r| r.adaptive_bytes > 0).all(|r| !r.cached));
    assert!(same(&first, &third));
    let _ = std::fs::remove_dir_all(&dir);
}
