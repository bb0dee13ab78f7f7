//! The `vv` technique (vectorized visibility, issue 9 part B) on the Vulkan device (lavapipe):
//! every shading mode renders the coarse scene validation-clean, its accuracy against the CPU
//! reference, the tessellation stages run (graph and triangle counts), and the GPU SAT matches
//! the CPU SAT.

use penumbra::{FrameImages, RenderSettings, Renderer};
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{render as reference_render, Mode, ReferenceOptions};
use penumbra_scene::Scene;
use std::path::PathBuf;

mod common;
use common::reference_at;
use common::{hdr_image as image, scene, with, with_env};

fn render(scene: &Scene, w: u32, h: u32, validation: bool) -> (Renderer, Vec<FrameImages>) {
    let settings = RenderSettings::with_technique(w, h, "vv", &scene.technique_params);
    let mut r = Renderer::new_headless(scene, settings, validation).expect("renderer");
    let mut out = Vec::new();
    for _ in 0..1 {
        out.extend(r.render(&scene.at(0.0, Some(0.0)), None, true).expect("render"));
    }
    out.extend(r.finish().expect("finish"));
    (r, out)
}

/// One frame of `scene` with the unshadowed `env` technique (the scene's parameters belong to
/// its own technique, `vv`, so `env` gets none).
fn render_env(scene: &Scene, w: u32, h: u32) -> FrameImages {
    let settings = RenderSettings { width: w, height: h, technique: Some("env".into()), ..Default::default() };
    let mut r = Renderer::new_headless(scene, settings, false).unwrap();
    let mut env = r.render(&scene.at(0.0, Some(0.0)), None, true).unwrap();
    env.extend(r.finish().unwrap());
    env.remove(0)
}

#[test]
fn modes_render_validation_clean_and_match_the_reference() {
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let s = with(&scene("vv_coarse.toml"), &[("sat_width", "64"), ("resolution", "24"), ("arcs", "12")]);
    let (w, h) = (24, 18);
    let reference = reference_render(
        &s,
        &ReferenceOptions { width: w, height: h, spp: 64, time: Some(0.0), mode: Mode::Exact, ..Default::default() },
    )
    .expect("reference");
    let env = render_env(&s, w, h);
    let env_psnr = compare(&reference.radiance, "reference", &image(&env), "env").unwrap().psnr_db.unwrap_or(99.0);
    println!("env (no shadows): PSNR {env_psnr:.2}");
    let input_triangles = penumbra_passes::vv::scene_model(&s, penumbra_passes::vv::VvSettings::default().refine)
        .unwrap()
        .model
        .triangle_count() as u64;
    for mode in ["fragment3", "fragment1", "tessellation"] {
        // zeta 4: the displayed radiance of some vertices near the studio lights' shadow edges
        // changes by >= 1/8 under the Phong-256 blur, so their triangles get level 2 or 4
        let sm = with(&s, &[("mode", mode), ("zeta", "4"), ("max_level", "4")]);
        let tess = mode.starts_with("tess");
        let (r, frames) = render(&sm, w, h, true);
        let log = r.context().validation.clone();
        let last = frames.last().expect("frames");
        assert!(
            last.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
            "{mode}: non-finite or negative radiance"
        );
        let pass = if mode.starts_with("tess") { "vv_tess" } else { "vv_shade" };
        assert!(last.gpu_ms.iter().any(|(p, _)| p == pass), "{mode}: no {pass} pass: {:?}", last.gpu_ms);
        assert!(last.gpu_ms.iter().any(|(p, _)| p == "vv_sat_cols"), "{mode}: no SAT build pass");
        let c = compare(&reference.radiance, "reference", &image(last), mode).unwrap();
        if let Some(dir) = std::env::var_os("VV_DUMP") {
            let dir = PathBuf::from(dir);
            image(last).write_exr(dir.join(format!("{mode}.exr"))).unwrap();
            reference.radiance.write_exr(dir.join("reference.exr")).unwrap();
            image(&env).write_exr(dir.join("env.exr")).unwrap();
        }
        let psnr = c.psnr_db.unwrap_or(99.0);
        println!("{mode}: PSNR {psnr:.2} relRMSE {:.4} FLIP {:.4} gpu {:?}", c.rel_rmse, c.flip_mean, last.gpu_ms);
        // the last finished frame's pipeline statistics (the renderer has finished its frames)
        let tessellated =
            r.technique_stats::<penumbra_passes::vv::VvStats>().expect("vv keeps statistics").tessellated_triangles;
        drop(r);
        if tess {
            let n = tessellated.expect("tessellated triangle count");
            println!("{mode}: {n} triangles after tessellation ({input_triangles} input)");
            assert!(
                n > input_triangles,
                "{mode}: {n} triangles after tessellation, not more than the {input_triangles} input triangles"
            );
        }
        assert_eq!(log.error_count(), 0, "{mode}: validation errors: {:#?}", log.errors());
        assert!(psnr > env_psnr + 1.0, "{mode}: PSNR {psnr:.2} not better than unshadowed env {env_psnr:.2}");
    }
}

