//! Unit tests of the vv module on tiny hand-made models (the integration tests with scene
//! meshes are in `tests/vv_precompute.rs`).

use super::precompute::{trace_occluder, Topology};
use super::trace::Tracer;
use super::*;

/// `n x n` quad grid of side `size` in the plane y = `y`, facing +y.
pub(crate) fn grid(n: u32, size: f32, y: f32) -> (Vec<Vec3>, Vec<Vec3>, Vec<u32>) {
    let mut p = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            p.push(Vec3::new(size * (i as f32 / n as f32 - 0.5), y, size * (j as f32 / n as f32 - 0.5)));
        }
    }
    let mut idx = Vec::new();
    let id = |i: u32, j: u32| i * (n + 1) + j;
    for i in 0..n {
        for j in 0..n {
            idx.extend([id(i, j), id(i, j + 1), id(i + 1, j), id(i + 1, j), id(i, j + 1), id(i + 1, j + 1)]);
        }
    }
    let nrm = vec![Vec3::Y; p.len()];
    (p, nrm, idx)
}

/// Axis-aligned box (flat normals, 24 vertices), outward facing.
pub(crate) fn cuboid(c: Vec3, h: Vec3) -> (Vec<Vec3>, Vec<Vec3>, Vec<u32>) {
    let mut p = Vec::new();
    let mut nrm = Vec::new();
    let mut idx = Vec::new();
    for axis in 0..3 {
        for s in [-1.0f32, 1.0] {
            let mut n = Vec3::ZERO;
            n[axis] = s;
            let (u, v) = (n.any_orthonormal_vector(), n.cross(n.any_orthonormal_vector()));
            let b = p.len() as u32;
            for (a, bb) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let q = n + u * a + v * bb;
                p.push(c + q * h);
                nrm.push(n);
            }
            idx.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
        }
    }
    (p, nrm, idx)
}

pub(crate) fn model(parts: &[((Vec<Vec3>, Vec<Vec3>, Vec<u32>), bool)]) -> VvModel {
    VvModel::from_objects(parts.iter().map(|((p, n, i), occ)| ObjectMesh {
        positions: p,
        normals: n,
        indices: i,
        world: Mat4::IDENTITY,
        casts_shadow: *occ,
    }))
}

/// Occluded solid angle at `p` by uniform hemisphere sampling (stratified) with the
/// precompute's tracing conventions.
fn traced_occluded_solid_angle(m: &VvModel, v: usize, n_samples: u32) -> f64 {
    let topo = Topology::new(m);
    let tracer = Tracer::new(&m.positions, &m.indices, &m.occluder);
    let nn = m.normals[v].as_dvec3();
    let f = frame(m.normals[v]);
    let mut occ = 0;
    for i in 0..n_samples {
        for j in 0..n_samples {
            // equal-area: uniform in the Lambert disk
            let u = -1.0 + (i as f64 + 0.5) * 2.0 / n_samples as f64;
            let w = -1.0 + (j as f64 + 0.5) * 2.0 / n_samples as f64;
            if u * u + w * w >= 1.0 {
                continue;
            }
            let d = lambert_inv(u, w, &f);
            if trace_occluder(&tracer, &topo, &[topo.pos_group[v]], m.positions[v].as_dvec3(), nn, d).is_some() {
                occ += 1;
            }
        }
    }
    // each disk cell of area (2/n)^2 is a solid angle 2 pi * area / pi
    occ as f64 * 2.0 * (2.0 / n_samples as f64).powi(2)
}

fn occluded_solid_angle(vis: &VectorizedVisibility, m: &VvModel, v: usize) -> f64 {
    synthesize(vis, v, m.positions[v], m.normals[v]).iter().map(|l| signed_solid_angle(l, m.normals[v])).sum()
}

