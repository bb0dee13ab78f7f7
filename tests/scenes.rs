//! Every built-in scene (and a bare glTF model) renders on the device with validation clean and
//! the frame graph its requirements call for; every registered technique can be named by a scene
//! file.

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
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

/// Every built-in scene through the renderer with the unshadowed `env` technique (the scenes'
/// own techniques, with their parameters, render validation clean in the accuracy matrix,
/// `tools/tests/matrix.rs`): validation clean, finite, lit, and the graph the scene needs.
#[test]
fn every_builtin_scene_renders_validation_clean() {
    let files = scene_files();
    assert!(files.len() >= 6, "expected the built-in scenes, found {files:?}");
    let mut failures = Vec::new();
    for f in files {
        let scene = Scene::load(&f).unwrap_or_else(|e| panic!("{e}"));
        let settings =
            penumbra::RenderSettings { width: 64, height: 48, technique: Some("env".into()), ..Default::default() };
        let mut r = penumbra::Renderer::new_headless(&scene, settings, true)
            .unwrap_or_else(|e| panic!("{}: {e:#}", f.display()));
        let mut frames = Vec::new();
        let mut prev = None;
        for k in 0..3 {
            let t = k as f32 / 30.0;
            frames
                .extend(r.render(&scene.at(t, prev), None, true).unwrap_or_else(|e| panic!("{}: {e:#}", f.display())));
            prev = Some(t);
        }
        frames.extend(r.finish().unwrap());
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

/// `mc` integrates a scene's medium itself (attenuation and single scattering, as the
/// reference): the renderer adds no volumetric effect to it (and says so when a volumetric method
/// was asked for); `mc-denoised` (whose
/// ratio estimator is of surface light) and the other techniques keep the effect.
#[test]
fn mc_integrates_the_medium_and_others_keep_the_volumetric_effect() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let scene = Scene::load(dir.join("vol_dragon.toml")).unwrap();
    assert!(scene.medium.is_some());
    let effect = |passes: &Vec<String>| passes.iter().any(|p| p == "vol_composite");
    let mc = passes_per_frame(&scene, "mc", 1);
    assert!(!effect(&mc[0]), "mc got the volumetric effect: {:?}", mc[0]);
    assert!(mc[0].iter().any(|p| p == "mc"), "{:?}", mc[0]);
    for t in ["mc-denoised", "env"] {
        let f = passes_per_frame(&scene, t, 1);
        assert!(effect(&f[0]), "{t} lost the volumetric effect: {:?}", f[0]);
    }
    // nothing to report, unless a volumetric method was asked for that mc does not use
    let notes = |volumetric: Option<&str>| {
        let settings = penumbra::RenderSettings {
            width: 32,
            height: 24,
            technique: Some("mc".into()),
            frames_in_flight: 1,
            effects: penumbra::passes::effect::EffectOverrides { volumetric: volumetric.map(String::from) },
            ..Default::default()
        };
        penumbra::Renderer::new_headless(&scene, settings, false).unwrap().notes()
    };
    assert!(notes(None).is_empty(), "{:?}", notes(None));
    let n = notes(Some("full"));
    assert!(n.iter().any(|n| n.contains("integrates the medium itself") && n.contains("'full'")), "{n:?}");
}

/// A static-only technique refuses a moving scene with a message naming why. (Every technique
/// on every scene renders validation clean in the accuracy matrix, `tools/tests/matrix.rs`,
/// which runs each cell under synchronization validation.)
#[test]
fn static_only_techniques_refuse_moving_scenes() {
    let falling = Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/falling.toml")).unwrap();
    let static_only: Vec<_> = penumbra_passes::registry::REGISTRY.iter().filter(|t| t.static_only).collect();
    assert!(!static_only.is_empty());
    for info in static_only {
        let settings = penumbra::RenderSettings {
            width: 48,
            height: 36,
            technique: Some(info.name.to_string()),
            ..Default::default()
        };
        match penumbra::Renderer::new_headless(&falling, settings, false) {
            Ok(_) => panic!("{}: a static-only technique accepted a moving scene", info.name),
            Err(e) => assert!(format!("{e:#}").contains("static"), "{}: unclear refusal: {e:#}", info.name),
        }
    }
}

/// Every registered technique can be named by a scene file: the scene loads with the name as
/// written and the renderer builds and renders it (no `--technique` override); an unregistered
/// name is an error naming the file and listing the registered techniques.
#[test]
fn every_registered_technique_can_be_named_by_a_scene_file() {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("technique_in_scene_file");
    std::fs::create_dir_all(&dir).unwrap();
    let body = "[camera]\neye = [0.0, 1.2, 2.5]\ntarget = [0.0, 0.3, 0.0]\n\n[environment]\nprocedural = \"sky\"\n\n\
                [materials.clay]\ntype = \"diffuse\"\nalbedo = 0.6\n\n\
                [[object]]\nname = \"ground\"\nmesh = { type = \"plane\", size = 3 }\nmaterial = \"clay\"\ncasts_shadow = false\n\n\
                [[object]]\nname = \"ball\"\nmesh = { type = \"icosphere\", radius = 0.3, subdivisions = 1 }\nmaterial = \"clay\"\nposition = [0.0, 0.3, 0.0]\n";
    // Small settings for the techniques with precomputes, from the file's [technique_params].
    let params = |name: &str| match name {
        "isg" | "isg-vertex" => "lobes = 4\nspheres = 8\nside = 6\n",
        "avs" => "r = 32\npoints = 16\niterations = 0\n",
        "shadow-fields" | "shadow-fields-fixed" => "shells = 4\nresolution = 8\nmap_res = 8\n",
        "vv" => "resolution = 16\nsat_width = 64\narcs = 8\n",
        _ => "",
    };
    let mut failures = Vec::new();
    for info in penumbra_passes::registry::REGISTRY {
        let path = dir.join(format!("{}.toml", info.name));
        let p = params(info.name);
        let table = if p.is_empty() { String::new() } else { format!("\n[technique_params]\n{p}") };
        std::fs::write(&path, format!("technique = \"{}\"\n{body}{table}", info.name)).unwrap();
        let scene = match Scene::load(&path) {
            Ok(s) => s,
            Err(e) => {
                failures.push(format!("{}: {e}", info.name));
                continue;
            }
        };
        assert_eq!(scene.technique, info.name);
        let settings = penumbra::RenderSettings { width: 16, height: 12, frames_in_flight: 1, ..Default::default() };
        let t0 = std::time::Instant::now();
        let rendered = penumbra::Renderer::new_headless(&scene, settings, false).and_then(|mut r| {
            let mut frames = r.render(&scene.at(0.0, None), None, true)?;
            frames.extend(r.finish()?);
            Ok(frames)
        });
        match rendered {
            Ok(frames) if frames.len() == 1 && frames[0].hdr.iter().flatten().all(|c| c.is_finite()) => {}
            Ok(_) => failures.push(format!("{}: no frame or non-finite radiance", info.name)),
            Err(e) => failures.push(format!("{}: {e:#}", info.name)),
        }
        println!("{}: created and rendered in {:.1} s", info.name, t0.elapsed().as_secs_f64());
    }
    assert!(failures.is_empty(), "{failures:#?}");
    let path = dir.join("unknown.toml");
    std::fs::write(&path, format!("technique = \"hsdt\"\n{body}")).unwrap();
    let scene = Scene::load(&path).expect("the scene keeps the name as written");
    let e = penumbra::Renderer::new_headless(
        &scene,
        penumbra::RenderSettings { width: 16, height: 12, ..Default::default() },
        false,
    )
    .err()
    .expect("an unregistered technique is refused")
    .to_string();
    assert!(e.contains("unknown.toml") && e.contains("unknown technique 'hsdt'") && e.contains("avs"), "{e}");
}

/// The papers' scenes at their scale (`scenes/paper/`, outside the matrix and the render test
/// above) load, with the objects and vertex counts `scenes/README.md` states beside the papers'.
#[test]
fn paper_scenes_load_at_their_stated_scale() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/paper");
    for (file, objects, vertices) in [
        ("rigid_bodies.toml", 17, 63028),
        ("chess_set.toml", 33, 99720),
        ("cloth_bunnies.toml", 6, 25949),
        ("sf_statues.toml", 6, 33235),
        ("sf_bowling.toml", 15, 41435),
        ("sf_falling.toml", 20, 88739),
        ("avs_hat_on_cloth.toml", 2, 21954),
        ("avs_balls_on_dish.toml", 4, 30922),
        ("avs_walking_man.toml", 6, 31949),
    ] {
        let s = Scene::load(dir.join(file)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((s.objects.len(), s.vertex_count()), (objects, vertices), "{file}: objects, vertices");
    }
}
