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

/// Passes of each of `frames` consecutive frames of `scene` rendered with `technique`.
fn passes_per_frame(scene: &Scene, technique: &str, frames: u32) -> Vec<Vec<String>> {
    let settings = penumbra::RenderSettings {
        width: 32,
        height: 24,
        technique: Some(technique.into()),
        frames_in_flight: 1,
        ..Default::default()
    };
    let mut r = penumbra::Renderer::new_headless(scene, settings, false).unwrap();
    let mut out = Vec::new();
    let mut prev = None;
    for k in 0..frames {
        let t = k as f32 / 30.0;
        r.render(&scene.at(t, prev), None, false).unwrap();
        prev = Some(t);
        out.push(r.last_graph.as_ref().unwrap().live_passes().map(|(_, p)| p.name.clone()).collect());
    }
    r.finish().unwrap();
    out
}

#[test]
fn acceleration_structures_are_rebuilt_only_for_changing_geometry() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let builds = |passes: &Vec<String>| passes.iter().filter(|p| p.starts_with("kdtree_")).count();
    // chess: static geometry (only its materials animate).
    let chess = Scene::load(dir.join("chess.toml")).unwrap();
    assert!(chess.requirements().is_static_geometry());
    let frames = passes_per_frame(&chess, "mc", 3);
    assert!(builds(&frames[0]) > 0, "the first frame builds the kd-tree: {:?}", frames[0]);
    assert_eq!(builds(&frames[1]), 0, "static scene rebuilt its kd-tree: {:?}", frames[1]);
    assert_eq!(builds(&frames[2]), 0, "static scene rebuilt its kd-tree: {:?}", frames[2]);
    // falling: objects move every frame.
    let falling = Scene::load(dir.join("falling.toml")).unwrap();
    assert!(!falling.requirements().is_static_geometry());
    let frames = passes_per_frame(&falling, "mc", 3);
    assert!(frames.iter().all(|f| builds(f) > 0), "moving scene must rebuild every frame: {frames:?}");
}

#[test]
fn every_implemented_technique_renders_through_the_renderer_validation_clean() {
    std::env::set_var("PENUMBRA_QUIET_VALIDATION", "1");
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    // A textured static scene and a moving one.
    let scenes = [Scene::load(dir.join("chess.toml")).unwrap(), Scene::load(dir.join("falling.toml")).unwrap()];
    let mut failures = Vec::new();
    for technique in penumbra_passes::technique::IMPLEMENTED {
        if penumbra_passes::technique::STATIC_ONLY.contains(technique) {
            // Static geometry only (tests/vv.rs renders its static scene through the renderer,
            // validation clean): the moving scene must be refused with a message naming why.
            let settings = penumbra::RenderSettings {
                width: 48,
                height: 36,
                technique: Some(technique.to_string()),
                ..Default::default()
            };
            match penumbra::Renderer::new_headless(&scenes[1], settings, false) {
                Ok(_) => failures.push(format!("{technique}/falling: a static-only technique accepted a moving scene")),
                Err(e) if format!("{e:#}").contains("static") => {}
                Err(e) => failures.push(format!("{technique}/falling: unclear refusal: {e:#}")),
            }
            continue;
        }
        for scene in &scenes {
            let settings = penumbra::RenderSettings {
                width: 48,
                height: 36,
                technique: Some(technique.to_string()),
                ..Default::default()
            };
            let mut r = match penumbra::Renderer::new_headless(scene, settings, true) {
                Ok(r) => r,
                Err(e) => {
                    failures.push(format!("{technique}/{}: {e:#}", scene.name));
                    continue;
                }
            };
            let mut frames = Vec::new();
            let mut prev = None;
            for k in 0..2 {
                let t = k as f32 / 30.0;
                match r.render(&scene.at(t, prev), None, true) {
                    Ok(f) => frames.extend(f),
                    Err(e) => failures.push(format!("{technique}/{} frame {k}: {e:#}", scene.name)),
                }
                prev = Some(t);
            }
            frames.extend(r.finish().unwrap_or_default());
            let log = r.context().validation.clone();
            drop(r);
            if log.error_count() > 0 {
                failures.push(format!(
                    "{technique}/{}: {} validation errors: {:?}",
                    scene.name,
                    log.error_count(),
                    log.errors()
                ));
            }
            if frames.len() != 2 || frames.iter().any(|f| f.hdr.iter().flatten().any(|c| !c.is_finite())) {
                failures.push(format!("{technique}/{}: missing frames or non-finite radiance", scene.name));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
