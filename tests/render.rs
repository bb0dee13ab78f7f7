//! End-to-end rendering on the Vulkan device (lavapipe in CI).

mod common;

use common::{hdr_image, render_frames};
use penumbra::engine::dump;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::{compare, write_diff_png};
use penumbra_scene::Scene;
use std::path::PathBuf;

#[test]
fn default_scene_is_validation_clean() {
    let scene = Scene::default_scene();
    let (r, frames) = render_frames(&scene, 160, 120, 3, true);
    assert!(r.context().validation_enabled);
    let log = r.context().validation.clone();
    assert_eq!(frames.len(), 3);
    for f in &frames {
        assert_eq!(f.hdr.len(), 160 * 120);
        assert!(f.hdr.iter().flatten().all(|c| c.is_finite()), "non-finite radiance");
        let mean: f32 = f.hdr.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>() / f.hdr.len() as f32;
        assert!(mean > 0.05, "image is black (mean {mean})");
        assert_eq!(f.ldr.len(), 160 * 120 * 4);
        assert!(f.gpu_ms.iter().all(|(_, ms)| *ms >= 0.0 && ms.is_finite()));
    }
    drop(r);
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());
}

#[test]
fn golden_image_matches() {
    let scene = Scene::default_scene();
    let (_r, frames) = render_frames(&scene, 160, 120, 1, false);
    let got = hdr_image(&frames[0]);
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let path = dir.join("default_160x120.exr");
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        got.write_exr(&path).unwrap();
    }
    let want = Image::read_exr(&path).expect("golden image (regenerate with UPDATE_GOLDEN=1)");
    let c = compare(&want, "golden", &got, "render").unwrap();
    // Software rasterisation is deterministic; allow for driver/LLVM differences in float
    // rounding and derivative evaluation, not for visible changes.
    let ok = c.psnr_db.is_none_or(|p| p >= 45.0) && c.rel_rmse <= 0.01;
    if !ok {
        let diff = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("golden_diff.png");
        let _ = write_diff_png(&want, &got, &diff);
        let _ = got.write_exr(PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("golden_got.exr"));
        panic!("golden mismatch: {}\ndifference image: {}", c.summary(), diff.display());
    }
}

#[test]
fn graph_of_default_scene_and_resource_reuse() {
    let scene = Scene::default_scene();
    let settings = penumbra::RenderSettings { width: 64, height: 48, frames_in_flight: 1, ..Default::default() };
    let mut r = penumbra::Renderer::new_headless(&scene, settings, false).unwrap();
    let f = scene.at(0.0, None);
    r.render(&f, None, true).unwrap();
    let g0 = r.last_graph.clone().unwrap();
    let names: Vec<_> = g0.live_passes().map(|(_, p)| p.name.as_str()).collect();
    // the default scene's technique is `auto`: shadowmaps
    assert_eq!(
        names,
        ["env_upload", "textures_upload", "gbuffer", "shadowmaps_depth", "shadowmaps_shade", "tonemap", "readback"]
    );
    let created = r.engine.pool_stats.created;
    r.render(&f, None, true).unwrap();
    let g1 = r.last_graph.clone().unwrap();
    let names: Vec<_> = g1.live_passes().map(|(_, p)| p.name.as_str()).collect();
    assert_eq!(
        names,
        ["gbuffer", "shadowmaps_shade", "tonemap", "readback"],
        "env map, textures and the shadow maps of static geometry must persist across frames"
    );
    // The second frame (one frame in flight) reuses every transient of the first.
    assert_eq!(r.engine.pool_stats.created, created, "transients were not reused");
    assert!(r.engine.pool_stats.reused >= 8);
    // Without readback the output image is still produced (marked output), nothing else.
    let json = dump::to_json(&g1, None);
    assert_eq!(json["summary"]["live_passes"], 4);
    r.finish().unwrap();
    let prof = r.engine.profiler.to_json();
    assert_eq!(prof["frames"], 2);
    assert!(prof["passes"].as_array().unwrap().iter().any(|p| p["pass"] == "gbuffer"));
}

