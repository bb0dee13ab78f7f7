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
    let s = with(&scene("vv_coarse.toml"), &[("sat_width", "64"), ("resolution", "24"), ("arcs", "12")]);
    let (w, h) = (24, 18);
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
    for mode in ["fragment3", "fragment1", "tessellation"] {
        let sm = with(&s, &[("mode", mode), ("zeta", "1"), ("max_level", "2")]);
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

/// The GPU SAT (fp32, Kahan-compensated prefix sums) against the CPU SAT (f64) of the same map:
/// the scene's map and a 1024 x 512 map with a sun 1e4 times the sky.
#[test]
fn gpu_sat_matches_cpu_sat() {
    use penumbra_engine::{Context, ContextDesc, Engine, Graph};
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let base = with(&scene("vv_coarse.toml"), &[("resolution", "16"), ("mode", "fragment3")]);
    let mut big = with(&base, &[("sat_width", "1024")]);
    {
        let e = big.environment.as_mut().unwrap();
        let (w, h) = (1024usize, 512usize);
        e.width = w as u32;
        e.height = h as u32;
        e.texels = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let sky = 0.2 + 0.8 * (1.0 - y as f32 / h as f32) + 0.1 * ((x as f32) * 0.05).sin();
                let d2 = (x as f32 - 300.0).powi(2) + (y as f32 - 120.0).powi(2);
                if d2 < 9.0 { [1.0e4, 0.9e4, 0.8e4] } else { [sky, sky * 0.9, sky * 1.1] }
            })
            .collect();
    }
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let shaders = penumbra::shader_library();
    for (name, s) in [("scene map 256x128", with(&base, &[("sat_width", "256")])), ("1024x512 with a 1e4 sun", big)] {
        let settings = penumbra_passes::vv::VvSettings::from_params(&s.technique_params).unwrap();
        let tech = penumbra_passes::vv::VvTechnique::new(&ctx, &shaders, &s, settings).expect("technique");
        let (w, h, texels) = tech.sat_input();
        let mut engine = Engine::new(ctx.clone(), 1).unwrap();
        let mut g = Graph::new();
        let sat = tech.add_sat(&mut g, "vv_sat", &texels);
        penumbra_passes::readback::add(&mut g, "sat_readback", &[(sat, "sat")]);
        engine.submit(g).unwrap();
        let outs = engine.drain().unwrap();
        let bytes = outs.last().unwrap().readbacks.get("sat").expect("readback").clone();
        let gpu: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        let tex3: Vec<[f32; 3]> = texels.chunks_exact(16).map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
            [f(0), f(4), f(8)]
        }).collect();
        let cpu = penumbra_math::vv_sat::Sat::new(w as usize, h as usize, &tex3).unwrap();
        let (cw, ch) = (w as usize + 1, h as usize + 1);
        let (mut max_err, mut scale) = (0.0f64, 0.0f64);
        for k in 0..3 {
            for y in 0..ch {
                for x in 0..cw {
                    let c = cpu.corners[y * cw + x].0[k];
                    let i = ((k * ch + y) * cw + x) * 4;
                    for ch3 in 0..3 {
                        max_err = max_err.max((gpu[i + ch3] as f64 - c[ch3]).abs());
                        scale = scale.max(c[ch3].abs());
                    }
                }
            }
        }
        let rel = max_err / scale;
        println!("{name}: GPU vs CPU SAT max abs error {max_err:.3e}, relative to the largest corner {rel:.3e}");
        assert!(rel < 2e-6, "{name}: GPU SAT error {rel:.3e} of the largest value");
        drop(tech);
        drop(engine);
    }
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:#?}", ctx.validation.errors());
}
