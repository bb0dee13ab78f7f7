//! The adaptive-visibility-sampling technique (`avs`) on the Vulkan device (lavapipe):
//! validation on the three paper scenes, accuracy against the CPU reference, sample points that
//! follow deforming vertices, parameters, extremes.

use penumbra::{FrameImages, RenderSettings, Renderer};
use penumbra_passes::avs::AvsStats;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::Mode;
use penumbra_scene::Scene;
use std::path::PathBuf;

mod common;
use common::reference_at;
use common::{hdr_image as image, render_times as render, scene, with};

/// The avs technique's statistics of `r`'s last frame.
fn avs_stats(r: &Renderer) -> AvsStats {
    r.technique_stats::<AvsStats>().expect("avs keeps statistics")
}

/// Writes `img` as an sRGB PNG (exposure 1, clamped) into `$AVS_DUMP/name.png` when set.
fn dump(img: &Image, name: &str) {
    let Ok(dir) = std::env::var("AVS_DUMP") else { return };
    let mut rgb = Vec::new();
    for y in 0..img.height {
        for x in 0..img.width {
            for c in img.get(x, y) {
                let v = c.max(0.0) / (1.0 + c.max(0.0));
                rgb.push((v.powf(1.0 / 2.2) * 255.0) as u8);
            }
        }
    }
    penumbra_reference::image::write_png_rgb8(
        &PathBuf::from(dir).join(format!("{name}.png")),
        img.width,
        img.height,
        &rgb,
    )
    .unwrap();
}

/// `adaptation = rounds` (the default, named for tests that rely on it): the statistics of a
/// frame's own maps (`visible_fraction`, `rays`, `maps`) once it is built; the late adaptation
/// reports those of an earlier finished frame (`AvsStats::late_vertices`).
const ROUNDS: (&str, &str) = ("adaptation", "rounds");

fn psnr(c: &penumbra_reference::metrics::Comparison) -> f64 {
    c.psnr_db.unwrap_or(f64::INFINITY)
}

/// Small maps and few points keep the tests short.
const FAST: &[(&str, &str)] = &[("r", "32"), ("points", "96"), ("iterations", "1")];

#[test]
fn paper_scenes_are_validation_clean_and_points_follow_vertices() {
    for name in ["hat_on_cloth.toml", "balls_on_dish.toml", "falling.toml"] {
        let s = with(&scene(name), FAST);
        let mut r = avs_renderer(&s, 64, 48, true);
        let mut frames = Vec::new();
        let mut stats = Vec::new();
        let mut prev = None;
        for t in [0.0f32, 0.5] {
            let f = s.at(t, prev);
            prev = Some(t);
            frames.extend(r.render(&f, None, true).expect("render"));
            stats.push((avs_stats(&r), f));
        }
        frames.extend(r.finish().expect("finish"));
        let log = r.context().validation.clone();
        assert_eq!(frames.len(), 2);
        for f in &frames {
            assert!(f.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0), "{name}: non-finite radiance");
            let mean: f32 = f.hdr.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>() / f.hdr.len() as f32;
            assert!(mean > 0.05, "{name}: image is black (mean {mean})");
            assert!(f.gpu_ms.iter().any(|(p, _)| p == "avs_shade"), "{name}: no avs_shade pass timed: {:?}", f.gpu_ms);
            assert!(f.gpu_ms.iter().any(|(p, _)| p.starts_with("avs_hsdt")), "{name}: no HSDT pass");
        }
        // the sample points are vertices of the current frame (they move with the geometry)
        for (st, f) in &stats {
            assert!(st.points >= 16 && st.points <= 8192, "{name}: {} points", st.points);
            let pool = penumbra_passes::avs::vertex_pool(&s, f, &st.pool_plan).unwrap();
            assert_eq!(pool.len(), st.vertices);
            assert!(st.point_vertices.iter().all(|&v| v < pool.len()));
        }
        drop(r);
        assert_eq!(log.error_count(), 0, "{name}: validation errors: {:#?}", log.errors());
    }
}

#[test]
fn accuracy_against_the_reference() {
    let s = scene("hat_on_cloth.toml");
    let (w, h, t) = (80, 60, 0.5);
    let sg_ref = reference_at(&s, (w, h), 32, t, Mode::Exact);
    // the paper's pool (vertices only): a fixed k = 240 spread over the refined cloth's extra
    // candidates leaves the hat too few points (relRMSE 1.74); the automatic k grows with the pool
    let fast = with(&s, &[("r", "64"), ("points", "240"), ("iterations", "1"), ("pool_points", "0")]);
    let (r_avs, avs) = render(&fast, "avs", w, h, &[t], false);
    if std::env::var("AVS_DUMP").is_ok() {
        let st = avs_stats(&r_avs);
        let pool = penumbra_passes::avs::vertex_pool(&fast, &fast.at(t, None), &st.pool_plan).unwrap();
        for (i, &v) in st.point_vertices.iter().enumerate() {
            println!("point {i}: {:?} n {:?} visible {:.3}", pool[v].pos, pool[v].normal, st.visible_fraction[i]);
        }
    }
    let (_r, cells) = render(&with(&fast, &[("integration", "cells")]), "avs", w, h, &[t], false);
    let (_r, table) = render(&with(&fast, &[("integration", "table")]), "avs", w, h, &[t], false);
    let (_r, open) = render(&with(&fast, &[("shadows", "false")]), "avs", w, h, &[t], false);
    dump(&sg_ref.radiance, "reference");
    for (f, n) in [(&avs[0], "axis"), (&cells[0], "cells"), (&open[0], "open")] {
        dump(&image(f), n);
    }
    let cmp = |f: &FrameImages, name: &str| compare(&sg_ref.radiance, "reference", &image(f), name).unwrap();
    let (a, c, o) = (cmp(&avs[0], "avs axis"), cmp(&cells[0], "avs cells"), cmp(&open[0], "avs unshadowed"));
    let tb = cmp(&table[0], "avs table");
    for (what, x) in [("axis", &a), ("cells", &c), ("table", &tb), ("no shadows", &o)] {
        println!("exact ref / avs {what}: PSNR {:.2} dB, relRMSE {:.4}, FLIP {:.4}", psnr(x), x.rel_rmse, x.flip_mean);
    }
    // each integration mode is its own pipeline (avs_shade.comp's AVS_MODE, a specialization
    // constant set when the technique is created): a mode that did not reach the shader would
    // draw the axis mode's image
    for (f, n) in [(&cells[0], "cells"), (&table[0], "table")] {
        let d = compare(&image(&avs[0]), "avs axis", &image(f), n).unwrap();
        assert!(d.rel_rmse > 1e-6, "the {n} integration draws the axis image: relRMSE {}", d.rel_rmse);
    }
    // Shadows from the sampled visibility must bring the image much closer to the reference
    // than no shadows, in both integration modes. Measured (80x60, t = 0.5, r = 64, 240 initial
    // points, 1 round, 32-spp exact reference): relRMSE 0.334 (axis) / 0.335 (cells) against
    // 2.63 unshadowed; PSNR 25.94 / 25.94 against 21.61 (0.406 / 0.411 and 21.83 / 21.78 before
    // studio.exr's key lights were split off the maps, `key_lights`; 0.550 / 0.553 and 21.44 / 21.41 before
    // the diffuse term became the map's irradiance times the lobes' visible share; PSNR is dominated by the brim and crown,
    // too dark: their vertices lie only at the brim's edges, see the note of issue 8).
    assert!(a.rel_rmse < 0.7, "axis relRMSE {}", a.rel_rmse);
    assert!(c.rel_rmse < 0.7, "cells relRMSE {}", c.rel_rmse);
    assert!(a.rel_rmse < 0.35 * o.rel_rmse, "axis {} vs unshadowed {}", a.rel_rmse, o.rel_rmse);
    assert!(c.rel_rmse < 0.35 * o.rel_rmse, "cells {} vs unshadowed {}", c.rel_rmse, o.rel_rmse);
    assert!(psnr(&a) > 19.0 && psnr(&c) > 19.0, "PSNR {} / {}", psnr(&a), psnr(&c));
    // part A's tabulated T(lambda, d) at the lobe axis: the same bars
    assert!(
        tb.rel_rmse < 0.7 && tb.rel_rmse < 0.35 * o.rel_rmse && psnr(&tb) > 19.0,
        "table: relRMSE {}, PSNR {}",
        tb.rel_rmse,
        psnr(&tb)
    );
}

#[test]
fn parameters_are_checked() {
    use penumbra_passes::avs::AvsSettings;
    let p = |kv: &[(&str, &str)]| {
        AvsSettings::from_params(&kv.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect())
    };
    let d = p(&[]).unwrap();
    // r = 32 since session 37 (the paper's 128 measured no more accurate on any matrix scene)
    assert_eq!((d.r, d.initial_grid, d.e_max, d.e_min, d.iterations), (32, 16, 0.10, 0.05, 2));
    assert_eq!(d.levels(), 2);
    assert_eq!(p(&[("r", "128")]).unwrap().levels(), 4);
    assert_eq!(p(&[("r", "256"), ("initial_grid", "32")]).unwrap().levels(), 4);
    for (k, v) in [
        ("r", "100"),
        ("r", "8"),
        ("r", "512"),
        ("initial_grid", "20"),
        ("e_max", "nan"),
        ("integration", "exact"),
        ("bogus", "1"),
        ("e_min", "0.5"),
        ("cull", "maybe"),
        ("keep_hits", "2"),
    ] {
        let e = p(&[(k, v)]).unwrap_err().to_string();
        assert!(e.contains(k), "{k} = {v}: {e}");
    }
    let e = p(&[("r", "48")]).unwrap_err().to_string();
    assert!(e.contains("power of two"), "{e}");
}

