//! Sphere-set approximation: coverage on procedural closed meshes, file round trip, deformation
//! binding, bad input.

use glam::Vec3;
use penumbra_math::sphereset::*;
use std::f32::consts::PI;

fn uv_sphere(r: f32, seg: u32) -> (Vec<Vec3>, Vec<u32>) {
    let mut p = Vec::new();
    let mut idx = Vec::new();
    let rings = seg / 2;
    for i in 0..=rings {
        let t = PI * i as f32 / rings as f32;
        for j in 0..seg {
            let f = 2.0 * PI * j as f32 / seg as f32;
            p.push(Vec3::new(t.sin() * f.cos(), t.cos(), t.sin() * f.sin()) * r);
        }
    }
    for i in 0..rings {
        for j in 0..seg {
            let a = i * seg + j;
            let b = i * seg + (j + 1) % seg;
            let c = a + seg;
            let d = b + seg;
            idx.extend([a, c, b, b, c, d]);
        }
    }
    (p, idx)
}

fn box_mesh(ext: Vec3) -> (Vec<Vec3>, Vec<u32>) {
    let p: Vec<Vec3> = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 == 1 { ext.x } else { -ext.x },
                if i & 2 == 2 { ext.y } else { -ext.y },
                if i & 4 == 4 { ext.z } else { -ext.z },
            )
        })
        .collect();
    let q = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let idx = q.iter().flat_map(|f| [f[0], f[1], f[2], f[0], f[2], f[3]]).collect();
    (p, idx)
}

fn torus(big: f32, small: f32, seg: u32) -> (Vec<Vec3>, Vec<u32>) {
    let mut p = Vec::new();
    let mut idx = Vec::new();
    for i in 0..seg {
        let u = 2.0 * PI * i as f32 / seg as f32;
        for j in 0..seg / 2 {
            let v = 2.0 * PI * j as f32 / (seg / 2) as f32;
            p.push(Vec3::new((big + small * v.cos()) * u.cos(), small * v.sin(), (big + small * v.cos()) * u.sin()));
        }
    }
    let m = seg / 2;
    for i in 0..seg {
        for j in 0..m {
            let a = i * m + j;
            let b = ((i + 1) % seg) * m + j;
            let c = i * m + (j + 1) % m;
            let d = ((i + 1) % seg) * m + (j + 1) % m;
            idx.extend([a, b, c, c, b, d]);
        }
    }
    (p, idx)
}

#[test]
fn coverage_of_simple_solids() {
    let (p, i) = uv_sphere(1.0, 48);
    let set = approximate_spheres(&p, &i, 1).unwrap();
    assert_eq!(set.spheres.len(), 1);
    let cov = measure_coverage(&p, &i, &set.spheres, 80).unwrap();
    println!(
        "sphere, 1 sphere: covered {:.3} outside {:.4} (r {:.3})",
        cov.covered, cov.outside, set.spheres[0].radius
    );
    assert!((cov.mesh_volume - 4.0 / 3.0 * std::f64::consts::PI).abs() < 0.15, "volume {}", cov.mesh_volume);
    assert!(cov.covered > 0.9 && cov.outside < 0.05, "{cov:?}");

    let (p, i) = box_mesh(Vec3::new(1.5, 0.5, 0.5));
    let mut last = 0.0;
    for n in [4, 16, 64] {
        let set = approximate_spheres(&p, &i, n).unwrap();
        let cov = measure_coverage(&p, &i, &set.spheres, 80).unwrap();
        println!("box 3x1x1, {n} spheres: covered {:.3} outside {:.4}", cov.covered, cov.outside);
        assert!(cov.covered >= last, "coverage must grow with the count");
        assert!(cov.outside < 0.03, "{cov:?}");
        last = cov.covered;
    }
    assert!(last > 0.8, "box coverage with 64 spheres {last}");

    let (p, i) = torus(1.0, 0.3, 48);
    let set = approximate_spheres(&p, &i, 32).unwrap();
    let cov = measure_coverage(&p, &i, &set.spheres, 80).unwrap();
    println!("torus, 32 spheres: covered {:.3} outside {:.4}", cov.covered, cov.outside);
    assert!(cov.covered > 0.75 && cov.outside < 0.03, "{cov:?}");
    // No sphere in the hole.
    assert!(set.spheres.iter().all(|s| s.center.length() > 0.6), "sphere in the torus hole");
}

#[test]
fn file_round_trip_and_deformation() {
    let (p, i) = box_mesh(Vec3::new(1.0, 0.5, 0.5));
    let set = approximate_spheres(&p, &i, 8).unwrap();
    let back = SphereSet::parse(&set.to_text()).unwrap();
    assert_eq!(set.spheres.len(), back.spheres.len());
    for (a, b) in set.spheres.iter().zip(&back.spheres) {
        assert!((a.center - b.center).length() < 1e-6 && (a.radius - b.radius).abs() < 1e-6 && a.anchors == b.anchors);
    }
    // Translating every vertex translates every sphere.
    let moved: Vec<Vec3> = p.iter().map(|v| *v + Vec3::new(0.0, 2.0, 0.0)).collect();
    for (a, b) in set.spheres.iter().zip(set.deformed(&p, &moved, &i)) {
        assert!((b.center - a.center - Vec3::new(0.0, 2.0, 0.0)).length() < 1e-5);
        assert!((b.radius - a.radius).abs() < 1e-5 * a.radius, "a translation changed a radius");
    }
    // Bad files.
    for bad in [
        "",
        "penumbra-spheres 2 0",
        "penumbra-spheres 1 1",
        "penumbra-spheres 1 1\n0 0 0 -1 0 0 0 0",
        "penumbra-spheres 1 1\n0 0 nan 1 0 0 0 0",
        "penumbra-spheres 1 1\n0 0 0 1 0 0 0",
    ] {
        assert!(SphereSet::parse(bad).is_err(), "accepted `{bad}`");
    }
    assert_eq!(SphereSet::parse("# none\npenumbra-spheres 1 0\n").unwrap().spheres.len(), 0);
}

