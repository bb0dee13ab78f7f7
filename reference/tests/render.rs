//! Analytic tests of the reference renderer at tiny sizes.

use glam::{Mat4, Vec3};
use penumbra_reference::{render, ReferenceOptions};
use penumbra_scene::{BrdfKind, Camera, Environment, Material, MeshData, Object, Scene};

fn uniform_env(c: [f32; 3], intensity: f32) -> Environment {
    Environment { width: 8, height: 4, texels: vec![c; 32], intensity, rotation: 0.3 }
}

fn camera(eye: Vec3, target: Vec3, fov: f32) -> Camera {
    Camera { eye, target, up: Vec3::Y, fov_y_deg: fov, near: 0.01, far: 100.0 }
}

/// A scene with only what the test sets (built from the default scene so that fields the scene
/// crate adds keep their defaults).
fn plane_scene(material: Material, env: Environment, cam: Camera) -> Scene {
    let mut s = Scene::default_scene();
    s.name = "plane".into();
    s.camera = cam;
    s.environment = Some(env);
    s.meshes = vec![MeshData::plane(40.0, 1)];
    s.materials = vec![material];
    s.objects = vec![Object { name: "ground".into(), mesh: 0, material: 0, transform: Mat4::IDENTITY }];
    s.lights.clear();
    s.medium = None;
    s.material_extras.clear();
    s.object_info.clear();
    s.material_animations.clear();
    s.camera_path = None;
    s
}

fn opts(w: u32, h: u32, spp: u32, seed: u64) -> ReferenceOptions {
    ReferenceOptions { width: w, height: h, spp, seed, ..Default::default() }
}

/// Uniform environment radiance L over an unoccluded Lambertian plane: irradiance E = pi L,
/// exitant radiance L_o = (albedo / pi) E = albedo * L (what a pixel measures). Checked per
/// pixel and channel within 5 standard errors.
#[test]
fn uniform_env_over_diffuse_plane_gives_albedo_times_radiance() {
    let albedo = Vec3::new(0.2, 0.5, 0.8);
    let l = [1.5f32, 1.0, 0.5];
    let scene = plane_scene(
        Material::diffuse("d", albedo),
        uniform_env(l, 2.0),
        camera(Vec3::new(0.0, 3.0, 3.0), Vec3::ZERO, 30.0),
    );
    let r = render(&scene, &opts(8, 6, 4096, 1)).unwrap();
    let expect = albedo * Vec3::from_array(l) * 2.0;
    let mut worst = 0.0f32;
    for (m, s) in r.radiance.pixels.iter().zip(&r.std_error.pixels) {
        for c in 0..3 {
            let z = (m[c] - expect[c]).abs() / s[c].max(1e-9);
            worst = worst.max(z);
            assert!(z <= 5.0, "pixel {m:?} +- {s:?} vs {expect}");
        }
    }
    // Aggregate over all pixels: much tighter.
    let n = r.radiance.pixels.len() as f64;
    for c in 0..3 {
        let mean = r.radiance.pixels.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let se = (r.std_error.pixels.iter().map(|p| (p[c] as f64).powi(2)).sum::<f64>()).sqrt() / n;
        eprintln!(
            "uniform env: channel {c}: {mean:.5} vs {:.5} (error {:.2e}, se {se:.2e})",
            expect[c],
            mean - expect[c] as f64
        );
        assert!((mean - expect[c] as f64).abs() <= 5.0 * se);
    }
    eprintln!("uniform env: worst per-pixel |error| / se = {worst:.2}");
}

