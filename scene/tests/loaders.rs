//! Round trips for every loader: glTF (.gltf embedded / external buffer, .glb), animations,
//! skinning, morph targets, textures, EXR (several encodings), Radiance HDR.

mod common;
use common::*;
use glam::{Mat4, Vec3};
use penumbra_scene::{BrdfKind, Environment, Scene, SceneError};
use serde_json::json;
use std::path::Path;

fn approx(a: Vec3, b: Vec3, eps: f32) -> bool {
    (a - b).abs().max_element() < eps
}

#[test]
fn gltf_embedded_external_and_glb_give_the_same_scene() {
    let dir = temp_dir("roundtrip");
    let (pos, idx) = tetra();
    // .gltf with an external .bin
    let mut bin = Bin::default();
    let doc = simple(&mut bin, &pos, &idx, Some("tet data.bin".into()));
    std::fs::write(dir.join("tet data.bin"), &bin.bytes).unwrap();
    std::fs::write(dir.join("ext.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    // .gltf with a data URI
    let doc2 = simple(&mut Bin::default(), &pos, &idx, Some(bin.data_uri()));
    std::fs::write(dir.join("emb.gltf"), serde_json::to_vec(&doc2).unwrap()).unwrap();
    // .glb
    let doc3 = simple(&mut Bin::default(), &pos, &idx, None);
    std::fs::write(dir.join("bin.glb"), glb(&doc3, &bin.bytes)).unwrap();

    for f in ["ext.gltf", "emb.gltf", "bin.glb"] {
        let s = Scene::load(dir.join(f)).unwrap_or_else(|e| panic!("{e}"));
        // model + ground plane
        assert_eq!(s.objects.len(), 2, "{f}");
        let m = &s.meshes[s.objects[0].mesh];
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.indices, idx);
        for (k, p) in m.positions.iter().enumerate() {
            assert_eq!(p.to_array(), [pos[3 * k], pos[3 * k + 1], pos[3 * k + 2]]);
        }
        // Normals were missing: computed, unit length, and the repair is reported.
        assert!(m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5));
        assert!(s.warnings.iter().any(|w| w.contains(f) && w.contains("no normals")), "{:?}", s.warnings);
        assert!(m.is_closed());
        // Node translation.
        assert_eq!(s.objects[0].transform, Mat4::from_translation(Vec3::Y));
        // Metallic-roughness material mapped to Cook-Torrance: metal -> no diffuse, F0 = base.
        let mat = &s.materials[s.objects[0].material];
        assert_eq!(mat.kind, BrdfKind::CookTorrance);
        assert_eq!(mat.name, "metal");
        assert!(approx(mat.albedo, Vec3::ZERO, 1e-6) && approx(mat.specular, Vec3::new(0.8, 0.6, 0.2), 1e-6));
        assert!((mat.roughness - 0.3).abs() < 1e-6);
        // Bare model scene: environment, ground under the model, camera sees the model.
        assert!(s.environment.is_some());
        let ground = s.world_at(1, 0.0).transform_point3(Vec3::ZERO);
        assert!((ground.y - 1.0).abs() < 1e-6, "ground at the model's lowest point");
        let c = &s.camera;
        let center = Vec3::new(0.5, 1.5, 0.5);
        let clip = c.proj(1.0) * c.view() * center.extend(1.0);
        assert!(clip.w > 0.0 && (clip.x / clip.w).abs() < 0.2 && (clip.y / clip.w).abs() < 0.2);
        for corner in
            [Vec3::new(0.0, 1.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 1.0, 1.0)]
        {
            let q = c.proj(1.0) * c.view() * corner.extend(1.0);
            assert!(q.w > c.near && (q.x / q.w).abs() < 1.0 && (q.y / q.w).abs() < 1.0, "{f}: {corner} not in view");
        }
        let r = s.requirements();
        assert!(r.environment_light && !r.moving_objects && !r.deforming_objects);
    }
}

#[test]
fn gltf_node_animation_moves_object_with_prev_transform() {
    let dir = temp_dir("nodeanim");
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let p = bin.f32s(&pos, "VEC3");
    let i = bin.u32s(&idx);
    let times = bin.f32s(&[0.0, 2.0], "SCALAR");
    let trans = bin.f32s(&[0.0, 0.0, 0.0, 2.0, 0.0, 0.0], "VEC3");
    let rot = bin.f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, (0.5f32).sqrt(), 0.0, (0.5f32).sqrt()], "VEC4");
    let doc = bin.document(
        None,
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"children": [1], "scale": [2.0, 2.0, 2.0]}, {"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": p}, "indices": i}]}],
            "animations": [{"name": "slide", "samplers": [
                {"input": times, "output": trans},
                {"input": times, "output": rot, "interpolation": "STEP"}],
                "channels": [
                    {"sampler": 0, "target": {"node": 1, "path": "translation"}},
                    {"sampler": 1, "target": {"node": 1, "path": "rotation"}}]}],
        }),
    );
    let f = dir.join("anim.glb");
    std::fs::write(&f, glb(&doc, &bin.bytes)).unwrap();
    let s = Scene::load(&f).unwrap();
    assert!(s.requirements().moving_objects);
    // At t = 1: translation halfway (1, 0, 0) in the child, scaled by the parent's 2.
    let w = s.world_at(0, 1.0);
    assert!(approx(w.transform_point3(Vec3::ZERO), Vec3::new(2.0, 0.0, 0.0), 1e-5));
    // Step rotation: still identity before t = 2, 90 degrees about Y at the end.
    assert!(approx(w.transform_vector3(Vec3::X), Vec3::new(2.0, 0.0, 0.0), 1e-5));
    let w2 = s.world_at(0, 2.0);
    assert!(approx(w2.transform_vector3(Vec3::X), Vec3::new(0.0, 0.0, -2.0), 1e-5));
    // Frame reports the motion and the previous transform.
    let fr = s.at(1.0, Some(0.5));
    let inst = &fr.instances[0];
    assert!(inst.moved);
    assert!(approx(inst.prev_world.transform_point3(Vec3::ZERO), Vec3::new(1.0, 0.0, 0.0), 1e-5));
    assert!(!fr.instances[1].moved, "ground plane is static");
    // Playback loops: t = 2.5 equals t = 0.5.
    assert!(s.world_at(0, 2.5).abs_diff_eq(s.world_at(0, 0.5), 1e-6));
}