#[test]
fn extremes_free_hemispheres_and_points_following_deformation() {
    // Nothing casts a shadow: every map is fully visible (SSDF +pi everywhere), so the image equals
    // the unshadowed one.
    let mut s = with(&scene("hat_on_cloth.toml"), &[("r", "32"), ("points", "48"), ("iterations", "0"), ROUNDS]);
    for info in s.object_info.iter_mut() {
        info.casts_shadow = false;
    }
    let (r, free) = render(&s, "avs", 40, 30, &[0.5], false);
    let st = avs_stats(&r);
    assert!(st.visible_fraction.iter().all(|v| (v - 1.0).abs() < 2e-3), "not all maps free: {:?}", st.visible_fraction);
    let (_r, open) = render(&with(&s, &[("shadows", "false")]), "avs", 40, 30, &[0.5], false);
    for (a, b) in free[0].hdr.iter().zip(&open[0].hdr) {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 1e-3 * b[c].abs() + 1e-5, "free {a:?} vs unshadowed {b:?}");
        }
    }
    // Deforming geometry: without adaptation rounds the sample points are the same vertices in
    // both frames, at their deformed positions (the hat squashes).
    // (culling off: with it the second frame traces only the points the first frame's pixels used)
    let s = with(
        &scene("hat_on_cloth.toml"),
        &[("r", "32"), ("points", "48"), ("iterations", "0"), ("cull", "false"), ROUNDS],
    );
    let mut r = avs_renderer(&s, 40, 30, false);
    let f0 = s.at(0.0, None);
    r.render(&f0, None, true).expect("render");
    let a = avs_stats(&r);
    let f1 = s.at(0.5, Some(0.0));
    r.render(&f1, None, true).expect("render");
    let b = avs_stats(&r);
    r.finish().expect("finish");
    assert_eq!(a.point_vertices, b.point_vertices);
    let (p0, p1) = (
        penumbra_passes::avs::vertex_pool(&s, &f0, &b.pool_plan).unwrap(),
        penumbra_passes::avs::vertex_pool(&s, &f1, &b.pool_plan).unwrap(),
    );
    let moved = a.point_vertices.iter().filter(|&&v| (p0[v].pos - p1[v].pos).length() > 1e-3).count();
    assert!(moved > 0, "no sample point moved with the deforming hat");
    // Some maps are partly occluded (the hat over the cloth), some fully free.
    assert!(
        b.visible_fraction.iter().any(|&v| v < 0.5) && b.visible_fraction.iter().any(|&v| v > 0.95),
        "{:?}",
        b.visible_fraction
    );
}

/// A headless renderer of `s` with the avs technique and the scene's parameters, at `width` x
/// `height`, with or without the validation layer.
fn avs_renderer(s: &Scene, width: u32, height: u32, validation: bool) -> Renderer {
    let settings = RenderSettings::with_technique(width, height, "avs", &s.technique_params);
    Renderer::new_headless(s, settings, validation).expect("renderer")
}

// ---------------------------------------------------------------------------------------------
// Extremes on small synthetic scenes (issue 8): whole hemisphere occluded / free, a slim occluder
// thinner than one initial ray cell, light directions at the map's pole and phi seam, fp16 SSDFs
// at r = 256 in shading.

/// Writes `toml` to a temporary scene file and loads it.
fn scene_text(name: &str, toml: &str) -> Scene {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("penumbra_avs_{}_{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, toml).unwrap();
    let mut s = Scene::load(&path).expect("scene");
    let _ = std::fs::remove_dir_all(&dir);
    // these scenes place their floor vertices on purpose: the pool holds those only; they
    // measure the SSDFs' visibility, so the sky's sun stays in the map
    s.technique_params.insert("pool_points".into(), "0".into());
    s.technique_params.insert("key_lights".into(), "0".into());
    s
}

fn floor_points(st: &AvsStats, scene: &Scene, t: f32) -> Vec<(usize, penumbra_math::avs_sampling::SurfacePoint)> {
    let pool = penumbra_passes::avs::vertex_pool(scene, &scene.at(t, None), &st.pool_plan).unwrap();
    st.point_vertices.iter().enumerate().map(|(i, &v)| (i, pool[v])).collect()
}

/// Whether the ray from `o` along `d` surely hits the box `b` (it hits the box shrunk by `m` on
/// every side: `Some(true)`), surely misses it (it misses the box grown by `m`: `Some(false)`) or
/// passes too close to its surface to tell (`None`).
fn classify_ray(o: glam::Vec3, d: glam::Vec3, b: (glam::Vec3, glam::Vec3), m: f32) -> Option<bool> {
    if ray_hits_box(o, d, b.0 + m, b.1 - m) {
        Some(true)
    } else if !ray_hits_box(o, d, b.0 - m, b.1 + m) {
        Some(false)
    } else {
        None
    }
}

/// Ray-box slab test: does the ray o + s d (s > 0) pass through the box [lo, hi]?
fn ray_hits_box(o: glam::Vec3, d: glam::Vec3, lo: glam::Vec3, hi: glam::Vec3) -> bool {
    let (mut t0, mut t1) = (0.0f32, f32::MAX);
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return false;
            }
            continue;
        }
        let (mut u, mut v) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        if u > v {
            std::mem::swap(&mut u, &mut v);
        }
        t0 = t0.max(u);
        t1 = t1.min(v);
    }
    t0 <= t1
}

const SKY: &str = "[environment]\nprocedural = \"sky\"\nintensity = 1.0\n";

#[test]
fn extremes_whole_hemisphere_occluded_or_free() {
    // A floor under a 400 x 400 ceiling 0.3 above it: from every floor point the gap at the horizon
    // is below 0.0016 rad, under the lowest texel centres (at the poles next to the seam,
    // sin^2(h/2) = 0.0024 rad at r = 32; a 40 x 40 ceiling leaves 0.016 rad and those corner
    // texels see the sky), so every floor map is fully occluded. The ceiling (normal up) sees a free hemisphere. The camera sits
    // between the two and looks down at the floor.
    let base = format!(
        "name = \"cave\"\n[camera]\neye = [0.0, 0.27, 0.5]\ntarget = [0.0, 0.0, -0.2]\nfov_deg = 40\n{SKY}\
         [materials.floor]\ntype = \"diffuse\"\nalbedo = 0.7\n\
         [[object]]\nname = \"floor\"\nmesh = {{ type = \"plane\", size = 2, divisions = 12 }}\nmaterial = \"floor\"\n"
    );
    let ceiling = "[[object]]\nname = \"ceiling\"\nmesh = { type = \"plane\", size = 400, divisions = 4 }\nmaterial = \"floor\"\nposition = [0.0, 0.3, 0.0]\n";
    let fast = [("r", "32"), ("iterations", "0"), ROUNDS];
    let cave = with(&scene_text("cave", &format!("{base}{ceiling}")), &fast);
    // the unshadowed image (visibility 1 whatever the integration mode)
    let (_r, open) = render(&with(&cave, &[("shadows", "false")]), "avs", 48, 36, &[0.0], false);
    for mode in ["axis", "cells", "table", "adf"] {
        let (r, dark) = render(&with(&cave, &[("integration", mode)]), "avs", 48, 36, &[0.0], false);
        let st = avs_stats(&r);
        let pts = floor_points(&st, &cave, 0.0);
        let vf = st.visible_fraction;
        let (floor, top): (Vec<_>, Vec<_>) = pts.iter().partition(|(_, p)| p.pos.y < 0.15);
        assert!(!floor.is_empty() && !top.is_empty(), "{mode}: {} floor / {} ceiling points", floor.len(), top.len());
        for (i, p) in &floor {
            assert!(vf[*i].abs() < 1e-4, "{mode}: floor point {:?} sees {} of its hemisphere", p.pos, vf[*i]);
        }
        for (i, p) in &top {
            assert!((vf[*i] - 1.0).abs() < 2e-3, "{mode}: ceiling point {:?} sees only {}", p.pos, vf[*i]);
        }
        // every pixel is either background (the same environment lookup in both) or floor, which
        // must be black (at most 1e-3 of its unshadowed radiance)
        let mut floor_px = 0;
        for (a, b) in dark[0].hdr.iter().zip(&open[0].hdr) {
            if a == b {
                continue;
            }
            floor_px += 1;
            for c in 0..3 {
                assert!(a[c] <= 1e-3 * b[c] + 1e-6, "{mode}: occluded floor pixel {a:?} (unshadowed {b:?})");
            }
        }
        assert!(floor_px > 48 * 36 / 3, "{mode}: only {floor_px} floor pixels in view");
        println!(
            "{mode}: {} floor maps fully occluded, {} ceiling maps free, {floor_px} floor pixels black",
            floor.len(),
            top.len()
        );
    }
    // Without the ceiling every floor map is free and shading equals the unshadowed image.
    let open_sky = with(&scene_text("open_sky", &base), &fast);
    let (r, free) = render(&open_sky, "avs", 48, 36, &[0.0], false);
    let vf = avs_stats(&r).visible_fraction;
    assert!(vf.iter().all(|v| (v - 1.0).abs() < 2e-3), "free floor maps: {vf:?}");
    let (_r, open) = render(&with(&open_sky, &[("shadows", "false")]), "avs", 48, 36, &[0.0], false);
    for (a, b) in free[0].hdr.iter().zip(&open[0].hdr) {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 1e-3 * b[c].abs() + 1e-5, "free {a:?} vs unshadowed {b:?}");
        }
    }
}

#[test]
fn extremes_slim_occluder_thinner_than_an_initial_ray_cell() {
    slim_bar(128);
}

/// The slim-bar scene: a floor, a bar 0.01 thick 0.2 above it (at most 0.05 rad wide seen from
/// the floor, a quarter of one initial ray cell, pi/16 = 0.196 rad, and about 2 texels at r = 128)
/// and a 0.6 x 0.4 x 0.3 box beside it (control: 0.25-0.6 rad, 1.3-3 initial cells, wide).
/// Returns the scene, the bar's and the box's world boxes and the bar's half thickness.
fn bar_scene() -> (Scene, (glam::Vec3, glam::Vec3), (glam::Vec3, glam::Vec3), f32) {
    let (y, half) = (0.2f32, 0.005f32);
    let toml = format!(
        "name = \"bar\"\n[camera]\neye = [0.0, 2.0, 1.5]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 40\n{SKY}\
         [[object]]\nname = \"floor\"\nmesh = {{ type = \"plane\", size = 2, divisions = 12 }}\n\
         [[object]]\nname = \"bar\"\nmesh = {{ type = \"cube\", size = 1 }}\nposition = [0.0, {y}, 0.0]\nscale = [3.0, {}, {}]\n\
         [[object]]\nname = \"box\"\nmesh = {{ type = \"cube\", size = 1 }}\nposition = [0.0, 0.3, 0.6]\nscale = [0.6, 0.4, 0.3]\n",
        2.0 * half,
        2.0 * half
    );
    let bar = (glam::Vec3::new(-1.5, y - half, -half), glam::Vec3::new(1.5, y + half, half));
    let boxx = (glam::Vec3::new(-0.3, 0.1, 0.45), glam::Vec3::new(0.3, 0.5, 0.75));
    (scene_text("bar", &toml), bar, boxx, half)
}

