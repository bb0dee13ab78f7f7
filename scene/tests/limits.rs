//! Hostile sizes are refused before anything is allocated by them: glTF accessor counts (sparse
//! ones too) against their buffer views and the memory budget, image and environment headers
//! (EXR, Radiance HDR, PNG inside glTF and as textures) against the largest side and the budget,
//! scene file sizes. Each gives `SceneError::TooLarge` (or a glTF error) naming the file; none
//! allocates what the file claims (the claims here are 24 to 160 GB).

mod common;
use common::*;
use penumbra_scene::{Limits, LoadOptions, Scene, SceneError};
use std::path::{Path, PathBuf};

fn write(dir: &Path, name: &str, data: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, data).unwrap();
    p
}

/// Loads and expects an error naming `name` (the file at fault) and every needle.
fn refused(path: &Path, opts: &LoadOptions, name: &str, needles: &[&str]) -> SceneError {
    let e = match Scene::load_with(path, opts) {
        Ok(_) => panic!("{} loaded but should fail", path.display()),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert!(msg.contains(name), "message does not name {name}: {msg}");
    for n in needles {
        assert!(msg.to_lowercase().contains(&n.to_lowercase()), "message lacks '{n}': {msg}");
    }
    e
}

const HEAD: &str = "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n";

/// A .gltf whose POSITION is a sparse accessor of `count` elements with no buffer view.
fn sparse_gltf(count: u64) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":12,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAA"}}],
"bufferViews":[{{"buffer":0,"byteLength":12}}],
"accessors":[{{"componentType":5126,"count":{count},"type":"VEC3","max":[1,1,1],"min":[0,0,0],
"sparse":{{"count":1,"indices":{{"bufferView":0,"componentType":5125}},"values":{{"bufferView":0}}}}}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],"nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],"scene":0}}"#
    )
}

#[test]
fn gltf_accessor_counts_are_bounded_before_reading() {
    let dir = temp_dir("limits-gltf");
    let d = LoadOptions::default();
    // 2e9 sparse elements: 24 GB of positions claimed by a 500-byte file.
    let p = write(&dir, "sparse.gltf", sparse_gltf(2_000_000_000));
    let e = refused(&p, &d, "sparse.gltf", &["too large", "accessor 0", "2000000000 elements", "--memory-budget"]);
    assert!(matches!(e, SceneError::TooLarge { .. }), "{e:?}");
    // A sparse accessor with more entries than elements.
    let text = sparse_gltf(0).replace("\"sparse\":{\"count\":1", "\"sparse\":{\"count\":5");
    let p = write(&dir, "sparse_over.gltf", text.replace("\"count\":0", "\"count\":2"));
    refused(&p, &d, "sparse_over.gltf", &["sparse"]);
    // A plain accessor claiming more elements than its buffer view holds.
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, Some(String::new()));
    doc["buffers"][0]["uri"] = serde_json::json!(bin.data_uri());
    doc["accessors"][0]["count"] = serde_json::json!(1_000_000_000u64);
    let p = write(&dir, "overcount.gltf", serde_json::to_string(&doc).unwrap());
    refused(&p, &d, "overcount.gltf", &["accessor 0", "buffer view"]);
    // The same model within a tiny budget: refused, naming the budget and the flag.
    let mut b = Bin::default();
    let doc = simple(&mut b, &pos, &idx, None);
    let p = write(&dir, "ok.glb", glb(&doc, &b.bytes));
    assert!(Scene::load_with(&p, &d).is_ok());
    let tiny = LoadOptions { limits: Limits { memory_bytes: 64, ..Limits::default() }, ..Default::default() };
    refused(&p, &tiny, "ok.glb", &["too large", "budget", "--memory-budget"]);
    // ... and through a scene file that places it: the model's file is named.
    let s = write(
        &dir,
        "placed.toml",
        format!("{HEAD}[environment]\nprocedural = \"sky\"\n[[object]]\nname = \"m\"\nfile = \"sparse.gltf\"\n"),
    );
    refused(&s, &d, "sparse.gltf", &["too large"]);
}

