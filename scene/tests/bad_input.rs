//! Bad input never panics: each class gives a `SceneError` whose message names the file and
//! the problem; degenerate but renderable input is repaired with a warning.

mod common;
use common::*;
use penumbra_scene::{LoadOptions, Scene, SceneError};
use serde_json::json;
use std::path::{Path, PathBuf};

/// Load and expect an error mentioning the file name and every `needles` (case-insensitive).
fn fails(path: &Path, needles: &[&str]) -> SceneError {
    fails_with(path, &LoadOptions::default(), needles)
}

fn fails_with(path: &Path, opts: &LoadOptions, needles: &[&str]) -> SceneError {
    let e = match Scene::load_with(path, opts) {
        Ok(_) => panic!("{} loaded but should fail", path.display()),
        Err(e) => e,
    };
    let msg = e.to_string();
    let file = path.file_name().unwrap().to_string_lossy();
    assert!(msg.contains(&*file), "message does not name {file}: {msg}");
    for n in needles {
        assert!(msg.to_lowercase().contains(&n.to_lowercase()), "message lacks '{n}': {msg}");
    }
    e
}

fn write(dir: &Path, name: &str, data: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, data).unwrap();
    p
}

const HEAD: &str = "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[environment]\nprocedural = \"sky\"\n";

fn valid_glb() -> Vec<u8> {
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &idx, None);
    glb(&doc, &bin.bytes)
}