/// Origin of the visibility rays of a sample point (the point offset along its normal, as the
/// technique traces them).
fn ray_origin(scene: &Scene, p: &penumbra_math::avs_sampling::SurfacePoint) -> glam::Vec3 {
    let f = scene.at(0.0, None);
    let pool = penumbra_passes::avs::vertex_pool(
        scene,
        &f,
        &penumbra_passes::avs::PoolPlan::vertices_only(scene, &f).unwrap(),
    )
    .unwrap();
    p.pos + p.normal * penumbra_passes::avs::ray_offset(&pool)
}

/// A slim bar and a wide box over a floor at map resolution r: brute-force maps against the CPU
/// ray test, adaptive maps against brute force and against the initial rays.
fn slim_bar(r: u32) {
    use penumbra_math::avs_maps::{texel_dir_f32, texel_solid_angle};
    use penumbra_math::avs_sampling::point_frame;
    let (s, bar, boxx, half) = bar_scene();
    let rs = r.to_string();
    let run = |adaptive: bool, k: u32| {
        let ks = k.to_string();
        let p = [
            ("r", rs.as_str()),
            ("points", "169"),
            ("iterations", "0"),
            ROUNDS,
            ("ray_neighbours", ks.as_str()),
            ("adaptive", if adaptive { "true" } else { "false" }),
        ];
        let (renderer, _) = render(&with(&s, &p), "avs", 16, 12, &[0.0], false);
        let st = avs_stats(&renderer);
        (floor_points(&st, &with(&s, &p), 0.0), st.visible_fraction.clone(), st.rays)
    };
    let (pts, vf_bf, rays_bf) = run(false, 0);
    let (pts_a, vf_a0, rays_a0) = run(true, 0);
    let (_, vf_a4, rays_a4) = run(true, 4);
    assert_eq!(pts.iter().map(|p| p.1.pos).collect::<Vec<_>>(), pts_a.iter().map(|p| p.1.pos).collect::<Vec<_>>());
    // CPU prediction per texel-centre ray (robust: the ray hits the object shrunk by 20 % of the
    // bar's half thickness / misses it grown by as much; rays in between are ambiguous)
    let classify = |o, d, b| classify_ray(o, d, b, 0.2 * half);
    let two_pi = 2.0 * std::f64::consts::PI;
    let tol = 2e-4; // SH16 DC in f32 and texels hit by both objects
    let (mut checked, mut missed_seedless, mut seeded, mut found0, mut found4, mut seedless_near_box) =
        (0, 0, 0, 0, 0, 0);
    let (mut bar_bf, mut bar_a0, mut box_cpu, mut box_a0) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (i, p) in &pts {
        if p.pos.y.abs() > 1e-4 || p.normal.y < 0.99 || p.pos.x.abs() > 0.9 || p.pos.z > 0.3 {
            continue; // object vertices, floor points past the bar's ends or under the box
        }
        checked += 1;
        let f = point_frame(p.normal);
        let world = |l: glam::Vec3| (f.t.as_vec3() * l.x + f.b.as_vec3() * l.y + f.n.as_vec3() * l.z).normalize();
        let o = ray_origin(&s, p);
        // occluded solid angle at full resolution: bar only (lower bound), box and either object
        // (lower / upper bounds)
        let (mut bar_lo, mut box_lo, mut box_hi, mut any_lo, mut any_hi) = (0.0f64, 0.0, 0.0, 0.0, 0.0);
        // initial cells (16 x 16) the bar / the box surely occludes a texel of
        let (mut bar_cells, mut box_cells) = (vec![false; 256], vec![false; 256]);
        for a in 0..r {
            let sa = texel_solid_angle(a, r) / two_pi;
            for b in 0..r {
                let d = world(texel_dir_f32(a, b, r));
                let (cb, cx) = (classify(o, d, bar), classify(o, d, boxx));
                let cell = (a * 16 / r * 16 + b * 16 / r) as usize;
                bar_cells[cell] |= cb == Some(true);
                box_cells[cell] |= cx == Some(true);
                bar_lo += sa * (cb == Some(true) && cx == Some(false)) as u32 as f64;
                box_lo += sa * (cx == Some(true)) as u32 as f64;
                box_hi += sa * (cx != Some(false)) as u32 as f64;
                any_lo += sa * (cb == Some(true) || cx == Some(true)) as u32 as f64;
                any_hi += sa * (cb != Some(false) || cx != Some(false)) as u32 as f64;
            }
        }
        let bf = 1.0 - vf_bf[*i] as f64;
        assert!(
            bf >= any_lo - tol && bf <= any_hi + tol,
            "brute force at {:?}: occluded {bf:.5}, expected [{any_lo:.5}, {any_hi:.5}]",
            p.pos
        );
        let (a0, a4) = (1.0 - vf_a0[*i] as f64, 1.0 - vf_a4[*i] as f64);
        // the box (wider than an initial cell) is found: at least 95 % of its solid angle
        assert!(
            a0 >= 0.95 * box_lo - tol && a4 >= 0.95 * box_lo - tol,
            "box lost at {:?}: adaptive {a0:.5} / {a4:.5}, box {box_lo:.5}",
            p.pos
        );
        // copying parents never adds occlusion to objects without an interior at the coarse level,
        // and a kept hit (keep_hits) is one texel backed by a hit on its corner
        assert!(a0 <= bf + tol && a4 <= bf + tol, "adaptive {a0} / {a4} > brute force {bf} at {:?}", p.pos);
        let seeds: Vec<Option<bool>> = (0..16)
            .flat_map(|a| (0..16).map(move |b| (a, b)))
            .map(|(a, b)| classify(o, world(texel_dir_f32(a, b, 16)), bar))
            .collect();
        let bar_found = |occ: f64| occ > box_hi + 0.25 * bar_lo + tol;
        // the bar within one initial cell of the box: the box's boundary rays can find it
        let near_box = (0..256).any(|c| {
            bar_cells[c]
                && (0..9).any(|q| {
                    let (ca, cb) = ((c / 16) as i32 + q / 3 - 1, (c % 16) as i32 + q % 3 - 1);
                    (0..16).contains(&ca) && (0..16).contains(&cb) && box_cells[(ca * 16 + cb) as usize]
                })
        });
        if seeds.iter().all(|s| *s == Some(false)) {
            // no initial ray of its own on the bar and the bar away from the box: nothing can start
            // a refinement there (next to the box the box's boundary rays can: with keep_hits they
            // then follow the bar)
            assert!(
                near_box || !bar_found(a0),
                "point {:?} without a seed ray found the bar: {a0} vs box {box_hi}",
                p.pos
            );
            missed_seedless += 1;
            seedless_near_box += near_box as usize;
        } else if seeds.contains(&Some(true)) {
            seeded += 1;
        }
        found0 += bar_found(a0) as usize;
        found4 += bar_found(a4) as usize;
        bar_bf += bar_lo;
        bar_a0 += (a0 - box_lo).max(0.0);
        box_cpu += box_lo;
        box_a0 += a0.min(box_hi);
    }
    println!(
        "slim bar (r = {r}): {checked} floor points; {missed_seedless} have no initial ray on the bar ({seedless_near_box} of them next to the box), {seeded} have one; \
         bar found (adaptive occlusion > box + 1/4 of the bar) at {found0} points (own rays) / {found4} (with 4 neighbours' rays), \
         brute force finds it everywhere; occluded share summed over points: bar {bar_bf:.4} (CPU) vs adaptive beyond the box {bar_a0:.4}, \
         box {box_cpu:.4} (CPU) vs adaptive {box_a0:.4}; rays: every texel {rays_bf}, adaptive {rays_a0} / {rays_a4}"
    );
    assert!(checked >= 50, "{checked} floor points");
    assert!(
        missed_seedless > 0 && seeded > 0,
        "{missed_seedless} points without / {seeded} with a seed ray: the bar is not slim"
    );
    assert!(found4 >= found0, "neighbours' rays lost the bar: {found4} < {found0}");
    if r == 128 {
        // Measured (r = 128, 71 floor points): bar found at 35 / 52 points (own / with
        // neighbours' rays) with keep_hits, 5 / 33 without (the refinement re-traced a seed's
        // children, their centres missed the bar and the hit was lost); bar occlusion beyond the
        // box summed over the points 0.441 (CPU bar 0.412) against 0.037 without; rays 240534 /
        // 532684 against 207072 / 433464.
        assert!(found0 >= 30 && found4 >= 45, "bar found at {found0} / {found4} points");
        assert!(bar_a0 >= 0.5 * bar_bf, "bar captured {bar_a0} of {bar_bf}");
    }
}

/// Where the centre of pixel (px, py) of a w x h image sees the floor plane y = 0, through the
/// camera's inverse view-projection `inv` from `eye`; `None` when its ray does not point down.
fn floor_point(inv: &glam::Mat4, eye: glam::Vec3, w: u32, h: u32, px: u32, py: u32) -> Option<glam::Vec3> {
    let ndc = glam::Vec2::new((px as f32 + 0.5) / w as f32 * 2.0 - 1.0, (py as f32 + 0.5) / h as f32 * 2.0 - 1.0);
    let far = inv.project_point3(glam::Vec3::new(ndc.x, ndc.y, 1.0));
    let d = (far - eye).normalize();
    (d.y < -1e-3).then(|| eye + d * (-eye.y / d.y))
}

/// A 2 x 2 floor seen from above (48 x 48 pixels cover it), a wall box (centre `wall_c`, half
/// extents `wall_half`) on it and one local light (`light`: the TOML keys of its `[[light]]`
/// table), the environment off: the light-visibility tests' scene.
fn wall_scene(name: &str, light: &str, wall_c: glam::Vec3, wall_half: glam::Vec3) -> Scene {
    let toml = format!(
        "name = \"{name}\"\n[camera]\neye = [0.0, 2.4, 0.01]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 45\n\
         [environment]\nprocedural = \"sky\"\nintensity = 0.0\n\
         [[light]]\n{light}\n\
         [materials.floor]\ntype = \"diffuse\"\nalbedo = 0.8\n\
         [[object]]\nname = \"floor\"\nmesh = {{ type = \"plane\", size = 2, divisions = 20 }}\nmaterial = \"floor\"\n\
         [[object]]\nname = \"wall\"\nmesh = {{ type = \"cube\", size = 1 }}\nposition = [{}, {}, {}]\nscale = [{}, {}, {}]\n",
        wall_c.x,
        wall_c.y,
        wall_c.z,
        2.0 * wall_half.x,
        2.0 * wall_half.y,
        2.0 * wall_half.z
    );
    scene_text(name, &toml)
}