/// Map-space direction of lat-long angles (`penumbra_math::envmap::latlong_direction`).
fn dir(phi: f64, theta: f64) -> glam::DVec3 {
    glam::DVec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos())
}

/// Parity cases: `(name, n, occluder loops)`, loops positive (occluded interior on the left seen
/// from the centre, `penumbra_math::vv_sat` convention), inside the closed hemisphere of n.
/// Largest GLSL-vs-CPU difference of the diffuse integral, relative to the unoccluded value
/// (fp32 SAT corners, angles and interpolation against f64).
const PARITY_TOL: f64 = 1e-3;

fn parity_cases(sun: glam::DVec3) -> Vec<(&'static str, glam::DVec3, Vec<Vec<glam::DVec3>>)> {
    use glam::DVec3;
    use penumbra_math::vv_sat::cap_loop;
    let cap = |c: DVec3, r: f64, m: usize| cap_loop(c.normalize(), r.cos(), m);
    let clamp = |l: Vec<DVec3>, n: DVec3| -> Vec<DVec3> {
        l.into_iter().map(|d| if d.dot(n) < 0.0 { (d - n * d.dot(n)).normalize() } else { d }).collect()
    };
    // the sun's neighbourhood: an offset along its meridian
    let sun_t = sun.y.acos();
    let sun_p = sun.x.atan2(-sun.z);
    let nx = DVec3::new(1.0, 0.0, 0.0);
    let n_side = DVec3::new(1.0, 0.05, 0.0).normalize();
    vec![
        ("unoccluded, n up", DVec3::Y, vec![]),
        ("unoccluded, horizon through both poles", nx, vec![]),
        ("seam crossing", dir(0.05, 1.2), vec![cap(dir(0.0, 1.0), 0.35, 9)]),
        ("seam crossing, two loops", dir(6.2, 1.4), vec![cap(dir(0.1, 1.5), 0.3, 7), cap(dir(6.0, 1.1), 0.25, 6)]),
        ("around the north pole", DVec3::new(0.2, 1.0, 0.1).normalize(), vec![cap(dir(1.0, 0.1), 0.4, 10)]),
        (
            "arc exactly through the north pole",
            DVec3::Y,
            vec![vec![dir(0.0, 0.3), dir(std::f64::consts::FRAC_PI_2, 0.6), dir(std::f64::consts::PI, 0.3)]],
        ),
        (
            "over the pole, horizon near both poles",
            n_side,
            vec![clamp(cap(dir(std::f64::consts::FRAC_PI_2, 0.25), 0.4, 10), n_side)],
        ),
        (
            "around the south pole",
            DVec3::new(0.1, -1.0, 0.2).normalize(),
            vec![cap(dir(2.0, std::f64::consts::PI - 0.1), 0.4, 10)],
        ),
        (
            "crossing the tangent plane (clamped)",
            dir(2.5, 1.0),
            vec![clamp(cap(dir(2.5, 2.3), 0.5, 12), dir(2.5, 1.0))],
        ),
        ("sun hidden", sun, vec![cap(sun, 0.1, 8)]),
        ("sun half covered", sun, vec![cap(dir(sun_p, sun_t + 0.1), 0.1, 12)]),
        ("sun visible, occluder next to it", sun, vec![cap(dir(sun_p + 0.3, sun_t), 0.1, 8)]),
    ]
}