#[test]
fn truncated_and_invalid_gltf() {
    let dir = temp_dir("bad-gltf");
    let full = valid_glb();
    let p = write(&dir, "truncated.glb", &full[..full.len() / 2]);
    fails(&p, &["invalid glTF"]);
    let p = write(&dir, "short.glb", &full[..10]);
    fails(&p, &["invalid glTF"]);
    let p = write(&dir, "empty.glb", b"");
    fails(&p, &["empty"]);
    let p = write(&dir, "garbage.gltf", b"{ this is not json");
    fails(&p, &["malformed JSON"]);
    let p = write(
        &dir,
        "notgltf.gltf",
        br#"{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": {"POSITION": 7}}]}]}"#,
    );
    fails(&p, &["invalid glTF"]);
    // Every prefix of a valid file fails cleanly (no panic).
    for cut in (0..full.len()).step_by(37) {
        let p = write(&dir, "cut.glb", &full[..cut]);
        assert!(Scene::load(&p).is_err(), "prefix {cut}");
    }
    // A buffer shorter than its declared length.
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["buffers"][0]["byteLength"] = json!(bin.bytes.len() + 64);
    let p = write(&dir, "shortbuf.glb", glb(&doc, &bin.bytes));
    fails(&p, &["invalid glTF"]);
    // An accessor of the wrong type for POSITION (caught by validation) and NORMAL (by us).
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["accessors"][0]["type"] = json!("VEC2");
    doc["accessors"][0]["count"] = json!(6);
    let p = write(&dir, "wrongtype.glb", glb(&doc, &bin.bytes));
    fails(&p, &["POSITION", "invalid"]);
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    let n = bin.f32s(&[0.0; 8], "VEC2");
    doc["accessors"] = json!(bin.accessors);
    doc["bufferViews"] = json!(bin.views);
    doc["buffers"][0]["byteLength"] = json!(bin.bytes.len());
    doc["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = json!(n);
    let p = write(&dir, "wrongnormal.glb", glb(&doc, &bin.bytes));
    fails(&p, &["Normals", "expected one of [Vec3]"]);
    // An attribute referring to an accessor that does not exist.
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(7);
    let p = write(&dir, "noaccessor.glb", glb(&doc, &bin.bytes));
    fails(&p, &["accessor 7", "does not exist"]);
    // An accessor reading past the end of its view.
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["accessors"][0]["count"] = json!(400);
    let p = write(&dir, "overrun.glb", glb(&doc, &bin.bytes));
    fails(&p, &["buffer view"]);
}

#[test]
fn unsupported_required_extension_is_named() {
    let dir = temp_dir("required-ext");
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["extensionsUsed"] = json!(["EXT_meshopt_compression"]);
    doc["extensionsRequired"] = json!(["EXT_meshopt_compression"]);
    let p = write(&dir, "meshopt.glb", glb(&doc, &bin.bytes));
    let e = fails(&p, &["unsupported", "EXT_meshopt_compression"]);
    assert!(matches!(e, SceneError::Unsupported { .. }));
}

/// The real Draco asset with its compressed data damaged: the decoder's error, naming the file,
/// the mesh and the buffer view; a Draco extension without its buffer view is named too.
#[test]
fn damaged_draco_data_is_named() {
    let dir = temp_dir("draco");
    let real = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/bunny-draco.glb");
    let mut b = std::fs::read(&real).unwrap();
    Scene::load(&real).unwrap_or_else(|e| panic!("{e}"));
    // The BIN chunk follows the JSON chunk: overwrite the Draco stream after its header.
    let json_len = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    let bin_start = 20 + json_len + 8;
    for x in &mut b[bin_start + 8..] {
        *x = 0xA5;
    }
    let p = write(&dir, "damaged-draco.glb", &b);
    fails(&p, &["mesh 'base'", "KHR_draco_mesh_compression", "buffer view 0", "cannot be decoded"]);
    // An extension object without a bufferView.
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
    doc["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
    doc["meshes"][0]["primitives"][0]["extensions"] =
        json!({"KHR_draco_mesh_compression": {"attributes": {"POSITION": 0}}});
    let p = write(&dir, "no-view.glb", glb(&doc, &bin.bytes));
    fails(&p, &["KHR_draco_mesh_compression has no bufferView"]);
}

#[test]
fn indices_out_of_range() {
    let dir = temp_dir("indices");
    let (pos, _) = tetra();
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &[0, 1, 2, 0, 1, 9], None);
    let p = write(&dir, "idx.glb", glb(&doc, &bin.bytes));
    fails(&p, &["index 9", "out of range"]);
    // Same through a scene file: the scene loader reports the glTF file.
    let s = write(&dir, "s.toml", format!("{HEAD}[[object]]\nfile = \"idx.glb\"\n"));
    let e = Scene::load(&s).unwrap_err();
    assert!(e.to_string().contains("idx.glb") && e.to_string().contains("out of range"), "{e}");
    // A primitive mesh in a scene file cannot have bad indices, but a bad skin joint can.
}

#[test]
fn nan_and_inf_positions_and_transforms() {
    let dir = temp_dir("nan");
    let (mut pos, idx) = tetra();
    pos[4] = f32::NAN;
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &idx, None);
    let p = write(&dir, "nanpos.glb", glb(&doc, &bin.bytes));
    fails(&p, &["non-finite position"]);
    // 1e39 overflows f32: an infinite node translation.
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["nodes"][0]["translation"] = json!([1e39, 0.0, 0.0]);
    let p = write(&dir, "inf.glb", glb(&doc, &bin.bytes));
    fails(&p, &["node 0", "non-finite"]);
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["nodes"][0].as_object_mut().unwrap().remove("translation");
    doc["nodes"][0]["matrix"] =
        json!([1.0, 0.0, 0.0, 0.0, 0.0, 1e39, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    let p = write(&dir, "infmatrix.glb", glb(&doc, &bin.bytes));
    fails(&p, &["non-finite"]);
    // In a scene file.
    let s = write(
        &dir,
        "nan.toml",
        format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nposition = [nan, 0, 0]\n"),
    );
    fails(&s, &["line 6", "NaN"]);
    let s = write(&dir, "inf.toml", format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nscale = inf\n"));
    fails(&s, &["object 'object0'", "NaN or infinite"]);
    let s = write(&dir, "nankey.toml", format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nmotion = {{ type = \"keyframes\", keys = [{{ t = 0, position = [0, 0, 0] }}, {{ t = 1, position = [0, nan, 0] }}] }}\n"));
    fails(&s, &["motion", "NaN"]);
    let s = write(
        &dir,
        "nanenv.toml",
        "[camera]\neye = [0, nan, 4]\ntarget = 0\n[[object]]\nmesh = { type = \"cube\", size = 1 }\n",
    );
    fails(&s, &["camera.eye", "NaN"]);
}

#[test]
fn missing_buffers_textures_and_files() {
    let dir = temp_dir("missing");
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &idx, Some("gone.bin".into()));
    let p = write(&dir, "nobuf.gltf", serde_json::to_vec(&doc).unwrap());
    fails(&p, &["buffer 0", "missing file 'gone.bin'"]);
    // GLB that refers to a binary chunk it does not have.
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &idx, None);
    let p = write(&dir, "nochunk.gltf", serde_json::to_vec(&doc).unwrap());
    fails(&p, &["binary chunk"]);
    // Missing texture image.
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, None);
    doc["buffers"][0]["uri"] = json!(bin.data_uri());
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": 0});
    doc["textures"] = json!([{"source": 0}]);
    doc["images"] = json!([{"uri": "albedo.png"}]);
    let p = write(&dir, "notex.gltf", serde_json::to_vec(&doc).unwrap());
    fails(&p, &["image 0", "missing file 'albedo.png'"]);
    // A corrupt texture image.
    write(&dir, "albedo.png", b"not a png");
    fails(&p, &["image 0", "cannot be decoded"]);
    // Missing files referenced by a scene file.
    let s = write(&dir, "a.toml", format!("{HEAD}[[object]]\nfile = \"nothere.glb\"\n"));
    let e = fails(&s, &["line 6", "nothere.glb", "cannot read file"]);
    assert!(matches!(e.root_cause(), SceneError::Io { .. }));
    assert_eq!(e.path(), s.as_path());
    let s = write(&dir, "b.toml", "[camera]\neye = 1\ntarget = 0\n[environment]\nfile = \"sky.exr\"\n[[object]]\nmesh = { type = \"cube\", size = 1 }\n");
    fails(&s, &["line 4", "sky.exr", "cannot read file"]);
    let s = write(&dir, "c.toml", format!("{HEAD}[materials.m]\ntype = \"diffuse\"\nalbedo = 1\nalbedo_map = {{ file = \"wood.png\" }}\n[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nmaterial = \"m\"\n"));
    fails(&s, &["wood.png"]);
    // The scene file itself.
    fails(&dir.join("absent.toml"), &["cannot read file"]);
    fails(&dir.join("absent.glb"), &["cannot read file"]);
    fails(&write(&dir, "model.obj", b"v 0 0 0"), &["unknown scene file type"]);
}

#[test]
fn bad_environment_maps() {
    let dir = temp_dir("badenv");
    let p = write(&dir, "garbage.exr", b"definitely not an exr file");
    let e = penumbra_scene::Environment::load(&p).unwrap_err();
    assert!(e.to_string().contains("garbage.exr") && e.to_string().contains("EXR"), "{e}");
    let p = write(&dir, "garbage.hdr", b"#?RADIANCE\nbroken");
    let e = penumbra_scene::Environment::load(&p).unwrap_err();
    assert!(e.to_string().contains("garbage.hdr"), "{e}");
    // A luminance-only EXR has no R, G, B: unsupported, naming the channels.
    use exr::prelude::*;
    let p = dir.join("gray.exr");
    let ch = AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new("Y", FlatSamples::F32(vec![0.5; 16]))]));
    Image::from_channels((4, 4), ch).write().to_file(&p).unwrap();
    let e = penumbra_scene::Environment::load(&p).unwrap_err();
    assert!(matches!(e, SceneError::Unsupported { .. }) && e.to_string().contains("R, G and B"), "{e}");
    // Truncated EXR.
    let good = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/studio.exr")).unwrap();
    let p = write(&dir, "cut.exr", &good[..good.len() / 3]);
    let e = penumbra_scene::Environment::load(&p).unwrap_err();
    assert!(e.to_string().contains("cut.exr"), "{e}");
    // NaN texels are rejected.
    let p = dir.join("nan.exr");
    exr::prelude::write_rgb_file(&p, 2, 2, |x, _| (if x == 1 { f32::NAN } else { 1.0 }, 0.0, 0.0)).unwrap();
    let e = penumbra_scene::Environment::load(&p).unwrap_err();
    assert!(e.to_string().contains("NaN"), "{e}");
}