/// Floor pixels lit by one low point light whose direction from every floor point lies near the
/// map's pole (along the tangent) or on its phi seam (along the bitangent), behind a wall:
/// agreement of the shading's light visibility (avs / unshadowed avs, environment off) with the
/// exact point-to-light test, on pixels at least `margin` sample spacings from the shadow edge.
fn light_visibility_agreement(
    dir_local: glam::Vec3,
    r: u32,
    tag: &str,
    extra: &[(&str, &str)],
    margin: f32,
) -> (usize, usize, f64) {
    use penumbra_math::avs_sampling::point_frame;
    let f = point_frame(glam::Vec3::Y);
    let u = (f.t.as_vec3() * dir_local.x + f.b.as_vec3() * dir_local.y).normalize();
    assert!(u.x.abs() > 0.999 || u.z.abs() > 0.999, "frame of +Y is not axis-aligned: {u:?}");
    let elev = 6f32.to_radians();
    let light = (u * elev.cos() + glam::Vec3::Y * elev.sin()) * 3.0;
    // wall across u through the origin, 0.12 high, 1.2 long, 0.04 thick
    let wall_half = if u.x.abs() > 0.5 { glam::Vec3::new(0.02, 0.06, 0.6) } else { glam::Vec3::new(0.6, 0.06, 0.02) };
    let wall_c = glam::Vec3::new(0.0, 0.06, 0.0);
    let point = format!("type = \"point\"\nposition = [{}, {}, {}]\nintensity = 60", light.x, light.y, light.z);
    let s = with(
        &with(
            &wall_scene(&format!("wall_{tag}"), &point, wall_c, wall_half),
            &[("r", &r.to_string()), ("iterations", "0")],
        ),
        extra,
    );
    let (w, h) = (48u32, 48u32);
    let (renderer, shad) = render(&s, "avs", w, h, &[0.0], false);
    // one mean sample spacing (the search radius is `radius` = 2 spacings)
    let spacing = 0.5 * avs_stats(&renderer).radius;
    let (_r, open) = render(&with(&s, &[("shadows", "false")]), "avs", w, h, &[0.0], false);
    let frame = s.at(0.0, None);
    let cam = &frame.camera;
    let inv = (cam.proj(w as f32 / h as f32) * cam.view()).inverse();
    let shadowed = |p: glam::Vec3| {
        ray_hits_box(p, light - p, wall_c - wall_half, wall_c + wall_half) && (light - p).length() > 0.0
    };
    let (mut agree, mut total, mut err) = (0usize, 0usize, 0.0f64);
    for py in 0..h {
        for px in 0..w {
            let k = (py * w + px) as usize;
            let (a, b) = (shad[0].hdr[k][0], open[0].hdr[k][0]);
            assert!(a.is_finite() && a >= 0.0, "{tag}: pixel {px},{py} = {a}");
            let Some(p) = floor_point(&inv, cam.eye, w, h, px, py) else { continue };
            // floor pixels away from the wall and at least one sample spacing from the shadow edge
            if p.x.abs() > 0.95 || p.z.abs() > 0.95 || b <= 1e-4 {
                continue;
            }
            let on_wall = (p - wall_c).abs().cmple(wall_half + 0.02).all();
            if on_wall {
                continue;
            }
            let truth = shadowed(p);
            let stable = [glam::Vec3::X, glam::Vec3::NEG_X, glam::Vec3::Z, glam::Vec3::NEG_Z]
                .iter()
                .all(|o| shadowed(p + *o * (margin * spacing)) == truth);
            if !stable {
                continue;
            }
            let vis = (a / b) as f64;
            total += 1;
            err += (vis - if truth { 0.0 } else { 1.0 }).abs();
            if (vis > 0.5) != truth {
                agree += 1;
            }
        }
    }
    (agree, total, err / total.max(1) as f64)
}

#[test]
fn extremes_light_at_the_map_pole_and_seam() {
    // Local frame of the floor points: x = tangent (theta = 0 pole), y = bitangent (phi = 0 seam).
    // A light at 6 degrees elevation along +x lies 6-20 degrees from the pole of every floor map;
    // along +y / -y it lies 6 degrees from the phi = 0 / phi = pi seam columns. Measured (48 x 48,
    // r = 64): 1622 / 1623, 1622 / 1623, 1636 / 1636, 1640 / 1640 pixels agree, mean |error|
    // 0.0011 / 0.0011 / 0.0003 / 0.0003.
    for (dir, tag) in [
        (glam::Vec3::X, "pole0"),
        (glam::Vec3::NEG_X, "pole_pi"),
        (glam::Vec3::Y, "seam0"),
        (glam::Vec3::NEG_Y, "seam_pi"),
    ] {
        assert_light_agreement(dir, 64, tag, &[], 0.97, 0.08);
    }
}

/// Local lights' shadows traced through the kd-tree (`light_shadows = traced`, the default): the
/// wall's hard shadow edge is exact to the pixel, where the SSDF interpolated between sample
/// points (`light_shadows = ssdf`) blurs it over a sample spacing. Pixels a tenth of a sample
/// spacing from the edge and further: every one agrees with the exact point-to-light test
/// (measured 48 x 48: 2032 / 2032, mean |error| 0.0000; the SSDF 1986 / 2032, 0.0240).
#[test]
fn local_light_shadows_are_traced() {
    let (agree, total, err) = light_visibility_agreement(glam::Vec3::Y, 64, "traced", &[], 0.1);
    let (s_agree, s_total, s_err) =
        light_visibility_agreement(glam::Vec3::Y, 64, "ssdf_near", &[("light_shadows", "ssdf")], 0.1);
    println!("traced: {agree} / {total}, mean |error| {err:.4}; ssdf: {s_agree} / {s_total}, mean |error| {s_err:.4}");
    assert!(total >= 400, "only {total} floor pixels classified");
    assert_eq!(agree, total, "traced light visibility disagrees with the exact test on {} pixels", total - agree);
    assert!(err < 1e-3, "traced light visibility: mean |error| {err}");
}

/// A sphere light's soft shadow traced through the kd-tree (`light_shadows = traced`): 9 rays
/// toward its disk, the centre and the outer ring first, the inner ring only where those five
/// disagree (a penumbra). A wall between a large sphere light and the floor: every floor pixel's
/// traced visibility (shadowed / unshadowed avs, environment off) against the exact unoccluded
/// share of the light's disk (a 48 x 48 grid of rays through it): fully lit and umbral pixels
/// exact, the penumbra within the 9 rays' resolution and resolved into intermediate values (not
/// the 0 / 1 of five agreeing rays, nor the fifths of five rays). Measured (48 x 48): 216
/// penumbra pixels, mean |error| 0.058 there, 9 distinct values; lit and umbra 0 errors.
#[test]
fn sphere_light_penumbra_takes_every_ray_of_the_disk() {
    let (light, radius) = (glam::Vec3::new(0.9, 0.55, 0.0), 0.3f32);
    let (wall_c, wall_half) = (glam::Vec3::new(0.0, 0.06, 0.0), glam::Vec3::new(0.02, 0.06, 0.6));
    let sphere = format!(
        "type = \"sphere\"\nposition = [{}, {}, {}]\nradius = {radius}\nintensity = 60",
        light.x, light.y, light.z
    );
    let s = with(&wall_scene("penumbra", &sphere, wall_c, wall_half), &[("r", "32"), ("iterations", "0")]);
    let (w, h) = (48u32, 48u32);
    let (_r, shad) = render(&s, "avs", w, h, &[0.0], false);
    let (_r, open) = render(&with(&s, &[("shadows", "false")]), "avs", w, h, &[0.0], false);
    let frame = s.at(0.0, None);
    let cam = &frame.camera;
    let inv = (cam.proj(w as f32 / h as f32) * cam.view()).inverse();
    // the exact unoccluded share of the disk facing p (lights.glsl's light_disk_target: the disk
    // of the light's radius across the direction to its centre)
    let exact = |p: glam::Vec3| {
        let to = light - p;
        let wdir = to.normalize();
        let bx = if wdir.x.abs() < 0.9 { glam::Vec3::X.cross(wdir) } else { glam::Vec3::Y.cross(wdir) }.normalize();
        let by = wdir.cross(bx);
        let (mut free, mut all) = (0usize, 0usize);
        for i in 0..48 {
            for j in 0..48 {
                let (u, v) = ((i as f32 + 0.5) / 24.0 - 1.0, (j as f32 + 0.5) / 24.0 - 1.0);
                if u * u + v * v > 1.0 {
                    continue;
                }
                all += 1;
                let q = to + (bx * u + by * v) * radius;
                if !ray_hits_box(p, q, wall_c - wall_half, wall_c + wall_half) {
                    free += 1;
                }
            }
        }
        free as f64 / all as f64
    };
    let (mut lit_err, mut umbra_err, mut pen, mut pen_err) = (0usize, 0usize, 0usize, 0.0f64);
    let mut values: Vec<i64> = Vec::new();
    for py in 0..h {
        for px in 0..w {
            let k = (py * w + px) as usize;
            let (a, b) = (shad[0].hdr[k][0], open[0].hdr[k][0]);
            assert!(a.is_finite() && a >= 0.0, "pixel {px},{py} = {a}");
            let Some(p) = floor_point(&inv, cam.eye, w, h, px, py) else { continue };
            if p.x.abs() > 0.95 || p.z.abs() > 0.5 || b <= 1e-4 || (p - wall_c).abs().cmple(wall_half + 0.03).all() {
                continue;
            }
            let (vis, truth) = ((a / b) as f64, exact(p));
            if truth >= 1.0 {
                lit_err += usize::from((vis - 1.0).abs() > 1e-3);
            } else if truth <= 0.0 {
                umbra_err += usize::from(vis > 1e-3);
            } else if truth > 0.1 && truth < 0.9 {
                pen += 1;
                pen_err += (vis - truth).abs();
                values.push((vis * 9.0).round() as i64);
            }
        }
    }
    values.sort_unstable();
    values.dedup();
    let pen_mean = pen_err / pen.max(1) as f64;
    println!(
        "penumbra pixels {pen}, mean |error| {pen_mean:.4}, {} distinct values; lit errors {lit_err}, umbra errors {umbra_err}",
        values.len()
    );
    assert!(pen >= 40, "only {pen} penumbra pixels");
    assert_eq!(lit_err, 0, "fully lit pixels shadowed");
    assert_eq!(umbra_err, 0, "umbral pixels lit");
    assert!(pen_mean < 0.08, "penumbra: mean |error| {pen_mean} against the exact disk share");
    assert!(values.len() >= 8, "penumbra resolved into {} values only: {values:?}", values.len());
}

