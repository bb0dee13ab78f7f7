//! The G-buffer holds what it claims: world positions on the right objects, unit normals through
//! fp16 octahedral encoding (including the poles), instance ids, zero motion for a static frame.

mod common;

use common::{geometric_normal, oct_decode};
use penumbra::{RenderSettings, Renderer};
use penumbra_scene::Scene;

#[test]
fn gbuffer_positions_normals_ids_and_motion() {
    let scene = Scene::default_scene();
    let sphere = scene.objects.iter().position(|o| o.name == "sphere").expect("default scene has a sphere");
    let centre = scene.objects[sphere].transform.w_axis.truncate();
    let radius = scene.meshes[scene.objects[sphere].mesh].bounds().map(|(lo, hi)| 0.5 * (hi.x - lo.x)).unwrap();
    let settings = RenderSettings { width: 160, height: 120, dump_passes: true, ..Default::default() };
    let mut r = Renderer::new_headless(&scene, settings, false).unwrap();
    let f = scene.at(0.0, None);
    let mut out = r.render(&f, None, true).unwrap();
    out.extend(r.finish().unwrap());
    let img = &out[0];
    let get = |name: &str| &img.dumps.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no dump {name}")).1;
    let (pos, nrm, ids, motion) = (get("gb_position"), get("gb_normal"), get("gb_uv_mat"), get("gb_motion"));
    let mut sphere_px = 0;
    let mut worst_dot: f32 = 1.0;
    let mut worst_radius: f32 = 0.0;
    let mut up_facing = 0;
    // the face's normal in gb_position.w: within the facets' angle of the radial direction, on
    // the vertex normal's side, and the face's (not the interpolated normal)
    let (mut worst_ng, mut faceted) = (1.0f32, 0usize);
    for i in 0..pos.len() {
        if ids[i][3] < 0.5 {
            assert_eq!(pos[i][3], 0.0, "sky pixel {i} marked covered");
            continue; // sky
        }
        assert!(pos[i][3] >= 1.0, "covered pixel {i} without a geometric normal: {}", pos[i][3]);
        assert_eq!(motion[i][0], 0.0, "static frame has motion");
        assert_eq!(motion[i][1], 0.0, "static frame has motion");
        let n = oct_decode([nrm[i][0], nrm[i][1]]);
        assert!((n.length() - 1.0).abs() < 1e-3);
        let t = oct_decode([nrm[i][2], nrm[i][3]]);
        assert!(n.dot(t).abs() < 2e-2, "tangent not orthogonal to normal: {}", n.dot(t));
        if (ids[i][3] - 1.0).round() as usize == sphere {
            sphere_px += 1;
            let p = glam::Vec3::new(pos[i][0], pos[i][1], pos[i][2]);
            worst_radius = worst_radius.max(((p - centre).length() - radius).abs());
            worst_dot = worst_dot.min(n.dot((p - centre).normalize()));
            let ng = geometric_normal(pos[i][3]);
            worst_ng = worst_ng.min(ng.dot((p - centre).normalize()));
            assert!(ng.dot(n) > 0.0, "geometric normal {ng} against the shading normal {n}");
            faceted += (ng.dot(n) < 0.9999) as usize;
            if n.y > 0.99 {
                up_facing += 1;
            }
        }
    }
    assert!(sphere_px > 500, "sphere covers {sphere_px} pixels");
    // 48x24 tessellation: chords deviate from the sphere by at most r(1 - cos(pi/24)) = 0.006.
    assert!(worst_radius < 0.0065, "positions off the sphere by {worst_radius}");
    // Interpolated vertex normals vs the exact radial direction, through fp16 octahedral storage.
    assert!(worst_dot > 0.999, "normal error: dot {worst_dot}");
    assert!(up_facing > 0, "no pixel near the +Y pole of the sphere");
    // 48x24 facets: a face's normal is within ~5.3 degrees of the radial direction at any of
    // its points (plus 0.1 degree of 11-bit octahedral storage)
    assert!(worst_ng > 0.9925, "geometric normal off the radial direction: dot {worst_ng}");
    assert!(
        faceted > sphere_px / 2,
        "only {faceted} of {sphere_px} pixels have a face normal unlike the interpolated one"
    );
}