#[test]
fn empty_scenes() {
    let dir = temp_dir("empty");
    let s = write(&dir, "noobj.toml", HEAD);
    fails(&s, &["empty scene"]);
    let doc = json!({"asset": {"version": "2.0"}, "scenes": [{"nodes": []}]});
    let p = write(&dir, "nomesh.gltf", serde_json::to_vec(&doc).unwrap());
    fails(&p, &["empty scene"]);
    let p = write(&dir, "blank.toml", "");
    fails(&p, &["missing field `camera`"]);
}

#[test]
fn unknown_keys_and_wrong_types_name_line_and_column() {
    let dir = temp_dir("toml");
    let s = write(
        &dir,
        "unknown.toml",
        format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\ncolour = [1, 0, 0]\n"),
    );
    fails(&s, &["line 8", "column 1", "unknown field `colour`"]);
    let s = write(&dir, "unknown2.toml", format!("{HEAD}[materials.m]\ntype = \"diffuse\"\nalbedo = 1\nroughnes = 0.2\n[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\n"));
    fails(&s, &["line 9", "unknown field `roughnes`"]);
    let s =
        write(&dir, "toplevel.toml", format!("frames = 3\n{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\n"));
    fails(&s, &["line 1", "unknown field `frames`"]);
    let s = write(
        &dir,
        "wrongtype.toml",
        "[camera]\neye = [0, 1, 4]\ntarget = 0\nfov_deg = \"wide\"\n[[object]]\nmesh = { type = \"cube\", size = 1 }\n",
    );
    fails(&s, &["line 4", "invalid type"]);
    let s = write(
        &dir,
        "wrongvec.toml",
        "[camera]\neye = [0, 1]\ntarget = 0\n[[object]]\nmesh = { type = \"cube\", size = 1 }\n",
    );
    fails(&s, &["line 2", "array of 3 numbers"]);
    let s = write(&dir, "badprim.toml", format!("{HEAD}[[object]]\nmesh = {{ type = \"cone\", size = 1 }}\n"));
    fails(&s, &["line 7", "cone"]);
    let s = write(&dir, "primkey.toml", format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", radius = 1 }}\n"));
    fails(&s, &["line 7", "radius"]);
    let s = write(&dir, "syntax.toml", "[camera\neye = 1\n");
    fails(&s, &["line 1"]);
    let s = write(
        &dir,
        "badmat.toml",
        format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nmaterial = \"gold\"\n"),
    );
    fails(&s, &["line 6", "unknown material 'gold'"]);
    let s = write(
        &dir,
        "tech.toml",
        format!("technique = \"magic\"\n{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\n"),
    );
    // The scene keeps the name as written (the renderer checks it against its registry); a
    // caller-supplied list is checked at load.
    assert_eq!(Scene::load(&s).unwrap().technique, "magic");
    let opts = LoadOptions { techniques: Some(vec!["env".into()]), ..Default::default() };
    let e = Scene::load_with(&s, &opts).unwrap_err().to_string();
    assert!(e.contains("unknown technique 'magic'") && e.contains("tech.toml"), "{e}");
    let opts = LoadOptions { techniques: Some(vec!["magic".into()]), ..Default::default() };
    assert_eq!(Scene::load_with(&s, &opts).unwrap().technique, "magic");
    let s = write(&dir, "range.toml", format!("{HEAD}[materials.m]\ntype = \"cook_torrance\"\nalbedo = 1\nroughness = 3\n[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nmaterial = \"m\"\n"));
    fails(&s, &["line 6", "roughness must be in [0, 1]"]);
    let s = write(&dir, "g.toml", format!("{HEAD}[medium]\nsigma_a = 0.1\nsigma_s = 0.1\ng = 1.5\n[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\n"));
    fails(&s, &["medium", "g must be in (-1, 1)"]);
    let s = write(&dir, "keys.toml", format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nmotion = {{ type = \"keyframes\", keys = [{{ t = 1, position = 0 }}, {{ t = 0, position = 1 }}] }}\n"));
    fails(&s, &["strictly increasing"]);
    let s = write(
        &dir,
        "bothmesh.toml",
        format!("{HEAD}[[object]]\nmesh = {{ type = \"cube\", size = 1 }}\nfile = \"x.glb\"\n"),
    );
    fails(&s, &["exactly one of `mesh` or `file`"]);
    let s = write(&dir, "utf.toml", b"\xff\xfe[camera]");
    fails(&s, &["UTF-8"]);
}