#[test]
fn box_over_floor_loop_matches_traced_occlusion() {
    let m = model(&[(grid(4, 4.0, 0.0), false), (cuboid(Vec3::new(0.3, 1.0, 0.0), Vec3::new(0.5, 0.2, 0.4)), true)]);
    let params = VvParams { resolution: 48, ..Default::default() };
    let vis = precompute_visibility(&m, &params, &|_| {}).unwrap();
    // the floor centre vertex (i = j = 2) sees one loop around the box
    let v = 2 * 5 + 2;
    assert_eq!(vis.vertex_sequences(v).len(), 1, "{:?}", vis.vertex_seqs[v]);
    let a = occluded_solid_angle(&vis, &m, v);
    let t = traced_occluded_solid_angle(&m, v, 200);
    assert!(t > 0.3, "box subtends {t}");
    assert!((a - t).abs() < 0.03 * t + 0.01, "loop {a} vs traced {t}");
    // every point of that loop is on the box (w = 1)
    for k in vis.vertex_sequences(v) {
        assert!(vis.sequence(k).iter().all(|q| q[3] == 1.0 && (q[1] - 1.0).abs() <= 0.2001));
        assert!(vis.sequence(k).len() >= 4 && vis.sequence(k).len() < 200);
    }
    // a floor corner far from the box: occluded much less
    assert!(occluded_solid_angle(&vis, &m, 0) < a);
}

#[test]
fn unoccluded_vertex_has_no_sequence_and_enclosed_vertex_a_horizon_loop() {
    // a floor grid with nothing above: empty visibility everywhere
    let m = model(&[(grid(2, 2.0, 0.0), true)]);
    let vis = precompute_visibility(&m, &VvParams { resolution: 16, ..Default::default() }, &|_| {}).unwrap();
    assert_eq!(vis.sequence_count(), 0);
    assert!(vis.vertex_seqs.iter().all(|s| s[1] == 0));
    // a floor inside a closed box: the centre vertex is fully enclosed
    let m = model(&[(grid(2, 1.0, 0.0), false), (cuboid(Vec3::new(0.0, 0.5, 0.0), Vec3::new(1.0, 0.7, 1.0)), true)]);
    let vis = precompute_visibility(&m, &VvParams { resolution: 24, ..Default::default() }, &|_| {}).unwrap();
    let v = 4;
    assert_eq!(vis.vertex_sequences(v).len(), 1);
    let seq = vis.sequence(vis.vertex_sequences(v).start);
    assert!(seq.iter().all(|q| q[3] == 0.0), "horizon points are directions");
    let a = occluded_solid_angle(&vis, &m, v);
    assert!((a - 2.0 * std::f64::consts::PI).abs() < 0.05, "enclosed: {a}");
}

#[test]
fn points_behind_the_tangent_plane_are_clamped_to_the_horizon() {
    let n = Vec3::Y;
    let d = clamp_to_hemisphere(Vec3::new(1.0, -1.0, 0.0).normalize(), n);
    assert!((d - Vec3::X).length() < 1e-6);
    assert!(clamp_to_hemisphere(-n, n).dot(n).abs() < 1e-6);
    // a cap of radius 30 deg centred on the horizon: half of it is behind the tangent plane;
    // clamped, its loop encloses exactly the upper half
    let cap = |c: Vec3, r: f32, m: usize| -> Vec<Vec3> {
        let (u, v) = (c.any_orthonormal_vector(), c.cross(c.any_orthonormal_vector()));
        (0..m)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / m as f32;
                (c * r.cos() + (u * a.cos() + v * a.sin()) * r.sin()).normalize()
            })
            .collect()
    };
    let r = 30f32.to_radians();
    let l: Vec<Vec3> = cap(Vec3::X, r, 256).into_iter().map(|d| clamp_to_hemisphere(d, n)).collect();
    let half = std::f64::consts::PI * (1.0 - (r as f64).cos());
    let a = signed_solid_angle(&l, n);
    assert!((a - half).abs() < 0.01 * half, "{a} vs {half}");
    // the clamped loop says occluded exactly for directions inside the upper half of the cap
    let inside = Vec3::new(0.95, 0.2, 0.0).normalize();
    let outside = Vec3::new(0.7, 0.1, 0.7).normalize();
    assert!(occluded_by(std::slice::from_ref(&l), inside, n) && !occluded_by(&[l], outside, n));
    // a cap wholly behind the plane (not around -n) encloses nothing once clamped
    let below = Vec3::new(1.0, -1.0, 0.3).normalize();
    let l: Vec<Vec3> = cap(below, 20f32.to_radians(), 64).into_iter().map(|d| clamp_to_hemisphere(d, n)).collect();
    assert!(l.iter().all(|d| d.dot(n).abs() < 1e-6));
    assert!(signed_solid_angle(&l, n).abs() < 1e-6);
}