#[test]
fn empty_scene_and_degenerate_meshes_render_cleanly() {
    // No objects at all: only the environment is drawn.
    let mut scene = Scene::empty("empty");
    scene.environment = Some(penumbra_scene::Environment::procedural_sky(64, 32));
    let (r, frames) = render_frames(&scene, 48, 32, 2, true);
    let log = r.context().validation.clone();
    drop(r);
    assert_eq!(log.error_count(), 0, "{:#?}", log.errors());
    assert!(frames.iter().all(|f| f.hdr.iter().flatten().all(|c| c.is_finite())));
    // An object whose mesh has no triangles, and one whose triangles are all degenerate.
    let mut scene = Scene::default_scene();
    let empty = penumbra_scene::MeshData { name: "empty".into(), ..Default::default() };
    let mut flat = penumbra_scene::MeshData::plane(1.0, 1);
    for p in &mut flat.positions {
        *p = glam::Vec3::ZERO;
    }
    for (i, m) in [empty, flat].into_iter().enumerate() {
        scene.meshes.push(m);
        scene.objects.push(penumbra_scene::Object {
            name: format!("degenerate{i}"),
            mesh: scene.meshes.len() - 1,
            material: 0,
            transform: glam::Mat4::IDENTITY,
        });
    }
    let (r, frames) = render_frames(&scene, 48, 32, 1, true);
    let log = r.context().validation.clone();
    drop(r);
    assert_eq!(log.error_count(), 0, "{:#?}", log.errors());
    assert!(frames[0].hdr.iter().flatten().all(|c| c.is_finite()));
}

/// mc's `aa = false` traces its primary rays through the pixel centres, as rasterizing
/// techniques sample and as the matrix's references (`pixel_grid = 1`) do: over a black ground
/// under a uniform sky each pixel is then exactly ground or sky, the same as the reference's,
/// while the default (`aa = true`, jittered) mixes them along the horizon.
#[test]
fn mc_without_aa_samples_the_pixel_centres_like_the_reference_grid() {
    use glam::{Mat4, Vec3};
    use penumbra_scene::{Material, MeshData, Object};
    let sky = 0.8f32;
    let mut s = common::bare_scene(
        vec![MeshData::plane(40.0, 1)],
        vec![Material::diffuse("black", Vec3::ZERO)],
        vec![Object { name: "ground".into(), mesh: 0, material: 0, transform: Mat4::IDENTITY }],
    );
    s.camera.eye = Vec3::new(0.0, 1.0, 0.0);
    s.camera.target = Vec3::new(0.3, 1.13, -1.0);
    s.camera.up = Vec3::new(0.35, 1.0, 0.0).normalize();
    s.camera.fov_y_deg = 50.0;
    let s = common::with_env(&s, 8, 4, |_, _| [sky; 3]);
    let env = s.environment.as_ref().unwrap();
    let sky = sky * env.intensity;
    let (w, h) = (12u32, 10u32);
    let reference = penumbra_reference::render(
        &s,
        &penumbra_reference::ReferenceOptions { width: w, height: h, spp: 4, pixel_grid: 1, ..Default::default() },
    )
    .unwrap()
    .radiance;
    let class = |v: f32| {
        if v.abs() <= 1e-4 * sky {
            Some(false)
        } else if (v - sky).abs() <= 1e-4 * sky {
            Some(true)
        } else {
            None
        }
    };
    for (aa, must_match) in [("false", true), ("true", false)] {
        let scene = common::with(&s, &[("spp", "64"), ("aa", aa)]);
        let (_, frames) = common::render_times(&scene, "mc", w, h, &[0.0], true);
        let img = common::hdr_image(frames.last().unwrap());
        let mut mixed = 0;
        for y in 0..h {
            for x in 0..w {
                let (g, r) = (img.get(x, y)[0], reference.get(x, y)[0]);
                assert!(class(r).is_some(), "reference pixel ({x}, {y}) mixes: {r}");
                match class(g) {
                    Some(c) if must_match => {
                        assert_eq!(Some(c), class(r), "aa = {aa}: pixel ({x}, {y}) is {g}, the reference's {r}")
                    }
                    Some(_) => {}
                    None => mixed += 1,
                }
            }
        }
        if must_match {
            assert_eq!(mixed, 0, "aa = false mixed {mixed} pixels");
        } else {
            assert!(mixed >= 4, "aa = true should mix pixels along the horizon: {mixed}");
        }
    }
}

