//! What a technique ignores in a scene is reported (`Renderer::notes`, printed by the CLI),
//! never a silently different image.

use penumbra::{RenderSettings, Renderer};
use penumbra_scene::Scene;

fn notes(path: &str, technique: &str) -> Vec<String> {
    let scene = Scene::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).expect("scene");
    let settings = RenderSettings { width: 16, height: 16, technique: Some(technique.into()), ..Default::default() };
    Renderer::new_headless(&scene, settings, false).expect("renderer").notes()
}

#[test]
fn shadowmaps_and_mc_render_what_they_are_given() {
    // shadowmaps renders local lights (a cube map each), honours casts_shadow and renders the
    // texture maps (the one material model): nothing to report on god_rays (a spot light),
    // balls_on_dish (a floor with casts_shadow = false) or hat_on_cloth (texture maps).
    for s in ["scenes/god_rays.toml", "scenes/balls_on_dish.toml", "scenes/hat_on_cloth.toml"] {
        let n = notes(s, "shadowmaps");
        assert!(n.is_empty(), "{s}: {n:?}");
    }
    // mc renders local lights and honours casts_shadow: nothing to report.
    let n = notes("scenes/god_rays.toml", "mc");
    assert!(n.is_empty(), "{n:?}");
    // ... and chess's anisotropic Ashikhmin-Shirley queen and its textures (the one material
    // model): nothing to report either.
    let n = notes("scenes/chess.toml", "mc");
    assert!(n.is_empty(), "{n:?}");
}

#[test]
fn shadow_fields_and_vv_report_the_textures_and_lights_they_ignore() {
    // hat_on_cloth: checker and stripe albedo maps, rendered by shadow fields through the one
    // material model (its cloth and hat held still: the fields refuse deforming shadow casters,
    // naming them); coarse: static geometry and a sphere light, which vv renders (point
    // visibility from its loops): nothing to report.
    let mut hat =
        Scene::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hat_on_cloth.toml")).expect("scene");
    for t in ["shadow-fields", "shadow-fields-fixed", "shadow-fields-wavelet"] {
        let settings = RenderSettings { width: 16, height: 16, technique: Some(t.into()), ..Default::default() };
        let e = Renderer::new_headless(&hat, settings, false).err().expect("deforming shadow casters refused");
        assert!(format!("{e:#}").contains("'cloth', 'hat'"), "{t}: {e:#}");
    }
    for info in &mut hat.object_info {
        info.deformations.clear();
    }
    for t in ["shadow-fields", "shadow-fields-fixed"] {
        let settings = RenderSettings { width: 16, height: 16, technique: Some(t.into()), ..Default::default() };
        let n = Renderer::new_headless(&hat, settings, false).expect("renderer").notes();
        assert!(!n.iter().any(|l| l.contains("texture")), "{t}: {n:?}");
    }
    let n = notes("scenes/coarse.toml", "vv");
    assert!(n.is_empty(), "coarse: {n:?}");
    // more lights than vv shades: it names how many it leaves out
    let mut scene =
        Scene::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/coarse.toml")).expect("scene");
    let light = scene.lights[0].clone();
    scene.lights = (0..10).map(|_| light.clone()).collect();
    let settings = RenderSettings { width: 16, height: 16, technique: Some("vv".into()), ..Default::default() };
    let n = Renderer::new_headless(&scene, settings, false).expect("renderer").notes();
    assert!(n.iter().any(|l| l.contains("only the first 8 of the scene's 10 local lights")), "{n:?}");
}

/// `technique = "auto"` (the default: the built-in scene, scene files without a technique, bare
/// models) renders shadows and says what it chose; a scene without light takes `env`.
#[test]
fn auto_chooses_a_shadowing_technique_and_says_so() {
    let scene = Scene::default_scene();
    assert_eq!(scene.technique, "auto");
    let settings = RenderSettings { width: 16, height: 16, ..Default::default() };
    let r = Renderer::new_headless(&scene, settings, false).expect("renderer");
    assert_eq!(r.technique_name(), "shadowmaps");
    let n = r.notes();
    assert!(n[0].starts_with("auto: shadowmaps"), "{n:?}");
    assert!(!n.iter().any(|l| l.contains("renders no shadows")), "{n:?}");
    // a bare model (no technique line) lit by the default environment
    let model =
        Scene::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/assets/bunny.glb")).expect("model");
    assert_eq!(model.technique, "auto");
    let settings = RenderSettings { width: 16, height: 16, ..Default::default() };
    assert_eq!(Renderer::new_headless(&model, settings, false).expect("renderer").technique_name(), "shadowmaps");
    // nothing to cast shadows from
    let mut dark = Scene::empty("dark");
    dark.environment = None;
    let settings = RenderSettings { width: 16, height: 16, ..Default::default() };
    let r = Renderer::new_headless(&dark, settings, false).expect("renderer");
    assert_eq!(r.technique_name(), "env");
    assert!(r.notes()[0].contains("no light"), "{:?}", r.notes());
}

/// isg says when the driver ends shader loops early (Mesa 22.3's lavapipe, found by the loop
/// guard cutting isg's visibility loops short) and only then: the note follows the device's
/// measured loop limit.
#[test]
fn isg_names_a_driver_that_cuts_its_loops_short() {
    let ctx = penumbra::engine::Context::new(&Default::default()).expect("context");
    let mut engine = penumbra::engine::Engine::new(ctx.clone(), 1).expect("engine");
    let limit = penumbra_passes::kernels::loop_probe::loop_limit(&mut engine, &penumbra::shader_library(), 100_000)
        .expect("probe");
    drop(engine);
    for t in ["isg", "isg-vertex"] {
        let scene = Scene::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/falling.toml")).unwrap();
        let settings = RenderSettings { width: 16, height: 16, technique: Some(t.into()), ..Default::default() };
        let n = Renderer::new(ctx.clone(), &scene, settings).expect("renderer").notes();
        let said = n.iter().any(|l| l.contains("ends a shader invocation's loops after"));
        assert_eq!(said, limit.is_some(), "{t} on {} (limit {limit:?}): {n:?}", ctx.driver_info());
    }
}