#[test]
fn file_roundtrip_and_malformed_files() {
    let m = model(&[(grid(2, 4.0, 0.0), false), (cuboid(Vec3::new(0.0, 1.0, 0.0), Vec3::splat(0.4)), true)]);
    let vis = precompute_visibility(&m, &VvParams { resolution: 16, ..Default::default() }, &|_| {}).unwrap();
    let d = VvData {
        model_hash: m.hash(),
        vertex_count: m.positions.len() as u32,
        triangle_count: m.triangle_count() as u32,
        params: VvParams { resolution: 16, ..Default::default() },
        corr: Correspondence { tri_offsets: vec![0; m.triangle_count() + 1], loop_offsets: vec![0], triples: vec![] },
        vis,
        stats: VvStats::default(),
    }
    .with_sizes();
    let b = d.to_bytes();
    let back = VvData::from_bytes(&b, "x.pvv").unwrap();
    assert_eq!(back, d);
    back.check_model(&m).unwrap();
    for cut in [0, 3, 10, 40, b.len() - 1] {
        let e = VvData::from_bytes(&b[..cut], "x.pvv").unwrap_err();
        assert!(e.starts_with("x.pvv: ") && (e.contains("truncated") || e.contains("magic")), "{cut}: {e}");
    }
    let mut bad = b.clone();
    bad[4] = 9;
    assert!(VvData::from_bytes(&bad, "x.pvv").unwrap_err().contains("version 9"));
    let mut bad = b.clone();
    bad.push(0);
    assert!(VvData::from_bytes(&bad, "x.pvv").unwrap_err().contains("trailing"));
    let mut other = m.clone();
    other.positions[0].x += 0.5;
    assert!(back.check_model(&other).unwrap_err().contains("different model"));
}

/// Checks the spherical Delaunay property: V - E + F = 2 (E = 3F/2), every site is a vertex
/// of some face, and no site lies strictly inside a face's circumcircle (beyond the symbolic
/// perturbation).
fn check_delaunay(sites: &hull::Sites) {
    let f = hull::convex_hull(&sites.dirs);
    let n = sites.dirs.len();
    assert_eq!(f.len(), 2 * n - 4, "Euler: {} faces for {n} sites", f.len());
    let mut seen = vec![false; n];
    for t in &f {
        for &v in t {
            seen[v] = true;
        }
        let (a, b, c) = (sites.dirs[t[0]], sites.dirs[t[1]], sites.dirs[t[2]]);
        let cc = (b - a).cross(c - a).normalize();
        let r = cc.dot(a);
        for (i, s) in sites.dirs.iter().enumerate() {
            if !t.contains(&i) {
                assert!(cc.dot(*s) <= r + 1e-9, "site {i} inside the circumcircle of {t:?}");
            }
        }
    }
    assert!(seen.iter().all(|&s| s), "every site has a Voronoi cell");
}

#[test]
fn spherical_voronoi_of_duplicate_and_cocircular_sites() {
    use glam::DVec3;
    // 12 sites on one small circle, 12 on the equator (cocircular), the poles, and every site
    // duplicated (three colours seeing the same directions)
    let mut input = Vec::new();
    for i in 0..12 {
        let a = i as f64 * std::f64::consts::TAU / 12.0;
        input.push(DVec3::new(a.cos(), a.sin(), 0.0));
        input.push(DVec3::new(0.5 * a.cos(), 0.5 * a.sin(), 0.75f64.sqrt()));
    }
    input.push(DVec3::Z);
    input.push(-DVec3::Z);
    let dup: Vec<DVec3> = input.iter().chain(input.iter()).chain(input.iter()).copied().collect();
    let s = hull::sites(&dup, 7);
    assert_eq!(s.dirs.len(), input.len(), "duplicates merged");
    assert!(s.members.iter().all(|m| m.len() == 3));
    check_delaunay(&s);
    // deterministic for a seed
    let s2 = hull::sites(&dup, 7);
    assert_eq!(hull::convex_hull(&s.dirs), hull::convex_hull(&s2.dirs));
    // all sites on one great circle (a fully enclosed triangle's horizon loops): no 3D hull,
    // the fan still gives triangles over all sites
    let ring: Vec<DVec3> = (0..16)
        .map(|i| {
            let a = i as f64 * std::f64::consts::TAU / 16.0;
            DVec3::new(a.cos(), 0.0, a.sin())
        })
        .collect();
    let s = hull::sites(&ring, 3);
    let f = hull::convex_hull(&s.dirs);
    assert!(!f.is_empty());
    let mut seen = [false; 16];
    f.iter().flatten().for_each(|&v| seen[v] = true);
    assert!(seen.iter().all(|&x| x));
    // fewer than three sites
    assert!(hull::convex_hull(&[DVec3::X, DVec3::Y]).is_empty());
    // RGB tripoints of three identical colour sets: every site is its own zero-distance triple
    let dirs: Vec<Vec3> = input.iter().map(|d| d.as_vec3()).collect();
    let ents = [(0..26).collect::<Vec<u32>>(), (100..126).collect(), (200..226).collect()];
    let c = corr::rgb_tripoints(&ents, &[dirs.clone(), dirs.clone(), dirs], 5, 0.0);
    for i in 0..26u32 {
        assert!(c.iter().any(|(t, d)| *t == [i, 100 + i, 200 + i] && *d < 1e-3), "site {i}");
    }
}