#[test]
fn degenerate_input_is_repaired_with_warnings() {
    let dir = temp_dir("repair");
    // A tetrahedron plus a zero-area triangle, with one normal scaled by 5.
    let (pos, mut idx) = tetra();
    idx.extend_from_slice(&[0, 1, 1]);
    let mut bin = Bin::default();
    let p = bin.f32s(&pos, "VEC3");
    let mut normals = vec![0.0, 0.0, -1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    normals[3] = 5.0;
    let n = bin.f32s(&normals, "VEC3");
    let i = bin.u32s(&idx);
    let doc = bin.document(
        None,
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": p, "NORMAL": n}, "indices": i}]}],
        }),
    );
    let f = write(&dir, "degenerate.glb", glb(&doc, &bin.bytes));
    let s = Scene::load(&f).unwrap();
    let m = &s.meshes[s.objects[0].mesh];
    assert_eq!(m.triangle_count(), 4, "zero-area triangle removed");
    assert!(m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-6));
    assert_eq!(m.normals[1], glam::Vec3::X);
    assert!(m.is_closed());
    let w = s.warnings.join("\n");
    assert!(w.contains("degenerate.glb") && w.contains("removed 1 zero-area triangle"), "{w}");
    assert!(w.contains("normalized 1 unnormalized normal"), "{w}");
    // The same file in a scene file: warnings are carried to the scene.
    let t = write(&dir, "s.toml", format!("{HEAD}[[object]]\nfile = \"degenerate.glb\"\n"));
    let s = Scene::load(&t).unwrap();
    assert!(s.warnings.iter().any(|w| w.contains("zero-area")));
}

