//! Mutated and truncated glTF / scene files never panic (not even a panic caught inside the
//! loader): every outcome is Ok or a SceneError naming the file.

mod common;
use common::*;
use penumbra_scene::Scene;
use std::sync::atomic::{AtomicUsize, Ordering};

static PANICS: AtomicUsize = AtomicUsize::new(0);

/// xorshift, deterministic.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// Count every panic of the process (caught or not).
fn install_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let prev = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICS.fetch_add(1, Ordering::SeqCst);
            prev(info);
        }));
    });
}

fn iterations(default: usize) -> usize {
    std::env::var("PENUMBRA_FUZZ_ITERS").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

#[test]
fn mutated_inputs_never_panic() {
    install_hook();
    let dir = temp_dir("fuzz");
    // A skinned, animated, morphing file exercises most readers.
    let mut bin = Bin::default();
    let (pos, idx) = tetra();
    let p = bin.f32s(&pos, "VEC3");
    let n = bin.f32s(&[0.0, 0.0, 1.0].repeat(4), "VEC3");
    let uv = bin.f32s(&[0.5; 8], "VEC2");
    let i = bin.u32s(&idx);
    let j = bin.u16x4(&[[0, 1, 0, 0]; 4]);
    let w = bin.f32s(&[0.5, 0.5, 0.0, 0.0].repeat(4), "VEC4");
    let d = bin.f32s(&[0.0, 0.1, 0.0].repeat(4), "VEC3");
    let times = bin.f32s(&[0.0, 1.0], "SCALAR");
    let tr = bin.f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], "VEC3");
    let wt = bin.f32s(&[0.0, 1.0], "SCALAR");
    let ibm = bin.f32s(&glam::Mat4::IDENTITY.to_cols_array().repeat(2), "MAT4");
    let doc = bin.document(
        None,
        serde_json::json!({
            "scenes": [{"nodes": [0, 2]}],
            "nodes": [{"children": [1]}, {"translation": [0.0, 1.0, 0.0]}, {"mesh": 0, "skin": 0}],
            "skins": [{"joints": [0, 1], "inverseBindMatrices": ibm}],
            "meshes": [{"weights": [0.0], "primitives": [{"attributes": {"POSITION": p, "NORMAL": n, "TEXCOORD_0": uv, "JOINTS_0": j, "WEIGHTS_0": w}, "indices": i, "targets": [{"POSITION": d}], "material": 0}]}],
            "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0]}}],
            "animations": [{"samplers": [{"input": times, "output": tr}, {"input": times, "output": wt}],
                "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}},
                             {"sampler": 1, "target": {"node": 2, "path": "weights"}}]}],
        }),
    );
    let good = glb(&doc, &bin.bytes);
    let s = Scene::load({
        let f = dir.join("good.glb");
        std::fs::write(&f, &good).unwrap();
        f
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(s.requirements().deforming_objects);
    let json = serde_json::to_string(&doc).unwrap();
    // PENUMBRA_FUZZ_ITERS / PENUMBRA_FUZZ_SEED run longer or other campaigns by hand.
    let iters = iterations(400);
    let seed: u64 = std::env::var("PENUMBRA_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(0x9e3779b97f4a7c15);
    let mut rng = Rng(seed | 1);
    let f = dir.join("m.glb");
    let g = dir.join("m.gltf");
    let mut errors = 0;
    for k in 0..iters {
        // Binary mutation: flip a few bytes of the GLB.
        let mut b = good.clone();
        for _ in 0..1 + k % 4 {
            let at = (rng.next() as usize) % b.len();
            b[at] = rng.next() as u8;
        }
        std::fs::write(&f, &b).unwrap();
        match Scene::load(&f) {
            Ok(s) => {
                for t in [0.0, 0.5, 1.0] {
                    let fr = s.at(t, Some(t - 0.1));
                    assert!(fr.instances.iter().all(|i| i.world.is_finite()));
                }
            }
            Err(e) => {
                errors += 1;
                assert!(e.to_string().contains("m.glb"), "{e}");
            }
        }
        // JSON mutation: change a digit of the document (a .gltf with a data URI buffer).
        let mut text: Vec<u8> = json.clone().into_bytes();
        let digits: Vec<usize> = text.iter().enumerate().filter(|(_, c)| c.is_ascii_digit()).map(|(i, _)| i).collect();
        let at = digits[(rng.next() as usize) % digits.len()];
        text[at] = b"0123456789"[(rng.next() % 10) as usize];
        let mut v: serde_json::Value = match serde_json::from_slice(&text) {
            Ok(v) => v,
            Err(_) => continue,
        };
        v["buffers"][0]["uri"] = serde_json::json!(bin.data_uri());
        std::fs::write(&g, serde_json::to_vec(&v).unwrap()).unwrap();
        match Scene::load(&g) {
            Ok(s) => {
                let _ = s.at(0.7, Some(0.2));
            }
            Err(e) => assert!(e.to_string().contains("m.gltf"), "{e}"),
        }
    }
    assert!(errors > 0);
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "a loader panicked (caught or not)");
}

/// The Draco-compressed bunny with bytes of its compressed stream flipped: the Draco decoder
/// (draco-core) either decodes something or gives an error naming the file, never a panic.
#[test]
fn mutated_draco_streams_never_panic() {
    install_hook();
    let dir = temp_dir("fuzz-draco");
    let real = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/bunny-draco.glb");
    let good = std::fs::read(&real).unwrap();
    let json_len = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
    let bin_start = 20 + json_len + 8;
    let seed: u64 = std::env::var("PENUMBRA_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(0x2545f4914f6cdd1d);
    let mut rng = Rng(seed | 1);
    let f = dir.join("d.glb");
    let mut errors = 0;
    for k in 0..iterations(200) {
        let mut b = good.clone();
        // Mostly the stream's header and connectivity (its first bytes), sometimes anywhere.
        let span = if k % 2 == 0 { 64 } else { b.len() - bin_start };
        for _ in 0..1 + k % 3 {
            let at = bin_start + (rng.next() as usize) % span;
            b[at] = rng.next() as u8;
        }
        std::fs::write(&f, &b).unwrap();
        match Scene::load(&f) {
            Ok(s) => assert!(s.meshes.iter().all(|m| m.positions.iter().all(|p| p.is_finite()))),
            Err(e) => {
                errors += 1;
                assert!(e.to_string().contains("d.glb"), "{e}");
            }
        }
    }
    assert!(errors > 0);
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "a loader panicked (caught or not)");
}

/// Random numbers (including huge, tiny and negative ones) in the documented example scene.
#[test]
fn mutated_scene_files_never_panic() {
    install_hook();
    let src = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/example.toml")).unwrap();
    let dir = temp_dir("fuzz-toml");
    std::fs::create_dir_all(dir.join("assets")).unwrap();
    for a in ["studio.exr", "bunny.glb"] {
        std::fs::copy(format!("{}/../scenes/assets/{a}", env!("CARGO_MANIFEST_DIR")), dir.join("assets").join(a))
            .unwrap();
    }
    // Positions of numbers in the text.
    let bytes = src.as_bytes();
    let mut nums = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit()
            && (i == 0 || !bytes[i - 1].is_ascii_alphanumeric() && bytes[i - 1] != b'_' && bytes[i - 1] != b'.')
        {
            let s = i;
            while i < bytes.len() && (bytes[i].is_ascii_digit() || bytes[i] == b'.') {
                i += 1;
            }
            nums.push((s, i));
        } else {
            i += 1;
        }
    }
    // Only numbers outside comments.
    nums.retain(|&(s, _)| {
        let line_start = src[..s].rfind('\n').map_or(0, |k| k + 1);
        !src[line_start..s].contains('#')
    });
    let repl = ["0", "-1", "1e30", "1e-30", "-1e30", "3.5", "1024", "nan", "inf", "100000", "0.999", "-0.5"];
    let seed: u64 =
        std::env::var("PENUMBRA_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(0x1234_5678_9abc_def1);
    let mut rng = Rng(seed | 1);
    let f = dir.join("m.toml");
    let (mut ok, mut err) = (0, 0);
    for _ in 0..iterations(150) {
        let mut text = src.clone();
        let mut picks: Vec<usize> = (0..2).map(|_| (rng.next() as usize) % nums.len()).collect();
        picks.sort();
        picks.dedup();
        for &k in picks.iter().rev() {
            let (s, e) = nums[k];
            text.replace_range(s..e, repl[(rng.next() as usize) % repl.len()]);
        }
        std::fs::write(&f, &text).unwrap();
        match Scene::load(&f) {
            Ok(s) => {
                ok += 1;
                for t in [0.0f32, 1.0, 2.0] {
                    let fr = s.at(t, Some(t - 0.5));
                    assert!(fr.instances.iter().all(|i| i.world.is_finite()), "{text}");
                    assert!(fr.lights.iter().all(|l| l.position.is_finite() && l.direction.is_finite()), "{text}");
                    assert!(fr.camera.view().is_finite());
                }
            }
            Err(e) => {
                err += 1;
                assert!(e.to_string().contains("m.toml"), "{e}");
            }
        }
    }
    assert!(ok > 0 && err > 0, "ok {ok} err {err}");
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "a loader panicked");
}