/// A sphere of radius r centred at height h above a plane point, under a uniform environment:
/// it hides a cone of half-angle asin(r/h) around the normal, whose cosine-weighted share of the
/// hemisphere is (r/h)^2, so L_o = albedo L (1 - (r/h)^2). The tessellated sphere lies between
/// radius r cos(pi/slices) cos(pi/stacks) and r, which bounds the exact answer; the check is
/// that interval widened by 5 standard errors.
#[test]
fn sphere_occluder_of_known_solid_angle() {
    let (r, h) = (0.5f32, 2.0f32);
    let (slices, stacks) = (64u32, 32u32);
    let albedo = 0.8f32;
    let mut scene = plane_scene(
        Material::diffuse("d", Vec3::splat(albedo)),
        uniform_env([1.0; 3], 1.0),
        camera(Vec3::new(4.0, 1.5, 0.0), Vec3::ZERO, 0.2),
    );
    scene.meshes.push(MeshData::uv_sphere(r, slices, stacks));
    scene.objects.push(Object {
        name: "occluder".into(),
        mesh: 1,
        material: 0,
        transform: Mat4::from_translation(Vec3::new(0.0, h, 0.0)),
    });
    let res = render(&scene, &opts(2, 2, 16384, 7)).unwrap();
    let r_in = r * (std::f32::consts::PI / slices as f32).cos() * (std::f32::consts::PI / stacks as f32).cos();
    let hi = albedo * (1.0 - (r_in / h).powi(2));
    let lo = albedo * (1.0 - (r / h).powi(2));
    let n = res.radiance.pixels.len() as f64;
    for c in 0..3 {
        let mean = res.radiance.pixels.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let se = (res.std_error.pixels.iter().map(|p| (p[c] as f64).powi(2)).sum::<f64>()).sqrt() / n;
        eprintln!(
            "sphere occluder: channel {c}: {mean:.5} +- {se:.1e}, analytic {lo:.5} (smooth sphere) .. {hi:.5} (inscribed)"
        );
        assert!(mean >= lo as f64 - 5.0 * se && mean <= hi as f64 + 5.0 * se);
    }
    // Without the sphere the answer is albedo: the occluder is visible in the estimate.
    assert!(hi < albedo - 0.04);
}

/// White furnace through the whole renderer: a plane of each BRDF, white, under a uniform unit
/// environment, seen at angles from ~20 to ~70 degrees. Lambert must give exactly 1, every BRDF
/// at most 1 (5 standard errors).
#[test]
fn white_furnace_each_brdf() {
    let mats = [
        Material::diffuse("lambert", Vec3::ONE),
        Material {
            name: "blinn-phong".into(),
            kind: BrdfKind::BlinnPhong,
            albedo: Vec3::ZERO,
            specular: Vec3::ONE,
            roughness: 0.5,
            shininess: 30.0,
        },
        Material::glossy("ggx", Vec3::ZERO, Vec3::ONE, 0.4),
        Material {
            name: "ashikhmin-shirley".into(),
            kind: BrdfKind::AshikhminShirley,
            albedo: Vec3::ZERO,
            specular: Vec3::ONE,
            roughness: 0.5,
            shininess: 40.0,
        },
        Material::glossy("ggx+lambert", Vec3::splat(0.9), Vec3::splat(0.04), 0.5),
    ];
    for m in mats {
        let name = m.name.clone();
        let is_lambert = m.kind == BrdfKind::Diffuse;
        let scene = plane_scene(m, uniform_env([1.0; 3], 1.0), camera(Vec3::new(0.0, 2.0, 2.0), Vec3::ZERO, 60.0));
        let r = render(&scene, &opts(6, 6, 128, 3)).unwrap();
        let (mut lo, mut hi) = (f32::MAX, 0.0f32);
        for (p, s) in r.radiance.pixels.iter().zip(&r.std_error.pixels) {
            lo = lo.min(p[1]);
            hi = hi.max(p[1]);
            assert!(p[1] <= 1.0 + 5.0 * s[1], "{name}: {} +- {} > 1", p[1], s[1]);
            if is_lambert {
                assert!((p[1] - 1.0).abs() <= 5.0 * s[1], "{name}: {} +- {} != 1", p[1], s[1]);
            }
        }
        let (m, se) = mean_se(&r)[1];
        eprintln!(
            "furnace {name:18}: pixel albedo in [{lo:.4}, {hi:.4}], image mean {m:.4} +- {se:.1e}, mean rel. s.e. {:.2e}",
            r.noise.mean_rel_std_error
        );
        if is_lambert {
            assert!((m - 1.0).abs() <= 5.0 * se, "{name}: image mean {m} +- {se} != 1");
        }
    }
}

