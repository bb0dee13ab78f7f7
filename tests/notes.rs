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
fn shadowmaps_reports_the_local_lights_and_receivers_it_ignores() {
    // god_rays: a spot light; balls_on_dish: a floor with casts_shadow = false.
    let n = notes("scenes/god_rays.toml", "shadowmaps");
    assert!(n.iter().any(|l| l.contains("local light(s) are not rendered")), "{n:?}");
    let n = notes("scenes/balls_on_dish.toml", "shadowmaps");
    assert!(n.iter().any(|l| l.contains("casts_shadow = false")), "{n:?}");
    assert!(!n.iter().any(|l| l.contains("local light")), "balls_on_dish has no local light: {n:?}");
    // mc renders local lights and honours casts_shadow: nothing to report.
    let n = notes("scenes/god_rays.toml", "mc");
    assert!(n.is_empty(), "{n:?}");
    // ... and chess's anisotropic Ashikhmin-Shirley queen and its textures (the one material
    // model): nothing to report either.
    let n = notes("scenes/chess.toml", "mc");
    assert!(n.is_empty(), "{n:?}");
    // shadowmaps renders the texture maps (the one material model).
    let n = notes("scenes/hat_on_cloth.toml", "shadowmaps");
    assert!(!n.iter().any(|l| l.contains("texture")), "{n:?}");
}

#[test]
fn shadow_fields_and_vv_report_the_textures_and_lights_they_ignore() {
    // hat_on_cloth: checker and stripe albedo maps, rendered by shadow fields through the one
    // material model; coarse: static geometry and a sphere light, which vv does not render.
    for t in ["shadow-fields", "shadow-fields-fixed"] {
        let n = notes("scenes/hat_on_cloth.toml", t);
        assert!(!n.iter().any(|l| l.contains("texture")), "{t}: {n:?}");
    }
    let n = notes("scenes/coarse.toml", "vv");
    assert!(n.iter().any(|l| l.contains("local light(s) are not rendered")), "{n:?}");
    assert!(!n.iter().any(|l| l.contains("texture")), "coarse has no texture maps: {n:?}");
}