/// The GPU SAT (fp32, Kahan-compensated prefix sums) against the CPU SAT (f64) of the same map,
/// and the GLSL integral (`vv_sat.glsl` through `glsl/tests/vv_parity.comp`: hemisphere minus occluder
/// loops, eq. 9-12) against `penumbra_math::vv_sat` on seam, pole, tangent-plane and sun cases:
/// the scene's map and a 1024 x 512 map with a sun 1e4 times the sky.
#[test]
fn gpu_sat_and_glsl_integral_match_cpu() {
    use penumbra_engine::{Context, ContextDesc, Engine, Graph};
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let base = with(&scene("vv_coarse.toml"), &[("resolution", "16"), ("mode", "fragment3")]);
    let big = with_env(&with(&base, &[("sat_width", "1024")]), 1024, 512, |x, y| {
        let sky = 0.2 + 0.8 * (1.0 - y as f32 / 512.0) + 0.1 * ((x as f32) * 0.05).sin();
        let d2 = (x as f32 - 300.0).powi(2) + (y as f32 - 120.0).powi(2);
        if d2 < 9.0 {
            [1.0e4, 0.9e4, 0.8e4]
        } else {
            [sky, sky * 0.9, sky * 1.1]
        }
    });
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let shaders = penumbra::shader_library();
    let t0 = std::time::Instant::now();
    let parity = penumbra_passes::kernels::vv::VvParity::new(&ctx, &shaders).expect("parity pipeline");
    println!("parity pipeline created in {:.2} s", t0.elapsed().as_secs_f64());
    let sun = dir(2.0 * std::f64::consts::PI * 300.5 / 1024.0, std::f64::consts::PI * 120.5 / 512.0);
    let cases = parity_cases(sun);
    let mut failures = Vec::new();
    for (name, s) in [("scene map 256x128", with(&base, &[("sat_width", "256")])), ("1024x512 with a 1e4 sun", big)] {
        let settings = penumbra_passes::vv::VvSettings::from_params(&s.technique_params).unwrap();
        let t0 = std::time::Instant::now();
        let tech = penumbra_passes::vv::VvTechnique::sat_only(&ctx, &shaders, &s, settings).expect("technique");
        println!("{name}: technique without its raster pipeline in {:.2} s", t0.elapsed().as_secs_f64());
        let t0 = std::time::Instant::now();
        let (w, h, texels) = tech.sat_input();
        let mut engine = Engine::new(ctx.clone(), 1).unwrap();
        let mut g = Graph::new();
        let sat = tech.add_sat(&mut g, "vv_sat", &texels);
        let gpu_cases: Vec<(glam::Vec3, Vec<Vec<glam::Vec3>>)> = cases
            .iter()
            .map(|(_, n, loops)| {
                (n.as_vec3(), loops.iter().map(|l| l.iter().rev().map(|d| d.as_vec3()).collect()).collect())
            })
            .collect();
        let integrals = parity.add(&tech, &mut g, sat, &gpu_cases);
        penumbra_passes::readback::add(&mut g, "sat_readback", &[(sat, "sat"), (integrals, "integrals")]);
        engine.submit(g).unwrap();
        let outs = engine.drain().unwrap();
        println!("{name}: GPU SAT + parity graph in {:.2} s", t0.elapsed().as_secs_f64());
        let bytes = outs.last().unwrap().readbacks.get("sat").expect("readback").clone();
        let gpu: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        let cpu = cpu_sat(w, h, &texels);
        let (mut max_err, mut scale) = (0.0f64, 0.0f64);
        for k in 0..3 {
            let (e, s) = sat_error(&cpu, &gpu, k);
            (max_err, scale) = (max_err.max(e), scale.max(s));
        }
        let rel = max_err / scale;
        println!("{name}: GPU vs CPU SAT max abs error {max_err:.3e}, relative to the largest corner {rel:.3e}");
        assert!(rel < 2e-6, "{name}: GPU SAT error {rel:.3e} of the largest value");
        // the GLSL integral against the CPU one (same arcs, alpha', nudge, pole rule)
        let ib = outs.last().unwrap().readbacks.get("integrals").expect("readback").clone();
        let gi: Vec<f32> = ib.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        let settings = tech.settings().clone();
        let o = penumbra_math::vv_sat::IntegrateOptions {
            alpha: settings.alpha as f64,
            circle_step: 2.0 * std::f64::consts::PI / settings.hemisphere_arcs as f64 * (1.0 + 1e-9),
            clip: false,
        };
        let lum = |c: glam::DVec3| 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
        let mut worst = 0.0f64;
        for (i, (case, n, loops)) in cases.iter().enumerate() {
            let nn = penumbra_math::vv_sat::nudge_axis(*n, 0.0);
            let c = penumbra_math::vv_sat::visible_moments(&cpu, *n, loops, &o).moments.dot(nn);
            let open = penumbra_math::vv_sat::visible_moments(&cpu, *n, &[], &o).moments.dot(nn);
            let g = glam::DVec3::new(gi[4 * i] as f64, gi[4 * i + 1] as f64, gi[4 * i + 2] as f64);
            let err = (lum(g) - lum(c)).abs() / lum(open);
            worst = worst.max(err);
            println!(
                "{name}: {case:<40} CPU {:.6e} GPU {:.6e} unoccluded {:.6e} error {err:.2e} of unoccluded",
                lum(c),
                lum(g),
                lum(open)
            );
            if !loops.is_empty() && lum(c) > lum(open) * (1.0 + 1e-9) {
                failures.push(format!(
                    "{name}: {case}: the occluder adds light on the CPU ({} > {})",
                    lum(c),
                    lum(open)
                ));
            }
            if !(g.is_finite() && err < PARITY_TOL) {
                failures.push(format!(
                    "{name}: {case}: GLSL {} vs CPU {} ({err:.2e} of the unoccluded {})",
                    lum(g),
                    lum(c),
                    lum(open)
                ));
            }
        }
        println!("{name}: worst GLSL-vs-CPU integral error {worst:.2e} of the unoccluded value");
        drop(tech);
        drop(engine);
    }
    assert!(failures.is_empty(), "GLSL integral differs from the CPU:\n{}", failures.join("\n"));
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:#?}", ctx.validation.errors());
}