/// Pixel (0, 0) is the top left: with the camera looking at the horizon, the top row sees the
/// sky (exactly, primary rays that miss return the environment), the bottom row the ground,
/// and a sphere placed at -X (left of a camera looking down -Z) appears in the left half.
#[test]
fn image_orientation() {
    let scene = sphere_left_of_centre("left");
    let r = render(&scene, &opts(16, 8, 4, 0)).unwrap();
    for x in 0..16 {
        assert_eq!(r.radiance.get(x, 0), [0.0, 0.0, 1.0], "top row must be sky at x={x}");
        let b = r.radiance.get(x, 7);
        assert!(b[0] == 0.0 && b[2] > 0.0, "bottom row is ground lit by the blue sky at x={x}: {b:?}");
    }
    // The sphere is left of centre at mid height.
    let left = r.radiance.get(5, 3);
    let right = r.radiance.get(10, 3);
    assert_eq!(right, [0.0, 0.0, 1.0], "right side sees sky");
    assert_ne!(left, [0.0, 0.0, 1.0], "left side sees the sphere");
}

/// Same seed: bit-identical images with 1 and 2 threads; another seed differs.
#[test]
fn deterministic_across_thread_counts() {
    let scene = Scene::default_scene();
    let o = opts(12, 8, 4, 42);
    let run = |threads: usize, o: &ReferenceOptions| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| render(&scene, o).unwrap())
    };
    let a = run(1, &o);
    let b = run(2, &o);
    assert!(a
        .radiance
        .pixels
        .iter()
        .flatten()
        .zip(b.radiance.pixels.iter().flatten())
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!(a.std_error, b.std_error);
    let c = run(2, &ReferenceOptions { seed: 43, ..o });
    assert_ne!(a.radiance, c.radiance);
}

/// The standard error falls as 1/sqrt(spp): 16x more samples, 4x smaller error (within 15%,
/// averaged over all pixels of a scene without fireflies) and the 16-spp image agrees with the
/// 256-spp one within the errors.
#[test]
fn standard_error_decreases_as_inverse_sqrt_spp() {
    let mut env = Environment::procedural_sky(32, 16);
    // Remove the sun: heavy tails make 16-spp variance estimates unreliable.
    env.texels.iter_mut().for_each(|t| *t = t.map(|c| c.min(2.0)));
    let mut scene =
        plane_scene(Material::diffuse("d", Vec3::splat(0.6)), env, camera(Vec3::new(0.0, 2.0, 3.0), Vec3::ZERO, 40.0));
    scene.meshes.push(MeshData::uv_sphere(0.5, 24, 12));
    scene.materials.push(Material::glossy("g", Vec3::new(0.5, 0.2, 0.1), Vec3::splat(0.04), 0.5));
    scene.objects.push(Object {
        name: "s".into(),
        mesh: 1,
        material: 1,
        transform: Mat4::from_translation(Vec3::new(0.0, 0.5, 0.0)),
    });
    let a = render(&scene, &opts(12, 8, 16, 5)).unwrap();
    let b = render(&scene, &opts(12, 8, 256, 6)).unwrap();
    let ratio = a.noise.mean_std_error / b.noise.mean_std_error;
    eprintln!(
        "s.e. 16 spp {:.3e}, 256 spp {:.3e}, ratio {ratio:.3} (expected 4); mean rel. s.e. {:.3e} -> {:.3e}",
        a.noise.mean_std_error, b.noise.mean_std_error, a.noise.mean_rel_std_error, b.noise.mean_rel_std_error
    );
    assert!((ratio - 4.0).abs() <= 0.6, "ratio {ratio}");
    // Consistency of the two estimates, on the image means (per-pixel 16-spp variance
    // estimates are too unreliable for a 5-sigma test on every pixel).
    let n = a.radiance.pixels.len() as f64;
    for c in 0..3 {
        let mean =
            |r: &penumbra_reference::ReferenceImage| r.radiance.pixels.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let var = |r: &penumbra_reference::ReferenceImage| {
            r.std_error.pixels.iter().map(|p| (p[c] as f64).powi(2)).sum::<f64>() / (n * n)
        };
        let (d, s) = ((mean(&a) - mean(&b)).abs(), (var(&a) + var(&b)).sqrt());
        assert!(d <= 5.0 * s, "channel {c}: 16 spp mean differs from 256 spp by {d} (se {s})");
    }
}

