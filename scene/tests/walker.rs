//! The procedural walking figure (`penumbra_scene::walker`, `scenes/paper/walker.glb`): the file
//! is the generator's output, it loads as a skinned, animated model whose pieces are closed and
//! turned outwards, its feet stay on the floor, its hat on its head, and it walks its circle.

use glam::Vec3;
use penumbra_scene::walker::{self, node_global, HAT_NODE, HEAD_NODE, WALK_DURATION, WALK_RADIUS};
use penumbra_scene::Scene;
use std::collections::HashMap;
use std::path::PathBuf;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The checked-in file decodes to what the generator makes now: the same topology, joints,
/// materials and animation layout exactly, positions, normals, weights and keys within 1e-5 (the
/// generator's sines and cosines come from the platform's libm, whose last bit may differ
/// between CPUs, so the bytes are not compared).
#[test]
fn the_checked_in_walker_is_the_generators_output() {
    use penumbra_scene::gltf_load::load_bytes;
    use penumbra_scene::motion::Channel;
    let path = repo().join("scenes/paper/walker.glb");
    let file = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let base = path.parent().unwrap();
    let a = load_bytes(&path, &file, base).unwrap_or_else(|e| panic!("{e}"));
    let b = load_bytes(&path, &walker::walker_glb(), base).unwrap_or_else(|e| panic!("{e}"));
    let hint = "regenerate it with `penumbra asset walker`";
    let close = |x: &[f32], y: &[f32], what: &str| {
        assert_eq!(x.len(), y.len(), "{what}: lengths ({hint})");
        let d = x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
        assert!(d <= 1e-5, "{what}: differs by {d} ({hint})");
    };
    assert_eq!(a.primitives.len(), b.primitives.len(), "{hint}");
    for (k, (p, q)) in a.primitives.iter().zip(&b.primitives).enumerate() {
        assert!(p.mesh.indices == q.mesh.indices, "primitive {k}: indices differ ({hint})");
        assert!(p.joints == q.joints, "primitive {k}: joints differ ({hint})");
        assert_eq!(p.material, q.material, "primitive {k}: material ({hint})");
        let flat = |v: &[glam::Vec3]| v.iter().flat_map(|x| x.to_array()).collect::<Vec<f32>>();
        close(&flat(&p.mesh.positions), &flat(&q.mesh.positions), &format!("primitive {k} positions"));
        close(&flat(&p.mesh.normals), &flat(&q.mesh.normals), &format!("primitive {k} normals"));
        let w = |v: &Option<Vec<[f32; 4]>>| v.iter().flatten().flatten().copied().collect::<Vec<f32>>();
        close(&w(&p.weights), &w(&q.weights), &format!("primitive {k} weights"));
    }
    assert!(a.materials == b.materials, "materials differ ({hint})");
    assert_eq!((&a.rig.parent, &a.animation_names), (&b.rig.parent, &b.animation_names), "{hint}");
    assert_eq!(a.rig.skins.len(), b.rig.skins.len(), "{hint}");
    let (ca, cb) = (&a.rig.animations[0].channels, &b.rig.animations[0].channels);
    assert_eq!(ca.len(), cb.len(), "{hint}");
    for (x, y) in ca.iter().zip(cb) {
        assert_eq!(x.node, y.node, "{hint}");
        let keys = |c: &Channel| -> (Vec<f32>, Vec<f32>) {
            match c {
                Channel::Translation(t) => (t.times.clone(), t.values.iter().flat_map(|v| v.to_array()).collect()),
                Channel::Rotation(t) => (t.times.clone(), t.values.iter().flat_map(|v| v.to_array()).collect()),
                Channel::Scale(t) => (t.times.clone(), t.values.iter().flat_map(|v| v.to_array()).collect()),
                Channel::Weights(t) => (t.times.clone(), t.values.iter().flatten().copied().collect()),
            }
        };
        let ((ta, va), (tb, vb)) = (keys(&x.target), keys(&y.target));
        close(&ta, &tb, &format!("node {} key times", x.node));
        close(&va, &vb, &format!("node {} key values", x.node));
    }
}