#[test]
fn bad_meshes_are_errors() {
    assert!(approximate_spheres(&[], &[], 4).is_err());
    assert!(approximate_spheres(&[Vec3::ZERO; 3], &[0, 1, 5], 4).is_err());
    assert!(approximate_spheres(&[Vec3::ZERO, Vec3::X, Vec3::splat(f32::NAN)], &[0, 1, 2], 4).is_err());
    // Degenerate (flat) but valid: no interior, no spheres, no panic.
    let s = approximate_spheres(&[Vec3::ZERO, Vec3::X, Vec3::Y], &[0, 1, 2], 4).unwrap();
    assert!(s.spheres.is_empty());
    assert!(approximate_spheres(&[Vec3::ZERO, Vec3::X, Vec3::Y], &[0, 1, 2], 0).unwrap().spheres.is_empty());
}

/// How far a sphere reaches out of the mesh (radius minus the centre's distance to the nearest
/// triangle; negative: inset).
fn poke_out(s: &BoundSphere, p: &[Vec3], i: &[u32]) -> f32 {
    s.radius - penumbra_math::sphereset::surface_distance(s.center, p, i).unwrap()
}

#[test]
fn squashed_spheres_shrink_with_the_mesh() {
    // A box squashed to 0.5 of its height about its base, widened to keep its volume (the scene
    // format's `squash`): the rest radii reach out of the flattened box; the deformed set's
    // radii follow the clearance so that they reach out much less.
    let (p, i) = box_mesh(Vec3::new(0.5, 0.5, 0.5));
    let set = approximate_spheres(&p, &i, 8).unwrap();
    let base = p.iter().fold(f32::MAX, |m, v| m.min(v.y));
    let (sy, sx) = (0.5f32, 1.0 / 0.5f32.sqrt());
    let squashed: Vec<Vec3> = p.iter().map(|v| Vec3::new(v.x * sx, base + (v.y - base) * sy, v.z * sx)).collect();
    let deformed = set.deformed(&p, &squashed, &i);
    let kept = set.deformed(&p, &squashed, &[]);
    let worst = |v: &[BoundSphere]| v.iter().map(|s| poke_out(s, &squashed, &i)).fold(f32::MIN, f32::max);
    let rest_worst = set.spheres.iter().map(|s| poke_out(s, &p, &i)).fold(f32::MIN, f32::max);
    println!(
        "reach out of the mesh: rest {rest_worst:.4}, squashed with rest radii {:.4}, deformed {:.4}",
        worst(&kept),
        worst(&deformed)
    );
    assert!(kept.iter().zip(&set.spheres).all(|(k, s)| k.radius == s.radius), "no triangles: radii kept");
    assert!(worst(&kept) > 0.1, "the test's squash should push rest radii out: {}", worst(&kept));
    assert!(worst(&deformed) < 0.5 * worst(&kept), "{} vs {}", worst(&deformed), worst(&kept));
    for (d, s) in deformed.iter().zip(&set.spheres) {
        assert!(d.radius < s.radius && d.radius > 0.5 * s.radius, "{} from {}", d.radius, s.radius);
    }
    // the rest clearances stored once (a deforming object's set) give the same spheres, bit for bit
    let cached = set.clone().with_rest_clearances(&p, &i);
    assert_eq!(cached.rest_clearance.len(), set.spheres.len());
    assert!(cached.rest_clearance.iter().all(|c| c.is_some_and(|d| d > 0.0)), "{:?}", cached.rest_clearance);
    assert_eq!(cached.deformed(&p, &squashed, &i), deformed);
}

#[test]
fn closest_point_on_triangle_by_region() {
    use penumbra_math::sphereset::closest_point_on_triangle as cp;
    let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
    let near = |x: Vec3, y: Vec3| (x - y).length() < 1e-6;
    assert!(near(cp(Vec3::new(0.2, 0.2, 1.0), a, b, c), Vec3::new(0.2, 0.2, 0.0)), "face");
    assert!(near(cp(Vec3::new(-1.0, -1.0, 0.0), a, b, c), a), "vertex a");
    assert!(near(cp(Vec3::new(2.0, -0.5, 0.3), a, b, c), b), "vertex b");
    assert!(near(cp(Vec3::new(0.5, -1.0, 0.0), a, b, c), Vec3::new(0.5, 0.0, 0.0)), "edge ab");
    assert!(near(cp(Vec3::new(1.0, 1.0, 0.0), a, b, c), Vec3::new(0.5, 0.5, 0.0)), "edge bc");
    // degenerate (collinear) triangle: the nearest point of its edges
    assert!(near(cp(Vec3::new(0.5, 1.0, 0.0), a, b, Vec3::new(2.0, 0.0, 0.0)), Vec3::new(0.5, 0.0, 0.0)), "degenerate");
}