/// Specular parity cases: `(name, n, r, occluder loops)` with the loops positive (occluded
/// interior on the left seen from the centre, `penumbra_math::vv_sat` convention), inside the
/// closed hemisphere of n; the cap W has the cosine `cos_xi` around r.
fn cap_cases(cos_xi: f64) -> Vec<(&'static str, glam::DVec3, glam::DVec3, Vec<Vec<glam::DVec3>>)> {
    use glam::DVec3;
    use penumbra_math::vv_sat::{basis, cap_loop, winding_about};
    let xi = cos_xi.acos();
    let cap = |c: DVec3, r: f64, m: usize| cap_loop(c.normalize(), r.cos(), m);
    let clamp = |l: Vec<DVec3>, n: DVec3| -> Vec<DVec3> {
        l.into_iter().map(|d| if d.dot(n) < 0.0 { (d - n * d.dot(n)).normalize() } else { d }).collect()
    };
    let positive = |l: Vec<DVec3>| -> Vec<DVec3> {
        let c = l.iter().copied().sum::<DVec3>().normalize();
        if winding_about(&l, c) > 0 {
            l
        } else {
            l.into_iter().rev().collect()
        }
    };
    // a triangle whose first edge crosses the cap with both ends outside it (an arc dipping in)
    let dip = |r: DVec3| -> Vec<DVec3> {
        let (u, v) = basis(r);
        let w = (r * 0.3f64.cos() + u * 0.3f64.sin()).normalize();
        let p1 = (w * 0.8f64.cos() + v * 0.8f64.sin()).normalize();
        let p2 = (w * 0.8f64.cos() - v * 0.8f64.sin()).normalize();
        let p3 = (r * 1.2f64.cos() + u * 1.2f64.sin()).normalize();
        positive(vec![p1, p2, p3])
    };
    let r_free = dir(1.0, 0.6);
    let r_in = dir(0.5, 0.4);
    let r_seam = dir(0.05, 1.0);
    let r_pole = dir(1.0, 0.2);
    let r_low = dir(2.0, 1.3);
    let r_dip = dir(3.0, 0.8);
    let (ru, _) = basis(r_free);
    vec![
        ("free cap (gamma 1)", DVec3::Y, r_free, vec![]),
        ("free cap, occluder beside it", DVec3::Y, r_free, vec![cap((r_free + ru * 1.2).normalize(), 0.2, 8)]),
        ("cap inside an occluder (gamma 0)", DVec3::Y, r_in, vec![cap(r_in, xi + 0.15, 14)]),
        ("occluder inside the cap", DVec3::Y, r_in, vec![cap(dir(0.6, 0.35), 0.15, 8)]),
        ("occluder across the cap edge", DVec3::Y, r_free, vec![cap((r_free + ru * 0.5).normalize(), 0.3, 10)]),
        (
            "two occluders, inside and across",
            DVec3::Y,
            r_free,
            vec![cap((r_free - ru * 0.1).normalize(), 0.1, 7), cap((r_free + ru * 0.55).normalize(), 0.25, 9)],
        ),
        ("cap across the seam", dir(0.0, 1.1), r_seam, vec![cap(dir(6.1, 1.1), 0.3, 9)]),
        ("cap over the north pole", DVec3::Y, r_pole, vec![cap(dir(2.0, 0.15), 0.25, 10)]),
        ("cap across the horizon", DVec3::Y, r_low, vec![clamp(cap(dir(2.2, 1.4), 0.3, 10), DVec3::Y)]),
        ("arc dipping into the cap", r_dip, r_dip, vec![dip(r_dip)]),
    ]
}