/// The winding flip of issue 9: a vertex enclosed up to its horizon (one loop of horizon points
/// around the whole hemisphere) next to vertices that see two separate regions. The triangle's
/// two groups each hold two interleaved arcs of the ring; closed by chords, each group winds
/// once around the normal at that vertex (2 pi each, 4 pi in all instead of 2 pi). With the
/// jumps routed through the vertex's pole (corr step 6) eq. 21 at every corner gives back that
/// vertex's own visibility.
#[test]
fn split_horizon_ring_is_reproduced_at_the_corners() {
    let n = Vec3::Y;
    let mut points: Vec<[f32; 4]> = Vec::new();
    // vertex 0: 12 horizon directions, counter-clockwise about the occluded hemisphere
    for i in 0..12 {
        let a = (i as f32 * 30.0).to_radians();
        points.push([a.cos(), 0.0, -a.sin(), 0.0]);
    }
    // vertices 1 and 2: two small regions each, points on occluders (w = 1)
    let region = |c: Vec3| -> Vec<[f32; 4]> {
        let (u, v) = (Vec3::Y, c.cross(Vec3::Y).normalize());
        (0..4)
            .map(|i| {
                let a = (i as f32 * -90.0).to_radians();
                let p = c + 0.2 * (u * a.cos() + v * a.sin()) + 0.25 * u;
                [p.x, p.y, p.z, 1.0]
            })
            .collect()
    };
    for c in [Vec3::X, -Vec3::X, Vec3::Z, -Vec3::Z] {
        points.extend(region(c));
    }
    let vis0 = VectorizedVisibility {
        vertex_points: points.len() as u32,
        seq_offsets: vec![0, 12, 16, 20, 24, 28],
        vertex_seqs: vec![[0, 1], [1, 2], [3, 2]],
        points,
    };
    let m = VvModel {
        positions: vec![Vec3::ZERO, Vec3::new(0.05, 0.0, 0.0), Vec3::new(0.0, 0.0, 0.05)],
        normals: vec![n; 3],
        indices: vec![0, 1, 2],
        occluder: vec![true],
    };
    let own: Vec<f64> = (0..3)
        .map(|v| synthesize(&vis0, v, m.positions[v], n).iter().map(|l| signed_solid_angle(l, n)).sum())
        .collect();
    assert!((own[0] - std::f64::consts::TAU).abs() < 1e-6, "ring: {}", own[0]);
    // two groups: ring arcs {0,1,2} + {6,7} with the first regions, {3,4,5} + {8..11} with the
    // second ones (interleaved, as the relaxed stage leaves them)
    let g0: Vec<[u32; 3]> =
        [(0, 12, 20), (1, 13, 21), (2, 14, 22), (6, 15, 23), (7, 15, 23)].iter().map(|&(a, b, c)| [a, b, c]).collect();
    let g1: Vec<[u32; 3]> =
        [(3, 16, 24), (4, 17, 25), (5, 18, 26), (8, 19, 27), (9, 19, 27), (10, 19, 27), (11, 19, 27)]
            .iter()
            .map(|&(a, b, c)| [a, b, c])
            .collect();
    let build = |vis: &VectorizedVisibility, loops: &[Vec<[u32; 3]>]| {
        let mut c =
            Correspondence { tri_offsets: vec![0, loops.len() as u32], loop_offsets: vec![0], triples: Vec::new() };
        for l in loops {
            c.triples.extend_from_slice(l);
            c.loop_offsets.push(c.triples.len() as u32);
        }
        let _ = vis;
        c
    };
    let corner = |vis: &VectorizedVisibility, c: &Correspondence, k: usize| -> f64 {
        let mut l = [0.0f32; 3];
        l[k] = 1.0;
        interpolate(vis, c, 0, l, m.positions[k], n).iter().map(|x| signed_solid_angle(x, n)).sum()
    };
    // before: chords along the horizon take the short way, each group winds once
    let before = build(&vis0, &[g0.clone(), g1.clone()]);
    let e0 = (corner(&vis0, &before, 0) - own[0]).abs();
    assert!(e0 > 3.0, "the unrouted groups should show the flip: error {e0}");
    // after: jumps through the poles
    let mut vis = vis0.clone();
    let pole = [0, 1, 2].map(|_| {
        vis.points.push([n.x, n.y, n.z, 0.0]);
        vis.points.len() as u32 - 1
    });
    let mut info = vec![(0u32, 0u32); vis.vertex_points as usize];
    for s in 0..vis.sequence_count() {
        for g in vis.seq_offsets[s]..vis.seq_offsets[s + 1] {
            info[g as usize] = (s as u32, g - vis.seq_offsets[s]);
        }
    }
    let mut loops = vec![g0, g1];
    let added = corr::route_jumps(&vis, &info, &mut loops, pole);
    assert!(added > 0);
    let after = build(&vis, &loops);
    for (k, &own_k) in own.iter().enumerate() {
        let e = (corner(&vis, &after, k) - own_k).abs();
        assert!(e < 1e-4, "corner {k}: interpolated {} own {own_k}", corner(&vis, &after, k));
    }
    // every original triple is still there, in order
    for (l, orig) in loops.iter().zip([&before.triples[..5], &before.triples[5..]]) {
        let kept: Vec<[u32; 3]> = l.iter().copied().filter(|t| t.iter().all(|&g| g < vis.vertex_points)).collect();
        let mut it = kept.iter();
        assert!(orig.iter().all(|o| it.any(|x| x == o)), "{l:?}");
    }
}

