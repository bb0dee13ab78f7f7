//! Animation evaluation at known times: keyframe tracks, analytic rigid motions, lights,
//! camera paths, material animation, and the frame's moved / prev flags.

use glam::{Mat4, Quat, Vec3};
use penumbra_scene::{Interp, RigidMotion, Scene, Track};
use std::path::PathBuf;

#[test]
fn track_interpolation_clamping_and_looping() {
    let t = Track::new(vec![1.0, 3.0], vec![10.0f32, 20.0], Interp::Linear, false).unwrap();
    assert_eq!(t.sample(0.0), 10.0);
    assert_eq!(t.sample(2.0), 15.0);
    assert_eq!(t.sample(3.5), 20.0);
    assert_eq!(t.sample(f32::NAN), 10.0);
    let s = Track::new(vec![0.0, 1.0, 2.0], vec![1.0f32, 2.0, 3.0], Interp::Step, true).unwrap();
    assert_eq!(s.sample(0.99), 1.0);
    assert_eq!(s.sample(1.5), 2.0);
    assert_eq!(s.sample(2.5), 1.0, "loops with period 2");
    let q =
        Track::new(vec![0.0, 1.0], vec![Quat::IDENTITY, Quat::from_rotation_y(1.0)], Interp::Linear, false).unwrap();
    assert!(q.sample(0.5).abs_diff_eq(Quat::from_rotation_y(0.5), 1e-6));
    assert!(Track::new(vec![0.0, 0.0], vec![1.0f32, 2.0], Interp::Linear, false).is_err());
    assert!(Track::new(vec![], Vec::<f32>::new(), Interp::Linear, false).is_err());
    assert!(Track::new(vec![0.0], vec![1.0f32, 2.0], Interp::Linear, false).is_err());
}

#[test]
fn rolling_ball_does_not_slip() {
    let b = 0.2;
    let m = RigidMotion::Roll { center: Vec3::new(0.0, b, 0.0), radius: 0.8, ball_radius: b, period: 4.0, phase: 0.3 };
    for t in [0.0f32, 0.37, 1.9, 3.3] {
        let w = m.eval(t);
        let contact = w.transform_point3(Vec3::ZERO) - Vec3::Y * b;
        assert!(contact.y.abs() < 1e-5);
        // The material point at the contact has zero velocity.
        let body = w.inverse().transform_point3(contact);
        let h = 1e-3;
        let v = (m.eval(t + h).transform_point3(body) - m.eval(t - h).transform_point3(body)) / (2.0 * h);
        let speed = std::f32::consts::TAU / 4.0 * 0.8;
        assert!(v.length() < 0.01 * speed, "t={t}: contact slips at {v}");
        // Centre speed is the path speed; the transform stays rigid.
        let c = |t: f32| m.eval(t).transform_point3(Vec3::ZERO);
        assert!((((c(t + h) - c(t - h)) / (2.0 * h)).length() - speed).abs() < 1e-2);
        assert!((Mat4::from_mat3(glam::Mat3::from_mat4(w)).determinant() - 1.0).abs() < 1e-4);
    }
}

#[test]
fn falling_body_lands_and_settles() {
    let m = RigidMotion::Fall { height: 2.0, gravity: 9.81, restitution: 0.5, delay: 0.5, axis: Vec3::X, spin: 1.0 };
    let y = |t: f32| m.eval(t).transform_point3(Vec3::ZERO).y;
    assert_eq!(y(0.0), 2.0);
    assert_eq!(y(0.5), 2.0);
    let t1 = (2.0f32 * 2.0 / 9.81).sqrt();
    assert!((y(0.5 + t1 / 2.0) - (2.0 - 0.5 * 9.81 * (t1 / 2.0).powi(2))).abs() < 1e-5);
    assert!(y(0.5 + t1).abs() < 1e-4);
    // First bounce apex: e^2 h.
    let v = 9.81 * t1 * 0.5;
    assert!((y(0.5 + t1 + v / 9.81) - 0.5).abs() < 1e-3);
    // Never below the rest pose; at rest long after, in the rest orientation.
    for k in 0..200 {
        assert!(y(k as f32 * 0.05) >= -1e-6);
    }
    assert!(m.eval(30.0).abs_diff_eq(Mat4::IDENTITY, 1e-6));
    // Tumbling: rotated by `spin` at the start, not after landing.
    let r0 = m.eval(0.0).transform_vector3(Vec3::Y);
    assert!(r0.abs_diff_eq(Quat::from_rotation_x(1.0) * Vec3::Y, 1e-5));
}