/// The specular visibility ratio gamma of eq. 15-16 in GLSL (`vv_cap_parity.comp`: streaming
/// clip of the loops to the cap W, circle walks, the enclosed-cap test, W clipped to the
/// hemisphere, the 4th SAT channel) against `penumbra_math::vv_sat::cap_ratio` on the CPU: free
/// cap (gamma 1), cap enclosed by an occluder (gamma 0), occluders inside and across the cap,
/// caps across the phi seam, over the pole and across the horizon, an arc dipping into the cap.
/// Also the GPU SAT's 4th channel (∫ L_e dω) against the CPU SAT.
#[test]
fn gpu_cap_ratio_matches_cpu() {
    use penumbra_engine::{Context, ContextDesc, Engine, Graph};
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let base = with(&scene("vv_coarse.toml"), &[("resolution", "16"), ("mode", "fragment3"), ("sat_width", "256")]);
    // a smooth sky (no compact sources: gamma follows the covered part of the cap)
    let smooth = with_env(&base, 256, 128, |x, y| {
        let v = 0.3 + 0.7 * (1.0 - y as f32 / 128.0) + 0.2 * ((x as f32) * 0.07).sin();
        [v, v * 0.9, v * 1.1]
    });
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let shaders = penumbra::shader_library();
    let parity = penumbra_passes::kernels::vv::VvCapParity::new(&ctx, &shaders).expect("cap parity pipeline");
    // Phong alpha 16 (Blinn-Phong shininess 64): W of radius 33 degrees
    let cos_xi = penumbra_math::vv_sat::phong_cap_cos(16.0);
    let cases = cap_cases(cos_xi);
    let gpu_cases: Vec<penumbra_passes::kernels::vv::CapCase> = cases
        .iter()
        .map(|(_, n, r, loops)| {
            (
                n.as_vec3(),
                r.as_vec3(),
                cos_xi as f32,
                loops.iter().map(|l| l.iter().rev().map(|d| d.as_vec3()).collect()).collect(),
            )
        })
        .collect();
    let mut failures = Vec::new();
    for (map, s) in [("smooth sky 256x128", smooth), ("studio map 256x128", base)] {
        let settings = penumbra_passes::vv::VvSettings::from_params(&s.technique_params).unwrap();
        let tech = penumbra_passes::vv::VvTechnique::sat_only(&ctx, &shaders, &s, settings).expect("technique");
        let (w, h, texels) = tech.sat_input();
        let mut engine = Engine::new(ctx.clone(), 1).unwrap();
        let mut g = Graph::new();
        let sat = tech.add_sat(&mut g, "vv_sat", &texels);
        let out = parity.add(&tech, &mut g, sat, &gpu_cases);
        penumbra_passes::readback::add(&mut g, "cap_readback", &[(sat, "sat"), (out, "gamma")]);
        engine.submit(g).unwrap();
        let outs = engine.drain().unwrap();
        let rb = &outs.last().unwrap().readbacks;
        let f32s = |b: &Vec<u8>| -> Vec<f32> {
            b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
        };
        let gpu_sat = f32s(rb.get("sat").expect("sat readback"));
        let cpu = cpu_sat(w, h, &texels);
        let (max_err, scale) = sat_error(&cpu, &gpu_sat, 3);
        println!(
            "{map}: GPU vs CPU SAT channel 4 (∫ L_e dω): max abs error {max_err:.3e}, {:.3e} of the largest corner",
            max_err / scale
        );
        assert!(max_err / scale < 2e-6, "{map}: GPU SAT channel 4 error {:.3e} of the largest value", max_err / scale);
        let gi = f32s(rb.get("gamma").expect("gamma readback"));
        let nc = cases.len();
        let o = penumbra_math::vv_sat::IntegrateOptions {
            alpha: tech.settings().alpha as f64,
            circle_step: 2.0 * std::f64::consts::PI / tech.settings().hemisphere_arcs as f64 * (1.0 + 1e-9),
            clip: true,
        };
        let lum = |c: glam::DVec3| 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
        // fp32 floor of a SAT integral: the corners carry ~1e-7 relative error of the largest
        // corner, and an integral takes 4 lookups per arc piece, tens of pieces
        let floor = CAP_FP32_FLOOR * lum(cpu.total().radiance());
        let mut worst = 0.0f64;
        for (i, (name, n, r, loops)) in cases.iter().enumerate() {
            let cpu_g = penumbra_math::vv_sat::cap_ratio(&cpu, *n, *r, cos_xi, loops, &o);
            let px = |row: usize| {
                glam::DVec3::new(
                    gi[4 * (row * nc + i)] as f64,
                    gi[4 * (row * nc + i) + 1] as f64,
                    gi[4 * (row * nc + i) + 2] as f64,
                )
            };
            let (gpu_g, num, den) = (px(0), px(1), px(2));
            let err = (gpu_g - cpu_g).abs().max_element();
            worst = worst.max(err);
            println!(
                "{map}: {name:<36} gamma CPU {:.5} GPU {:.5} (num {:.4e} den {:.4e}) error {err:.2e}",
                lum(cpu_g),
                lum(gpu_g),
                lum(num),
                lum(den)
            );
            // gamma error times the denominator = the numerator's error
            if !(gpu_g.is_finite() && err * lum(den) < CAP_PARITY_TOL * lum(den) + floor) {
                failures.push(format!(
                    "{map}: {name}: GLSL gamma {gpu_g:?} vs CPU {cpu_g:?} (den {:.3e}, fp32 floor {floor:.3e})",
                    lum(den)
                ));
            }
        }
        println!("{map}: worst GLSL-vs-CPU gamma error {worst:.2e}");
        // the limits themselves (CPU and GPU agree within the tolerance above)
        let g_of = |name: &str| {
            let i = cases.iter().position(|c| c.0 == name).unwrap();
            glam::DVec3::new(gi[4 * i] as f64, gi[4 * i + 1] as f64, gi[4 * i + 2] as f64)
        };
        for name in ["free cap (gamma 1)", "free cap, occluder beside it"] {
            assert!(
                (g_of(name) - glam::DVec3::ONE).abs().max_element() < 1e-3,
                "{map}: {name}: gamma {:?}",
                g_of(name)
            );
        }
        assert!(
            g_of("cap inside an occluder (gamma 0)").max_element() < 1e-3,
            "{map}: enclosed cap gamma {:?}",
            g_of("cap inside an occluder (gamma 0)")
        );
        if map.starts_with("smooth") {
            for name in [
                "occluder inside the cap",
                "occluder across the cap edge",
                "two occluders, inside and across",
                "cap across the seam",
                "cap over the north pole",
                "cap across the horizon",
                "arc dipping into the cap",
            ] {
                let g = g_of(name);
                assert!(
                    g.max_element() < 0.99 && g.min_element() > 0.01,
                    "{map}: {name}: gamma {g:?} should be partial"
                );
            }
        }
        drop(tech);
        drop(engine);
    }
    assert!(failures.is_empty(), "GLSL gamma differs from the CPU:\n{}", failures.join("\n"));
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:#?}", ctx.validation.errors());
}