#[test]
fn bad_options_and_scenes_are_errors() {
    let scene = Scene::default_scene();
    assert!(render(&scene, &opts(0, 4, 4, 0)).unwrap_err().to_string().contains("0x4"));
    assert!(render(&scene, &opts(4, 4, 1, 0)).unwrap_err().to_string().contains("spp"));
    let mut bad = Scene::default_scene();
    bad.objects[1].mesh = 99;
    let e = render(&bad, &opts(4, 4, 4, 0)).unwrap_err().to_string();
    assert!(e.contains("sphere") && e.contains("mesh 99"), "{e}");
    let mut bad = Scene::default_scene();
    bad.environment.as_mut().unwrap().texels.pop();
    let e = render(&bad, &opts(4, 4, 4, 0)).unwrap_err().to_string();
    assert!(e.contains("environment"), "{e}");
    // No environment and no geometry: black, not a panic.
    let mut empty = Scene::default_scene();
    empty.environment = None;
    empty.objects.clear();
    let r = render(&empty, &opts(4, 4, 4, 0)).unwrap();
    assert!(r.radiance.pixels.iter().all(|p| *p == [0.0; 3]));
}

#[test]
fn writes_exr_and_json() {
    let scene = Scene::default_scene();
    let r = render(&scene, &opts(8, 6, 4, 0)).unwrap();
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("penumbra-ref-render-{}", std::process::id()));
    let s = r.write(&dir).unwrap();
    let back = penumbra_reference::Image::read_exr(&s.image).unwrap();
    assert_eq!(back, r.radiance);
    let se = penumbra_reference::Image::read_exr(&s.std_error_image).unwrap();
    assert_eq!(se, r.std_error);
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("reference.json")).unwrap()).unwrap();
    assert_eq!(j["options"]["spp"], 4);
    std::fs::remove_dir_all(&dir).ok();
}

fn light(kind: penumbra_scene::LightKind, position: Vec3, color: Vec3, intensity: f32) -> penumbra_scene::Light {
    penumbra_scene::Light {
        name: "l".into(),
        kind,
        position,
        direction: Vec3::NEG_Y,
        color,
        intensity,
        motion: penumbra_scene::RigidMotion::Static,
        fixture: None,
    }
}

/// Image mean and its standard error per channel.
fn mean_se(r: &penumbra_reference::ReferenceImage) -> [(f64, f64); 3] {
    let n = r.radiance.pixels.len() as f64;
    [0, 1, 2].map(|c| {
        let m = r.radiance.pixels.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let se = r.std_error.pixels.iter().map(|p| (p[c] as f64).powi(2)).sum::<f64>().sqrt() / n;
        (m, se)
    })
}

/// Point light of intensity I at height h over a Lambertian plane point (no environment):
/// L_o = albedo / pi * I / h^2. A sphere light of radiance Le and radius R at height h:
/// irradiance pi Le (R/h)^2, so L_o = albedo Le (R/h)^2.
#[test]
fn local_lights_over_diffuse_plane() {
    let albedo = 0.7f32;
    let base = || {
        let mut s = plane_scene(
            Material::diffuse("d", Vec3::splat(albedo)),
            uniform_env([0.0; 3], 1.0),
            camera(Vec3::new(4.0, 1.5, 0.0), Vec3::ZERO, 0.02),
        );
        s.environment = None;
        s
    };
    let h = 2.0f32;
    let mut s = base();
    s.lights.push(light(penumbra_scene::LightKind::Point, Vec3::new(0.0, h, 0.0), Vec3::new(1.0, 2.0, 3.0), 5.0));
    let r = render(&s, &opts(2, 2, 16, 1)).unwrap();
    for (c, (m, se)) in mean_se(&r).into_iter().enumerate() {
        let expect = (albedo / std::f32::consts::PI * 5.0 * (c + 1) as f32 / (h * h)) as f64;
        eprintln!("point light: channel {c}: {m:.6} vs {expect:.6} (se {se:.1e})");
        assert!((m - expect).abs() <= 5.0 * se + 1e-4 * expect, "{m} vs {expect}");
    }
    let radius = 0.5f32;
    let mut s = base();
    s.lights.push(light(
        penumbra_scene::LightKind::Sphere { radius },
        Vec3::new(0.0, h, 0.0),
        Vec3::new(3.0, 2.0, 1.0),
        1.0,
    ));
    let r = render(&s, &opts(2, 2, 4096, 2)).unwrap();
    for (c, (m, se)) in mean_se(&r).into_iter().enumerate() {
        let expect = (albedo * (3 - c) as f32 * (radius / h).powi(2)) as f64;
        eprintln!("sphere light: channel {c}: {m:.6} vs {expect:.6} (se {se:.1e})");
        assert!((m - expect).abs() <= 5.0 * se, "{m} vs {expect}");
    }
}