/// A vertical strip of two quads skinned to two joints; joint 1 bends 90 degrees about Z.
fn rigged(bin: &mut Bin) -> serde_json::Value {
    let pos = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 2.0, 0.0, 1.0, 2.0, 0.0];
    let idx = [0, 1, 3, 0, 3, 2, 2, 3, 5, 2, 5, 4];
    let p = bin.f32s(&pos, "VEC3");
    let i = bin.u32s(&idx);
    let j = bin.u16x4(&[[0, 0, 0, 0], [0, 0, 0, 0], [0, 1, 0, 0], [0, 1, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0]]);
    let w = bin.f32s(
        &[
            1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0,
            0.0, 0.0, 0.0,
        ],
        "VEC4",
    );
    let mut ibm = Vec::new();
    ibm.extend_from_slice(&Mat4::IDENTITY.to_cols_array());
    ibm.extend_from_slice(&Mat4::from_translation(Vec3::new(0.0, -1.0, 0.0)).to_cols_array());
    let ibm = bin.f32s(&ibm, "MAT4");
    let times = bin.f32s(&[0.0, 1.0], "SCALAR");
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let rot = bin.f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, s, s], "VEC4");
    bin.document(
        None,
        json!({
            "scenes": [{"nodes": [0, 2]}],
            "nodes": [
                {"name": "root", "children": [1]},
                {"name": "upper", "translation": [0.0, 1.0, 0.0]},
                {"name": "strip", "mesh": 0, "skin": 0, "translation": [5.0, 0.0, 0.0]}],
            "skins": [{"joints": [0, 1], "inverseBindMatrices": ibm}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": p, "JOINTS_0": j, "WEIGHTS_0": w}, "indices": i}]}],
            "animations": [{"samplers": [{"input": times, "output": rot}],
                "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}]}],
        }),
    )
}

#[test]
fn gltf_skinning_bends_the_strip() {
    let dir = temp_dir("skin");
    let mut bin = Bin::default();
    let doc = rigged(&mut bin);
    let f = dir.join("rig.glb");
    std::fs::write(&f, glb(&doc, &bin.bytes)).unwrap();
    let s = Scene::load(&f).unwrap_or_else(|e| panic!("{e}"));
    let r = s.requirements();
    assert!(r.deforming_objects && !r.moving_objects, "{r:?}");
    // Skinned mesh ignores its node's translation (glTF rule).
    assert_eq!(s.objects[0].transform, Mat4::IDENTITY);
    // t = 0: rest pose.
    let m0 = s.deformed_mesh(0, 0.0);
    assert!(approx(m0.positions[4], Vec3::new(0.0, 2.0, 0.0), 1e-5));
    // t = 1: joint 1 rotated 90 degrees about Z at (0,1,0): (0,2,0) -> (-1,1,0), (1,2,0) -> (-1,2,0).
    let m1 = s.deformed_mesh(0, 1.0);
    assert!(approx(m1.positions[4], Vec3::new(-1.0, 1.0, 0.0), 1e-5), "{:?}", m1.positions[4]);
    assert!(approx(m1.positions[5], Vec3::new(-1.0, 2.0, 0.0), 1e-5), "{:?}", m1.positions[5]);
    // Half weights at the joint: (1,1,0) -> average of (1,1,0) and (0,2,0) = (0.5,1.5,0).
    assert!(approx(m1.positions[3], Vec3::new(0.5, 1.5, 0.0), 1e-5), "{:?}", m1.positions[3]);
    // Root-bound vertices stay.
    assert!(approx(m1.positions[1], Vec3::new(1.0, 0.0, 0.0), 1e-6));
    // t = 0.5: 45 degrees.
    let m = s.deformed_mesh(0, 0.5);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert!(approx(m.positions[4], Vec3::new(-h, 1.0 + h, 0.0), 1e-5), "{:?}", m.positions[4]);
    // Normals stay unit; the frame flags the deformation.
    assert!(m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-4));
    let fr = s.at(0.5, Some(0.4));
    assert!(fr.instances[0].deformed && fr.instances[0].prev_deformed_mesh.is_some());
    assert!(!s.at(0.5, None).instances[0].deformed);
}

#[test]
fn gltf_morph_target_weights_animate() {
    let dir = temp_dir("morph");
    let mut bin = Bin::default();
    let p = bin.f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], "VEC3");
    let i = bin.u32s(&[0, 1, 2]);
    let d = bin.f32s(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "VEC3");
    let times = bin.f32s(&[0.0, 2.0], "SCALAR");
    let weights = bin.f32s(&[0.0, 1.0], "SCALAR");
    let doc = bin.document(
        None,
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"weights": [0.25], "primitives": [{"attributes": {"POSITION": p}, "indices": i, "targets": [{"POSITION": d}]}]}],
            "animations": [{"samplers": [{"input": times, "output": weights}],
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]}],
        }),
    );
    let f = dir.join("morph.glb");
    std::fs::write(&f, glb(&doc, &bin.bytes)).unwrap();
    let s = Scene::load(&f).unwrap_or_else(|e| panic!("{e}"));
    assert!(s.requirements().deforming_objects);
    for (t, z) in [(0.0f32, 0.0f32), (1.0, 0.5), (2.0, 1.0)] {
        let m = s.deformed_mesh(0, t);
        assert!((m.positions[2].z - z).abs() < 1e-6, "t={t}: {:?}", m.positions[2]);
        assert_eq!(m.positions[0], Vec3::ZERO);
    }
    // Without animation the mesh default weight applies.
    let f2 = dir.join("scene.toml");
    std::fs::write(
        &f2,
        "[camera]\neye = [0, 0, 3]\ntarget = 0\n[environment]\nprocedural = \"sky\"\n[[object]]\nfile = \"morph.glb\"\nanimation = false\n",
    )
    .unwrap();
    let s = Scene::load(&f2).unwrap_or_else(|e| panic!("{e}"));
    assert!((s.deformed_mesh(0, 1.0).positions[2].z - 0.25).abs() < 1e-6);
    assert!(!s.requirements().deforming_objects);
}