#[test]
fn interpolation_disagreement_flags_a_corrupted_correspondence() {
    // a box over a 4 x 4 floor: the correspondence of the floor triangles under the box is sound
    let m = model(&[(grid(4, 4.0, 0.0), false), (cuboid(Vec3::new(0.3, 1.0, 0.0), Vec3::new(0.5, 0.2, 0.4)), true)]);
    let params = VvParams { resolution: 32, ..Default::default() };
    let d = compute(&m, &params, &|_, _| {}).unwrap();
    let dis = interpolation_disagreement(&m, &d.vis, &d.corr);
    assert_eq!(dis.len(), m.triangle_count());
    assert!(dis.iter().all(|x| x.is_finite() && *x >= 0.0));
    // a floor triangle with loops under the box, and its disagreement when sound
    let t = (0..32).filter(|&t| !d.corr.triangle_loops(t).is_empty()).max_by(|&a, &b| {
        let len = |t: usize| d.corr.triangle_loops(t).map(|l| d.corr.loop_triples(l).len()).sum::<usize>();
        len(a).cmp(&len(b))
    });
    let t = t.expect("a floor triangle sees the box");
    assert!(dis[t] < 0.25, "sound triangle {t}: {}", dis[t]);
    // turn its loops inside out (reversed triple order: the occluded region becomes its
    // complement within the hemisphere, far more than eq. 19's blend)
    let mut corr = d.corr.clone();
    for l in corr.triangle_loops(t) {
        let (a, b) = (corr.loop_offsets[l] as usize, corr.loop_offsets[l + 1] as usize);
        corr.triples[a..b].reverse();
    }
    let bad = interpolation_disagreement(&m, &d.vis, &corr);
    assert!(bad[t] > 0.5, "reversed loops of triangle {t}: {} (sound {})", bad[t], dis[t]);
    // the other triangles are unchanged
    assert!((0..m.triangle_count()).filter(|&u| u != t).all(|u| bad[u] == dis[u]));
}