#[test]
fn motion_vectors_match_reprojection_of_moving_objects() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/falling.toml");
    let scene = Scene::load(&path).unwrap();
    let (w, h) = (160u32, 120u32);
    let settings = RenderSettings { width: w, height: h, dump_passes: true, frames_in_flight: 1, ..Default::default() };
    let mut r = Renderer::new_headless(&scene, settings, false).unwrap();
    let (t0, t1) = (4.0 / 30.0, 5.0 / 30.0);
    r.render(&scene.at(t0, None), None, false).unwrap();
    let f = scene.at(t1, Some(t0));
    assert!(f.any_moved(), "falling scene must move between frames 4 and 5");
    let mut out = r.render(&f, None, true).unwrap();
    out.extend(r.finish().unwrap());
    let img = out.last().unwrap();
    let get = |name: &str| &img.dumps.iter().find(|(n, _)| n == name).unwrap().1;
    let (pos, ids, motion) = (get("gb_position"), get("gb_uv_mat"), get("gb_motion"));
    let aspect = w as f32 / h as f32;
    let vp = f.camera.proj(aspect) * f.camera.view();
    let prev_vp = f.prev_camera.proj(aspect) * f.prev_camera.view();
    let to_px = |m: glam::Mat4, p: glam::Vec3| {
        let c = m * p.extend(1.0);
        glam::Vec2::new(c.x / c.w, c.y / c.w) * 0.5 * glam::Vec2::new(w as f32, h as f32)
    };
    let (mut checked, mut moving, mut worst) = (0, 0, 0.0f32);
    for i in 0..pos.len() {
        if ids[i][3] < 0.5 {
            continue;
        }
        let inst = &f.instances[(ids[i][3] - 1.0).round() as usize];
        if inst.deformed_mesh.is_some() {
            continue;
        }
        let p = glam::Vec3::new(pos[i][0], pos[i][1], pos[i][2]);
        let p_obj = inst.world.inverse().transform_point3(p);
        let prev = inst.prev_world.transform_point3(p_obj);
        let want = to_px(vp, p) - to_px(prev_vp, prev);
        let got = glam::Vec2::new(motion[i][0], motion[i][1]);
        let err = (want - got).length();
        // fp16 storage of pixel offsets: relative 1e-3 plus interpolation/rounding slack.
        worst = worst.max(err / (1.0 + want.length()));
        checked += 1;
        if want.length() > 0.5 {
            moving += 1;
        }
    }
    assert!(checked > 1000 && moving > 50, "checked {checked}, moving {moving}");
    assert!(worst < 0.02, "motion vector error {worst} (relative to 1 + |motion| px)");
}

/// Two-sided shading follows the reference's rule (render.rs; mc.comp): the face's normal on the
/// vertex normals' side, turned towards the viewer, the vertex normal on its side. Flipping by
/// the rasterizer's facing instead shaded every triangle whose vertex normals disagree with its
/// winding from behind: black. Two walls facing the camera under a uniform sky, one wound
/// clockwise with its normals towards the camera, one counter-clockwise with them away: the
/// reference lights both (albedo x sky), and so must `env` through the G-buffer.
#[test]
fn vertex_normals_against_the_winding_shade_as_in_the_reference() {
    use glam::{Mat4, Vec2, Vec3};
    use penumbra_scene::{Material, MeshData, Object};
    let sky = 0.8f32;
    let wall = |x0: f32, clockwise: bool, nz: f32| {
        let positions = vec![
            Vec3::new(x0, -0.5, 0.0),
            Vec3::new(x0 + 1.0, -0.5, 0.0),
            Vec3::new(x0 + 1.0, 0.5, 0.0),
            Vec3::new(x0, 0.5, 0.0),
        ];
        let indices = if clockwise { vec![0, 2, 1, 0, 3, 2] } else { vec![0, 1, 2, 0, 2, 3] };
        MeshData {
            name: format!("wall{x0}"),
            positions,
            normals: vec![Vec3::new(0.0, 0.0, nz); 4],
            uvs: vec![Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y],
            indices,
        }
    };
    // seen from +z: clockwise winding faces away, so its normals (+z) disagree; the second's
    // winding faces the camera and its normals (-z) do not
    let mut s = common::bare_scene(
        vec![wall(-1.2, true, 1.0), wall(0.2, false, -1.0)],
        vec![Material::diffuse("grey", Vec3::splat(0.5))],
        (0..2).map(|i| Object { name: format!("wall{i}"), mesh: i, material: 0, transform: Mat4::IDENTITY }).collect(),
    );
    s.camera.eye = Vec3::new(0.0, 0.0, 3.0);
    s.camera.target = Vec3::ZERO;
    s.camera.up = Vec3::Y;
    s.camera.fov_y_deg = 40.0;
    let s = common::with_env(&s, 8, 4, |_, _| [sky; 3]);
    let lit = 0.5 * sky * s.environment.as_ref().unwrap().intensity;
    let (w, h) = (48u32, 24u32);
    let (reference, img) = common::reference_and_frame(&s, "env", w, h, 16);
    let mut walls = [0usize; 2];
    for y in 0..h {
        for x in 0..w {
            let (g, rf) = (img.get(x, y)[0], reference.get(x, y)[0]);
            // the walls' pixels: the reference's lit value (the sky behind is `sky`, brighter)
            if (rf - lit).abs() > 0.05 * lit {
                continue;
            }
            walls[(x >= w / 2) as usize] += 1;
            assert!((g - lit).abs() < 0.05 * lit, "pixel ({x}, {y}) of the wall: {g}, the reference's {rf}");
        }
    }
    assert!(walls.iter().all(|&n| n >= 60), "walls' pixels (left, right): {walls:?}");
}