#[test]
fn gltf_base_color_texture_is_loaded_linear() {
    let dir = temp_dir("texture");
    // 2x1 PNG: sRGB 255 and 128.
    let img = image::RgbaImage::from_raw(2, 1, vec![255, 0, 0, 255, 128, 128, 128, 255]).unwrap();
    img.save(dir.join("tex.png")).unwrap();
    let (pos, idx) = tetra();
    let mut bin = Bin::default();
    let p = bin.f32s(&pos, "VEC3");
    let uv = bin.f32s(&[0.0; 8], "VEC2");
    let i = bin.u32s(&idx);
    let doc = bin.document(
        Some(bin.data_uri()),
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": p, "TEXCOORD_0": uv}, "indices": i, "material": 0}]}],
            "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0}}],
            "textures": [{"source": 0}],
            "images": [{"uri": "tex.png"}],
        }),
    );
    std::fs::write(dir.join("t.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    let s = Scene::load(dir.join("t.gltf")).unwrap_or_else(|e| panic!("{e}"));
    let ex = s.material_extra(s.objects[0].material);
    let tex = &s.textures[ex.albedo_map.unwrap()];
    assert_eq!((tex.width, tex.height), (2, 1));
    assert_eq!(tex.texels[0], [1.0, 0.0, 0.0, 1.0]);
    assert!((tex.texels[1][0] - 0.2158605).abs() < 1e-4, "sRGB 128 -> linear {}", tex.texels[1][0]);
    assert!(s.requirements().spatially_varying_materials);
}

#[test]
fn real_assets_load() {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets");
    let s = Scene::load(assets.join("bunny.glb")).unwrap();
    let m = &s.meshes[s.objects[0].mesh];
    assert_eq!(m.positions.len(), 2826);
    assert_eq!(m.triangle_count(), 5648);
    assert!(m.is_closed(), "{:?}", m.edge_stats());
    assert!(m.is_closed_outward(), "the bunny is wound counter-clockwise from outside");
    // suzi (open mesh) from the shared assets, when present.
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/assets/suzi.glb");
    if shared.exists() {
        let s = Scene::load(&shared).unwrap();
        let m = &s.meshes[s.objects[0].mesh];
        assert!(!m.is_closed());
        assert_eq!(m.edge_stats().boundary, 160);
    }
}

fn write_exr(path: &Path, w: usize, h: usize, encoding: exr::prelude::Encoding, half: bool, alpha: bool) {
    use exr::prelude::*;
    let f = |x: usize, y: usize| (x as f32 * 0.5 + 0.25, y as f32 * 2.0 + 1.0, (x + y) as f32 * 100.0);
    let attrs = LayerAttributes::named("main");
    let result = match (half, alpha) {
        (false, false) => {
            let ch = SpecificChannels::rgb(|p: Vec2<usize>| f(p.x(), p.y()));
            Image::from_layer(Layer::new((w, h), attrs, encoding, ch)).write().to_file(path)
        }
        (true, true) => {
            let ch = SpecificChannels::rgba(|p: Vec2<usize>| {
                let (r, g, b) = f(p.x(), p.y());
                (f16::from_f32(r), f16::from_f32(g), f16::from_f32(b), f16::from_f32(0.5))
            });
            Image::from_layer(Layer::new((w, h), attrs, encoding, ch)).write().to_file(path)
        }
        (true, false) => {
            let ch = SpecificChannels::rgb(|p: Vec2<usize>| {
                let (r, g, b) = f(p.x(), p.y());
                (f16::from_f32(r), f16::from_f32(g), f16::from_f32(b))
            });
            Image::from_layer(Layer::new((w, h), attrs, encoding, ch)).write().to_file(path)
        }
        (false, true) => unreachable!(),
    };
    result.unwrap();
}

#[test]
fn exr_round_trips_in_several_encodings() {
    use exr::prelude::*;
    let dir = temp_dir("exr");
    let (w, h) = (37, 19);
    let cases = [
        ("f32-scan-none", Compression::Uncompressed, Blocks::ScanLines, false, false),
        ("half-tiled-zip", Compression::ZIP16, Blocks::Tiles(Vec2(16, 8)), true, true),
        ("half-scan-piz", Compression::PIZ, Blocks::ScanLines, true, false),
        ("half-scan-rle", Compression::RLE, Blocks::ScanLines, true, true),
        ("f32-tiled-zips", Compression::ZIP1, Blocks::Tiles(Vec2(8, 8)), false, false),
    ];
    for (name, compression, blocks, half, alpha) in cases {
        let p = dir.join(format!("{name}.exr"));
        write_exr(&p, w, h, Encoding { compression, blocks, line_order: LineOrder::Increasing }, half, alpha);
        let env = Environment::load(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((env.width, env.height), (w as u32, h as u32), "{name}");
        for (x, y) in [(0, 0), (5, 3), (36, 18), (20, 10)] {
            let t = env.texels[y * w + x];
            let e = [x as f32 * 0.5 + 0.25, y as f32 * 2.0 + 1.0, (x + y) as f32 * 100.0];
            for k in 0..3 {
                let tol = if half { e[k].abs() * 1e-3 + 1e-3 } else { 0.0 };
                assert!((t[k] - e[k]).abs() <= tol, "{name} ({x},{y})[{k}]: {} vs {}", t[k], e[k]);
            }
        }
    }
}

#[test]
fn dwab_environment_loads() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/sunset-dwab.exr");
    let env = Environment::load(&p).unwrap_or_else(|e| panic!("{e}"));
    assert!(env.width >= 2 * env.height / 2 && env.width > 0);
    let max = env.texels.iter().flatten().fold(0.0f32, |m, &c| m.max(c));
    let mean = env.texels.iter().flatten().sum::<f32>() / (env.texels.len() * 3) as f32;
    assert!(max > 10.0 && mean > 0.0 && mean < max, "max {max} mean {mean}");
    // The sun is above the horizon: the brightest texel is in the upper half.
    let k = env.texels.iter().enumerate().max_by(|a, b| a.1[0].total_cmp(&b.1[0])).unwrap().0;
    assert!((k as u32 / env.width) < env.height / 2);
}

#[test]
fn hdr_round_trip() {
    let dir = temp_dir("hdr");
    let (w, h) = (8usize, 4usize);
    let px: Vec<image::Rgb<f32>> = (0..w * h).map(|i| image::Rgb([i as f32 * 0.5, 1.0, 100.0 + i as f32])).collect();
    let p = dir.join("env.hdr");
    let file = std::io::BufWriter::new(std::fs::File::create(&p).unwrap());
    image::codecs::hdr::HdrEncoder::new(file).encode(&px, w, h).unwrap();
    let env = Environment::load(&p).unwrap();
    assert_eq!((env.width, env.height), (8, 4));
    for (i, t) in env.texels.iter().enumerate() {
        let e = px[i].0;
        for k in 0..3 {
            // RGBE keeps 8 bits of mantissa per pixel (relative to the largest channel).
            assert!((t[k] - e[k]).abs() <= e[0].max(e[1]).max(e[2]) / 128.0, "{i}: {t:?} vs {e:?}");
        }
    }
    // Through a scene file, with intensity and rotation.
    let toml = "[camera]\neye = [0, 0, 3]\ntarget = 0\n[environment]\nfile = \"env.hdr\"\nintensity = 3\nrotation_deg = 90\n[[object]]\nmesh = { type = \"sphere\", radius = 1 }\n";
    std::fs::write(dir.join("s.toml"), toml).unwrap();
    let s = Scene::load(dir.join("s.toml")).unwrap_or_else(|e| panic!("{e}"));
    let e = s.environment.as_ref().unwrap();
    assert_eq!((e.width, e.height, e.intensity), (8, 4, 3.0));
    assert!((e.rotation - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
    assert_eq!(e.texels, env.texels);
    assert!(s.requirements().environment_light);
}

#[test]
fn environment_orientation_convention() {
    // A map that is bright only in the column at u = 0.25 (towards +X), upper half.
    let (w, h) = (16u32, 8u32);
    let mut texels = vec![[0.0f32; 3]; (w * h) as usize];
    texels[(2 * w + 4) as usize] = [1.0, 1.0, 1.0];
    let env = Environment { width: w, height: h, texels, intensity: 2.0, rotation: 0.0 };
    let d = Environment::direction(4.5 / 16.0, 2.5 / 8.0);
    assert!(d.x > 0.6 && d.y > 0.5 && d.z.abs() < 0.2, "{d}");
    assert_eq!(env.radiance(d), Vec3::splat(2.0));
    // Rotating the map by 90 degrees about +Y moves that texel from +X to -Z.
    let rotated = Environment { rotation: std::f32::consts::FRAC_PI_2, ..env.clone() };
    let d2 = glam::Quat::from_rotation_y(std::f32::consts::FRAC_PI_2) * d;
    assert!(d2.z < -0.6);
    assert_eq!(rotated.radiance(d2), Vec3::splat(2.0));
    assert_eq!(rotated.radiance(d), Vec3::ZERO);
    let (u, v) = Environment::uv(Vec3::Z);
    assert!((u - 0.5).abs() < 1e-6 && (v - 0.5).abs() < 1e-6);
}

#[test]
fn error_type_is_displayable_with_path() {
    let e = SceneError::UnknownFormat { path: "a/b.obj".into() };
    assert_eq!(e.path(), Path::new("a/b.obj"));
    assert!(e.to_string().starts_with("a/b.obj: "));
}

#[test]
fn negative_environment_texels_are_black_for_everyone_and_reported() {
    // studio.exr holds texels with channels down to -149: the loader blacks out each such texel
    // (the whole texel, as the GPU map and the reference read it) so that every technique's
    // fits, cubes, tables and SATs see the same radiance, and says so in the scene's warnings.
    let raw = Environment::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/studio.exr")).unwrap();
    let bad = raw.bad_texels();
    assert!(bad > 0, "studio.exr no longer has negative texels: pick another test map");
    let scene =
        penumbra_scene::Scene::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/hat_on_cloth.toml")).unwrap();
    let env = scene.environment.as_ref().unwrap();
    assert_eq!(env.bad_texels(), 0);
    let changed = raw.texels.iter().zip(&env.texels).filter(|(a, b)| a != b).count();
    assert_eq!(changed, bad, "only the bad texels change");
    assert!(env.texels.iter().zip(&raw.texels).all(|(t, r)| *t == [0.0; 3] || t == r));
    let w = scene.warnings.iter().find(|w| w.contains("read as black")).expect("a warning");
    assert!(w.contains("studio.exr") && w.contains(&bad.to_string()), "{w}");
    let mut e = Environment {
        width: 2,
        height: 1,
        texels: vec![[1.0, -0.0, 2.0], [f32::NAN, 1.0, 1.0]],
        intensity: 1.0,
        rotation: 0.0,
    };
    assert_eq!(e.repair_texels(), 1);
    assert_eq!(e.texels, vec![[1.0, -0.0, 2.0], [0.0; 3]]);
}

/// `scenes/assets/sun_and_spot.gltf`: its KHR_lights_punctual sun and spot become scene lights
/// (placed by their nodes, candela and lux over 683 lm/W), its perspective camera the scene's
/// camera, its emissive material an emission, its normal map a normal map tiled four times by
/// its KHR_texture_transform (read, not warned about).
#[test]
fn gltf_lights_camera_and_ignored_features() {
    use penumbra_scene::LightKind;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/sun_and_spot.gltf");
    let s = Scene::load(&path).unwrap();
    assert_eq!(s.lights.len(), 2, "{:?}", s.lights);
    let sun = s.lights.iter().find(|l| l.name == "sun").unwrap();
    assert_eq!(sun.kind, LightKind::Directional);
    assert!(approx(sun.direction, Vec3::new(-0.5, -1.0, -0.3).normalize(), 1e-4), "{:?}", sun.direction);
    assert!((sun.intensity - 3.0).abs() < 1e-4, "sun irradiance {}", sun.intensity);
    let spot = s.lights.iter().find(|l| l.name == "spot").unwrap();
    let LightKind::Spot { inner_deg, outer_deg } = spot.kind else { panic!("{:?}", spot.kind) };
    assert!((inner_deg - 0.35f32.to_degrees()).abs() < 1e-3 && (outer_deg - 0.6f32.to_degrees()).abs() < 1e-3);
    assert!(approx(spot.position, Vec3::new(1.6, 2.4, 1.2), 1e-5), "{:?}", spot.position);
    assert!(approx(spot.direction, Vec3::new(-1.6, -2.4, -1.2).normalize(), 1e-4), "{:?}", spot.direction);
    assert!((spot.intensity - 8.0).abs() < 1e-4);
    let c = &s.camera;
    assert!(approx(c.eye, Vec3::new(0.0, 2.2, 4.2), 1e-5), "{:?}", c.eye);
    let forward = (c.target - c.eye).normalize();
    assert!(approx(forward, (Vec3::new(0.0, 0.35, 0.0) - c.eye).normalize(), 1e-4), "{forward:?}");
    assert!((c.fov_y_deg - 0.75f32.to_degrees()).abs() < 1e-3 && c.near == 0.05 && c.far == 50.0, "{c:?}");
    let w = s.warnings.join("\n");
    // its normal map, its texture transform and its emissive material are read, not warned about
    assert!(!w.contains("normal map") && !w.contains("emission") && !w.contains("KHR_texture_transform"), "{w}");
    let crate_m = s.materials.iter().position(|m| m.name == "crate").unwrap();
    let x = s.material_extra(crate_m);
    assert!(x.normal_map.is_some() && x.normal_scale == 1.0, "{x:?}");
    let t = x.uv_transform.expect("the crate's texture transform");
    assert_eq!((t.offset, t.rotation, t.scale), ([0.0, 0.0], 0.0, [4.0, 4.0]));
    let crate_uvs = s.objects.iter().filter(|o| o.material == crate_m).flat_map(|o| &s.meshes[o.mesh].uvs);
    assert!(crate_uvs.fold(0.0f32, |m, uv| m.max(uv.x).max(uv.y)) > 3.9, "the crate's UVs span 0..4");
    let lamp = s.materials.iter().position(|m| m.name == "lamp").unwrap();
    assert_eq!(s.material_extra(lamp).emission, Vec3::new(1.0, 0.9, 0.5));
    assert_eq!(s.material_extra(lamp).emission_map, None);
    // the same model placed by a scene file: the file's camera wins, and the model's is named
    let dir = common::temp_dir("sun_and_spot");
    let toml = format!(
        "[camera]\neye = [0, 1, 5]\ntarget = [0, 0, 0]\n[[object]]\nname = \"m\"\nfile = \"{}\"\n",
        path.display()
    );
    std::fs::write(dir.join("placed.toml"), toml).unwrap();
    let placed = Scene::load(dir.join("placed.toml")).unwrap();
    assert_eq!(placed.camera.eye, Vec3::new(0.0, 1.0, 5.0));
    assert_eq!(placed.lights.len(), 2);
    assert!(placed.warnings.iter().any(|w| w.contains("camera 'view' ignored")), "{:?}", placed.warnings);
}

/// Directional lights in scene files: `direction` required, no `position`, refused with a
/// medium (nothing from infinity crosses a medium that fills all space).
#[test]
fn directional_lights_in_scene_files() {
    use penumbra_scene::LightKind;
    let dir = common::temp_dir("directional");
    let head = "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[[object]]\nname = \"b\"\nmesh = { type = \"cube\", size = 1 }\n";
    let ok = format!("{head}[[light]]\ntype = \"directional\"\ndirection = [0, -2, 0]\nintensity = 2\n");
    std::fs::write(dir.join("ok.toml"), ok).unwrap();
    let s = Scene::load(dir.join("ok.toml")).unwrap();
    assert_eq!(s.lights[0].kind, LightKind::Directional);
    assert_eq!(s.lights[0].direction, Vec3::NEG_Y);
    for (name, body, needle) in [
        (
            "pos.toml",
            "type = \"directional\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\nintensity = 1\n",
            "has no position",
        ),
        ("nodir.toml", "type = \"directional\"\nintensity = 1\n", "needs a non-zero `direction`"),
        ("nopos.toml", "type = \"point\"\nintensity = 1\n", "missing `position`"),
    ] {
        std::fs::write(dir.join(name), format!("{head}[[light]]\n{body}")).unwrap();
        let e = Scene::load(dir.join(name)).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
    }
    let medium = format!(
        "{head}[medium]\nsigma_a = [0.01, 0.01, 0.01]\nsigma_s = [0.1, 0.1, 0.1]\ng = 0.5\n[[light]]\nname = \"sun\"\ntype = \"directional\"\ndirection = [0, -1, 0]\nintensity = 1\n"
    );
    std::fs::write(dir.join("medium.toml"), medium).unwrap();
    let e = Scene::load(dir.join("medium.toml")).unwrap_err();
    assert!(matches!(e, penumbra_scene::SceneError::Unsupported { .. }), "{e}");
    assert!(e.to_string().contains("directional light 'sun'") && e.to_string().contains("medium.toml"), "{e}");
}

/// A light's fixture (`fixture = "object"`): the light takes the object's motion (or must give
/// the same), the name must be one object, rigid; a directional light has none.
#[test]
fn light_fixtures_in_scene_files() {
    let dir = common::temp_dir("fixture");
    let head = "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[[object]]\nname = \"b\"\nmesh = { type = \"cube\", size = 1 }\n\
                [[object]]\nname = \"shade\"\nmesh = { type = \"dish\", radius = 0.4, depth = 0.3 }\nposition = [0, 2, 0]\n\
                motion = { type = \"oscillate\", amplitude = [0.5, 0, 0], period = 2.0 }\n";
    let ok =
        format!("{head}[[light]]\ntype = \"sphere\"\nposition = [0, 1.8, 0]\nintensity = 1\nfixture = \"shade\"\n");
    std::fs::write(dir.join("ok.toml"), ok).unwrap();
    let s = Scene::load(dir.join("ok.toml")).unwrap();
    assert_eq!(s.lights[0].fixture, Some(1));
    assert_eq!(s.lights[0].motion, s.object_info[1].motion, "the light moves with its fixture");
    let (a, b) = (s.at(0.5, None), s.at(0.0, None));
    let moved = a.lights[0].position - b.lights[0].position;
    let obj_moved = a.instances[1].world.w_axis.truncate() - b.instances[1].world.w_axis.truncate();
    assert!((moved - obj_moved).length() < 1e-5 && moved.length() > 0.1, "{moved} {obj_moved}");
    for (name, body, needle) in [
        ("unknown.toml", "type = \"point\"\nposition = [0, 1, 0]\nintensity = 1\nfixture = \"lamp\"\n", "fixture 'lamp' is no object"),
        (
            "moves.toml",
            "type = \"point\"\nposition = [0, 1, 0]\nintensity = 1\nfixture = \"shade\"\nmotion = { type = \"spin\", axis = [0, 1, 0], speed_deg = 10 }\n",
            "its motion differs from its fixture 'shade'",
        ),
        (
            "sun.toml",
            "type = \"directional\"\ndirection = [0, -1, 0]\nintensity = 1\nfixture = \"shade\"\n",
            "a directional light has no fixture",
        ),
    ] {
        std::fs::write(dir.join(name), format!("{head}[[light]]\n{body}")).unwrap();
        let e = Scene::load(dir.join(name)).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
    }
    let bent = format!(
        "{head}[[object]]\nname = \"wavy\"\nmesh = {{ type = \"plane\", size = 1, divisions = 4 }}\n\
         deform = [{{ type = \"wave\", amplitude = 0.1, wavelength = 1, period = 1 }}]\n\
         [[light]]\ntype = \"point\"\nposition = [0, 1, 0]\nintensity = 1\nfixture = \"wavy\"\n"
    );
    std::fs::write(dir.join("bent.toml"), bent).unwrap();
    let e = Scene::load(dir.join("bent.toml")).unwrap_err().to_string();
    assert!(e.contains("bent.toml") && e.contains("must be rigid"), "{e}");
}

/// Emission in scene files (`emission = [r, g, b]`) and glTF (factor x
/// KHR_materials_emissive_strength, with an emissive texture as a map); negative or non-finite
/// emission is an error.
#[test]
fn emission_from_scene_files_and_gltf() {
    let dir = common::temp_dir("emission");
    let head = "[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[[object]]\nname = \"b\"\nmesh = { type = \"cube\", size = 1 }\nmaterial = \"glow\"\n";
    std::fs::write(
        dir.join("ok.toml"),
        format!("{head}[materials.glow]\ntype = \"diffuse\"\nalbedo = 0.5\nemission = [2, 1, 0]\n"),
    )
    .unwrap();
    let s = Scene::load(dir.join("ok.toml")).unwrap();
    assert_eq!(s.material_extra(s.objects[0].material).emission, Vec3::new(2.0, 1.0, 0.0));
    // a normal map in a scene file (tangent space, linear)
    std::fs::write(
        dir.join("bumps.toml"),
        format!("{head}[materials.glow]\ntype = \"diffuse\"\nalbedo = 0.5\nnormal_map = {{ pattern = \"noise\", a = [0.5, 0.5, 1], b = [0.6, 0.5, 0.9] }}\n"),
    )
    .unwrap();
    let s = Scene::load(dir.join("bumps.toml")).unwrap();
    let x = s.material_extra(s.objects[0].material);
    let k = x.normal_map.expect("normal map");
    assert!(s.textures[k].name.ends_with(".normal"), "{}", s.textures[k].name);
    std::fs::write(
        dir.join("bad.toml"),
        format!("{head}[materials.glow]\ntype = \"diffuse\"\nalbedo = 0.5\nemission = [-1, 0, 0]\n"),
    )
    .unwrap();
    let e = Scene::load(dir.join("bad.toml")).unwrap_err().to_string();
    assert!(e.contains("bad.toml") && e.contains("emission must be finite and >= 0"), "{e}");
    // glTF: strength 4 times the factor, and the emissive texture as the emission map
    let (pos, idx) = common::tetra();
    let mut bin = Bin::default();
    let mut doc = common::simple(&mut bin, &pos, &idx, None);
    doc["extensionsUsed"] = json!(["KHR_materials_emissive_strength"]);
    doc["materials"][0]["emissiveFactor"] = json!([0.5, 0.25, 1.0]);
    doc["materials"][0]["extensions"] = json!({"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}});
    common::white_texture(&mut doc);
    doc["materials"][0]["emissiveTexture"] = json!({"index": 0});
    let p = dir.join("glow.glb");
    std::fs::write(&p, common::glb(&doc, &bin.bytes)).unwrap();
    let s = Scene::load(&p).unwrap();
    let x = s.material_extra(s.objects[0].material);
    assert_eq!(x.emission, Vec3::new(2.0, 1.0, 4.0));
    let map = x.emission_map.expect("emission map");
    assert_eq!(s.textures[map].texels[0], [1.0, 1.0, 1.0, 1.0]);
    assert!(s.warnings.iter().all(|w| !w.contains("emissive_strength")), "{:?}", s.warnings);
}

/// KHR_texture_transform (the extension's own example: the lower-left quadrant of the image,
/// rotated clockwise 90 degrees) is baked into the texture coordinates of the material's
/// primitives; a texture of the same material with another transform, and a texCoord override,
/// are said in warnings; a malformed transform is an error naming the material.
#[test]
fn gltf_texture_transform_is_baked_into_the_uvs() {
    let (pos, idx) = common::tetra();
    let mut bin = Bin::default();
    let doc = common::simple(&mut bin, &pos, &idx, None);
    let uv = bin.f32s(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.5, 0.25], "VEC2");
    let mut doc = bin.document(None, doc);
    doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = json!(uv);
    common::white_texture(&mut doc);
    doc["extensionsUsed"] = json!(["KHR_texture_transform"]);
    let tt = json!({"offset": [0.0, 1.0], "rotation": std::f64::consts::FRAC_PI_2, "scale": [0.5, 0.5]});
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] =
        json!({"index": 0, "extensions": {"KHR_texture_transform": tt}});
    let dir = common::temp_dir("texture_transform");
    let load = |doc: &serde_json::Value, name: &str| {
        let p = dir.join(name);
        std::fs::write(&p, common::glb(doc, &bin.bytes)).unwrap();
        Scene::load(&p)
    };
    let s = load(&doc, "quadrant.glb").unwrap();
    let uvs = &s.meshes[s.objects[0].mesh].uvs;
    let want = [[0.0, 1.0], [0.0, 0.5], [0.5, 1.0], [0.125, 0.75]];
    assert_eq!(uvs.len(), 4);
    for (u, w) in uvs.iter().zip(want) {
        assert!((u.x - w[0]).abs() < 1e-5 && (u.y - w[1]).abs() < 1e-5, "{uvs:?} against {want:?}");
    }
    assert!(s.warnings.iter().all(|w| !w.contains("KHR_texture_transform")), "{:?}", s.warnings);
    // a normal map of the same material with another transform, and a texCoord override
    doc["materials"][0]["normalTexture"] =
        json!({"index": 0, "extensions": {"KHR_texture_transform": {"scale": [4.0, 4.0], "texCoord": 1}}});
    let s = load(&doc, "mixed.glb").unwrap();
    let w = s.warnings.join("\n");
    assert!(w.contains("material 'metal': its normal texture has another KHR_texture_transform"), "{w}");
    assert!(w.contains("normal texture's KHR_texture_transform selects TEXCOORD_1"), "{w}");
    assert!((s.meshes[s.objects[0].mesh].uvs[1].y - 0.5).abs() < 1e-5, "the base colour's transform applies");
    // malformed: an error naming the file and the material
    doc["materials"][0]["normalTexture"] =
        json!({"index": 0, "extensions": {"KHR_texture_transform": {"scale": [4.0]}}});
    let e = load(&doc, "bad.glb").unwrap_err().to_string();
    assert!(
        e.contains("bad.glb") && e.contains("material 'metal': normal texture: KHR_texture_transform scale"),
        "{e}"
    );
}

/// The Draco-compressed bunny (`KHR_draco_mesh_compression`, the asset `bunny.glb` was decoded
/// from by other tools) decodes to the same mesh as `bunny.glb`: the same vertex and triangle
/// counts, every vertex within the Draco quantisation of one in the plain file, same normals.
#[test]
fn draco_bunny_decodes_to_the_plain_bunny() {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets");
    let draco = penumbra_scene::gltf_load::load(&assets.join("bunny-draco.glb")).unwrap_or_else(|e| panic!("{e}"));
    let plain = penumbra_scene::gltf_load::load(&assets.join("bunny.glb")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(draco.primitives.len(), 1);
    let (d, p) = (&draco.primitives[0].mesh, &plain.primitives[0].mesh);
    assert_eq!(d.positions.len(), p.positions.len());
    assert_eq!(d.indices.len(), p.indices.len());
    assert!(!draco.warnings.iter().any(|w| w.contains("KHR_draco")), "{:?}", draco.warnings);
    // Bounding boxes agree to the quantisation (the file's accessor min/max: about 1.8 units wide).
    let bounds = |m: &penumbra_scene::MeshData| {
        m.positions.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), &v| (lo.min(v), hi.max(v)))
    };
    let ((dl, dh), (pl, ph)) = (bounds(d), bounds(p));
    assert!(approx(dl, pl, 2e-3) && approx(dh, ph, 2e-3), "{dl} {dh} against {pl} {ph}");
    // Every decoded vertex has a plain vertex within 2e-3 with a normal within 3 degrees.
    let mut worst = 0f32;
    for (v, n) in d.positions.iter().zip(&d.normals) {
        let k = (0..p.positions.len())
            .min_by(|&a, &b| p.positions[a].distance_squared(*v).total_cmp(&p.positions[b].distance_squared(*v)))
            .unwrap();
        worst = worst.max(p.positions[k].distance(*v));
        assert!(n.dot(p.normals[k]) > 3f32.to_radians().cos(), "normal {n} against {}", p.normals[k]);
    }
    assert!(worst < 2e-3, "farthest decoded vertex from the plain mesh: {worst}");
    // The same surface: total area within 0.1 %.
    let area = |m: &penumbra_scene::MeshData| -> f32 {
        m.indices
            .chunks_exact(3)
            .map(|t| {
                let [a, b, c] = [0, 1, 2].map(|i| m.positions[t[i] as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    };
    assert!((area(d) / area(p) - 1.0).abs() < 1e-3, "{} against {}", area(d), area(p));
    assert!(d.is_closed(), "the decoded bunny is closed like the plain one");
}

/// `is_closed_outward` (the G-buffer culls such meshes' back faces): closed, counter-clockwise
/// from outside, the vertex normals on the same side; not an open mesh, a mesh wound inside
/// out, or one whose normals point inwards.
#[test]
fn closed_outward_meshes_are_told_apart() {
    use penumbra_scene::MeshData;
    let sphere = MeshData::uv_sphere(0.7, 24, 12);
    let (cube, torus) = (MeshData::cube(0.5), MeshData::torus(1.0, 0.3, 24, 12));
    for m in [&sphere, &cube, &torus] {
        assert!(m.is_closed_outward(), "{}", m.name);
        let mut inside_out = m.clone();
        for t in inside_out.indices.chunks_exact_mut(3) {
            t.swap(1, 2);
        }
        assert!(inside_out.is_closed() && !inside_out.is_closed_outward(), "{} wound inside out", m.name);
        let mut inward = m.clone();
        for n in &mut inward.normals {
            *n = -*n;
        }
        assert!(!inward.is_closed_outward(), "{} with inward normals", m.name);
        // both: consistent, but the winding's outside is the normals' inside
        let mut both = inside_out.clone();
        both.normals = inward.normals.clone();
        assert!(!both.is_closed_outward(), "{} inside out with inward normals", m.name);
    }
    assert!(!MeshData::plane(2.0, 2).is_closed_outward());
    let mut open = sphere.clone();
    open.indices.truncate(open.indices.len() - 3);
    assert!(!open.is_closed_outward());
}
