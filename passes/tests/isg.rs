//! ISG technique CPU side: sphere sets of the scenes (coverage), per-frame sphere transform and
//! deformation, BVH bounds.

use glam::Vec3;
use penumbra_math::sphereset::measure_coverage;
use penumbra_passes::isg::{build_bvh, frame_spheres, merge_spheres, scene_sphere_sets, WorldSphere};
use penumbra_scene::Scene;
use std::path::PathBuf;

fn scene(name: &str) -> Scene {
    Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name)).expect("scene")
}

#[test]
fn bvh_parents_bound_children() {
    let mut seed = 7u64;
    let mut rnd = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 40) as f32 / (1u64 << 24) as f32
    };
    for n in [0usize, 1, 2, 3, 17, 200] {
        let spheres: Vec<WorldSphere> = (0..n)
            .map(|_| WorldSphere { center: Vec3::new(rnd(), rnd(), rnd()) * 10.0, radius: 0.05 + rnd() })
            .collect();
        let nodes = build_bvh(&spheres);
        assert_eq!(nodes.len(), if n == 0 { 0 } else { 2 * n - 1 });
        let mut leaves = vec![0; n];
        for nd in &nodes {
            if nd.info[0] < 0 {
                leaves[nd.info[2] as usize] += 1;
                continue;
            }
            for c in [nd.info[0], nd.info[1]] {
                let ch = &nodes[c as usize];
                let d = (Vec3::from_slice(&ch.sphere[..3]) - Vec3::from_slice(&nd.sphere[..3])).length();
                assert!(d + ch.sphere[3] <= nd.sphere[3] * (1.0 + 1e-5) + 1e-5, "child outside parent");
            }
        }
        assert!(leaves.iter().all(|&c| c == 1), "every sphere in exactly one leaf");
    }
    let a = WorldSphere { center: Vec3::ZERO, radius: 1.0 };
    assert_eq!(merge_spheres(a, WorldSphere { center: Vec3::X * 0.2, radius: 0.1 }), a);
}

#[test]
fn scene_sphere_sets_cover_and_follow_the_objects() {
    let s = scene("falling.toml");
    let sets = scene_sphere_sets(&s, 48);
    for (i, o) in s.objects.iter().enumerate() {
        let Some(set) = &sets[i] else {
            println!("{}: no sphere set (thin shell, non-caster or open mesh)", o.name);
            continue;
        };
        let m = &s.meshes[o.mesh];
        let cov = measure_coverage(&m.positions, &m.indices, &set.spheres, 64).unwrap();
        println!("{}: {} spheres, covered {:.3}, outside {:.4}", o.name, set.spheres.len(), cov.covered, cov.outside);
        assert!(!set.spheres.is_empty());
        assert!(cov.covered > 0.6 && cov.outside < 0.05, "{}: {cov:?}", o.name);
    }
    assert!(sets.iter().filter(|x| x.is_some()).count() >= 3, "bunny, pieces and cube have sets");
    // Spheres move with the rigid motion.
    let f0 = s.at(0.0, None);
    let f1 = s.at(0.5, Some(0.0));
    let w0 = frame_spheres(&s, &sets, &f0);
    let w1 = frame_spheres(&s, &sets, &f1);
    assert_eq!(w0.len(), w1.len());
    assert!(w0.iter().zip(&w1).any(|(a, b)| (a.center - b.center).length() > 0.05), "nothing moved");

    // Deforming hat: spheres follow the squash through their vertex anchors; cloth has none.
    let s = scene("hat_on_cloth.toml");
    let sets = scene_sphere_sets(&s, 32);
    let cloth = s.objects.iter().position(|o| o.name == "cloth").unwrap();
    let hat = s.objects.iter().position(|o| o.name == "hat").unwrap();
    assert!(sets[cloth].is_none(), "thin shell must not get spheres");
    let hs = sets[hat].as_ref().expect("hat sphere set");
    let mut heights = Vec::new();
    for t in [0.0f32, 0.5, 1.0] {
        let f = s.at(t, None);
        let w = frame_spheres(&s, &sets, &f);
        assert_eq!(w.len(), hs.spheres.len());
        let top = w.iter().map(|x| x.center.y).fold(f32::NEG_INFINITY, f32::max);
        heights.push(top);
        // Every sphere stays near the deformed surface's bounds.
        let inst = f.instances.iter().find(|i| i.object == hat).unwrap();
        let mesh = inst.deformed_mesh.as_deref().unwrap_or(&s.meshes[inst.mesh]);
        let (lo, hi) = mesh.bounds().unwrap();
        let (lo, hi) = (inst.world.transform_point3(lo), inst.world.transform_point3(hi));
        for x in &w {
            assert!(
                x.center.cmpge(lo.min(hi) - Vec3::splat(0.05)).all()
                    && x.center.cmple(lo.max(hi) + Vec3::splat(0.05)).all()
            );
        }
    }
    println!("hat top sphere heights over time: {heights:?}");
    assert!(heights.iter().any(|h| (h - heights[0]).abs() > 1e-3), "hat spheres do not deform");
}