/// mc's sample points (`qmc_2d`, glsl/include/qmc.glsl: Owen-scrambled Sobol'): every aligned
/// block of 2^k indices of any sequence is a (0,k,2)-net (each 2^a x 2^(k-a) cell of the unit
/// square holds exactly one point: what makes 8 samples per pixel worth more than 8 independent
/// ones), the points lie in [0, 1), and over many sequences (pixels) each point is uniform.
#[test]
fn mc_sample_points_are_scrambled_sobol_nets() {
    use penumbra_passes::kernels::qmc::qmc_points;
    let ctx = penumbra::engine::Context::new(&penumbra::engine::ContextDesc { validation: true, ..Default::default() })
        .expect("context");
    let log = ctx.validation.clone();
    let mut engine = penumbra::engine::Engine::new(ctx, 1).expect("engine");
    let shaders = penumbra::shader_library();
    let seeds = [0u32, 1, 2, 0xdead_beef, u32::MAX];
    let seqs = qmc_points(&mut engine, &shaders, &seeds, 0, 512).expect("points");
    // a net of 2^k points: every elementary interval of area 2^-k holds exactly one
    let is_net = |pts: &[[f32; 2]], k: u32| {
        (0..=k).all(|a| {
            let (nx, ny) = (1usize << a, 1usize << (k - a));
            let mut cells = vec![0u32; nx * ny];
            for p in pts {
                cells[(p[1] * ny as f32) as usize * nx + (p[0] * nx as f32) as usize] += 1;
            }
            cells.iter().all(|&c| c == 1)
        })
    };
    for (s, pts) in seeds.iter().zip(&seqs) {
        assert!(pts.iter().flatten().all(|&v| (0.0..1.0).contains(&v)), "seed {s}: a point outside [0, 1)");
        for k in [1u32, 2, 3, 8] {
            for block in 0..(512usize >> k).min(4) {
                let b = &pts[block << k..(block + 1) << k];
                assert!(
                    is_net(b, k),
                    "seed {s}: points {}..{} are not a (0,{k},2)-net: {b:?}",
                    block << k,
                    (block + 1) << k
                );
            }
        }
    }
    // independent sequences: different points, and each point index uniform over the sequences
    assert_ne!(seqs[0][0], seqs[1][0]);
    let many: Vec<u32> = (0..4096u32).map(|i| i.wrapping_mul(0x9e37_79b9) ^ 0x1234).collect();
    let seqs = qmc_points(&mut engine, &shaders, &many, 5, 1).expect("points");
    for axis in 0..2 {
        let mut hist = [0u32; 8];
        for p in &seqs {
            hist[(p[0][axis] * 8.0) as usize] += 1;
        }
        // 512 expected per bin, standard deviation about 21
        assert!(hist.iter().all(|&c| (512 - 110..=512 + 110).contains(&c)), "axis {axis}: {hist:?}");
    }
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());
}

/// Every registered technique that accepts `scene`, rendered at time 0 at `w` x `h` under the
/// validation layer, with `adjust` setting up each one's `RenderSettings`: (technique, its
/// frame, validation errors).
fn every_technique(
    scene: &Scene,
    w: u32,
    h: u32,
    adjust: impl Fn(&str, &mut penumbra::RenderSettings),
) -> Vec<(&'static str, penumbra::FrameImages, usize)> {
    let mut out = Vec::new();
    for name in penumbra_passes::registry::names() {
        if penumbra_passes::registry::refusal(name, scene).is_some() {
            continue;
        }
        let mut settings =
            penumbra::RenderSettings { width: w, height: h, technique: Some(name.into()), ..Default::default() };
        adjust(name, &mut settings);
        let mut rr =
            penumbra::Renderer::new_headless(scene, settings, true).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let mut frames = rr.render(&scene.at(0.0, None), None, true).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        frames.extend(rr.finish().unwrap());
        let errors = rr.context().validation.error_count();
        drop(rr);
        out.push((name, frames.pop().expect("a frame"), errors));
    }
    out
}

