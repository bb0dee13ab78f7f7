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
    let settings = RenderSettings {
        width: w,
        height: h,
        technique: Some(technique.into()),
        technique_params: Some(scene.technique_params.clone()),
        ..Default::default()
    };
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