/// isg_bunny (the studio map's key light behind the bunny: a long shadow) without its scene
/// parameters and with diffuse materials: the scene's shininess-1000 reflections of the key light
/// are fireflies in a 256-spp reference, and the glossy term is not what the key-light tests
/// measure.
fn diffuse_isg_bunny() -> Scene {
    let mut s = scene("isg_bunny.toml");
    s.technique_params.clear();
    for m in s.materials.iter_mut() {
        *m = penumbra_scene::Material::diffuse(&m.name, m.albedo);
    }
    s
}

/// avs's frame of `s` at time `t` under the validation layer, asserted free of validation errors.
fn render_validated(s: &Scene, w: u32, h: u32, t: f32) -> Vec<FrameImages> {
    let (r, frames) = render(s, "avs", w, h, &[t], true);
    let log = r.context().validation.clone();
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());
    frames
}

/// The environment's key lights split off its map (`key_lights = 4`, default with
/// `light_shadows = traced`): a studio key light's sharp shadow comes from rays through the
/// kd-tree, the rest of the map through the SSDFs. isg_bunny made diffuse (studio.exr, a long
/// shadow of the bunny on a two-triangle floor) against the exact reference: with the whole map through the
/// SSDFs (`key_lights = 0`, the paper's) the shadow is drawn as blotches interpolated between
/// sample points; with the key lights split off it follows the bunny's outline. Validation clean.
/// Measured (64x48, t = 0.5, r = 32, 1 round, 256-spp reference): rmse/mean 0.086 with the key
/// lights split off, 0.144 with the whole map through the SSDFs (the shadow displaced and cut
/// into patches), 0.315 unshadowed.
#[test]
fn key_lights_split_off_the_environment_cast_their_shadows() {
    let s = diffuse_isg_bunny();
    let (w, h, t) = (64, 48, 0.5);
    let reference = reference_at(&s, (w, h), 256, t, Mode::Exact);
    let fast = [("r", "32"), ("iterations", "1")];
    let key = render_validated(&with(&s, &fast), w, h, t);
    let (_r, whole) = render(&with(&with(&s, &fast), &[("key_lights", "0")]), "avs", w, h, &[t], false);
    let (_r, open) = render(&with(&with(&s, &fast), &[("shadows", "false")]), "avs", w, h, &[t], false);
    let err = |f: &FrameImages, name: &str| {
        let c = compare(&reference.radiance, "reference", &image(f), name).unwrap();
        c.rmse / c.reference_mean
    };
    dump(&reference.radiance, "key_lights_reference");
    for (f, n) in [(&key[0], "key_lights_4"), (&whole[0], "key_lights_0"), (&open[0], "key_lights_open")] {
        dump(&image(f), n);
    }
    let (e_key, e_whole, e_open) =
        (err(&key[0], "key lights"), err(&whole[0], "whole map"), err(&open[0], "unshadowed"));
    println!(
        "rmse/mean: key lights split off {e_key:.4}, whole map through the SSDFs {e_whole:.4}, unshadowed {e_open:.4}"
    );
    assert!(e_key < 0.1, "key lights split off: rmse/mean {e_key} over avs's budget 0.1");
    assert!(e_key < 0.7 * e_whole, "key lights split off {e_key} against the whole map {e_whole}");
    assert!(e_key < 0.3 * e_open, "key lights split off {e_key} against unshadowed {e_open}");
    // the centre ray alone where the SSDF clears a key light's disk (key_rays = predicted, the
    // default) draws what every ray of the disk draws
    let (_r, every) = render(&with(&with(&s, &fast), &[("key_rays", "all")]), "avs", w, h, &[t], false);
    let e_every = err(&every[0], "every key ray");
    let c = compare(&image(&every[0]), "key_rays = all", &image(&key[0]), "key_rays = predicted").unwrap();
    println!("key_rays = all: rmse/mean {e_every:.4}; predicted against all {:.5}", c.rmse / c.reference_mean);
    assert!(c.rmse / c.reference_mean < 0.01, "key_rays = predicted differs from all by {}", c.rmse / c.reference_mean);
    assert!(e_key < e_every + 0.003, "key_rays = predicted {e_key} against all {e_every}");
    // stratified rays per pixel: grain in the penumbrae instead of the fixed pattern's bands, a
    // different image within the budget
    let (_r, strat) = render(&with(&with(&s, &fast), &[("key_pattern", "stratified")]), "avs", w, h, &[t], false);
    let e_strat = err(&strat[0], "stratified key rays");
    let c = compare(&image(&key[0]), "fixed", &image(&strat[0]), "stratified").unwrap();
    println!("key_pattern = stratified: rmse/mean {e_strat:.4}; against fixed {:.5}", c.rmse / c.reference_mean);
    assert!(c.rmse > 0.0, "key_pattern = stratified drew the fixed pattern's image");
    assert!(e_strat < 0.1 && e_strat < 0.7 * e_whole, "key_pattern = stratified: {e_strat} (whole map {e_whole})");
    // 16 more rays where the 9 disagree: a different image (only in penumbrae), no less accurate
    let (_r, refine) = render(&with(&with(&s, &fast), &[("key_penumbra", "refine")]), "avs", w, h, &[t], false);
    let e_refine = err(&refine[0], "refined penumbrae");
    let c = compare(&image(&key[0]), "rays", &image(&refine[0]), "refine").unwrap();
    println!("key_penumbra = refine: rmse/mean {e_refine:.4}; against rays {:.5}", c.rmse / c.reference_mean);
    assert!(c.rmse > 0.0, "key_penumbra = refine drew the 9 rays' image");
    assert!(e_refine < e_key + 0.002, "key_penumbra = refine {e_refine} against the 9 rays' {e_key}");
}

/// `key_filter` (default 4): the key lights' visible share averaged over a Gaussian a sixteenth
/// of the penumbra's width (`glsl/avs/avs_key_filter.comp`). isg_bunny made diffuse (the studio's
/// softbox behind the bunny: a long soft shadow) against the exact reference: the filter changes
/// the image, is no less accurate than the 9 rays' bands, and leaves alone every pixel whose 3 x 3
/// neighbourhood is lit (the unfiltered image equal to the unshadowed one there). Validation
/// clean. Measured (160x120, t = 0.5, r = 32, 1 round, 256-spp reference): rmse/mean 0.0679
/// filtered, 0.0689 unfiltered (1897 pixels changed, 10435 lit ones not); with `key_pattern =
/// stratified` 0.0697 and 0.0718.
#[test]
fn key_filter_smooths_penumbrae_and_leaves_lit_pixels_alone() {
    let s = diffuse_isg_bunny();
    let (w, h, t) = (160, 120, 0.5);
    let reference = reference_at(&s, (w, h), 256, t, Mode::Exact);
    let fast = [("r", "32"), ("iterations", "1")];
    let filtered = render_validated(&with(&s, &fast), w, h, t);
    let (_r, raw) = render(&with(&with(&s, &fast), &[("key_filter", "0")]), "avs", w, h, &[t], false);
    let (_r, open) = render(&with(&with(&s, &fast), &[("shadows", "false")]), "avs", w, h, &[t], false);
    let (f, u, o) = (image(&filtered[0]), image(&raw[0]), image(&open[0]));
    let err = |img: &Image, name: &str| {
        let c = compare(&reference.radiance, "reference", img, name).unwrap();
        c.rmse / c.reference_mean
    };
    let (e_f, e_u) = (err(&f, "key_filter = 4"), err(&u, "key_filter = 0"));
    dump(&f, "key_filter_4");
    dump(&u, "key_filter_0");
    let close = |a: [f32; 3], b: [f32; 3], tol: f32| (0..3).all(|c| (a[c] - b[c]).abs() <= tol * b[c].abs() + 1e-6);
    let (mut changed, mut lit) = (0, 0);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if !close(f.get(x, y), u.get(x, y), 1e-3) {
                changed += 1;
            }
            let lit_around = (0..9).all(|i| {
                let (qx, qy) = (x + i % 3 - 1, y + i / 3 - 1);
                close(u.get(qx, qy), o.get(qx, qy), 1e-4)
            });
            if lit_around {
                lit += 1;
                assert!(
                    close(f.get(x, y), u.get(x, y), 1e-4),
                    "lit pixel ({x}, {y}) filtered: {:?} against {:?}",
                    f.get(x, y),
                    u.get(x, y)
                );
            }
        }
    }
    println!("rmse/mean: key_filter = 4 {e_f:.4}, 0 {e_u:.4}; {changed} pixels changed, {lit} lit pixels unchanged");
    assert!(changed >= 20, "the filter changed {changed} pixels only");
    assert!(lit >= 500, "{lit} lit pixels only");
    assert!(e_f < e_u, "key_filter = 4 {e_f} against the unfiltered {e_u}");
    assert!(e_f < 0.1, "key_filter = 4: rmse/mean {e_f} over avs's budget 0.1");
    // stratified rays: the filter averages their grain
    let strat = with(&with(&s, &fast), &[("key_pattern", "stratified")]);
    let (_r, sf) = render(&strat, "avs", w, h, &[t], false);
    let (_r, su) = render(&with(&strat, &[("key_filter", "0")]), "avs", w, h, &[t], false);
    let (e_sf, e_su) = (err(&image(&sf[0]), "stratified, filtered"), err(&image(&su[0]), "stratified"));
    println!("key_pattern = stratified: rmse/mean filtered {e_sf:.4}, unfiltered {e_su:.4}");
    assert!(e_sf < e_su - 0.001, "stratified rays filtered {e_sf} against unfiltered {e_su}");
}

