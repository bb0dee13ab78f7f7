//! `[technique_params]` in scene files.

use penumbra_scene::Scene;

fn write(name: &str, text: &str) -> std::path::PathBuf {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("technique_params");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const BASE: &str = "technique = \"isg\"\n[camera]\neye = [0, 1, 3]\ntarget = [0, 0, 0]\n[[object]]\nmesh = { type = \"sphere\", radius = 1 }\n";

#[test]
fn parameters_are_read_as_text_and_bad_types_are_errors() {
    let p = write(
        "ok.toml",
        &format!("{BASE}[technique_params]\nlobes = 8\nepsilon = 0.02\nshadows = false\nmode = \"fast\"\n"),
    );
    let s = Scene::load(&p).unwrap();
    let got: Vec<_> = s.technique_params.iter().map(|(k, v)| format!("{k}={v}")).collect();
    assert_eq!(got, ["epsilon=0.02", "lobes=8", "mode=fast", "shadows=false"]);
    let p = write("bad.toml", &format!("{BASE}[technique_params]\nlobes = [1, 2]\n"));
    let e = Scene::load(&p).unwrap_err().to_string();
    assert!(e.contains("bad.toml") && e.contains("technique_params.lobes"), "{e}");
    let p = write("none.toml", BASE);
    assert!(Scene::load(&p).unwrap().technique_params.is_empty());
}