/// Pure absorption between camera and surface: L = albedo L_env exp(-sigma_a d), d from the eye
/// (not from the near plane, here 1 unit in front of it, where the primary ray starts; the GPU
/// techniques' volumetric pass measures from the eye); the environment itself is not attenuated
/// on its way in, see the render module docs.
#[test]
fn absorbing_medium_attenuates_the_view_ray() {
    let albedo = Vec3::new(0.5, 0.6, 0.7);
    let eye = Vec3::new(0.0, 3.0, 3.0);
    let cam = Camera { near: 1.0, ..camera(eye, Vec3::ZERO, 0.005) };
    let mut s = plane_scene(Material::diffuse("d", albedo), uniform_env([1.0; 3], 1.0), cam);
    let sa = Vec3::new(0.1, 0.2, 0.3);
    s.medium = Some(penumbra_scene::Medium { sigma_a: sa, sigma_s: Vec3::ZERO, g: 0.0 });
    let r = render(&s, &opts(2, 2, 2048, 3)).unwrap();
    let dist = eye.length();
    for (c, (m, se)) in mean_se(&r).into_iter().enumerate() {
        let expect = (albedo[c] * (-sa[c] * dist).exp()) as f64;
        eprintln!("absorbing medium: channel {c}: {m:.6} vs {expect:.6} (se {se:.1e})");
        assert!((m - expect).abs() <= 5.0 * se + 1e-4 * expect, "{m} vs {expect}");
    }
}

/// Single scattering of a point light in an infinite homogeneous medium (no surfaces), seen
/// along a camera ray: L = integral_0^inf T(t) sigma_s p(wi . d) I T(r) / r^2 dt, evaluated
/// here by composite Simpson quadrature in f64 for a forward-scattering Henyey-Greenstein
/// medium.
#[test]
fn single_scattering_of_a_point_light_matches_quadrature() {
    let eye = Vec3::ZERO;
    let mut s = plane_scene(
        Material::diffuse("d", Vec3::ONE),
        uniform_env([0.0; 3], 1.0),
        camera(eye, Vec3::new(0.0, 0.0, -1.0), 0.01),
    );
    s.objects.clear();
    s.environment = None;
    let p = Vec3::new(0.0, 1.0, -3.0);
    let i0 = 10.0f32;
    s.lights.push(light(penumbra_scene::LightKind::Point, p, Vec3::ONE, i0));
    let (sa, ss, g) = (0.05f32, Vec3::new(0.1, 0.2, 0.3), 0.6f32);
    s.medium = Some(penumbra_scene::Medium { sigma_a: Vec3::splat(sa), sigma_s: ss, g });
    let r = render(&s, &opts(1, 1, 200_000, 4)).unwrap();
    let [(m0, se0), (m1, se1), (m2, se2)] = mean_se(&r);
    let hg = |c: f64| {
        let g = g as f64;
        (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * c).powf(1.5))
    };
    for (c, (m, se)) in [(m0, se0), (m1, se1), (m2, se2)].into_iter().enumerate() {
        let st = (sa + ss[c]) as f64;
        let f = |t: f64| {
            let x = [0.0, 0.0, -t];
            let v = [p.x as f64 - x[0], p.y as f64 - x[1], p.z as f64 - x[2]];
            let rr = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let cos = -v[2] / rr; // wi . d with d = -Z
            (-st * t).exp() * ss[c] as f64 * hg(cos) * i0 as f64 * (-st * rr).exp() / (rr * rr)
        };
        // From the eye (the primary ray starts on the near plane, 0.01 in front of it).
        let (t0, t1, n) = (0.0f64, 200.0f64, 400_000usize);
        let hstep = (t1 - t0) / n as f64;
        let mut acc = f(t0) + f(t1);
        for k in 1..n {
            acc += f(t0 + k as f64 * hstep) * if k % 2 == 1 { 4.0 } else { 2.0 };
        }
        let expect = acc * hstep / 3.0;
        eprintln!("single scattering: channel {c}: {m:.6} vs quadrature {expect:.6} (se {se:.1e})");
        assert!((m - expect).abs() <= 5.0 * se, "{m} vs {expect} +- {se}");
    }
}

