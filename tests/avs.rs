//! The adaptive-visibility-sampling technique (`avs`) on the Vulkan device (lavapipe):
//! validation on the three paper scenes, accuracy against the CPU reference, sample points that
//! follow deforming vertices, parameters, extremes.

use penumbra::{FrameImages, RenderSettings, Renderer};
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{render as reference_render, Mode, ReferenceOptions};
use penumbra_scene::Scene;
use std::path::PathBuf;
use std::sync::Mutex;

// The technique's last-frame statistics are process-global: tests reading them run one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn scene(name: &str) -> Scene {
    Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)).expect("scene")
}

fn with(s: &Scene, params: &[(&str, &str)]) -> Scene {
    let mut s = s.clone();
    for (k, v) in params {
        s.technique_params.insert(k.to_string(), v.to_string());
    }
    s
}

fn render(scene: &Scene, technique: &str, w: u32, h: u32, times: &[f32], validation: bool) -> (Renderer, Vec<FrameImages>) {
    let settings = RenderSettings { width: w, height: h, technique: Some(technique.into()), ..Default::default() };
    let mut r = Renderer::new_headless(scene, settings, validation).expect("renderer");
    let mut out = Vec::new();
    let mut prev = None;
    for &t in times {
        let f = scene.at(t, prev);
        prev = Some(t);
        out.extend(r.render(&f, None, true).expect("render"));
    }
    out.extend(r.finish().expect("finish"));
    (r, out)
}

fn image(f: &FrameImages) -> Image {
    Image::from_fn(f.width, f.height, |x, y| {
        let p = f.hdr[(y * f.width + x) as usize];
        [p[0], p[1], p[2]]
    })
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
    penumbra_reference::image::write_png_rgb8(&PathBuf::from(dir).join(format!("{name}.png")), img.width, img.height, &rgb).unwrap();
}

fn psnr(c: &penumbra_reference::metrics::Comparison) -> f64 {
    c.psnr_db.unwrap_or(f64::INFINITY)
}

/// Small maps and few points keep the tests short.
const FAST: &[(&str, &str)] = &[("r", "32"), ("points", "96"), ("iterations", "1")];

#[test]
fn paper_scenes_are_validation_clean_and_points_follow_vertices() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    for name in ["hat_on_cloth.toml", "balls_on_dish.toml", "falling.toml"] {
        let s = with(&scene(name), FAST);
        let settings = RenderSettings { width: 64, height: 48, technique: Some("avs".into()), ..Default::default() };
        let mut r = Renderer::new_headless(&s, settings, true).expect("renderer");
        let mut frames = Vec::new();
        let mut stats = Vec::new();
        let mut prev = None;
        for t in [0.0f32, 0.5] {
            let f = s.at(t, prev);
            prev = Some(t);
            frames.extend(r.render(&f, None, true).expect("render"));
            stats.push((penumbra_passes::avs::last_stats(), f));
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
            let pool = penumbra_passes::avs::vertex_pool(&s, f).unwrap();
            assert_eq!(pool.len(), st.vertices);
            assert!(st.point_vertices.iter().all(|&v| v < pool.len()));
        }
        drop(r);
        assert_eq!(log.error_count(), 0, "{name}: validation errors: {:#?}", log.errors());
    }
}

#[test]
fn accuracy_against_the_reference() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let s = scene("hat_on_cloth.toml");
    let (w, h) = (80, 60);
    let t = 0.5;
    let opts = ReferenceOptions { width: w, height: h, spp: 32, time: Some(t), mode: Mode::Exact, ..Default::default() };
    let sg_ref = reference_render(&s, &opts).expect("reference");
    let fast = with(&s, &[("r", "64"), ("points", "240"), ("iterations", "1")]);
    let (_r, avs) = render(&fast, "avs", w, h, &[t], false);
    if std::env::var("AVS_DUMP").is_ok() {
        let st = penumbra_passes::avs::last_stats();
        let pool = penumbra_passes::avs::vertex_pool(&fast, &fast.at(t, None)).unwrap();
        for (i, &v) in st.point_vertices.iter().enumerate() {
            println!("point {i}: {:?} n {:?} visible {:.3}", pool[v].pos, pool[v].normal, st.visible_fraction[i]);
        }
    }
    let (_r, cells) = render(&with(&fast, &[("integration", "cells")]), "avs", w, h, &[t], false);
    let (_r, open) = render(&with(&fast, &[("shadows", "false")]), "avs", w, h, &[t], false);
    dump(&sg_ref.radiance, "reference");
    for (f, n) in [(&avs[0], "axis"), (&cells[0], "cells"), (&open[0], "open")] {
        dump(&image(f), n);
    }
    let cmp = |f: &FrameImages, name: &str| compare(&sg_ref.radiance, "reference", &image(f), name).unwrap();
    let (a, c, o) = (cmp(&avs[0], "avs axis"), cmp(&cells[0], "avs cells"), cmp(&open[0], "avs unshadowed"));
    for (what, x) in [("axis", &a), ("cells", &c), ("no shadows", &o)] {
        println!("exact ref / avs {what}: PSNR {:.2} dB, relRMSE {:.4}, FLIP {:.4}", psnr(x), x.rel_rmse, x.flip_mean);
    }
    // Shadows from the sampled visibility must bring the image much closer to the reference
    // than no shadows, in both integration modes. Measured (80x60, t = 0.5, r = 64, 240 initial
    // points, 1 round, 32-spp exact reference): relRMSE 0.556 (axis) / 0.560 (cells) against
    // 2.46 unshadowed; PSNR 20.8 / 20.75 against 20.9 (PSNR is dominated by the brim and crown,
    // too dark: their vertices lie only at the brim's edges, see the note of issue 8).
    assert!(a.rel_rmse < 0.7, "axis relRMSE {}", a.rel_rmse);
    assert!(c.rel_rmse < 0.7, "cells relRMSE {}", c.rel_rmse);
    assert!(a.rel_rmse < 0.35 * o.rel_rmse, "axis {} vs unshadowed {}", a.rel_rmse, o.rel_rmse);
    assert!(c.rel_rmse < 0.35 * o.rel_rmse, "cells {} vs unshadowed {}", c.rel_rmse, o.rel_rmse);
    assert!(psnr(&a) > 19.0 && psnr(&c) > 19.0, "PSNR {} / {}", psnr(&a), psnr(&c));
}