/// Writes the sphere sets of the ISG scenes beside them (`scenes/<scene>.<object>.spheres`),
/// which the technique then loads instead of building them at start-up:
/// `ISG_WRITE_SPHERES=1 cargo test -p penumbra-passes --test isg write_scene_sphere_files -- --ignored`.
#[test]
#[ignore]
fn write_scene_sphere_files() {
    if std::env::var_os("ISG_WRITE_SPHERES").is_none() {
        return;
    }
    for name in ["falling.toml", "hat_on_cloth.toml", "isg_bunny.toml"] {
        let s = scene(name);
        let sets = scene_sphere_sets(&s, 48);
        let res: usize = std::env::var("ISG_SPHERE_RES").ok().and_then(|v| v.parse().ok()).unwrap_or(64);
        let count: usize = std::env::var("ISG_SPHERE_COUNT").ok().and_then(|v| v.parse().ok()).unwrap_or(48);
        for (o, set) in s.objects.iter().zip(&sets) {
            let Some(_) = set else { continue };
            let m = &s.meshes[o.mesh];
            let set =
                &penumbra_math::sphereset::approximate_spheres_with(&m.positions, &m.indices, count, res).unwrap();
            let cov = measure_coverage(&m.positions, &m.indices, &set.spheres, 64).unwrap();
            let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../scenes")
                .join(format!("{}.{}.spheres", s.name, o.name));
            let text = format!(
                "# {} spheres for object '{}' of scene '{}' (penumbra_math::sphereset, {res} voxels)\n# coverage: {:.3} of the mesh volume, {:.4} outside\n{}",
                set.spheres.len(), o.name, s.name, cov.covered, cov.outside, set.to_text()
            );
            std::fs::write(&path, text).unwrap();
            println!("{}: covered {:.3} outside {:.4}", path.display(), cov.covered, cov.outside);
        }
    }
}