#[test]
fn open_meshes_rejected_when_closed_meshes_are_required() {
    let dir = temp_dir("closed");
    // One open triangle.
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], &[0, 1, 2], None);
    write(&dir, "open.glb", glb(&doc, &bin.bytes));
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &idx, None);
    write(&dir, "closed.glb", glb(&doc, &bin.bytes));
    let opts = LoadOptions { require_closed_meshes: true, ..Default::default() };
    let s = write(&dir, "open.toml", format!("technique = \"shadow-fields\"\n{HEAD}[[object]]\nname = \"floor\"\nmesh = {{ type = \"plane\", size = 4 }}\ncasts_shadow = false\n[[object]]\nname = \"leaf\"\nfile = \"open.glb\"\n"));
    let e = fails_with(&s, &opts, &["open.toml", "open.glb", "object 'leaf'", "3 boundary edges", "shadow-fields"]);
    assert!(matches!(e, SceneError::NotClosed { .. }));
    // Without the requirement it loads; thin shells and closed meshes pass the check.
    assert!(Scene::load(&s).is_ok());
    let s2 = write(&dir, "ok.toml", format!("{HEAD}[[object]]\nmesh = {{ type = \"plane\", size = 4 }}\ncasts_shadow = false\n[[object]]\nfile = \"open.glb\"\nthin_shell = true\n[[object]]\nfile = \"closed.glb\"\n[[object]]\nmesh = {{ type = \"chess\", piece = \"queen\" }}\n"));
    Scene::load_with(&s2, &opts).unwrap_or_else(|e| panic!("{e}"));
    // A bare open model, checked by the caller.
    let scene = Scene::load(dir.join("open.glb")).unwrap();
    let e = scene.check_closed_meshes("needs closed meshes").unwrap_err();
    assert!(e.to_string().contains("open.glb"), "{e}");
}