/// SG-lighting mode on an unoccluded Lambertian plane: the pixel must equal
/// albedo / pi * integral over the upper hemisphere of (sum of the fitted SG lobes, rotated and
/// scaled like the map) * cos, computed here by midpoint quadrature.
#[test]
fn sg_lighting_mode_matches_quadrature_of_the_fit() {
    let mut env = Environment::procedural_sky(32, 16);
    env.rotation = 0.5;
    env.intensity = 2.0;
    let k = 6usize;
    let fit = penumbra_math::envmap::fit_sg_lighting(32, 16, &env.texels, k).unwrap();
    let albedo = 0.5f32;
    let s = plane_scene(
        Material::diffuse("d", Vec3::splat(albedo)),
        env,
        camera(Vec3::new(0.0, 3.0, 3.0), Vec3::ZERO, 0.01),
    );
    let o = ReferenceOptions { mode: penumbra_reference::Mode::SgLighting, sg_lobes: k as u32, ..opts(2, 2, 4096, 9) };
    let r = render(&s, &o).unwrap();
    assert_eq!(r.sg_fit_rel_l2, Some(fit.rel_l2_error));
    // Quadrature: E = int_{y > 0} L(R_y(rot) d_map) ... expressed in world space:
    // L_world(w) = intensity * sum_k mu_k exp(lambda_k (dot(R axis_k, w) - 1)).
    let rot = glam::DQuat::from_rotation_y(0.5);
    let e = upper_hemisphere_integral(400, 800, |w| {
        let l: glam::DVec3 =
            fit.lobes.iter().map(|g| g.mu * 2.0 * (g.lambda * ((rot * g.axis).dot(w) - 1.0)).exp()).sum();
        l * w.y
    });
    for (c, (m, se)) in mean_se(&r).into_iter().enumerate() {
        let expect = albedo as f64 / std::f64::consts::PI * e[c];
        eprintln!(
            "SG lighting ({} lobes, fit error {:.3}): channel {c}: {m:.5} vs {expect:.5} (se {se:.1e})",
            fit.lobes.len(),
            fit.rel_l2_error
        );
        assert!((m - expect).abs() <= 5.0 * se + 1e-4 * expect, "{m} vs {expect}");
    }
}

/// Frame K is the scene at time K / fps: a sphere oscillating along X (quarter period = 1 s)
/// is left of centre at frame 0 and right of centre at frame 30; an explicit time of 1 s gives
/// the same image as frame 30.
#[test]
fn frame_time_moves_objects() {
    let mut scene = sphere_left_of_centre("mover");
    scene.object_info = vec![
        penumbra_scene::ObjectInfo::default(),
        penumbra_scene::ObjectInfo {
            motion: penumbra_scene::RigidMotion::Oscillate {
                amplitude: Vec3::new(2.4, 0.0, 0.0),
                period: 4.0,
                phase: 0.0,
            },
            ..Default::default()
        },
    ];
    let sky = [0.0, 0.0, 1.0];
    let f0 = render(&scene, &opts(16, 8, 4, 0)).unwrap();
    assert_ne!(f0.radiance.get(5, 3), sky);
    assert_eq!(f0.radiance.get(10, 3), sky);
    let f30 = render(&scene, &ReferenceOptions { frame: 30, ..opts(16, 8, 4, 0) }).unwrap();
    assert_eq!(f30.time_s, 1.0);
    assert_eq!(f30.radiance.get(5, 3), sky);
    assert_ne!(f30.radiance.get(10, 3), sky);
    let t1 = render(&scene, &ReferenceOptions { time: Some(1.0), ..opts(16, 8, 4, 0) }).unwrap();
    assert_eq!(t1.radiance, f30.radiance);
}