/// Largest GLSL-vs-CPU difference of gamma (a ratio in [0, 1]) where the cap carries enough
/// light: fp32 SAT corners and angles, bisected circle crossings.
const CAP_PARITY_TOL: f64 = 2e-3;
/// Plus this fraction of the whole map's integral (luminance) in the numerator: fp32
/// cancellation of SAT differences, which dominates caps in dark parts of a map with compact
/// bright sources (the studio map: 66% of the energy in 0.1% of the texels).
const CAP_FP32_FLOOR: f64 = 1e-6;

/// `vv_coarse` with glossy materials: the clay objects and the ground Blinn-Phong (shininess 64,
/// Phong alpha 16 in the technique).
fn glossy_scene() -> Scene {
    let mut s = scene("vv_coarse.toml");
    for m in s.materials.iter_mut() {
        let spec = if m.name == "ground" { 0.25 } else { 0.4 };
        *m = penumbra_scene::Material::blinn_phong(&m.name, m.albedo * 0.6, glam::Vec3::splat(spec), 64.0);
    }
    with(&s, &[("sat_width", "64"), ("resolution", "24"), ("arcs", "12")])
}

/// Specular (eq. 14-16) on the GPU in every mode on a glossy scene: validation-clean, finite,
/// and closer to the CPU reference (PSNR, by more than 1 dB) with the specular term than with
/// the diffuse part only: fragment3 (eq. 19) and fragment1 (eq. 21) against themselves,
/// tessellation and tessellation3 against tessellation without specular. Measured (24 x 18,
/// reference 256 spp): fragment3 26.22 -> 31.71 dB, fragment1 26.14 -> 31.42, tessellation
/// 26.05 -> 27.68, tessellation3 27.64; env (no shadows) 26.25.
#[test]
fn glossy_specular_in_all_modes() {
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let s = glossy_scene();
    let (w, h) = (24, 18);
    let reference = reference_render(
        &s,
        &ReferenceOptions { width: w, height: h, spp: 256, time: Some(0.0), mode: Mode::Exact, ..Default::default() },
    )
    .expect("reference");
    let mut psnr = std::collections::BTreeMap::new();
    {
        // context: the env technique (glossy from the prefiltered map, no shadows)
        let env = render_env(&s, w, h);
        let c = compare(&reference.radiance, "reference", &image(&env), "env").unwrap();
        println!(
            "glossy env (no shadows): PSNR {:.2} relRMSE {:.4} FLIP {:.4}",
            c.psnr_db.unwrap_or(99.0),
            c.rel_rmse,
            c.flip_mean
        );
    }
    for (mode, spec) in [
        ("fragment3", "on"),
        ("fragment3", "off"),
        ("fragment1", "on"),
        ("fragment1", "off"),
        ("tessellation", "on"),
        ("tessellation", "off"),
        ("tessellation3", "on"),
    ] {
        let sm = with(&s, &[("mode", mode), ("specular", spec), ("zeta", "2"), ("max_level", "4")]);
        let t0 = std::time::Instant::now();
        let (r, frames) = render(&sm, w, h, true);
        let log = r.context().validation.clone();
        let last = frames.last().expect("frames");
        assert!(
            last.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
            "{mode} specular {spec}: non-finite or negative radiance"
        );
        let c = compare(&reference.radiance, "reference", &image(last), mode).unwrap();
        if let Some(dir) = std::env::var_os("VV_DUMP") {
            let dir = PathBuf::from(dir);
            image(last).write_exr(dir.join(format!("glossy_{mode}_{spec}.exr"))).unwrap();
            reference.radiance.write_exr(dir.join("glossy_reference.exr")).unwrap();
        }
        let p = c.psnr_db.unwrap_or(99.0);
        println!(
            "glossy {mode} specular {spec}: PSNR {p:.2} relRMSE {:.4} FLIP {:.4} ({:.1} s)",
            c.rel_rmse,
            c.flip_mean,
            t0.elapsed().as_secs_f64()
        );
        drop(r);
        assert_eq!(log.error_count(), 0, "{mode} specular {spec}: validation errors: {:#?}", log.errors());
        psnr.insert((mode, spec), p);
    }
    for mode in ["fragment3", "fragment1"] {
        let (on, off) = (psnr[&(mode, "on")], psnr[&(mode, "off")]);
        assert!(on > off + 1.0, "{mode}: PSNR with specular {on:.2} not better than diffuse only {off:.2}");
    }
    for mode in ["tessellation", "tessellation3"] {
        let on = psnr[&(mode, "on")];
        let off = psnr[&("tessellation", "off")];
        assert!(
            on > off + 1.0,
            "{mode}: PSNR with specular {on:.2} not better than tessellation diffuse only {off:.2}"
        );
    }
}