fn scene_from(text: &str, name: &str) -> Scene {
    let dir =
        PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("penumbra-scene-{}-motion-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p: PathBuf = dir.join(format!("{name}.toml"));
    std::fs::write(&p, text).unwrap();
    Scene::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn keyframed_object_light_camera_and_material() {
    let s = scene_from(
        r#"
[camera]
eye = [0, 1, 5]
target = 0
keys = [{ t = 0, eye = [0, 1, 5], target = 0 }, { t = 2, eye = [2, 1, 5], target = [1, 0, 0] }]
[[light]]
type = "point"
position = [1, 2, 0]
intensity = 3
color = [1, 0.5, 0.25]
motion = { type = "spin", axis = [0, 1, 0], speed_deg = 90 }
[[light]]
type = "spot"
position = [0, 3, 0]
direction = [0, -1, 0]
intensity = 1
motion = { type = "keyframes", keys = [{ t = 0, rotation_deg = [0, 0, 0] }, { t = 1, rotation_deg = [0, 0, 90] }] }
[materials.m]
type = "blinn_phong"
albedo = 0.5
keys = [{ t = 0, roughness = 0.1, albedo = 0.5 }, { t = 2, roughness = 0.5, albedo = 0.7 }]
[[object]]
name = "box"
mesh = { type = "cube", size = 1 }
material = "m"
scale = 2
motion = { type = "keyframes", keys = [
  { t = 0, position = [0, 0, 0], rotation_deg = [0, 0, 0] },
  { t = 2, position = [4, 0, 0], rotation_deg = [0, 90, 0] },
] }
"#,
        "kf",
    );
    let r = s.requirements();
    assert!(r.moving_objects && r.animated_camera && r.animated_lights && r.animated_materials && r.local_lights);
    assert!(!r.environment_light && !r.deforming_objects);
    // Object at t = 1: halfway, rotated 45 degrees, scale 2 kept (world = M(t) * T R S).
    let w = s.world_at(0, 1.0);
    assert!(w.transform_point3(Vec3::ZERO).abs_diff_eq(Vec3::new(2.0, 0.0, 0.0), 1e-5));
    let x = w.transform_vector3(Vec3::X);
    let h = 2.0 * std::f32::consts::FRAC_1_SQRT_2;
    assert!(x.abs_diff_eq(Vec3::new(h, 0.0, -h), 1e-5), "{x}");
    let f = s.at(1.0, Some(0.5));
    assert!(f.instances[0].moved && f.camera_moved);
    assert!(f.instances[0].prev_world.transform_point3(Vec3::ZERO).abs_diff_eq(Vec3::new(1.0, 0.0, 0.0), 1e-5));
    assert!(f.camera.eye.abs_diff_eq(Vec3::new(1.0, 1.0, 5.0), 1e-6));
    assert!(f.prev_camera.eye.abs_diff_eq(Vec3::new(0.5, 1.0, 5.0), 1e-6));
    // Point light spun 90 degrees about Y at t = 1: (1,2,0) -> (0,2,-1).
    assert!(f.lights[0].position.abs_diff_eq(Vec3::new(0.0, 2.0, -1.0), 1e-5), "{}", f.lights[0].position);
    assert!(f.lights[0].moved);
    assert_eq!(f.lights[0].power, Vec3::new(3.0, 1.5, 0.75));
    // Spot turned 90 degrees about Z: pointing down becomes pointing +X.
    assert!(f.lights[1].direction.abs_diff_eq(Vec3::X, 1e-5), "{}", f.lights[1].direction);
    // Material: roughness 0.3, albedo 0.6 at t = 1, shininess follows.
    let m = &f.materials[0];
    assert!((m.roughness - 0.3).abs() < 1e-6 && (m.albedo.x - 0.6).abs() < 1e-6);
    assert!((m.shininess - (2.0 / 0.09 - 2.0)).abs() < 1e-3);
    assert_eq!(f.materials_changed, vec![0]);
    // After the last key everything holds: nothing changes between t = 3 and t = 4.
    let late = s.at(4.0, Some(3.0));
    assert!(!late.instances[0].moved && !late.camera_moved && late.materials_changed.is_empty());
    assert!(!late.lights[1].moved && late.lights[0].moved);
}

#[test]
fn static_objects_never_move() {
    let s = scene_from(
        "[camera]\neye = [0, 1, 5]\ntarget = 0\n[environment]\nprocedural = \"sky\"\nintensity = 2\nrotation_deg = 90\n[[object]]\nmesh = { type = \"torus\", major_radius = 1, minor_radius = 0.2 }\nposition = [1, 2, 3]\nmotion = { type = \"static\" }\n",
        "static",
    );
    let env = s.environment.as_ref().unwrap();
    assert_eq!(env.intensity, 2.0);
    assert!((env.rotation - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
    let r = s.requirements();
    assert!(r.is_static_geometry() && !r.animated_camera && !r.animated_lights && !r.animated_materials);
    for (t, p) in [(1.0, 0.0), (7.0, 6.9)] {
        let f = s.at(t, Some(p));
        assert!(!f.any_moved() && !f.any_deformed() && !f.camera_moved);
        assert_eq!(f.instances[0].world, Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)));
        assert!(f.instances[0].deformed_mesh.is_none());
    }
}

#[test]
fn environment_keys_turn_and_dim_the_lighting_over_time() {
    let s = scene_from(
        "[camera]\neye = [0, 1, 5]\ntarget = 0\n[environment]\nprocedural = \"sky\"\nintensity = 2\nrotation_deg = 10\nkeys = [{ t = 0, rotation_deg = 0, intensity = 1 }, { t = 2, rotation_deg = 90, intensity = 3 }]\n[[object]]\nmesh = { type = \"sphere\", radius = 1 }\n",
        "env_keys",
    );
    assert!(s.requirements().animated_environment);
    let f = s.at(1.0, Some(0.5));
    assert!((f.environment.rotation - 45f32.to_radians()).abs() < 1e-6, "{:?}", f.environment);
    assert!((f.environment.intensity - 2.0).abs() < 1e-6);
    assert!(f.environment_changed && !f.any_moved());
    // the first frame has no previous one; after the last key the lighting holds
    assert!(!s.at(1.0, None).environment_changed);
    let late = s.at(5.0, Some(4.0));
    assert!(!late.environment_changed && (late.environment.intensity - 3.0).abs() < 1e-6);
    // the loaded values stand without keys, and without an environment nothing lights
    let plain = scene_from(
        "[camera]\neye = [0, 1, 5]\ntarget = 0\n[environment]\nprocedural = \"sky\"\nintensity = 2\nrotation_deg = 90\n[[object]]\nmesh = { type = \"sphere\", radius = 1 }\n",
        "env_plain",
    );
    assert!(!plain.requirements().animated_environment);
    let e = plain.at(3.0, Some(2.0)).environment;
    assert_eq!(e, penumbra_scene::EnvironmentState { rotation: 90f32.to_radians(), intensity: 2.0 });
    let none = scene_from(
        "[camera]\neye = [0, 1, 5]\ntarget = 0\n[[object]]\nmesh = { type = \"sphere\", radius = 1 }\n",
        "no_env",
    );
    assert_eq!(none.at(0.0, None).environment, penumbra_scene::EnvironmentState::NONE);
}

#[test]
fn environment_keys_are_checked() {
    for (keys, want) in [
        ("[{ t = 0, rotation_deg = 0 }, { t = 1, intensity = 2 }]", "give `rotation_deg` in every key or in none"),
        ("[{ t = 0, intensity = -1 }]", "intensity must be finite and >= 0"),
        ("[{ t = 0 }, { t = 1 }]", "give rotation_deg or intensity in the keys"),
        ("[{ t = 1, intensity = 1 }, { t = 0, intensity = 2 }]", "environment.keys"),
    ] {
        let text = format!(
            "[camera]\neye = [0, 1, 5]\ntarget = 0\n[environment]\nprocedural = \"sky\"\nkeys = {keys}\n[[object]]\nmesh = {{ type = \"sphere\", radius = 1 }}\n"
        );
        let dir = std::env::temp_dir().join(format!("penumbra-envkeys-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bad.toml");
        std::fs::write(&path, text).unwrap();
        let err = penumbra_scene::Scene::load(&path).unwrap_err().to_string();
        assert!(err.contains(want) && err.contains("bad.toml"), "{keys}: {err}");
    }
}