/// Full SG mode on an unoccluded Blinn-Phong plane: the pixel must equal the quadrature of
/// (SG lighting) x (albedo / pi + specular x the math crate's warped SG lobe for this wo) x cos
/// over the upper hemisphere.
#[test]
fn sg_mode_matches_quadrature_of_sg_lighting_and_sg_brdf() {
    let mut env = Environment::procedural_sky(32, 16);
    env.rotation = -0.8;
    let k = 6usize;
    let fit = penumbra_math::envmap::fit_sg_lighting(32, 16, &env.texels, k).unwrap();
    let (albedo, spec, s) = (0.2f32, 0.8f32, 30.0f32);
    let mat = Material::blinn_phong("bp", Vec3::splat(albedo), Vec3::splat(spec), s);
    let eye = Vec3::new(0.0, 3.0, 3.0);
    let scene = plane_scene(mat, env, camera(eye, Vec3::ZERO, 0.01));
    let o = ReferenceOptions { mode: penumbra_reference::Mode::Sg, sg_lobes: k as u32, ..opts(2, 2, 4096, 11) };
    let r = render(&scene, &o).unwrap();
    // The plane's shading frame: tangent +X (dP/du), normal +Y, bitangent n x t = -Z.
    let (tx, by, nz) = (glam::DVec3::X, glam::DVec3::NEG_Z, glam::DVec3::Y);
    let wo = eye.as_dvec3().normalize();
    let wo_l = glam::DVec3::new(wo.dot(tx), wo.dot(by), wo.dot(nz));
    let lobe = penumbra_math::brdf::BlinnPhong { shininess: s as f64 }.sg_warp(wo_l);
    let rot = glam::DQuat::from_rotation_y(-0.8);
    let acc = upper_hemisphere_integral(600, 1200, |w| {
        let l: glam::DVec3 = fit.lobes.iter().map(|g| g.mu * (g.lambda * ((rot * g.axis).dot(w) - 1.0)).exp()).sum();
        let wl = glam::DVec3::new(w.dot(tx), w.dot(by), w.dot(nz));
        let f = albedo as f64 / std::f64::consts::PI + spec as f64 * lobe.eval(wl);
        l * f * w.y
    });
    for (c, (m, se)) in mean_se(&r).into_iter().enumerate() {
        eprintln!("SG mode: channel {c}: {m:.5} vs quadrature {:.5} (se {se:.1e})", acc[c]);
        assert!((m - acc[c]).abs() <= 5.0 * se + 1e-4 * acc[c], "{m} vs {}", acc[c]);
    }
    // For information: the exact mode on the same pixel (the SG approximations' effect).
    let ex = render(&scene, &ReferenceOptions { mode: penumbra_reference::Mode::Exact, ..o }).unwrap();
    eprintln!("exact mode: {:?}", mean_se(&ex));
}

/// An infinite medium lit by a uniform environment L (not attenuated on its way in, see the
/// render module docs), no surfaces: every camera ray sees
/// integral_0^inf exp(-sigma_t t) sigma_s L dt = (sigma_s / sigma_t) L, for any phase function.
#[test]
fn medium_under_uniform_environment() {
    let mut s = plane_scene(
        Material::diffuse("d", Vec3::ONE),
        uniform_env([2.0, 1.0, 0.5], 1.0),
        camera(Vec3::ZERO, Vec3::new(0.0, 0.3, -1.0), 50.0),
    );
    s.objects.clear();
    let (sa, ss) = (Vec3::new(0.1, 0.2, 0.05), Vec3::new(0.3, 0.1, 0.2));
    s.medium = Some(penumbra_scene::Medium { sigma_a: sa, sigma_s: ss, g: 0.7 });
    let r = render(&s, &opts(4, 4, 256, 12)).unwrap();
    for (c, (m, se)) in mean_se(&r).into_iter().enumerate() {
        let expect = (ss[c] / (sa[c] + ss[c]) * [2.0, 1.0, 0.5][c]) as f64;
        eprintln!("medium under uniform env: channel {c}: {m:.5} vs {expect:.5} (se {se:.1e})");
        assert!((m - expect).abs() <= 5.0 * se + 1e-5, "{m} vs {expect}");
    }
}