/// At tessellation level 1 (zeta 0) both tessellation modes evaluate only at the triangles'
/// corners, where eq. 21 must reproduce each vertex's own visibility (the correspondence's pole
/// routing) for the triangle being drawn (the model triangle comes from the vertex stage:
/// lavapipe's evaluation-stage gl_PrimitiveID is not the patch index): the two images agree.
/// On the bunny (5776 triangles, coarse precompute): 135 dB between them; with the evaluation
/// stage's gl_PrimitiveID 21 dB (vv_coarse does not show that bug).
#[test]
fn tessellation_eq21_equals_eq19_at_the_corners() {
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let s = with(&scene("vv_bunny.toml"), &[("sat_width", "64"), ("resolution", "24"), ("arcs", "12"), ("zeta", "0")]);
    let (w, h) = (48, 36);
    let mut images = Vec::new();
    for mode in ["tessellation", "tessellation3"] {
        let (r, frames) = render(&with(&s, &[("mode", mode)]), w, h, true);
        let log = r.context().validation.clone();
        assert_eq!(log.error_count(), 0, "{mode}: validation errors: {:#?}", log.errors());
        images.push(image(frames.last().expect("frames")));
    }
    let c = compare(&images[1], "tessellation3", &images[0], "tessellation").unwrap();
    let psnr = c.psnr_db.unwrap_or(f64::INFINITY);
    println!("tessellation (eq. 21) vs tessellation3 (eq. 19) at level 1: PSNR {psnr:.2} relRMSE {:.2e}", c.rel_rmse);
    assert!(c.rel_rmse < 1e-3, "eq. 21 differs from eq. 19 at the corners: relRMSE {:.3e}, PSNR {psnr:.2}", c.rel_rmse);
}

/// Receivers made of a few large triangles (`coarse`: a two-triangle floor) get visibility
/// samples from the refinement (`refine`): with the meshes as given the floor's visibility is
/// known at its four corners only and its shadows are missing; refined, the error against the
/// reference falls. And the scene's sphere light is shaded with the loops' point visibility:
/// under a black environment (the light alone) vv's shadows of it beat `env`'s unshadowed
/// light. Measured (32 x 24, resolution 24, reference 256 spp): relRMSE refine 0 0.178, refine
/// 256 0.092; the light alone: env 0.070, vv 0.046.
#[test]
fn refined_receivers_and_local_light_shadows() {
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let s = with(&scene("coarse.toml"), &[("sat_width", "64"), ("resolution", "24"), ("arcs", "12")]);
    let (w, h) = (32, 24);
    let opts =
        ReferenceOptions { width: w, height: h, spp: 256, time: Some(0.0), mode: Mode::Exact, ..Default::default() };
    let err = |reference: &penumbra_reference::image::Image, s: &Scene, name: &str| {
        let (r, frames) = render(s, w, h, true);
        let log = r.context().validation.clone();
        let last = frames.last().expect("frames");
        assert!(
            last.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
            "{name}: non-finite or negative radiance"
        );
        assert_eq!(log.error_count(), 0, "{name}: validation errors: {:#?}", log.errors());
        let c = compare(reference, "reference", &image(last), name).unwrap();
        println!("{name}: relRMSE {:.4}", c.rel_rmse);
        c.rel_rmse
    };
    let reference = reference_render(&s, &opts).expect("reference");
    let coarse = err(&reference.radiance, &with(&s, &[("refine", "0")]), "refine 0");
    let refined = err(&reference.radiance, &with(&s, &[("refine", "256")]), "refine 256");
    assert!(refined < 0.8 * coarse, "refinement did not help: {refined:.4} vs {coarse:.4}");
    // the light alone
    let dark = with_env(&s, 8, 4, |_, _| [0.0; 3]);
    let reference = reference_render(&dark, &opts).expect("reference");
    let env = render_env(&dark, w, h);
    let env_err = compare(&reference.radiance, "reference", &image(&env), "env").unwrap().rel_rmse;
    println!("light alone, env (unshadowed): relRMSE {env_err:.4}");
    let vv = err(&reference.radiance, &with(&dark, &[("refine", "256")]), "light alone, vv");
    assert!(vv < 0.8 * env_err, "vv's shadows of the light {vv:.4} not better than none {env_err:.4}");
}