/// [`light_visibility_agreement`] at resolution `r`, asserted: at least 400 classified floor
/// pixels, at least `min_fraction` of them agreeing, mean |error| below `max_err`.
fn assert_light_agreement(
    dir: glam::Vec3,
    r: u32,
    tag: &str,
    params: &[(&str, &str)],
    min_fraction: f64,
    max_err: f64,
) {
    // the SSDF's light visibility (the traced one: `local_light_shadows_are_traced`)
    let params = [&[("light_shadows", "ssdf")], params].concat();
    let (agree, total, mean_err) = light_visibility_agreement(dir, r, tag, &params, 1.0);
    println!(
        "{tag} (r = {r}): {agree} / {total} pixels agree with the exact light visibility, mean |error| {mean_err:.4}"
    );
    assert!(total >= 400, "{tag}: only {total} floor pixels classified");
    assert!(
        agree as f64 >= min_fraction * total as f64,
        "{tag}: {agree} / {total} pixels agree with the exact light visibility"
    );
    assert!(mean_err < max_err, "{tag}: mean visibility error {mean_err}");
}

/// fp16 SSDFs and maps at r = 256 (issue 8). The brute-force maps (every texel traced) of the
/// slim-bar scene agree with the CPU ray test on every unambiguous texel, every ray of every level
/// is traced, the SH16 DC equals each map's visible solid angle, and shading with r = 256 SSDFs
/// (texel 0.7 degrees, fp16 step 0.002 rad near pi) classifies a low light on the phi seam as
/// well as r = 64 does (`extremes_light_at_the_map_pole_and_seam`: 1636 / 1636, mean |error|
/// 0.0003).
/// Found by this test: with one workgroup per map, each invocation traced 1024 rays at r = 256
/// and lavapipe's loop limit (65535 iterations per invocation, shared by all loops of a shader)
/// ended the texel loop of the workgroup's last 8 invocations early: ~6 % of the rays were never
/// traced and their texels stayed occluded (a floor point next to the bar: 2.9 % occluded
/// against 1.4-1.6 % by the CPU; seam light 1620 / 1636 pixels, mean |error| 0.0098). Fixed by
/// 1024-texel workgroups (16 rays per invocation); a probe loop reports the limit (`truncated`).
#[test]
fn extremes_r256_maps_and_fp16_shading() {
    use penumbra_math::avs_maps::{texel_dir_f32, texel_solid_angle};
    use penumbra_math::avs_sampling::point_frame;
    let (s, bar, boxx, half) = bar_scene();
    let r = 256u32;
    let s = with(
        &s,
        &[("r", "256"), ("points", "24"), ("iterations", "0"), ("adaptive", "false"), ("capture_maps", "true"), ROUNDS],
    );
    let (renderer, frames) = render(&s, "avs", 16, 12, &[0.0], false);
    let st = avs_stats(&renderer);
    assert_eq!(st.truncated, 0, "visibility passes hit the loop limit");
    hsdt_timed_in_the_frame(&frames, &st.maps, r);
    // without adaptivity only the final level runs: every texel traced once
    let per_map = (r * r) as u64;
    assert_eq!(st.rays, st.traced_points as u64 * per_map, "rays of {} maps", st.traced_points);
    assert_eq!(st.maps.len(), st.points);
    let classify = |o, d, b| classify_ray(o, d, b, 0.2 * half);
    let (mut floor, mut sure, mut wrong, mut occluded) = (0usize, 0usize, 0usize, 0usize);
    let mut worst_dc = 0.0f64;
    for (i, p) in floor_points(&st, &s, 0.0) {
        let map = &st.maps[i];
        // the SH16 DC against the map's visible solid angle (every point, objects included)
        let mut vis_sa = 0.0f64;
        for k in 0..(r * r) as usize {
            if (map[k / 32] >> (k % 32)) & 1 == 1 {
                vis_sa += texel_solid_angle(k as u32 / r, r);
            }
        }
        worst_dc = worst_dc.max((vis_sa / (2.0 * std::f64::consts::PI) - st.visible_fraction[i] as f64).abs());
        if p.pos.y.abs() > 1e-4 || p.normal.y < 0.99 {
            continue; // the objects' vertices
        }
        floor += 1;
        let f = point_frame(p.normal);
        let o = ray_origin(&s, &p);
        for k in 0..(r * r) as usize {
            let l = texel_dir_f32(k as u32 / r, k as u32 % r, r);
            let d = (f.t.as_vec3() * l.x + f.b.as_vec3() * l.y + f.n.as_vec3() * l.z).normalize();
            let (cb, cx) = (classify(o, d, bar), classify(o, d, boxx));
            let visible = (map[k / 32] >> (k % 32)) & 1 == 1;
            if cb == Some(true) || cx == Some(true) {
                sure += 1;
                occluded += 1;
                wrong += visible as usize;
            } else if cb == Some(false) && cx == Some(false) {
                sure += 1;
                wrong += !visible as usize;
            }
        }
    }
    println!("r = 256 maps: {floor} floor points, {wrong} of {sure} unambiguous texels disagree with the CPU ray test ({occluded} occluded); worst |SH DC - visible solid angle| {worst_dc:.2e}");
    assert!(floor >= 12 && occluded > 1000, "{floor} floor points, {occluded} occluded texels");
    assert_eq!(wrong, 0, "{wrong} of {sure} unambiguous texels disagree with the CPU ray test");
    assert!(worst_dc < 1e-4, "SH16 DC vs map: {worst_dc}");
    assert_light_agreement(glam::Vec3::Y, 256, "seam0_r256", &[("points", "48")], 0.995, 0.005);
}

/// `frames` frames of hat_on_cloth's moment t = 0.5 (the first without a previous frame) at 64x48
/// with `cull` set on `s`'s avs parameters: the images and avs's statistics after each frame;
/// validation (with synchronization) must stay clean. Each frame is finished before the next is
/// built (as by an application that waits for its frames), so frame k's late readbacks (culling
/// flags, the SH the late adaptation steps on) reach frame k + 1.
fn static_frames(s: &Scene, cull: &str, frames: usize) -> (Vec<FrameImages>, Vec<AvsStats>) {
    let s = with(s, &[("cull", cull)]);
    let mut r = avs_renderer(&s, 64, 48, true);
    let mut out = Vec::new();
    let mut stats = Vec::new();
    for k in 0..frames {
        out.extend(r.render(&s.at(0.5, (k > 0).then_some(0.5)), None, true).expect("render"));
        out.extend(r.finish().expect("finish"));
        stats.push(avs_stats(&r));
    }
    let log = r.context().validation.clone();
    drop(r);
    assert_eq!(log.error_count(), 0, "cull = {cull}: validation errors: {:#?}", log.errors());
    (out, stats)
}

#[test]
fn gbuffer_culling_traces_only_needed_points_and_keeps_the_image() {
    // Two frames of a static moment. Without adaptation rounds the sample set is fixed, so the
    // second frame's shading must pick exactly the same neighbours from the flagged points as from
    // all points: the culled image equals the unculled one, with fewer maps traced.
    // Both adaptation modes: the waited rounds (default) and the late one, whose flags and
    // statistics come back through late readbacks (a third frame reports the second one's rays).
    for mode in ["rounds", "late"] {
        let s = with(
            &scene("hat_on_cloth.toml"),
            &[("r", "32"), ("points", "160"), ("iterations", "0"), ("adaptation", mode)],
        );
        let two = |cull: &str| static_frames(&s, cull, 3);
        let (on, st_on) = two("true");
        let (off, st_off) = two("false");
        // the first frame traces every point
        assert_eq!(st_on[0].dormant, 0);
        assert_eq!(st_on[0].traced_points, st_off[0].traced_points);
        assert_eq!(st_off[1].dormant, 0);
        let (t_on, t_off) = (st_on[1].traced_points, st_off[1].traced_points);
        // the statistics of the second frame's maps
        let k = if mode == "late" { 2 } else { 1 };
        assert_eq!(st_on[k].late_vertices, st_on[1].point_vertices, "{mode}");
        println!(
            "{mode}: second frame: {t_on} of {t_off} maps traced ({} dormant), rays {} vs {}",
            st_on[1].dormant, st_on[k].rays, st_off[k].rays
        );
        assert!(
            st_on[1].dormant > 0 && t_on + st_on[1].dormant == t_off,
            "{mode}: traced {t_on} + dormant {} vs {t_off}",
            st_on[1].dormant
        );
        assert!(st_on[k].rays < st_off[k].rays, "{mode}");
        let (a, b) = (&on[1].hdr, &off[1].hdr);
        let mut worst = 0.0f32;
        for (p, q) in a.iter().zip(b.iter()) {
            for c in 0..3 {
                worst = worst.max((p[c] - q[c]).abs() / (q[c].abs() + 1e-3));
            }
        }
        assert!(worst <= 1e-4, "{mode}: culled image differs from the unculled one: max relative difference {worst}");
    }
}

#[test]
fn culled_adaptation_never_drops_points_it_did_not_see() {
    // With culling, a frame's adaptation sees only the flagged points: an erasure judged on that
    // subset must not remove the point for good (it goes dormant). Erasing for good cascaded over
    // frames and left pixels without sample points (black trails over balls_on_dish's dish).
    // Four frames of a static moment with adaptation rounds (each frame refines further, culled
    // or not): the culled kept set (traced + dormant) never shrinks, and the culled fourth image
    // stays the unculled one.
    let s = with(&scene("hat_on_cloth.toml"), &[("r", "32"), ("points", "160"), ("iterations", "2")]);
    let four = |cull: &str| static_frames(&s, cull, 4);
    let (on, st_on) = four("true");
    let (off, _) = four("false");
    let kept: Vec<std::collections::HashSet<usize>> =
        st_on.iter().map(|s| s.kept_vertices.iter().copied().collect()).collect();
    let erased: usize = st_on[1..].iter().map(|s| s.erased.iter().sum::<usize>()).sum();
    let dormant: Vec<usize> = st_on.iter().map(|s| s.dormant).collect();
    println!(
        "culled: kept per frame {:?}, dormant {dormant:?}, erased in culled frames {erased}",
        kept.iter().map(|k| k.len()).collect::<Vec<_>>()
    );
    assert!(erased > 0, "the culled frames erased nothing: the test does not test the erasure");
    for k in 1..kept.len() {
        let lost = kept[k - 1].difference(&kept[k]).count();
        assert_eq!(lost, 0, "frame {k}: {lost} kept points left the set under culling");
    }
    // no pixel turns (nearly) black where the unculled image is lit
    let (a, b) = (&on[3].hdr, &off[3].hdr);
    let lum = |p: &[f32; 4]| p[0] + p[1] + p[2];
    let dark = a.iter().zip(b.iter()).filter(|(p, q)| lum(q) > 0.05 && lum(p) < 0.25 * lum(q)).count();
    println!("fourth frame: {dark} of {} pixels under a quarter of the unculled image", a.len());
    assert!(dark * 200 <= a.len(), "{dark} pixels went dark under culling");
}