/// `pixel_grid`: primary rays through sub-pixel centres, as a rasterizer samples. A black ground
/// under a uniform sky makes every sample exactly 0 (ground) or the sky's radiance, so at grid 1
/// (pixel centres) every pixel is one or the other, while the jittered default mixes them along
/// the horizon; at grid 2 a pixel converges to the mean of the four pixel-centre values of the
/// same image at twice the size.
#[test]
fn pixel_grid_samples_sub_pixel_centres() {
    let sky = 0.8f32;
    let mut scene = plane_scene(
        Material::diffuse("black", Vec3::ZERO),
        uniform_env([sky; 3], 1.0),
        camera(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.3, 1.13, -1.0), 50.0),
    );
    // a tilted horizon crosses pixels at many sub-pixel offsets
    scene.camera.up = Vec3::new(0.35, 1.0, 0.0).normalize();
    let (w, h) = (12u32, 10u32);
    let is_pure = |v: [f32; 3]| v == [0.0; 3] || v == [sky; 3];
    let jittered = render(&scene, &opts(w, h, 64, 1)).unwrap();
    let mixed = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .filter(|&(x, y)| !is_pure(jittered.radiance.get(x, y)))
        .count();
    assert!(mixed >= 4, "the horizon should cross pixels: {mixed} mixed");
    let centre = render(&scene, &ReferenceOptions { pixel_grid: 1, ..opts(w, h, 8, 1) }).unwrap();
    for y in 0..h {
        for x in 0..w {
            assert!(
                is_pure(centre.radiance.get(x, y)),
                "pixel ({x}, {y}) mixes at grid 1: {:?}",
                centre.radiance.get(x, y)
            );
        }
    }
    let fine = render(&scene, &ReferenceOptions { pixel_grid: 1, ..opts(2 * w, 2 * h, 2, 1) }).unwrap();
    let grid2 = render(&scene, &ReferenceOptions { pixel_grid: 2, ..opts(w, h, 1024, 1) }).unwrap();
    for y in 0..h {
        for x in 0..w {
            let mean: f32 = (0..4).map(|k| fine.radiance.get(2 * x + k % 2, 2 * y + k / 2)[0]).sum::<f32>() / 4.0;
            let v = grid2.radiance.get(x, y)[0];
            // 1024 draws of the four centres: standard deviation at most 0.5 sky / 32
            assert!((v - mean).abs() <= 0.1 * sky, "pixel ({x}, {y}): grid 2 {v}, mean of the centres {mean}");
        }
    }
    assert!(penumbra_reference::render::validate(&ReferenceOptions { pixel_grid: 17, ..opts(w, h, 8, 1) }).is_err());
}

/// A grey plane under an environment of blue sky over a red ground (8 x 4 texels), seen from
/// 1 unit above the plane, and a sphere `name` of radius 0.8 left of the view's centre.
fn sphere_left_of_centre(name: &str) -> Scene {
    let texels = (0..32).map(|i| if i / 8 < 2 { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] }).collect();
    let env = Environment { width: 8, height: 4, texels, intensity: 1.0, rotation: 0.0 };
    let mut scene = plane_scene(
        Material::diffuse("d", Vec3::splat(0.5)),
        env,
        camera(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 1.0, -1.0), 60.0),
    );
    scene.meshes.push(MeshData::uv_sphere(0.8, 16, 8));
    scene.objects.push(Object {
        name: name.into(),
        mesh: 1,
        material: 0,
        transform: Mat4::from_translation(Vec3::new(-1.2, 1.0, -3.0)),
    });
    scene
}

/// The midpoint-rule integral of `f` over the hemisphere y > 0 (`nt` polar by `np` azimuthal
/// cells, each weighted by its solid angle).
fn upper_hemisphere_integral(nt: usize, np: usize, f: impl Fn(glam::DVec3) -> glam::DVec3) -> glam::DVec3 {
    let (dt, dp) = (std::f64::consts::FRAC_PI_2 / nt as f64, std::f64::consts::TAU / np as f64);
    let mut sum = glam::DVec3::ZERO;
    for i in 0..nt {
        let th = (i as f64 + 0.5) * dt;
        for j in 0..np {
            let ph = (j as f64 + 0.5) * dp;
            sum += f(glam::DVec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin())) * th.sin();
        }
    }
    sum * dt * dp
}