/// One material model: where a normal map bends the shading normal away from the eye, the
/// normal is turned back towards the eye until n.v = 0.01 (`facing_normal` in
/// `reference/src/render.rs`, `material_facing_normal` in `glsl/include/material.glsl`), in the
/// reference and in every technique alike (until session 44 the BRDF read zero there and such
/// pixels were black in all of them). A floor whose constant normal map lays the shading normal
/// along +u (almost in the surface) faces the eye on one side of the image and turns from it on
/// the other; the turned side is lit in the reference, and every technique draws it lit, in the
/// same proportion to the reference as the side that faces the eye (black, it was 0 of it). Where
/// the map tilts the normal this far, the techniques whose unshadowed terms come from the `env`
/// technique's maps draw both sides 21-24 % brighter than the reference (they take in light from
/// below the face that the reference, `mc` and `isg` block): a normal-map error of its own, held
/// under 30 % here, not this test's subject.
#[test]
fn a_normal_map_that_turns_from_the_eye_is_turned_back_in_every_technique() {
    let text = r#"
name = "facing_test"
[camera]
eye = [0.0, 3.0, 3.0]
target = [0.0, 0.0, 0.0]
fov_deg = 40
[environment]
procedural = "sky"
intensity = 1.0
[materials.floor]
type = "cook_torrance"
albedo = 0.6
specular = 0.04
roughness = 0.4
normal_map = { pattern = "checker", scale = 1, a = [1.0, 0.5, 0.0], b = [1.0, 0.5, 0.0], size = 4 }
[[object]]
name = "floor"
mesh = { type = "plane", size = 40, divisions = 8 }
material = "floor"
"#;
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join("facing_test.toml");
    let scene = penumbra_scene::format::parse_toml(&path, text, &Default::default()).expect("scene");
    let (w, h) = (32u32, 24u32);
    // mean radiance of the left and right quarters of the image's lower half (all floor)
    let quarters = |px: &dyn Fn(u32, u32) -> [f32; 3]| {
        let (mut l, mut r) = (0.0f64, 0.0f64);
        for y in h / 2..h {
            for x in 0..w / 4 {
                l += px(x, y).iter().map(|&c| c as f64).sum::<f64>();
                r += px(w - 1 - x, y).iter().map(|&c| c as f64).sum::<f64>();
            }
        }
        (l, r)
    };
    let opts = penumbra_reference::render::ReferenceOptions {
        width: w,
        height: h,
        spp: 64,
        time: Some(0.0),
        ..Default::default()
    };
    let reference = penumbra_reference::render::render(&scene, &opts).expect("reference");
    let (rl, rr) = quarters(&|x, y| reference.radiance.get(x, y));
    assert!(rl > 0.0 && rr > 0.0, "reference: left {rl}, right {rr}: a side is black");
    let mut failures = Vec::new();
    for (name, f, errors) in every_technique(&scene, w, h, |_, _| {}) {
        let (l, r) = quarters(&|x, y| {
            let p = f.hdr[(y * w + x) as usize];
            [p[0], p[1], p[2]]
        });
        eprintln!("{name}: left {l:.4} (reference {rl:.4}), right {r:.4} (reference {rr:.4})");
        let (sl, sr) = (l / rl, r / rr);
        if errors > 0 || (sl - sr).abs() > 0.1 || (sl - 1.0).abs() > 0.3 || (sr - 1.0).abs() > 0.3 {
            failures.push(format!(
                "{name}: left {l:.4} (reference {rl:.4}), right {r:.4} (reference {rr:.4}), {errors} validation errors"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Light from below the geometric surface is blocked by the surface itself (the reference's rule,
/// `light_incident` in `glsl/include/lights.glsl`): on a coarse torus with smooth normals (4
/// segments around the tube), the point light reaches pixels whose interpolated normal faces it
/// while their face turns from it. Every technique leaves those pixels black (the environment is
/// off), as the reference does. Found on vol_buddha, where the king's thin crown lit its far side
/// in every technique (160x120: avs 0.268 -> 0.038 rmse/mean, shadowmaps 0.398 -> 0.235).
#[test]
fn light_below_the_face_lights_nothing_in_every_technique() {
    let text = r#"
name = "face_test"
[camera]
eye = [0.0, 2.2, 2.2]
target = [0.0, 0.0, 0.0]
fov_deg = 40
[environment]
procedural = "sky"
intensity = 0.0
[[light]]
type = "point"
position = [0.0, 0.45, 0.0]
intensity = 20
[materials.m]
type = "diffuse"
albedo = 0.7
[[object]]
name = "ring"
mesh = { type = "torus", major_radius = 0.7, minor_radius = 0.3, major_segments = 12, minor_segments = 4 }
material = "m"
"#;
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join("face_test.toml");
    let scene = penumbra_scene::format::parse_toml(&path, text, &Default::default()).expect("scene");
    let light = glam::Vec3::new(0.0, 0.45, 0.0);
    let (w, h) = (96u32, 72u32);
    let mut failures = Vec::new();
    let mut checked = 0usize;
    let rendered = every_technique(&scene, w, h, |name, settings| {
        // mc through the pixel centres, where the G-buffer classified them
        settings.technique_params = (name == "mc").then(|| [("aa".to_string(), "false".to_string())].into());
        settings.dump_passes = true;
    });
    for (name, f, errors) in rendered {
        let get = |n: &str| &f.dumps.iter().find(|(d, _)| d == n).unwrap_or_else(|| panic!("{name}: no dump {n}")).1;
        let (pos, nrm) = (get("gb_position"), get("gb_normal"));
        // pixels whose shading normal faces the light by more than 3 degrees while their face
        // turns from it by more than 3 degrees, and the brightest pixel facing the light
        let (mut behind, mut worst, mut lit) = (0usize, 0.0f32, 0.0f32);
        for i in 0..pos.len() {
            if pos[i][3] < 1.0 {
                continue;
            }
            let p = glam::Vec3::new(pos[i][0], pos[i][1], pos[i][2]);
            let wi = (light - p).normalize();
            let (ns, ng) = (common::oct_decode([nrm[i][0], nrm[i][1]]), common::geometric_normal(pos[i][3]));
            let y = f.hdr[i][0].max(f.hdr[i][1]).max(f.hdr[i][2]);
            if ng.dot(wi) > 0.05 {
                lit = lit.max(y);
            } else if ng.dot(wi) < -0.05 && ns.dot(wi) > 0.05 {
                behind += 1;
                worst = worst.max(y);
            }
        }
        if name == "env" {
            assert!(behind >= 10, "the scene shows only {behind} pixels lit by their normal but not their face");
        }
        checked += 1;
        if errors > 0 || !(lit > 0.0 && worst <= 1e-3 * lit) {
            failures.push(format!("{name}: {behind} pixels behind their face, brightest {worst:.5} (lit {lit:.4}), {errors} validation errors"));
        }
    }
    assert!(checked >= 5, "only {checked} techniques accept the scene");
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Building a frame never waits on the GPU: no technique submits and waits for GPU work while it
/// declares a frame, the first one included, over frames of moving and deforming geometry (avs
/// with its default `adaptation = cpu`; its `rounds` and `late` modes, asked for, still wait).
#[test]
fn no_technique_waits_on_the_gpu_while_building_a_frame() {
    let scene =
        Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join("hat_on_cloth.toml")).unwrap();
    for name in penumbra_passes::registry::names() {
        if penumbra_passes::registry::refusal(name, &scene).is_some() {
            continue;
        }
        let mut settings =
            penumbra::RenderSettings { width: 24, height: 18, technique: Some(name.into()), ..Default::default() };
        if name == "avs" {
            // small maps, few points; its default adaptation (`adaptation = cpu`)
            settings.technique_params =
                Some([("r", "32"), ("points", "48")].iter().map(|(k, v)| (k.to_string(), v.to_string())).collect());
        }
        let mut r =
            penumbra::Renderer::new_headless(&scene, settings, false).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let setup = r.engine.waited_submissions();
        r.render(&scene.at(0.0, None), None, false).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        for k in 1..4 {
            let t = k as f32 / 30.0;
            r.render(&scene.at(t, Some(t - 1.0 / 30.0)), None, false).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        }
        r.finish().unwrap();
        assert_eq!(r.engine.waited_submissions(), setup, "{name} waited on the GPU while building frames 0-3");
    }
}

/// Local lights go through the reference's BRDFs in every technique (`light_brdf` in
/// `glsl/include/lights.glsl` is `brdf_eval` of `brdf_ref.glsl` in the reference's shading frame):
/// a glossy plane under one point light and no environment, where the reference is exact with its
/// samples at the pixel centre (a delta light is sampled deterministically; no other light),
/// rendered by `env` for Blinn-Phong, Cook-Torrance and an anisotropic Ashikhmin-Shirley (its lobe
/// stretched along the plane's dP/du, its diffuse lobe not Lambertian) matches it pixel by pixel.
/// With the approximation used before (Blinn-Phong with a Fresnel rise, GGX with Schlick's
/// masking, Ashikhmin-Shirley as a GGX lobe of its exponents' mean) the worst pixels differed by
/// 1.6 %, 6.9 % and a factor of 11; now by at most 1e-4.
#[test]
fn local_lights_shade_with_the_reference_brdfs() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("local_light_brdfs");
    std::fs::create_dir_all(&dir).unwrap();
    let materials = [
        ("blinn_phong", "type = \"blinn_phong\"\nalbedo = [0.3, 0.2, 0.1]\nspecular = 0.4\nshininess = 60"),
        ("cook_torrance", "type = \"cook_torrance\"\nalbedo = [0.3, 0.2, 0.1]\nspecular = 0.5\nroughness = 0.35"),
        (
            "ashikhmin_shirley",
            "type = \"ashikhmin_shirley\"\nalbedo = [0.3, 0.2, 0.1]\nspecular = 0.3\nshininess = 200\nshininess_v = 20",
        ),
    ];
    let (w, h) = (40u32, 30u32);
    for (name, mat) in materials {
        let text = format!(
            "name = \"{name}\"\n[camera]\neye = [0.0, 1.2, 2.2]\ntarget = [0.0, 0.0, -0.2]\nfov_deg = 50\n\n\
             [materials.m]\n{mat}\n\n[[object]]\nname = \"plane\"\nmesh = {{ type = \"plane\", size = 3 }}\nmaterial = \"m\"\n\n\
             [[light]]\nname = \"point\"\ntype = \"point\"\nposition = [0.4, 0.9, -0.6]\nintensity = 3\n"
        );
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, text).unwrap();
        let s = penumbra_scene::Scene::load(&path).expect("scene");
        let (reference, img) = common::reference_and_frame(&s, "env", w, h, 2);
        let (mut worst, mut peak) = (0.0f32, 0.0f32);
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let (g, r) = (img.get(x, y)[c], reference.get(x, y)[c]);
                    peak = peak.max(r);
                    worst = worst.max((g - r).abs() / r.abs().max(1e-3));
                }
            }
        }
        println!("{name}: worst relative difference {worst:.2e} (peak radiance {peak:.3})");
        assert!(peak > 0.1, "{name}: the light does not reach the plane");
        assert!(worst < 2e-3, "{name}: worst relative difference {worst}");
    }
}