/// Local lights' shadows are traced through the scene's kd-tree (`light_shadows = traced`,
/// default): a box hanging above a point light casts no shadow on the floor below the light. The
/// occluder loops carry no depth (`light_shadows = loops`), so they shadowed the floor wherever
/// the box lies behind the light as seen from it (sun_and_spot: the cube darkened the floor its
/// spot light lit in front of it).
#[test]
fn an_occluder_behind_a_light_casts_no_shadow() {
    std::env::set_var("PENUMBRA_NO_PROGRESS", "1");
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("penumbra_vv_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("behind_light.toml");
    std::fs::write(
        &path,
        "name = \"behind_light\"\n[camera]\neye = [0.0, 2.6, 1.6]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 45\n\
         [environment]\nprocedural = \"sky\"\nintensity = 1.0\n\
         [[light]]\nname = \"bulb\"\ntype = \"point\"\nposition = [0.0, 0.5, 0.0]\ncolor = [1.0, 1.0, 1.0]\nintensity = 2\n\
         [materials.m]\ntype = \"diffuse\"\nalbedo = 0.7\n\
         [[object]]\nname = \"floor\"\nmesh = { type = \"plane\", size = 2, divisions = 8 }\nmaterial = \"m\"\n\
         [[object]]\nname = \"box\"\nmesh = { type = \"cube\", size = 0.8 }\nmaterial = \"m\"\nposition = [0.0, 1.2, 0.0]\n",
    )
    .unwrap();
    let s = Scene::load(&path).expect("scene");
    let _ = std::fs::remove_dir_all(&dir);
    // the light alone (vv integrates an environment: a black one)
    let s = with_env(&s, 8, 4, |_, _| [0.0; 3]);
    let s = with(&s, &[("sat_width", "64"), ("resolution", "24"), ("arcs", "12"), ("refine", "256")]);
    let (w, h) = (32, 24);
    let reference = reference_at(&s, (w, h), 64, 0.0, Mode::Exact).radiance;
    let run = |shadows: &str| {
        let (r, frames) = render(&with(&s, &[("light_shadows", shadows)]), w, h, true);
        let log = r.context().validation.clone();
        assert_eq!(log.error_count(), 0, "{shadows}: validation errors: {:#?}", log.errors());
        let c = compare(&reference, "reference", &image(frames.last().expect("a frame")), shadows).unwrap();
        println!("{shadows}: relRMSE {:.4}", c.rel_rmse);
        c.rel_rmse
    };
    // measured (32x24, 64-spp reference): traced 0.111, loops 0.350
    let (traced, loops) = (run("traced"), run("loops"));
    assert!(traced < 0.5 * loops, "traced {traced:.4} not well below the loops' {loops:.4}");
    assert!(traced < 0.15, "traced relRMSE {traced:.4}");
}

/// The CPU summed-area table of `w x h` texels (RGBA f32 bytes, alpha unused).
fn cpu_sat(w: u32, h: u32, texels: &[u8]) -> penumbra_math::vv_sat::Sat {
    let f = |c: &[u8], i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
    let tex3: Vec<[f32; 3]> = texels.chunks_exact(16).map(|c| [f(c, 0), f(c, 4), f(c, 8)]).collect();
    penumbra_math::vv_sat::Sat::new(w as usize, h as usize, &tex3).unwrap()
}

/// The GPU summed-area table's channel `k` (`gpu`: the corners of each channel in turn, RGBA
/// f32) against the CPU one's: the largest absolute difference and the largest corner value.
fn sat_error(cpu: &penumbra_math::vv_sat::Sat, gpu: &[f32], k: usize) -> (f64, f64) {
    let n = cpu.corners.len();
    let (mut max_err, mut scale) = (0.0f64, 0.0f64);
    for (j, corner) in cpu.corners.iter().enumerate() {
        let i = (k * n + j) * 4;
        for (x, c) in corner.0[k].to_array().iter().enumerate() {
            max_err = max_err.max((gpu[i + x] as f64 - c).abs());
            scale = scale.max(c.abs());
        }
    }
    (max_err, scale)
}