#[test]
fn parameters_are_checked() {
    use penumbra_passes::avs::AvsSettings;
    let p = |kv: &[(&str, &str)]| {
        AvsSettings::from_params(&kv.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect())
    };
    let d = p(&[]).unwrap();
    assert_eq!((d.r, d.initial_grid, d.e_max, d.e_min, d.iterations), (128, 16, 0.10, 0.05, 2));
    assert_eq!(d.levels(), 4);
    assert_eq!(p(&[("r", "256"), ("initial_grid", "32")]).unwrap().levels(), 4);
    for (k, v) in [("r", "100"), ("r", "8"), ("r", "512"), ("initial_grid", "20"), ("e_max", "nan"), ("integration", "exact"), ("bogus", "1"), ("e_min", "0.5")] {
        let e = p(&[(k, v)]).unwrap_err().to_string();
        assert!(e.contains(k), "{k} = {v}: {e}");
    }
    let e = p(&[("r", "48")]).unwrap_err().to_string();
    assert!(e.contains("power of two"), "{e}");
}

#[test]
fn extremes_free_hemispheres_and_points_following_deformation() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    // Nothing casts a shadow: every map is fully visible (SSDF +pi everywhere), so the image equals
    // the unshadowed one.
    let mut s = with(&scene("hat_on_cloth.toml"), &[("r", "32"), ("points", "48"), ("iterations", "0")]);
    for info in s.object_info.iter_mut() {
        info.casts_shadow = false;
    }
    let (_r, free) = render(&s, "avs", 40, 30, &[0.5], false);
    let st = penumbra_passes::avs::last_stats();
    assert!(st.visible_fraction.iter().all(|v| (v - 1.0).abs() < 2e-3), "not all maps free: {:?}", st.visible_fraction);
    let (_r, open) = render(&with(&s, &[("shadows", "false")]), "avs", 40, 30, &[0.5], false);
    for (a, b) in free[0].hdr.iter().zip(&open[0].hdr) {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 1e-3 * b[c].abs() + 1e-5, "free {a:?} vs unshadowed {b:?}");
        }
    }
    // Deforming geometry: without adaptation rounds the sample points are the same vertices in
    // both frames, at their deformed positions (the hat squashes).
    let s = with(&scene("hat_on_cloth.toml"), &[("r", "32"), ("points", "48"), ("iterations", "0")]);
    let settings = RenderSettings { width: 40, height: 30, technique: Some("avs".into()), ..Default::default() };
    let mut r = Renderer::new_headless(&s, settings, false).expect("renderer");
    let f0 = s.at(0.0, None);
    r.render(&f0, None, true).expect("render");
    let a = penumbra_passes::avs::last_stats();
    let f1 = s.at(0.5, Some(0.0));
    r.render(&f1, None, true).expect("render");
    let b = penumbra_passes::avs::last_stats();
    r.finish().expect("finish");
    assert_eq!(a.point_vertices, b.point_vertices);
    let (p0, p1) = (penumbra_passes::avs::vertex_pool(&s, &f0).unwrap(), penumbra_passes::avs::vertex_pool(&s, &f1).unwrap());
    let moved = a.point_vertices.iter().filter(|&&v| (p0[v].pos - p1[v].pos).length() > 1e-3).count();
    assert!(moved > 0, "no sample point moved with the deforming hat");
    // Some maps are partly occluded (the hat over the cloth), some fully free.
    assert!(b.visible_fraction.iter().any(|&v| v < 0.5) && b.visible_fraction.iter().any(|&v| v > 0.95), "{:?}", b.visible_fraction);
}
