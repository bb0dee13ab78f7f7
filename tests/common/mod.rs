//! Helpers shared by the integration tests (lavapipe).
#![allow(dead_code)]

use penumbra::{FrameImages, RenderSettings, Renderer};
use penumbra_scene::Scene;
use std::path::PathBuf;

/// `scenes/<name>`.
pub fn scene(name: &str) -> Scene {
    Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)).expect("scene")
}

/// `s` with `params` added to its `[technique_params]`.
pub fn with(s: &Scene, params: &[(&str, &str)]) -> Scene {
    let mut s = s.clone();
    for (k, v) in params {
        s.technique_params.insert(k.to_string(), v.to_string());
    }
    s
}

/// `s` with its environment replaced by a `w x h` lat-long map of texel `f(x, y)` (the scene
/// must have an environment).
pub fn with_env(s: &Scene, w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Scene {
    let mut s = s.clone();
    let e = s.environment.as_mut().expect("the scene has an environment");
    e.width = w as u32;
    e.height = h as u32;
    e.texels = (0..w * h).map(|i| f(i % w, i / w)).collect();
    s
}

/// Renders `scene` with `technique` at the given times (seconds, in order) and returns every
/// finished frame's images.
pub fn render_times(
    scene: &Scene,
    technique: &str,
    w: u32,
    h: u32,
    times: &[f32],
    validation: bool,
) -> (Renderer, Vec<FrameImages>) {
    let settings = RenderSettings::with_technique(w, h, technique, &scene.technique_params);
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

/// Renders `frames` frames of `scene` and returns every frame's images.
pub fn render_frames(scene: &Scene, w: u32, h: u32, frames: u32, validation: bool) -> (Renderer, Vec<FrameImages>) {
    let settings = RenderSettings { width: w, height: h, ..Default::default() };
    let mut r = Renderer::new_headless(scene, settings, validation).expect("renderer");
    let mut out = Vec::new();
    let mut prev = None;
    for k in 0..frames {
        let t = k as f32 / 30.0;
        let f = scene.at(t, prev);
        prev = Some(t);
        out.extend(r.render(&f, None, true).expect("render"));
    }
    out.extend(r.finish().expect("finish"));
    (r, out)
}

pub fn hdr_image(img: &FrameImages) -> penumbra_reference::image::Image {
    penumbra_reference::image::Image::from_fn(img.width, img.height, |x, y| {
        let p = img.hdr[(y * img.width + x) as usize];
        [p[0], p[1], p[2]]
    })
}

/// The default scene with only `meshes`, `materials` and `objects` (its environment and camera
/// kept; no material extras, object motion, material animations, lights, medium or camera path).
pub fn bare_scene(
    meshes: Vec<penumbra_scene::MeshData>,
    materials: Vec<penumbra_scene::Material>,
    objects: Vec<penumbra_scene::Object>,
) -> Scene {
    let mut s = Scene::default_scene();
    s.meshes = meshes;
    s.materials = materials;
    s.objects = objects;
    s.material_extras.clear();
    s.object_info.clear();
    s.material_animations.clear();
    s.lights.clear();
    s.medium = None;
    s.camera_path = None;
    s
}

/// The CPU reference of `s` at time 0 through the pixel centres (`spp` samples each) and
/// `technique`'s frame at time 0, rendered under validation (asserted clean).
pub fn reference_and_frame(
    s: &Scene,
    technique: &str,
    w: u32,
    h: u32,
    spp: u32,
) -> (penumbra_reference::image::Image, penumbra_reference::image::Image) {
    let reference = penumbra_reference::render(
        s,
        &penumbra_reference::ReferenceOptions { width: w, height: h, spp, pixel_grid: 1, ..Default::default() },
    )
    .unwrap()
    .radiance;
    (reference, validated_frame(s, technique, w, h))
}

/// `technique`'s frame of `s` at time 0, rendered under validation (asserted clean).
pub fn validated_frame(s: &Scene, technique: &str, w: u32, h: u32) -> penumbra_reference::image::Image {
    let (r, frames) = render_times(s, technique, w, h, &[0.0], true);
    let log = r.context().validation.clone();
    drop(r);
    assert_eq!(log.error_count(), 0, "{technique}: {:#?}", log.errors());
    hdr_image(frames.last().unwrap())
}

/// The G-buffer's octahedral encoding (`oct_decode` of `glsl/include/common.glsl`).
pub fn oct_decode(e: [f32; 2]) -> glam::Vec3 {
    let mut n = glam::Vec3::new(e[0], e[1], 1.0 - e[0].abs() - e[1].abs());
    if n.z < 0.0 {
        let (x, y) = (n.x, n.y);
        n.x = (1.0 - y.abs()) * if x >= 0.0 { 1.0 } else { -1.0 };
        n.y = (1.0 - x.abs()) * if y >= 0.0 { 1.0 } else { -1.0 };
    }
    n.normalize()
}

/// The geometric normal `gb_position.w` holds (`gb_geometric_normal` of `glsl/include/common.glsl`:
/// octahedral, 11 bits per coordinate, as the integer 1 + qx + 2048 qy).
pub fn geometric_normal(w: f32) -> glam::Vec3 {
    let u = (w.max(1.0) as u32) - 1;
    let e = |q: u32| q as f32 / 2047.0 * 2.0 - 1.0;
    oct_decode([e(u & 2047), e(u >> 11)])
}

/// Mean of the RGB sums of `img`'s pixels in columns `xs` and rows `ys`.
pub fn box_mean(img: &penumbra_reference::image::Image, xs: std::ops::Range<u32>, ys: std::ops::Range<u32>) -> f64 {
    let n = (xs.len() * ys.len()).max(1) as f64;
    let sum: f64 = ys
        .flat_map(|py| xs.clone().map(move |px| (px, py)))
        .map(|(px, py)| img.get(px, py).iter().map(|&x| x as f64).sum::<f64>())
        .sum();
    sum / n
}

/// The CPU reference of `scene` at `w x h`, `spp` samples per pixel, at `t` seconds, in `mode`
/// (every other option at its default).
pub fn reference_at(
    scene: &Scene,
    (w, h): (u32, u32),
    spp: u32,
    t: f32,
    mode: penumbra_reference::render::Mode,
) -> penumbra_reference::render::ReferenceImage {
    let opts = penumbra_reference::render::ReferenceOptions {
        width: w,
        height: h,
        spp,
        time: Some(t),
        mode,
        ..Default::default()
    };
    penumbra_reference::render::render(scene, &opts).expect("reference")
}