#[test]
fn bad_skin_and_animation_data() {
    let dir = temp_dir("badanim");
    let (pos, idx) = tetra();
    // Animation with decreasing key times.
    let mut bin = Bin::default();
    let p = bin.f32s(&pos, "VEC3");
    let i = bin.u32s(&idx);
    let times = bin.f32s(&[1.0, 0.5], "SCALAR");
    let tr = bin.f32s(&[0.0; 6], "VEC3");
    let doc = bin.document(
        None,
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": p}, "indices": i}]}],
            "animations": [{"name": "bad", "samplers": [{"input": times, "output": tr}],
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]}],
        }),
    );
    let f = write(&dir, "anim.glb", glb(&doc, &bin.bytes));
    fails(&f, &["animation 'bad'", "strictly increasing"]);
    // Joint index beyond the skin's joints.
    let mut bin = Bin::default();
    let p = bin.f32s(&pos, "VEC3");
    let i = bin.u32s(&idx);
    let j = bin.u16x4(&[[0, 0, 0, 0], [0, 0, 0, 0], [5, 0, 0, 0], [0, 0, 0, 0]]);
    let w = bin.f32s(&[1.0, 0.0, 0.0, 0.0].repeat(4), "VEC4");
    let doc = bin.document(
        None,
        json!({
            "scenes": [{"nodes": [0, 1]}],
            "nodes": [{"name": "j"}, {"mesh": 0, "skin": 0}],
            "skins": [{"joints": [0]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": p, "JOINTS_0": j, "WEIGHTS_0": w}, "indices": i}]}],
        }),
    );
    let f = write(&dir, "skin.glb", glb(&doc, &bin.bytes));
    fails(&f, &["joint index 5", "out of range"]);
}

#[test]
fn default_scene_needs_no_files() {
    let s = Scene::default_scene();
    assert_eq!(s.objects.len(), 4);
    assert!(s.warnings.is_empty());
    let r = s.requirements();
    assert!(r.environment_light && r.is_static_geometry() && !r.medium && !r.local_lights);
    let f = s.at(1.0, Some(0.0));
    assert!(!f.any_moved());
}

/// KHR_lights_punctual: a node naming a light that does not exist, an invalid type, bad cone
/// angles and negative intensities are errors naming the file and the light.
#[test]
fn bad_punctual_lights() {
    let dir = temp_dir("lights");
    let (pos, idx) = tetra();
    let with_lights = |lights: serde_json::Value, index: usize| {
        let mut bin = Bin::default();
        let mut doc = simple(&mut bin, &pos, &idx, None);
        doc["extensionsUsed"] = json!(["KHR_lights_punctual"]);
        doc["extensions"] = json!({"KHR_lights_punctual": {"lights": lights}});
        doc["nodes"].as_array_mut().unwrap().push(json!({"extensions": {"KHR_lights_punctual": {"light": index}}}));
        doc["scenes"][0]["nodes"] = json!([0, 1]);
        glb(&doc, &bin.bytes)
    };
    let p = write(&dir, "missing.glb", with_lights(json!([{"type": "point"}]), 3));
    fails(&p, &["khrLightsPunctual.light", "out of bounds"]);
    let p = write(
        &dir,
        "cone.glb",
        with_lights(json!([{"name": "s", "type": "spot", "spot": {"innerConeAngle": 0.8, "outerConeAngle": 0.5}}]), 0),
    );
    fails(&p, &["light 's'", "cone"]);
    let p = write(&dir, "negative.glb", with_lights(json!([{"name": "n", "type": "point", "intensity": -1.0}]), 0));
    fails(&p, &["light 'n'", ">= 0"]);
    let p = write(&dir, "kind.glb", with_lights(json!([{"name": "k", "type": "area"}]), 0));
    fails(&p, &["lights[0].type", "invalid value"]);
}
