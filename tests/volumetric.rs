//! Volumetric single scattering (issue 7) on the Vulkan device: the full method against the CPU
//! reference, temporal vs full, the pass selection, the extremes of the issue.

mod common;

use penumbra::engine::{Context, ContextDesc};
use penumbra::passes::effect::EffectOverrides;
use penumbra::passes::volumetric::bench::{bench_volumetric, VolBenchOptions, VolBenchReport};
use penumbra::{RenderSettings, Renderer};
use penumbra_scene::Scene;
use std::path::PathBuf;
use std::sync::Arc;

fn scene_from(name: &str, text: &str) -> Scene {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("penumbra_vol_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, text).unwrap();
    Scene::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

fn builtin(name: &str) -> Scene {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name);
    Scene::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

/// A spot light over a black floor with a black sphere occluder: the image is the medium's
/// single scattering only (the technique's surface shading is zero), so the GPU and the CPU
/// reference compute the same thing. `extra` goes into the `[medium]` table's neighbourhood.
fn occluder_scene(name: &str, medium: &str, camera: &str, light: &str, motion: &str) -> Scene {
    scene_from(name, &occluder_text(name, medium, camera, light, motion))
}

fn occluder_text(name: &str, medium: &str, camera: &str, light: &str, motion: &str) -> String {
    format!(
        r#"
name = "{name}"
[camera]
{camera}
fov_deg = 45
[[light]]
{light}
[medium]
{medium}
[materials.black]
type = "diffuse"
albedo = 0.0
[[object]]
name = "floor"
mesh = {{ type = "plane", size = 8 }}
material = "black"
[[object]]
name = "ball"
mesh = {{ type = "icosphere", radius = 0.35, subdivisions = 3 }}
material = "black"
position = [0.0, 1.2, 0.0]
{motion}
"#
    )
}

const CAM: &str = "eye = [0.0, 1.3, 4.0]\ntarget = [0.0, 0.8, 0.0]";
const SPOT: &str = "name = \"spot\"\ntype = \"spot\"\nposition = [0.2, 3.0, 0.0]\ndirection = [-0.05, -1.0, 0.0]\ncolor = [1.0, 0.9, 0.8]\nintensity = 40\ninner_deg = 20\nouter_deg = 28";
const MEDIUM: &str = "sigma_a = 0.05\nsigma_s = 0.3\ng = 0.3";

fn render_one(scene: &Scene, method: &str, w: u32, h: u32) -> (Renderer, penumbra::FrameImages) {
    let settings = RenderSettings {
        width: w,
        height: h,
        effects: EffectOverrides { volumetric: Some(method.into()) },
        ..Default::default()
    };
    let mut r = Renderer::new_headless(scene, settings, true).expect("renderer");
    let f = scene.at(0.0, None);
    let mut out = r.render(&f, None, true).expect("render");
    out.extend(r.finish().expect("finish"));
    let img = out.pop().expect("a frame");
    (r, img)
}

#[test]
fn full_method_matches_the_cpu_reference() {
    full_vs_reference("vol_ref", SPOT);
}

#[test]
fn full_method_matches_the_cpu_reference_for_a_point_light() {
    // Six shadow-map faces; the light sits above the ball, the ball's shadow falls on the floor
    // and its volumetric shadow crosses face boundaries.
    full_vs_reference(
        "vol_ref_point",
        "name = \"p\"\ntype = \"point\"\nposition = [0.3, 2.2, 0.3]\ncolor = [1.0, 0.9, 0.8]\nintensity = 15",
    );
}

fn full_vs_reference(name: &str, light: &str) {
    let scene = occluder_scene(name, MEDIUM, CAM, light, "");
    let (w, h) = (96, 72);
    let (r, img) = render_one(&scene, "full", w, h);
    let log = r.context().validation.clone();
    let passes: Vec<String> = r.last_graph.as_ref().unwrap().live_passes().map(|(_, p)| p.name.clone()).collect();
    drop(r);
    assert_eq!(log.error_count(), 0, "{:?}", log.errors());
    for p in ["vol_shadow", "vol_march", "vol_composite"] {
        assert!(passes.iter().any(|x| x == p), "{p} missing from {passes:?}");
    }
    let opts = penumbra_reference::render::ReferenceOptions { width: w, height: h, spp: 256, ..Default::default() };
    let reference = penumbra_reference::render::render(&scene, &opts).expect("reference");
    let gpu = common::hdr_image(&img);
    let c = penumbra_reference::metrics::compare(&reference.radiance, "reference", &gpu, "gpu full").unwrap();
    let sum =
        |im: &penumbra_reference::image::Image| im.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>();
    let (sr, sg) = (sum(&reference.radiance), sum(&gpu));
    // The occluder's volumetric shadow: the column under the ball is darker than beside it.
    let lum = |x: u32, y: u32| {
        let p = img.hdr[(y * w + x) as usize];
        p[0] + p[1] + p[2]
    };
    println!(
        "{name}: full vs CPU reference: PSNR {:?} dB, relRMSE {:?}, total energy ratio {:.4}, reference noise {:?}",
        c.psnr_db,
        c.rel_rmse,
        sg / sr,
        reference.noise
    );
    assert!(sr > 0.0 && sg > 0.0);
    assert!((sg / sr - 1.0).abs() < 0.03, "energy ratio {}", sg / sr);
    assert!(c.psnr_db.unwrap_or(f64::INFINITY) > 30.0, "PSNR {:?}", c.psnr_db);
    let _ = lum;
}

#[test]
fn lit_surfaces_in_a_medium_match_the_reference() {
    // Grey floor, pale ball: the surfaces' light is attenuated through the medium on its way in
    // (every technique's local lights) and on its way to the eye (vol_composite), as the CPU
    // reference does; before, the floor under the spot was 1.7x too bright.
    let text = occluder_text("vol_lit", "sigma_a = 0.1\nsigma_s = 0.3\ng = 0.3", CAM, SPOT, "").replace(
        "[materials.black]\ntype = \"diffuse\"\nalbedo = 0.0",
        "[materials.black]\ntype = \"diffuse\"\nalbedo = 0.6",
    );
    assert!(text.contains("albedo = 0.6"));
    let (w, h) = (96, 72);
    for technique in ["shadowmaps", "mc"] {
        let scene = scene_from(
            &format!("vol_lit_{}", technique),
            &text.replace("name = \"vol_lit\"", &format!("name = \"vol_lit\"\ntechnique = \"{technique}\"")),
        );
        let (r, img) = render_one(&scene, "full", w, h);
        assert_eq!(r.context().validation.error_count(), 0, "{:?}", r.context().validation.errors());
        drop(r);
        let opts = penumbra_reference::render::ReferenceOptions { width: w, height: h, spp: 256, ..Default::default() };
        let reference = penumbra_reference::render::render(&scene, &opts).expect("reference");
        let gpu = common::hdr_image(&img);
        let c = penumbra_reference::metrics::compare(&reference.radiance, "reference", &gpu, technique).unwrap();
        let sum =
            |im: &penumbra_reference::image::Image| im.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>();
        let ratio = sum(&gpu) / sum(&reference.radiance);
        // The floor straight under the light (the image's lower middle): lit, in the medium.
        let floor = |im: &penumbra_reference::image::Image| {
            let mut s = 0.0f64;
            for y in 60..68 {
                for x in 40..56 {
                    let p = im.pixels[(y * w + x) as usize];
                    s += (p[0] + p[1] + p[2]) as f64;
                }
            }
            s
        };
        let floor_ratio = floor(&gpu) / floor(&reference.radiance);
        println!(
            "{technique}: relRMSE {}, PSNR {:?} dB, energy ratio {ratio:.4}, floor ratio {floor_ratio:.4}",
            c.rel_rmse, c.psnr_db
        );
        assert!((ratio - 1.0).abs() < 0.05, "{technique}: energy ratio {ratio}");
        assert!((floor_ratio - 1.0).abs() < 0.08, "{technique}: floor ratio {floor_ratio}");
    }
}

#[test]
fn lights_beyond_the_scattering_budget_are_named() {
    // One light scatters (the brightest); the user is told which others light surfaces only.
    let two = format!("{SPOT}\n[[light]]\nname = \"dim\"\ntype = \"point\"\nposition = [1.0, 2.0, 1.0]\nintensity = 2");
    let scene = occluder_scene("vol_two_lights", MEDIUM, CAM, &two, "");
    let settings = RenderSettings { width: 32, height: 24, ..Default::default() };
    let r = Renderer::new_headless(&scene, settings, false).expect("renderer");
    let notes = r.notes().join("\n");
    assert!(
        notes.contains("volumetric: ") && notes.contains("'spot'") && notes.contains("'dim' light surfaces only"),
        "{notes}"
    );
    // By contribution, not by intensity: a dimmer light beside the camera fills the medium the
    // camera looks through (I exp(-sigma_t d) / d).
    let near =
        format!("{SPOT}\n[[light]]\nname = \"near\"\ntype = \"point\"\nposition = [0.3, 1.3, 3.6]\nintensity = 30");
    let scene = occluder_scene("vol_near_light", MEDIUM, CAM, &near, "");
    let r =
        Renderer::new_headless(&scene, RenderSettings { width: 32, height: 24, ..Default::default() }, false).unwrap();
    let notes = r.notes().join("\n");
    assert!(notes.contains("('near' at t = 0)") && notes.contains("'spot' light surfaces only"), "{notes}");
    let one = occluder_scene("vol_one_light", MEDIUM, CAM, SPOT, "");
    let r =
        Renderer::new_headless(&one, RenderSettings { width: 32, height: 24, ..Default::default() }, false).unwrap();
    assert!(!r.notes().iter().any(|n| n.contains("scatters one light")), "{:?}", r.notes());
}

#[test]
fn a_scene_without_medium_has_no_volumetric_passes_and_god_rays_has_them() {
    let plain = builtin("balls_on_dish.toml");
    assert!(plain.medium.is_none());
    let (r, _) = render_one(&plain, "temporal", 48, 36);
    let passes: Vec<String> = r.last_graph.as_ref().unwrap().live_passes().map(|(_, p)| p.name.clone()).collect();
    assert!(passes.iter().all(|p| !p.starts_with("vol_")), "{passes:?}");
    drop(r);
    let god = builtin("god_rays.toml");
    let (r, img) = render_one(&god, "temporal", 48, 36);
    let passes: Vec<String> = r.last_graph.as_ref().unwrap().live_passes().map(|(_, p)| p.name.clone()).collect();
    assert!(passes.iter().any(|p| p == "vol_march"), "{passes:?}");
    assert!(img.hdr.iter().flatten().all(|c| c.is_finite()));
    // A bad override is an error, not ignored.
    let settings = RenderSettings {
        width: 8,
        height: 8,
        effects: EffectOverrides { volumetric: Some("fast".into()) },
        ..Default::default()
    };
    assert!(Renderer::new_headless(&god, settings, false).is_err());
}

fn ctx() -> Arc<Context> {
    Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context")
}

fn bench(ctx: &Arc<Context>, scene: &Scene, frames: u32, w: u32, h: u32) -> VolBenchReport {
    let opts = VolBenchOptions { width: w, height: h, frames, samples: 32, ..Default::default() };
    let rep = bench_volumetric(ctx, &penumbra::shader_library(), scene, &opts).expect("bench");
    println!("{}", rep.table());
    assert_eq!(ctx.validation.error_count(), 0, "{:?}", ctx.validation.errors());
    for f in &rep.frames {
        assert!(f.mean_abs.is_finite() && f.max_abs.is_finite());
    }
    rep
}

#[test]
fn temporal_equals_full_on_linear_motion_with_no_missed_pixels() {
    let ctx = ctx();
    let motion = "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [-0.4, 1.2, 0.0] }, { t = 1.0, position = [0.6, 1.2, 0.0] }] }";
    let scene = occluder_scene("vol_linear", MEDIUM, CAM, SPOT, motion);
    let rep = bench(&ctx, &scene, 6, 96, 72);
    assert_eq!(rep.missed_pixels, 0);
    // The motion changes the scattering every frame (else the comparison would be vacuous).
    assert!(
        rep.frames[1..].iter().all(|f| f.changed_pixels > 50),
        "{:?}",
        rep.frames.iter().map(|f| f.changed_pixels).collect::<Vec<_>>()
    );
    let masked: Vec<_> = rep.frames.iter().filter(|f| f.temporal_mode == "masked").collect();
    assert!(masked.len() >= 3, "{:?}", rep.frames.iter().map(|f| &f.temporal_mode).collect::<Vec<_>>());
    for f in &rep.frames {
        let peak_rel = f.max_abs;
        assert!(f.psnr > 50.0 || f.mean_abs < 1e-6, "frame {}: PSNR {} max {}", f.frame, f.psnr, peak_rel);
    }
    for f in masked {
        assert!(f.marched_fraction > 0.0 && f.marched_fraction < 0.6, "marched {}", f.marched_fraction);
    }
}

#[test]
fn skipping_the_masked_march_is_caught_as_missed_pixels() {
    // Negative control: the same linear motion with the masked march disabled must show
    // missed pixels and a difference, so zero above means something.
    let ctx = ctx();
    let motion = "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [-0.4, 1.2, 0.0] }, { t = 1.0, position = [0.6, 1.2, 0.0] }] }";
    let scene = occluder_scene("vol_linear_nomask", MEDIUM, CAM, SPOT, motion);
    let opts =
        VolBenchOptions { width: 64, height: 48, frames: 3, samples: 32, debug_skip_mask: true, ..Default::default() };
    let rep = bench_volumetric(&ctx, &penumbra::shader_library(), &scene, &opts).expect("bench");
    println!("{}", rep.table());
    assert!(rep.missed_pixels > 20, "{}", rep.missed_pixels);
    assert!(rep.frames[1].mean_abs > 0.0 && rep.frames[1].psnr < 60.0);
}

#[test]
fn hybrid_with_airlight_matches_the_reference_as_plain_marching_does() {
    // Wyman and Ramsey's hybrid: the lit segments in closed form (the airlight table), only the
    // shadowed interval marched. Both it and the plain march are judged against the CPU
    // reference of the same frame; the hybrid must be at least about as close (its lit segments
    // are exact up to the table's 0.2 %, the march's are a 32-sample quadrature).
    let ctx = ctx();
    let motion = "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [-0.4, 1.2, 0.0] }, { t = 1.0, position = [0.6, 1.2, 0.0] }] }";
    let (w, h) = (96u32, 72u32);
    for (name, light) in [
        ("vol_hybrid", SPOT),
        (
            "vol_hybrid_point",
            "name = \"p\"\ntype = \"point\"\nposition = [0.3, 2.2, 0.3]\ncolor = [1.0, 0.9, 0.8]\nintensity = 15",
        ),
    ] {
        let scene = occluder_scene(name, MEDIUM, CAM, light, motion);
        let run = |hybrid: bool| {
            let opts = VolBenchOptions { width: w, height: h, frames: 3, samples: 32, hybrid, ..Default::default() };
            let rep = bench_volumetric(&ctx, &penumbra::shader_library(), &scene, &opts).expect("bench");
            println!("{name} hybrid {hybrid}:\n{}", rep.table());
            rep
        };
        let (plain, hybrid) = (run(false), run(true));
        assert_eq!(ctx.validation.error_count(), 0, "{:?}", ctx.validation.errors());
        assert_eq!(hybrid.missed_pixels, 0);
        assert!(hybrid.temporal_pass_ms.iter().any(|(n, _)| n == "vol_volumes"));
        let to_img = |v: &Vec<[f32; 4]>| {
            penumbra_reference::image::Image::from_fn(w, h, |x, y| {
                let p = v[(y * w + x) as usize];
                [p[0], p[1], p[2]]
            })
        };
        let t_last = hybrid.frames.last().unwrap().time;
        let opts = penumbra_reference::render::ReferenceOptions {
            width: w,
            height: h,
            spp: 512,
            time: Some(t_last),
            ..Default::default()
        };
        let reference = penumbra_reference::render::render(&scene, &opts).expect("reference");
        let judge = |img: &Vec<[f32; 4]>, label: &str| {
            let c =
                penumbra_reference::metrics::compare(&reference.radiance, "reference", &to_img(img), label).unwrap();
            let sum = |im: &penumbra_reference::image::Image| {
                im.pixels.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>()
            };
            let ratio = sum(&to_img(img)) / sum(&reference.radiance);
            println!(
                "{name} {label} vs CPU reference: relRMSE {:?}, PSNR {:?} dB, energy ratio {ratio:.4}",
                c.rel_rmse, c.psnr_db
            );
            (c.rel_rmse, ratio)
        };
        let (e_plain, r_plain) = judge(&plain.last_full_hdr, "plain march");
        let (e_hybrid, r_hybrid) = judge(&hybrid.last_full_hdr, "hybrid (airlight)");
        assert!((r_hybrid - 1.0).abs() < 0.03, "{name}: hybrid energy ratio {r_hybrid} (plain {r_plain})");
        assert!(e_hybrid <= e_plain * 1.1 + 1e-3, "{name}: hybrid relRMSE {e_hybrid} vs plain {e_plain}");
    }
}

#[test]
fn deforming_mover_masks_like_a_rigid_one() {
    // A squashing ball (a deformation, no rigid motion): its previous shape is on the GPU, so
    // the temporal method masks instead of recomputing every frame, and misses nothing.
    let ctx = ctx();
    let deform = "deform = [{ type = \"squash\", amount = 0.4, period = 0.8 }]";
    let scene = occluder_scene("vol_squash", MEDIUM, CAM, SPOT, deform);
    let rep = bench(&ctx, &scene, 4, 64, 48);
    let modes: Vec<_> = rep.frames.iter().map(|f| f.temporal_mode.as_str()).collect();
    assert_eq!(modes, ["refresh", "masked", "masked", "masked"], "{}", rep.table());
    assert_eq!(rep.missed_pixels, 0, "{}", rep.table());
    assert!(rep.frames[1..].iter().all(|f| f.changed_pixels > 0), "the squash changes the shafts: {}", rep.table());
    for f in &rep.frames[1..] {
        assert!(
            f.marched_fraction < 0.9,
            "frame {}: the mask covers only the ball's volumes: {}",
            f.frame,
            rep.table()
        );
        assert_eq!(f.mean_abs, 0.0, "frame {}: temporal differs from full: {}", f.frame, rep.table());
    }
}

#[test]
fn static_scene_marches_nothing_between_refreshes() {
    let ctx = ctx();
    let scene = occluder_scene("vol_static", MEDIUM, CAM, SPOT, "");
    let rep = bench(&ctx, &scene, 5, 64, 48);
    let modes: Vec<_> = rep.frames.iter().map(|f| f.temporal_mode.as_str()).collect();
    // The thesis's reused frame number 3: a whole frame every 4 frames.
    assert_eq!(modes, ["refresh", "skipped", "skipped", "skipped", "refresh"]);
    for f in &rep.frames {
        assert_eq!(f.missed_pixels, 0);
        assert_eq!(f.mean_abs, 0.0, "frame {}", f.frame);
        if f.temporal_mode == "skipped" {
            assert_eq!(f.marched_fraction, 0.0);
            assert!(!f.temporal_ms.iter().any(|(n, _)| n == "vol_march" || n == "vol_mask"), "{:?}", f.temporal_ms);
        }
    }
}

#[test]
fn extremes_render_finite_and_consistent() {
    let ctx = ctx();
    let linear = "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [-0.3, 1.2, 0.0] }, { t = 2.0, position = [0.3, 1.2, 0.0] }] }";
    // Camera inside the moving ball's shadow volume (under it, looking up past it) and inside
    // the medium; light inside the medium (always: the medium fills space).
    let under = "eye = [0.15, 0.3, 0.0]\ntarget = [0.2, 3.0, 0.6]";
    let near_axis = "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [0.05, 1.2, 0.0] }, { t = 1.0, position = [0.35, 1.2, 0.0] }] }";
    let cases = [
        ("thin", "sigma_a = 0.0\nsigma_s = 2e-5\ng = 0.0", CAM, linear),
        ("dense", "sigma_a = 5.0\nsigma_s = 15.0\ng = 0.6", CAM, linear),
        ("inside", MEDIUM, under, near_axis),
        // Crosses the near plane and leaves the screen.
        ("near_cross", MEDIUM, "eye = [0.0, 1.2, 1.5]\ntarget = [0.0, 1.2, 0.0]",
            "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [0.0, 1.2, 0.6] }, { t = 0.2, position = [0.0, 1.2, 2.5] }] }"),
    ];
    for (name, medium, cam, motion) in cases {
        let scene = occluder_scene(&format!("vol_{name}"), medium, cam, SPOT, motion);
        let rep = bench(&ctx, &scene, 4, 48, 36);
        println!(
            "{name}: missed {} max_abs {:?}",
            rep.missed_pixels,
            rep.frames.iter().map(|f| f.max_abs).collect::<Vec<_>>()
        );
        assert_eq!(rep.missed_pixels, 0, "{name}");
        // Optical depth ~80 to the mover: its shadow is invisible through the dense medium.
        if name != "dense" {
            assert!(rep.frames[1..].iter().any(|f| f.changed_pixels > 0), "{name}: nothing changed");
        }
        if name == "inside" {
            // Inside the mover's shadow volume every view ray crosses its boundary: all masked.
            for f in rep.frames.iter().filter(|f| f.temporal_mode == "masked") {
                assert_eq!(f.marched_fraction, 1.0, "frame {}", f.frame);
            }
        }
    }
    // Point light inside the medium, many movers: the built-in donuts scene.
    let rep = bench(&ctx, &builtin("vol_donuts.toml"), 3, 48, 36);
    assert_eq!(rep.frames.len(), 3);
}

/// The bench table of every built-in volumetric scene (for the issue note; slow, not in CI):
/// `cargo test -p penumbra --test volumetric -- --ignored --nocapture`.
#[test]
#[ignore]
fn bench_builtin_volumetric_scenes() {
    let ctx = ctx();
    for name in ["vol_dragon.toml", "vol_donuts.toml", "vol_complex.toml", "vol_rotating.toml", "god_rays.toml"] {
        let scene = builtin(name);
        let opts = VolBenchOptions { width: 160, height: 120, frames: 9, ..Default::default() };
        let rep = bench_volumetric(&ctx, &penumbra::shader_library(), &scene, &opts).expect("bench");
        println!("{}", rep.table());
    }
    let opts = VolBenchOptions { width: 160, height: 120, frames: 9, hybrid: true, ..Default::default() };
    let rep = bench_volumetric(&ctx, &penumbra::shader_library(), &builtin("vol_dragon.toml"), &opts).expect("bench");
    println!("hybrid:\n{}", rep.table());
    assert_eq!(ctx.validation.error_count(), 0, "{:?}", ctx.validation.errors());
}

#[test]
fn scene_key_selects_the_method_and_bad_values_are_errors() {
    let base = "name = \"k\"\n[camera]\neye = [0, 1, 3]\ntarget = [0, 0, 0]\n[[light]]\nname = \"p\"\ntype = \"point\"\nposition = [0, 2, 0]\nintensity = 5\n[[object]]\nname = \"b\"\nmesh = { type = \"cube\", size = 0.5 }\n[medium]\nsigma_a = 0.1\nsigma_s = 0.1\n";
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("penumbra_vol_key_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let load = |extra: &str| {
        let p = dir.join("k.toml");
        std::fs::write(&p, format!("{base}{extra}")).unwrap();
        Scene::load(&p)
    };
    assert_eq!(load("").unwrap().volumetric, None);
    assert_eq!(load("volumetric = \"full\"\n").unwrap().volumetric.as_deref(), Some("full"));
    let err = load("volumetric = \"fast\"\n").unwrap_err().to_string();
    assert!(err.contains("volumetric") && err.contains("fast"), "{err}");
    // "full" from the scene: every frame marches every pixel, no mask pass.
    let scene = load("volumetric = \"full\"\n").unwrap();
    let settings = RenderSettings { width: 32, height: 24, ..Default::default() };
    let mut r = Renderer::new_headless(&scene, settings, false).expect("renderer");
    for k in 0..2 {
        r.render(&scene.at(k as f32 / 30.0, None), None, false).expect("render");
        let passes: Vec<String> = r.last_graph.as_ref().unwrap().live_passes().map(|(_, p)| p.name.clone()).collect();
        assert!(passes.iter().any(|p| p == "vol_march") && !passes.iter().any(|p| p == "vol_mask"), "{passes:?}");
    }
    r.finish().expect("finish");
}

#[test]
fn odd_lights_render_finite_and_validation_clean() {
    let motion = "motion = { type = \"keyframes\", keys = [{ t = 0.0, position = [-0.4, 1.2, 0.0] }, { t = 1.0, position = [0.6, 1.2, 0.0] }] }";
    let lights = [
        // Sphere light (scatters as a point of equal power), point light at the eye, a near-
        // hemispherical spot (shadow-map fov clamped), and no light at all (attenuation only).
        "name = \"s\"\ntype = \"sphere\"\nposition = [0.0, 2.5, 0.0]\nradius = 0.2\nintensity = 30",
        "name = \"p\"\ntype = \"point\"\nposition = [0.0, 1.3, 4.0]\nintensity = 30",
        "name = \"w\"\ntype = \"spot\"\nposition = [0.0, 2.5, 0.0]\ndirection = [0, -1, 0]\nintensity = 30\ninner_deg = 80\nouter_deg = 89",
        "name = \"off\"\ntype = \"point\"\nposition = [0.0, 2.5, 0.0]\nintensity = 0",
    ];
    for (i, light) in lights.iter().enumerate() {
        let scene = occluder_scene(&format!("vol_light{i}"), MEDIUM, CAM, light, motion);
        let settings = RenderSettings { width: 48, height: 36, ..Default::default() };
        let mut r = Renderer::new_headless(&scene, settings, true).expect("renderer");
        let mut frames = Vec::new();
        let mut prev = None;
        for k in 0..3 {
            let t = k as f32 / 30.0;
            frames.extend(r.render(&scene.at(t, prev), None, true).expect("render"));
            prev = Some(t);
        }
        frames.extend(r.finish().expect("finish"));
        let log = r.context().validation.clone();
        drop(r);
        assert_eq!(log.error_count(), 0, "light {i}: {:?}", log.errors());
        assert_eq!(frames.len(), 3);
        let total: f64 = frames[2].hdr.iter().map(|p| (p[0] + p[1] + p[2]) as f64).sum();
        assert!(total.is_finite(), "light {i}");
        if i < 3 {
            assert!(total > 0.0, "light {i}: no in-scattering");
        } else {
            assert_eq!(total, 0.0, "an unlit medium over black surfaces is black");
        }
    }
}