/// A corrupt or mismatched `.spheres` file is not ignored silently: the object gets fitted
/// spheres and the user a note naming the file.
#[test]
fn corrupt_sphere_files_are_reported() {
    let dir =
        std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("penumbra-spheres-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("s.toml");
    std::fs::write(
        &path,
        "name = \"s\"\n[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n[environment]\nprocedural = \"sky\"\n\
         [[object]]\nname = \"ball\"\nmesh = { type = \"icosphere\", radius = 0.5 }\n\
         [[object]]\nname = \"box\"\nmesh = { type = \"cube\", size = 1.0 }\nposition = [2, 0, 0]\n",
    )
    .unwrap();
    std::fs::write(dir.join("s.ball.spheres"), "this is not a sphere file\n").unwrap();
    let s = penumbra_scene::Scene::load(&path).unwrap();
    let (sets, notes) = penumbra_passes::isg::scene_sphere_sets_noting(&s, 8);
    assert!(sets.iter().all(|x| x.is_some()), "both objects still get spheres");
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(notes[0].contains("s.ball.spheres") && notes[0].contains("ball"), "{notes:?}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn thin_walls_cast_shadows_as_thin_shells() {
    // balls_on_dish's dish is a 3.75 cm thick closed wall: its 48 fitted spheres cover about a
    // fifth of it (almost no shadow on the table, and black speckles where they touch the dish's
    // surface), so isg takes its triangles instead and says so; the balls keep their spheres.
    let s = scene("balls_on_dish.toml");
    let (sets, notes) = penumbra_passes::isg::scene_sphere_sets_noting(&s, 48);
    let index = |name: &str| s.objects.iter().position(|o| o.name == name).unwrap();
    let (dish, red, table) = (index("dish"), index("ball_red"), index("table"));
    assert!(sets[dish].is_none() && penumbra_passes::isg::is_thin_caster(&s, &sets, dish));
    assert!(sets[red].is_some() && !penumbra_passes::isg::is_thin_caster(&s, &sets, red));
    // the table casts no shadow at all
    assert!(!penumbra_passes::isg::is_thin_caster(&s, &sets, table));
    assert!(notes.iter().any(|n| n.contains("'dish'") && n.contains("thin-shell")), "{notes:?}");
    let frame = s.at(1.0, None);
    // at 3 % of each object's size (the default, 1 %, also takes some of the balls' triangles)
    let parts = penumbra_passes::isg::thin_parts_with(&s, &sets, 0.03);
    let tris = penumbra_passes::isg::frame_thin_triangles(&s, &parts, &frame);
    let dish_tris = s.meshes[s.objects[dish].mesh].indices.len() / 3;
    assert_eq!(tris.len(), dish_tris, "exactly the dish's triangles");
    // the paper's closed objects keep their spheres (covered 85-96 %)
    for (file, object) in [("isg_bunny.toml", "bunny"), ("hat_on_cloth.toml", "hat"), ("chess.toml", "king")] {
        let s = scene(file);
        let sets = scene_sphere_sets(&s, 48);
        let i = s.objects.iter().position(|o| o.name == object).unwrap();
        assert!(sets[i].is_some(), "{file}: '{object}' lost its spheres");
    }
}

#[test]
fn thin_parts_outside_the_spheres_cast_as_triangles() {
    // hat_on_cloth's hat keeps its 48 spheres for the crown, but its 2 cm brim lies outside them
    // (no shadow on the cloth before): the brim's triangles, and only a part of the hat, are
    // thin-shell casters. The closed balls are held by their spheres whole.
    let s = scene("hat_on_cloth.toml");
    let sets = scene_sphere_sets(&s, 48);
    // at 3 % of the object's size (the default, 1 %, also takes parts of the crown)
    let parts = penumbra_passes::isg::thin_parts_with(&s, &sets, 0.03);
    let hat = s.objects.iter().position(|o| o.name == "hat").unwrap();
    let mesh = &s.meshes[s.objects[hat].mesh];
    let tris = mesh.indices.len() / 3;
    println!("hat: {} of {tris} triangles thin", parts[hat].len());
    assert!(!parts[hat].is_empty() && parts[hat].len() < tris, "{} of {tris}", parts[hat].len());
    // every thin triangle has a point well outside the crown's radius (the brim)
    let axis_dist = |k: u32| {
        let p = mesh.positions[k as usize];
        (p.x * p.x + p.z * p.z).sqrt()
    };
    let crown = (0..mesh.positions.len() as u32)
        .filter(|&k| mesh.positions[k as usize].y > 0.5 * mesh.positions.iter().map(|p| p.y).fold(0.0, f32::max))
        .map(axis_dist)
        .fold(0.0, f32::max);
    for &t in &parts[hat] {
        let far = mesh.indices[3 * t as usize..3 * t as usize + 3].iter().map(|&k| axis_dist(k)).fold(0.0, f32::max);
        assert!(far > crown, "triangle {t} reaches only {far} from the axis (crown radius {crown})");
    }
    // the default tolerance takes more: a superset
    let default = penumbra_passes::isg::thin_parts(&s, &sets);
    assert!(parts[hat].iter().all(|t| default[hat].contains(t)) && default[hat].len() > parts[hat].len());
    for (file, object) in [("balls_on_dish.toml", "ball_red"), ("coarse.toml", "ball")] {
        let s = scene(file);
        let sets = scene_sphere_sets(&s, 48);
        let parts = penumbra_passes::isg::thin_parts_with(&s, &sets, 0.03);
        let i = s.objects.iter().position(|o| o.name == object).unwrap();
        println!("{file} '{object}': {} thin triangles", parts[i].len());
        assert!(parts[i].is_empty(), "{file}: '{object}' has {} thin triangles", parts[i].len());
    }
}