/// A minimal scanline EXR header (RGB half, no compression) claiming `w` x `h` pixels.
fn exr_header(w: i32, h: i32) -> Vec<u8> {
    fn attr(out: &mut Vec<u8>, name: &str, ty: &str, data: &[u8]) {
        out.extend(name.as_bytes());
        out.push(0);
        out.extend(ty.as_bytes());
        out.push(0);
        out.extend((data.len() as i32).to_le_bytes());
        out.extend(data);
    }
    let mut ch = Vec::new();
    for c in ["B", "G", "R"] {
        ch.extend(c.as_bytes());
        ch.push(0);
        ch.extend(1i32.to_le_bytes()); // half
        ch.extend([0u8, 0, 0, 0]); // pLinear + reserved
        ch.extend(1i32.to_le_bytes());
        ch.extend(1i32.to_le_bytes());
    }
    ch.push(0);
    let boxi = |w: i32, h: i32| [0i32, 0, w - 1, h - 1].iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
    let mut out = Vec::new();
    out.extend(20000630i32.to_le_bytes());
    out.extend(2i32.to_le_bytes());
    attr(&mut out, "channels", "chlist", &ch);
    attr(&mut out, "compression", "compression", &[0]);
    attr(&mut out, "dataWindow", "box2i", &boxi(w, h));
    attr(&mut out, "displayWindow", "box2i", &boxi(w, h));
    attr(&mut out, "lineOrder", "lineOrder", &[0]);
    attr(&mut out, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut out, "screenWindowCenter", "v2f", &[0u8; 8]);
    attr(&mut out, "screenWindowWidth", "float", &1f32.to_le_bytes());
    out.push(0);
    out.extend([0u8; 32]);
    out
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// A PNG signature and IHDR chunk (valid CRC) claiming `w` x `h` RGBA8 pixels, nothing more.
fn png_header(w: u32, h: u32) -> Vec<u8> {
    let mut chunk = b"IHDR".to_vec();
    chunk.extend(w.to_be_bytes());
    chunk.extend(h.to_be_bytes());
    chunk.extend([8, 6, 0, 0, 0]);
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    out.extend(13u32.to_be_bytes());
    out.extend(&chunk);
    out.extend(crc32(&chunk).to_be_bytes());
    // an empty IDAT: decoders stop reading the header there
    out.extend(0u32.to_be_bytes());
    out.extend(b"IDAT");
    out.extend(crc32(b"IDAT").to_be_bytes());
    out
}

#[test]
fn image_headers_are_checked_before_decoding() {
    let dir = temp_dir("limits-images");
    let d = LoadOptions::default();
    // EXR: 100000 x 100000 (120 GB as f32 RGB) in 345 bytes.
    write(&dir, "huge.exr", exr_header(100_000, 100_000));
    let s = write(&dir, "exr.toml", format!("{HEAD}[environment]\nfile = \"huge.exr\"\n"));
    refused(&s, &d, "huge.exr", &["too large", "100000x100000"]);
    // Within the largest side but over the budget.
    write(&dir, "big.exr", exr_header(16_000, 16_000));
    let s = write(&dir, "big_exr.toml", format!("{HEAD}[environment]\nfile = \"big.exr\"\n"));
    refused(&s, &d, "big.exr", &["too large", "16000x16000", "budget"]);
    // Radiance HDR: the header's resolution line.
    write(&dir, "huge.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n\0\0\0\0");
    let s = write(&dir, "hdr.toml", format!("{HEAD}[environment]\nfile = \"huge.hdr\"\n"));
    refused(&s, &d, "huge.hdr", &["too large", "100000x100000"]);
    // A PNG texture file of a scene.
    write(&dir, "huge.png", png_header(100_000, 100_000));
    let s = write(
        &dir,
        "tex.toml",
        format!("{HEAD}[environment]\nprocedural = \"sky\"\n[materials.m]\ntype = \"diffuse\"\nalbedo = 0.5\nalbedo_map = {{ file = \"huge.png\" }}\n[[object]]\nname = \"c\"\nmesh = {{ type = \"cube\", size = 1.0 }}\nmaterial = \"m\"\n"),
    );
    refused(&s, &d, "huge.png", &["too large", "100000x100000"]);
    // A PNG inside a glTF (data URI): the model's file is named.
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let mut doc = simple(&mut bin, &pos, &idx, Some(String::new()));
    doc["buffers"][0]["uri"] = serde_json::json!(bin.data_uri());
    doc["images"] =
        serde_json::json!([{ "uri": format!("data:image/png;base64,{}", base64(&png_header(60_000, 60_000))) }]);
    doc["textures"] = serde_json::json!([{ "source": 0 }]);
    doc["materials"] = serde_json::json!([{ "pbrMetallicRoughness": { "baseColorTexture": { "index": 0 } } }]);
    doc["meshes"][0]["primitives"][0]["material"] = serde_json::json!(0);
    let p = write(&dir, "textured.gltf", serde_json::to_string(&doc).unwrap());
    refused(&p, &d, "textured.gltf", &["too large", "image 0", "60000x60000"]);
}

#[test]
fn scene_files_have_a_size_limit() {
    let dir = temp_dir("limits-scene");
    let opts = LoadOptions { limits: Limits { max_scene_file_bytes: 1000, ..Limits::default() }, ..Default::default() };
    let s =
        write(&dir, "long.toml", format!("{HEAD}[environment]\nprocedural = \"sky\"\n{}", "# padding\n".repeat(200)));
    refused(&s, &opts, "long.toml", &["too large", "scene file"]);
}