#[test]
fn hemicube_baseline_maps_match_the_cpu_ray_test() {
    // The Fig. 7 baseline (rasterized hemicubes converted to maps) on a floor with a box beside
    // the points: every texel whose centre ray robustly hits / misses the box (or the floor's own
    // plane) must come out occluded / visible, up to the texels the rasterizer's coarser sampling
    // cannot resolve (at most 3 % of the unambiguous texels per map at F = r / 2).
    use penumbra_engine::{Context, ContextDesc, Engine};
    use penumbra_math::avs_maps::{texel_dir_f32, words_per_map};
    use penumbra_math::avs_sampling::{point_frame, SurfacePoint};
    use penumbra_passes::avs::hemicube::HemicubeMaps;
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = penumbra::shader_library();
    let hc = HemicubeMaps::new(&ctx, &lib).expect("pipelines");
    let (lo, hi) = (glam::Vec3::new(-0.3, 0.0, 0.45), glam::Vec3::new(0.3, 0.4, 0.75));
    let c = [
        glam::Vec3::new(lo.x, lo.y, lo.z),
        glam::Vec3::new(hi.x, lo.y, lo.z),
        glam::Vec3::new(hi.x, hi.y, lo.z),
        glam::Vec3::new(lo.x, hi.y, lo.z),
        glam::Vec3::new(lo.x, lo.y, hi.z),
        glam::Vec3::new(hi.x, lo.y, hi.z),
        glam::Vec3::new(hi.x, hi.y, hi.z),
        glam::Vec3::new(lo.x, hi.y, hi.z),
    ];
    let quads = [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [3, 2, 6, 7], [0, 3, 7, 4], [1, 2, 6, 5]];
    let mut tris: Vec<[glam::Vec3; 3]> =
        quads.iter().flat_map(|q| [[c[q[0]], c[q[1]], c[q[2]]], [c[q[0]], c[q[2]], c[q[3]]]]).collect();
    // the floor (its own plane must not occlude the points on it)
    let f = [
        glam::Vec3::new(-1.0, 0.0, -1.0),
        glam::Vec3::new(1.0, 0.0, -1.0),
        glam::Vec3::new(1.0, 0.0, 1.0),
        glam::Vec3::new(-1.0, 0.0, 1.0),
    ];
    tris.push([f[0], f[1], f[2]]);
    tris.push([f[0], f[2], f[3]]);
    let points: Vec<SurfacePoint> = (0..12)
        .map(|i| SurfacePoint {
            pos: glam::Vec3::new(-0.6 + 0.11 * i as f32, 0.0, 0.3 - 0.07 * i as f32),
            normal: glam::Vec3::Y,
        })
        .collect();
    let r = 64u32;
    let offset = 1e-3;
    let mut engine = Engine::new(ctx.clone(), 1).expect("engine");
    engine.timestamps = true;
    let out = hc.run(&mut engine, &tris, &points, offset, r, true).expect("hemicube maps");
    assert!(out.gpu_ms.iter().any(|(n, _)| n.starts_with("avs_hc_raster")), "{:?}", out.gpu_ms);
    let words = words_per_map(r) as usize;
    let m = 0.02;
    let mut worst = 0.0f64;
    let mut occluded_total = 0;
    for (e, p) in points.iter().enumerate() {
        let fr = point_frame(p.normal);
        let eye = p.pos + glam::Vec3::Y * offset;
        let (mut wrong, mut sure) = (0usize, 0usize);
        for k in 0..(r * r) as usize {
            let l = texel_dir_f32((k as u32) / r, (k as u32) % r, r);
            let d = (fr.t.as_vec3() * l.x + fr.b.as_vec3() * l.y + fr.n.as_vec3() * l.z).normalize();
            let (inner, outer) = (ray_hits_box(eye, d, lo + m, hi - m), ray_hits_box(eye, d, lo - m, hi + m));
            if inner == outer {
                sure += 1;
                let visible = (out.maps[e * words + k / 32] >> (k % 32)) & 1 == 1;
                wrong += (visible == inner) as usize;
                occluded_total += inner as usize;
            }
        }
        worst = worst.max(wrong as f64 / sure as f64);
    }
    println!("hemicube maps at r = {r}: worst share of wrong unambiguous texels {worst:.4}; {occluded_total} occluded texels");
    assert!(occluded_total > 100, "the box occludes only {occluded_total} texels");
    assert!(worst <= 0.03, "hemicube maps disagree with the ray test on {:.2} % of a map's texels", 100.0 * worst);
    drop(engine);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

/// Issue 18, cause 1 (no shadows on `falling`, `balls_on_dish` and the medium scenes): the paper
/// takes sample points among mesh vertices, and their ground planes are two triangles, so no
/// candidate lay where the shadows fall and the floor interpolated its four corners. The candidate
/// pool (`PoolPlan`) adds points on triangles larger than its spacing. A box over a one-quad
/// floor under a sky: with the pool the image's error against the SG-lit reference (with the
/// paper's SG diffuse term, so that visibility alone differs) is a fraction of the unshadowed
/// one; with the vertices only (`pool_points = 0`) it is not.
#[test]
fn coarse_receivers_get_candidates_and_shadows() {
    let s = box_over_floor("coarse_floor", "size = 4 }\ncasts_shadow = false", 0.5);
    let (w, h) = (48, 36);
    let reference = sg_lit_reference(&s, w, h, 1024);
    let err = |f: &FrameImages, name: &str| {
        let c = compare(&reference, "reference", &image(f), name).unwrap();
        c.rmse / c.reference_mean
    };
    let fast = [("r", "32"), ("iterations", "1")];
    let (r, pooled) = render(&with(&s, &fast), "avs", w, h, &[0.0], false);
    let st = avs_stats(&r);
    let (_r, bare) =
        render(&with(&s, &[("r", "32"), ("iterations", "1"), ("pool_points", "0")]), "avs", w, h, &[0.0], false);
    let (_r, open) = render(&with(&s, &[("r", "32"), ("shadows", "false")]), "avs", w, h, &[0.0], false);
    dump(&reference, "coarse_floor_reference");
    for (f, n) in
        [(&pooled[0], "coarse_floor_pool"), (&bare[0], "coarse_floor_vertices"), (&open[0], "coarse_floor_open")]
    {
        dump(&image(f), n);
    }
    let (e_pool, e_bare, e_open) = (err(&pooled[0], "pool"), err(&bare[0], "vertices"), err(&open[0], "unshadowed"));
    let (_r, cells) =
        render(&with(&s, &[("r", "32"), ("iterations", "1"), ("integration", "cells")]), "avs", w, h, &[0.0], false);
    let e_cells = err(&cells[0], "cells");
    println!(
        "pool: {} candidates ({} extra, spacing {:.3}), {} points; rmse/mean pool {e_pool:.4} (cells {e_cells:.4}), vertices only {e_bare:.4}, unshadowed {e_open:.4}",
        st.vertices, st.pool_plan.extra, st.pool_plan.spacing, st.points
    );
    // Measured (r = 32, 1 round, 1024-spp SG-lit reference): pool 0.057 (axis) / 0.029 (cells),
    // vertices only 0.084, unshadowed 0.086. What the pool leaves is the axis integration's error
    // for the sky's broad lobes (cause 2: the straight-edge Phi(d sqrt(lambda)) of a lobe wider
    // than the occluder); the cells integration removes two thirds of the shadow's error.
    assert!(st.pool_plan.extra > 1000, "the one-quad floor got {} extra candidates", st.pool_plan.extra);
    assert!(e_pool < 0.75 * e_open, "with the pool: {e_pool} vs unshadowed {e_open}");
    assert!(e_cells < 0.5 * e_open, "with the pool, cells: {e_cells} vs unshadowed {e_open}");
    assert!(e_bare > 0.95 * e_open, "vertices only should miss the box's shadow: {e_bare} vs unshadowed {e_open}");
}

/// A 0.6 box centred `box_y` over a 4 x 4 floor plane (`floor`: the rest of its mesh table and
/// object keys, from after `type = "plane", `) under the sky, seen from above; avs with the paper's
/// SG diffuse term, so that against [`sg_lit_reference`] visibility alone differs.
fn box_over_floor(name: &str, floor: &str, box_y: f32) -> Scene {
    let toml = format!(
        "name = \"{name}\"\n[camera]\neye = [0.0, 3.0, 0.8]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 45\n{SKY}\
         [materials.m]\ntype = \"diffuse\"\nalbedo = 0.7\n\
         [[object]]\nname = \"floor\"\nmesh = {{ type = \"plane\", {floor}\nmaterial = \"m\"\n\
         [[object]]\nname = \"box\"\nmesh = {{ type = \"cube\", size = 0.6 }}\nmaterial = \"m\"\nposition = [0.0, {box_y}, 0.0]\n"
    );
    let mut s = scene_text(name, &toml);
    s.technique_params.clear();
    s.technique_params.insert("diffuse".into(), "sg".into());
    s.technique_params.insert("key_lights".into(), "0".into());
    s
}

/// The reference of `s` at time 0 lit by the environment's SG fit (as the techniques' SG terms
/// are): a comparison of visibility alone.
fn sg_lit_reference(s: &Scene, w: u32, h: u32, spp: u32) -> Image {
    reference_at(s, (w, h), spp, 0.0, Mode::SgLighting).radiance
}

/// A box resting on a finely divided floor: the floor's candidates under it start their rays
/// inside the closed box, and their maps are occluded in every direction (buried,
/// `penumbra_math::avs_sampling::buried`). They are left out of the adaptation, and the shading
/// interpolates them only where they are clearly the nearest (`glsl/include/avs_gather.glsl`):
/// before, their all-black maps were interpolated into the floor around the box as a dark ring
/// (chess at 160x120: black rings around every piece's base, rmse/mean 0.269 -> 0.159). The floor
/// next to the box (within 0.15 of its sides) matches the SG-lit reference's brightness: measured
/// 0.89 of it (24 of 318 points buried), 0.98 when buried points were never interpolated (which
/// lit the floor of `extremes_whole_hemisphere_occluded_or_free`'s cave), 0.67 when they were
/// interpolated like the others.
#[test]
fn buried_sample_points_draw_no_rings() {
    let s = box_over_floor("resting_box", "size = 4, divisions = 40 }", 0.3);
    let (w, h) = (48, 36);
    let reference = sg_lit_reference(&s, w, h, 512);
    let (r, f) = render(&with(&s, &[("r", "32"), ("iterations", "1")]), "avs", w, h, &[0.0], false);
    let st = avs_stats(&r);
    let img = image(&f[0]);
    // floor pixels within 0.15 of the box's sides (the ring the buried maps darkened)
    let frame = s.at(0.0, None);
    let cam = &frame.camera;
    let inv = (cam.proj(w as f32 / h as f32) * cam.view()).inverse();
    let (mut ring_avs, mut ring_ref, mut n) = (0.0f64, 0.0f64, 0usize);
    for py in 0..h {
        for px in 0..w {
            let Some(p) = floor_point(&inv, cam.eye, w, h, px, py) else { continue };
            let (ax, az) = (p.x.abs(), p.z.abs());
            // on the floor beside the box, and not hidden behind it (the box is 0.6 high)
            if ax.max(az) <= 0.32 || ax.max(az) > 0.45 || p.z < -0.3 {
                continue;
            }
            let (a, b) = (img.get(px, py), reference.get(px, py));
            ring_avs += (a[0] + a[1] + a[2]) as f64;
            ring_ref += (b[0] + b[1] + b[2]) as f64;
            n += 1;
        }
    }
    let ratio = ring_avs / ring_ref.max(1e-9);
    println!(
        "{} buried of {} points; floor ring next to the box: {n} pixels, avs / reference {ratio:.3}",
        st.buried, st.points
    );
    assert!(st.buried > 0, "no candidate under the box was found buried");
    assert!(n >= 20, "only {n} ring pixels");
    assert!((0.85..1.15).contains(&ratio), "the floor beside the box: avs / reference {ratio:.3}");
}

/// A run's relRMSE against the reference, its stats and its GPU waits, per frame.
type Moment = (f64, Vec<AvsStats>, Vec<u64>);

/// `frames` frames of `s` at time `t` (a static moment, each finished before the next is built)
/// with `adaptation = mode` under validation (zero errors asserted), at the reference's size:
/// the last frame's relRMSE against `reference`, each frame's statistics, and the engine's count
/// of waited submissions after each frame.
fn frames_of_a_moment(s: &Scene, mode: &str, reference: &Image, t: f32, frames: usize) -> Moment {
    let s = with(s, &[("adaptation", mode)]);
    let mut r = avs_renderer(&s, reference.width, reference.height, true);
    let (mut last, mut stats, mut waited) = (None, Vec::new(), Vec::new());
    for k in 0..frames {
        let mut f = r.render(&s.at(t, (k > 0).then_some(t)), None, true).expect("render");
        f.extend(r.finish().expect("finish"));
        last = f.pop();
        stats.push(avs_stats(&r));
        waited.push(r.engine.waited_submissions());
    }
    let log = r.context().validation.clone();
    drop(r);
    assert_eq!(log.error_count(), 0, "{mode}: validation errors: {:#?}", log.errors());
    let c = compare(reference, "reference", &image(&last.expect("a frame")), mode).unwrap();
    (c.rel_rmse, stats, waited)
}

/// `frames` frames of one moment of a small hat_on_cloth (r = 32, 96 points, one round a frame,
/// `first_iterations` on the first) with `adaptation = mode` and with the waited rounds, each
/// against the 16-spp reference: (relRMSE, stats per frame, waits per frame) of both.
fn against_waited_rounds(mode: &str, first_iterations: &str, frames: usize) -> (Moment, Moment) {
    let params = [("r", "32"), ("points", "96"), ("iterations", "1"), ("first_iterations", first_iterations)];
    let s = with(&scene("hat_on_cloth.toml"), &params);
    let (w, h, t) = (64, 48, 0.5);
    let reference = reference_at(&s, (w, h), 16, t, Mode::Exact).radiance;
    let (a, b) =
        (frames_of_a_moment(&s, mode, &reference, t, frames), frames_of_a_moment(&s, "rounds", &reference, t, frames));
    let points = |st: &[AvsStats]| st.iter().map(|s| (s.points, s.dormant)).collect::<Vec<_>>();
    println!(
        "relRMSE {mode} {:.4} / rounds {:.4}; points (kept, dormant) {mode} {:?} / rounds {:?}; waited {mode} {:?} / rounds {:?}",
        a.0,
        b.0,
        points(&a.1),
        points(&b.1),
        a.2,
        b.2
    );
    (a, b)
}

/// The late adaptation (`adaptation = late`): after a setup frame, each frame steps once on the maps of the
/// newest finished frame, never waiting. Over six frames of a static moment, each finished
/// before the next is built, it takes the same steps as one waited round per frame
/// (`adaptation = rounds`, `iterations = 1`), one frame later: the kept set grows where the
/// visibility changes and the image ends as close to the reference.
#[test]
fn late_adaptation_refines_over_frames_without_waiting() {
    let ((late, st, waited), (rounds, st_r, waited_r)) = against_waited_rounds("late", "1", 6);
    let points = |st: &[AvsStats]| st.iter().map(|s| (s.points, s.dormant)).collect::<Vec<_>>();
    // setup waits (frame 0), later frames never do; the waited rounds wait every frame
    assert!(waited[0] > 0 && waited.iter().all(|&w| w == waited[0]), "late waited {waited:?}");
    assert!(waited_r[5] > waited_r[0], "rounds waited {waited_r:?}");
    for k in 1..6 {
        // frame k steps on frame k - 1's maps (each frame was finished before the next)
        if k > 1 {
            assert_eq!(st[k].late_vertices, st[k - 1].point_vertices, "frame {k}: stepped on the wrong frame");
        }
    }
    let inserted: usize = st[1..].iter().flat_map(|s| s.inserted.iter()).sum();
    assert!(inserted > 0, "the late frames inserted no point");
    assert!(st[5].points > st[0].points, "points {:?}", points(&st));
    // measured: relRMSE 0.3101 late / 0.3102 rounds, 603 / 595 points after six frames (782
    // points, 780 of them dormant, while the late step also stepped on points culled since)
    assert!(late <= rounds * 1.1 + 0.01, "late relRMSE {late} vs waited rounds {rounds}");
    assert!(st[5].points <= st_r[5].points * 5 / 4, "late {:?} vs rounds {:?}", points(&st), points(&st_r));
}

/// `adaptation = cpu`: every round of the spatial adaptation on the CPU (the SH16 of 16 x 16 maps
/// traced through an `obvhs` BVH on all cores), the final set's maps in the frame's own graph:
/// no frame waits on the GPU, not even the first (whose fresh set is refined by its rounds), the
/// set still refines (points inserted), and the image is as close to the reference as with the
/// waited rounds.
#[test]
fn cpu_adaptation_never_waits() {
    let ((cpu, st, waited), (rounds, _, waited_r)) = against_waited_rounds("cpu", "2", 3);
    assert_eq!(waited, vec![0; 3], "adaptation = cpu waited on the GPU");
    assert!(waited_r[2] > waited_r[0] && waited_r[0] > 0, "rounds waited {waited_r:?}");
    let inserted: usize = st.iter().flat_map(|s| s.inserted.iter()).sum();
    assert!(inserted > 0, "the CPU rounds inserted no point");
    assert!(cpu <= rounds * 1.1 + 0.01, "cpu relRMSE {cpu} vs waited rounds {rounds}");
}

/// The glossy term's SSDF visibility weighted by the light (`glossy_visibility` in
/// `glsl/avs/avs_shade.comp`, as isg's): the lighting lobes' and key lights' visible shares of
/// the specular lobe weighted by their light in it, not the lobe's own visible fraction (every
/// direction alike). trace_test's Cook-Torrance ball (roughness 0.35) reflects the bright sky
/// above and the occluding ground below within one lobe and came out dark (160x120: the cell
/// 0.066 -> 0.046; the ball's mean 0.937 of the reference's before). Against the exact reference
/// at 80x60 (256 spp, r = 64, 1 round): the ball's mean within 3 % (measured 0.975).
#[test]
fn glossy_visibility_is_weighted_by_the_light() {
    let s = scene("trace_test.toml");
    let (w, h) = (80, 60);
    let reference = reference_at(&s, (w, h), 256, 1.0, Mode::Exact);
    let (_r, avs) = render(&with(&s, &[("r", "64"), ("iterations", "1")]), "avs", w, h, &[1.0], false);
    let avs = image(&avs[0]);
    // the metal ball: the box around it in the 160x120 frame (x 74-102, y 42-72), halved
    let mean = |img: &Image| common::box_mean(img, 37..51, 21..36);
    let (ball_ref, ball_avs) = (mean(&reference.radiance), mean(&avs));
    println!("metal ball: avs {ball_avs:.4} against the reference's {ball_ref:.4} ({:.3})", ball_avs / ball_ref);
    assert!((ball_avs / ball_ref - 1.0).abs() < 0.03, "the metal ball: {ball_avs} against {ball_ref}");
}

/// The frame's HSDT pass is timed as the same transform of the same maps in a graph of its own
/// (`bench hsdt`'s): on lavapipe the pass, whose start no barrier follows (its maps come from an
/// earlier submission), timed at 0.01-0.09 ms for about 700 ms of work (2084 maps at r = 128),
/// its work in no pass's interval, until the executor settled each pass's start timestamp.
fn hsdt_timed_in_the_frame(frames: &[FrameImages], maps: &[Vec<u32>], r: u32) {
    use penumbra::engine::{Context, ContextDesc, Engine};
    use penumbra_passes::hsdt::Hsdt;
    let in_frame: f64 =
        frames.last().unwrap().gpu_ms.iter().filter(|(n, _)| n.starts_with("avs_hsdt")).map(|(_, ms)| ms).sum();
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let lib = penumbra::shader_library();
    let h = Hsdt::new(&ctx, &lib).unwrap();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    engine.timestamps = true;
    let words: Vec<u32> = maps.iter().flatten().copied().collect();
    let mut alone = f64::MAX;
    for _ in 0..3 {
        let o = h.transform_alone(&mut engine, &words, maps.len() as u32, r).unwrap();
        alone = alone.min(o.gpu_ms.iter().filter(|(n, _)| n.starts_with("hsdt")).map(|(_, ms)| ms).sum());
    }
    println!("HSDT of {} maps at r = {r}: {in_frame:.2} ms in the frame, {alone:.2} ms alone", maps.len());
    assert!(in_frame >= 0.3 * alone, "the frame's HSDT timed {in_frame:.3} ms, the same maps alone {alone:.3} ms");
}
