//! Every built-in scene (and a bare glTF model) renders on the device with validation clean.

mod common;

use common::render_frames;
use penumbra_scene::Scene;
use std::path::PathBuf;

fn scene_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut v: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().map_or(false, |e| e == "toml"))
        .collect();
    v.sort();
    v
}

#[test]
fn every_builtin_scene_renders_validation_clean() {
    std::env::set_var("PENUMBRA_QUIET_VALIDATION", "1");
    let files = scene_files();
    assert!(files.len() >= 6, "expected the built-in scenes, found {files:?}");
    let mut failures = Vec::new();
    for f in files {
        let scene = Scene::load(&f).unwrap_or_else(|e| panic!("{e}"));
        let (r, frames) = render_frames(&scene, 96, 72, 3, true);
        let log = r.context().validation.clone();
        let graph = r.last_graph.clone().unwrap();
        drop(r);
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        if log.error_count() > 0 {
            failures.push(format!("{name}: {} validation errors: {:?}", log.error_count(), log.errors()));
        }
        if frames.len() != 3 || frames.iter().any(|fr| fr.hdr.iter().flatten().any(|c| !c.is_finite())) {
            failures.push(format!("{name}: missing frames or non-finite radiance"));
        }
        let lit = frames[2].hdr.iter().filter(|p| p[0] + p[1] + p[2] > 1e-4).count();
        if lit < frames[2].hdr.len() / 20 {
            failures.push(format!("{name}: only {lit} lit pixels"));
        }
        // The graph has the passes this scene needs: G-buffer first, tone mapping and readback
        // last, and volumetric passes only for scenes with a participating medium.
        let passes: Vec<_> = graph.live_passes().map(|(_, p)| p.name.clone()).collect();
        let n = passes.len();
        if n < 4 || passes[0] != "gbuffer" || passes[n - 2] != "tonemap" || passes[n - 1] != "readback" {
            failures.push(format!("{name}: unexpected passes {passes:?}"));
        }
        if !scene.requirements().medium && passes.iter().any(|p| p.starts_with("vol")) {
            failures.push(format!("{name}: volumetric passes without a medium: {passes:?}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn a_bare_gltf_model_is_a_scene() {
    let model = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/assets/bunny.glb");
    let scene = Scene::load(&model).expect("bare model");
    let (r, frames) = render_frames(&scene, 96, 72, 1, false);
    drop(r);
    let f = &frames[0];
    assert!(f.hdr.iter().flatten().all(|c| c.is_finite()));
    let lum = |x: u32, y: u32| {
        let p = f.hdr[(y * f.width + x) as usize];
        0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]
    };
    // The camera frames the model: the image centre shows it, unlike the top corners (sky).
    let centre: f32 = (40..56).flat_map(|x| (30..42).map(move |y| (x, y))).map(|(x, y)| lum(x, y)).sum::<f32>() / 192.0;
    let corner = 0.5 * (lum(1, 1) + lum(94, 1));
    assert!(centre > 0.01, "bare model renders black");
    assert!(
        (centre - corner).abs() > 0.05 * corner.max(centre),
        "no model in the centre: centre {centre}, corner {corner}"
    );
}
