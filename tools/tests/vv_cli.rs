//! `penumbra precompute vv`: writes a file that `--check` accepts; malformed files, files of
//! another model and bad parameters exit 2 naming the file or the parameter.

use std::path::PathBuf;
use std::process::{Command, Output};

mod common;
use common::text;

fn penumbra(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_penumbra"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run penumbra")
}

#[test]
fn precompute_vv_writes_checks_and_rejects_bad_files() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("vv_cli_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("coarse.pvv");
    let scene = "../scenes/coarse.toml";
    // the scene's meshes as given (--refine 0): the two-triangle floor stays two triangles
    let o =
        penumbra(&["precompute", "vv", scene, "--resolution", "12", "--refine", "0", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("257 vertices, 466 triangles")
            && t.contains("vectorized visibility:")
            && t.contains("triples")
            && t.contains("MB"),
        "{t}"
    );
    assert!(t.contains("eq. 21 vs eq. 19"), "{t}");
    // the file belongs to that model only: the default (refined) model is another one
    let o = penumbra(&["precompute", "vv", scene, "--check", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let o = penumbra(&["precompute", "vv", scene, "--refine", "0", "--check", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("valid for"));

    let bytes = std::fs::read(&out).unwrap();
    let bad = |name: &str, data: &[u8], needle: &str| {
        let p = dir.join(name);
        std::fs::write(&p, data).unwrap();
        let o = penumbra(&["precompute", "vv", scene, "--refine", "0", "--check", p.to_str().unwrap()]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", text(&o));
        let t = text(&o);
        assert!(t.contains(p.to_str().unwrap()) && t.contains(needle), "{name}: {t}");
    };
    bad("truncated.pvv", &bytes[..bytes.len() - 7], "truncated");
    bad("header.pvv", &bytes[..30], "truncated");
    bad("empty.pvv", &[], "truncated header");
    let mut v = bytes.clone();
    v[..4].copy_from_slice(b"PSF1");
    bad("magic.pvv", &v, "bad magic");
    let mut v = bytes.clone();
    v[4] = 7;
    bad("version.pvv", &v, "version 7");
    // another model: the built-in ring moved
    let o = penumbra(&["precompute", "vv", "../scenes/vv_coarse.toml", "--check", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("made for a model of 257 vertices"), "{}", text(&o));
    // bad parameter and missing file
    let o = penumbra(&["precompute", "vv", scene, "--resolution", "3", "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("resolution 3"), "{}", text(&o));
    let missing: PathBuf = dir.join("missing.pvv");
    let o = penumbra(&["precompute", "vv", scene, "--check", missing.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("missing.pvv"));
    let _ = std::fs::remove_dir_all(&dir);
}