/// Where the eye sees a triangle whose (interpolated, or normal-mapped) shading normal faces away
/// from it, as at the silhouette of a smooth low-poly mesh, the shading normal is turned towards
/// the eye until n.v = 0.01 (render.rs `facing_normal`, material.glsl `material_facing_normal`)
/// instead of the BRDF reading zero: such pixels drew black, and a pixel centre that the
/// rasterizer's sub-pixel snapping put on a sliver triangle the reference's ray missed by 1e-4
/// pixel made `vv_coarse`'s 40x30 isg cells fail. A wall seen from the side whose vertex normals
/// lean away from the eye (n.v from -0.57 to -0.74): not black in the reference, `env` shades
/// it as a surface seen at a grazing angle (albedo x sky under a uniform sky), and `mc`, which
/// traces the reference's estimator on the GPU, agrees with the reference.
#[test]
fn normals_facing_away_from_the_eye_are_turned_to_it_not_drawn_black() {
    use glam::{Mat4, Vec2, Vec3};
    use penumbra_scene::{Material, MeshData, Object};
    let sky = 0.8f32;
    let n = Vec3::new(-1.0, 0.0, 0.3).normalize();
    let wall = MeshData {
        name: "wall".into(),
        positions: vec![
            Vec3::new(-0.5, -0.5, 0.0),
            Vec3::new(0.5, -0.5, 0.0),
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::new(-0.5, 0.5, 0.0),
        ],
        normals: vec![n; 4],
        uvs: vec![Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y],
        indices: vec![0, 1, 2, 0, 2, 3],
    };
    let mut s = common::bare_scene(
        vec![wall],
        vec![Material::diffuse("grey", Vec3::splat(0.5))],
        vec![Object { name: "wall".into(), mesh: 0, material: 0, transform: Mat4::IDENTITY }],
    );
    s.camera.eye = Vec3::new(2.0, 0.0, 1.2);
    s.camera.target = Vec3::ZERO;
    s.camera.up = Vec3::Y;
    s.camera.fov_y_deg = 40.0;
    let s = common::with_env(&s, 8, 4, |_, _| [sky; 3]);
    let sky = sky * s.environment.as_ref().unwrap().intensity;
    let lit = 0.5 * sky;
    let (w, h) = (40u32, 30u32);
    let (reference, env) = common::reference_and_frame(&s, "env", w, h, 256);
    let mc = common::validated_frame(&s, "mc", w, h);
    let is_wall = |x: u32, y: u32| (env.get(x, y)[0] - sky).abs() >= 0.01 * sky; // else the sky
    let (mut wall_px, mut inner, mut sum_ref, mut sum_mc) = (0usize, 0usize, 0.0f64, 0.0f64);
    for y in 0..h {
        for x in 0..w {
            if !is_wall(x, y) {
                continue;
            }
            wall_px += 1;
            let g = env.get(x, y)[0];
            assert!((g - lit).abs() < 0.05 * lit, "env at ({x}, {y}): {g}, want albedo x sky = {lit}");
            let rf = reference.get(x, y)[0];
            // light from below the wall's plane is blocked by it: between a quarter and all of lit
            assert!(rf > 0.25 * lit && rf < 1.02 * lit, "reference at ({x}, {y}): {rf} (lit {lit})");
            // mc's rays spread over the pixel: away from the wall's outline, where they see sky
            let edge = x == 0 || y == 0 || x + 1 == w || y + 1 == h;
            if edge || !(is_wall(x - 1, y) && is_wall(x + 1, y) && is_wall(x, y - 1) && is_wall(x, y + 1)) {
                continue;
            }
            inner += 1;
            sum_ref += rf as f64;
            sum_mc += mc.get(x, y)[0] as f64;
        }
    }
    assert!(wall_px >= 100 && inner >= 60, "{wall_px} wall pixels, {inner} inside its outline");
    let rel = (sum_mc - sum_ref).abs() / sum_ref;
    assert!(rel < 0.05, "mc's wall {sum_mc} against the reference's {sum_ref}: {rel}");
}