#[test]
fn the_walker_is_skinned_closed_and_walks_its_circle_with_its_hat_on() {
    let scene = Scene::load(repo().join("scenes/paper/avs_walking_man.toml")).unwrap_or_else(|e| panic!("{e}"));
    let parts: Vec<usize> = (0..scene.objects.len()).filter(|&i| scene.objects[i].name != "floor").collect();
    assert_eq!(parts.len(), 5, "four skinned materials and the hat");
    let names: Vec<&str> = parts.iter().map(|&i| scene.objects[i].name.as_str()).collect();
    let hat = *parts
        .iter()
        .find(|&&i| scene.objects[i].name.ends_with("hat"))
        .unwrap_or_else(|| panic!("no hat among {names:?}"));
    let body: Vec<usize> = parts.iter().copied().filter(|&i| i != hat).collect();
    assert!(scene.warnings.iter().all(|w| !w.contains("walker.glb")), "{:?}", scene.warnings);
    let verts: usize = parts.iter().map(|&i| scene.meshes[scene.objects[i].mesh].positions.len()).sum();
    assert!((15_000..=20_000).contains(&verts), "{verts} vertices: with the floor about the paper's 32k");

    // every piece closed (each edge, by position, in two triangles, once each way) and its triangles
    // turned outwards (positive enclosed volume)
    for &i in &parts {
        let m = &scene.meshes[scene.objects[i].mesh];
        // vertices welded by position (the hat's creases repeat vertices)
        let key = |v: u32| (m.positions[v as usize] * 1e5).round().as_ivec3().to_array();
        let mut edges: HashMap<([i32; 3], [i32; 3]), i32> = HashMap::new();
        let mut volume = 0.0f64;
        for t in m.indices.chunks(3) {
            for k in 0..3 {
                let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
                *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
            let [p, q, r] = [t[0], t[1], t[2]].map(|v| m.positions[v as usize].as_dvec3());
            volume += p.dot(q.cross(r)) / 6.0;
        }
        let open = edges.values().filter(|&&c| c != 0).count();
        assert_eq!(open, 0, "{}: {open} edges not shared by two opposite triangles", scene.objects[i].name);
        assert!(volume > 0.0, "{}: volume {volume}", scene.objects[i].name);
    }

    let ground = |t: f32| -> (f32, Vec3) {
        let mut lo = f32::MAX;
        let (mut sum, mut n) = (Vec3::ZERO, 0.0);
        for &i in &body {
            let m = scene.deformed_mesh(i, t);
            let w = scene.world_at(i, t);
            for p in &m.positions {
                let q = w.transform_point3(*p);
                lo = lo.min(q.y);
                sum += q;
                n += 1.0;
            }
        }
        (lo, sum / n)
    };
    let rest = scene.deformed_mesh(body[0], 0.0);
    assert!(rest.positions != scene.meshes[scene.objects[body[0]].mesh].positions, "the skin deforms the mesh");
    for k in 0..64 {
        // the file's keys (30 a second) over two strides, then a few far in the lap
        let t = if k < 60 { k as f32 / 30.0 } else { (k - 59) as f32 * 1.5 };
        let (lo, centre) = ground(t);
        // a foot stands on the floor (its sole 4 mm above it) and none sinks below it
        assert!((-0.002..0.008).contains(&lo), "t = {t}: lowest point of the body at y = {lo}");
        // the body's centre follows the circle
        let r = Vec3::new(centre.x, 0.0, centre.z).length();
        assert!((r - WALK_RADIUS).abs() < 0.12, "t = {t}: centre {centre} at radius {r}");
        // the hat sits on the head: its world transform is the head joint's times its offset
        let hw = scene.world_at(hat, t);
        let expect = node_global(HAT_NODE, t);
        let d = hw.transform_point3(Vec3::ZERO) - expect.transform_point3(Vec3::ZERO);
        assert!(d.length() < 1e-3, "t = {t}: the hat is {d} off its node");
        let head = node_global(HEAD_NODE, t).transform_point3(Vec3::ZERO);
        let up = hw.transform_point3(Vec3::ZERO) - head;
        assert!((up.length() - 0.2).abs() < 1e-3 && up.y > 0.18, "t = {t}: hat {up} from the neck");
    }
    // a quarter lap moves the figure a quarter of the circle
    let a = ground(0.0).1;
    let b = ground(WALK_DURATION / 4.0).1;
    let turn = Vec3::new(a.x, 0.0, a.z).normalize().dot(Vec3::new(b.x, 0.0, b.z).normalize());
    assert!(turn.abs() < 0.15, "a quarter lap turns the figure by about 90 degrees (cos {turn})");
}
