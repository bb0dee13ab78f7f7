//! Vectorized visibility precompute and spherical-Voronoi correspondence (issue 9, part A) on
//! small models: accuracy of the synthesized (eq. 3) and interpolated (eq. 21) visibility
//! against ray-traced visibility at triangle interior points, triangles whose vertices see
//! different numbers of sequences, determinism, file round trip.

use glam::Vec3;
use penumbra_math::vv::{
    self, precompute::trace_occluder, trace::Tracer, ObjectMesh, Topology, VvData, VvModel, VvParams,
};
use penumbra_scene::Scene;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

fn scene(name: &str) -> Scene {
    Scene::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)).expect("scene")
}

fn model_of(s: &Scene) -> VvModel {
    VvModel::from_objects(s.objects.iter().enumerate().map(|(i, o)| {
        let m = &s.meshes[o.mesh];
        ObjectMesh {
            positions: &m.positions,
            normals: &m.normals,
            indices: &m.indices,
            world: o.transform,
            casts_shadow: s.object_info.get(i).is_none_or(|x| x.casts_shadow),
        }
    }))
}

/// Fraction of hemisphere directions (stratified in the Lambert disk) on which `loops` agree
/// with ray-traced visibility at the point `p` (barycentrics `lambda` of triangle `t`).
fn agreement(
    m: &VvModel,
    topo: &Topology,
    tracer: &Tracer,
    t: usize,
    lambda: [f32; 3],
    loops: &[Vec<Vec3>],
    res: u32,
) -> (f64, usize) {
    let idx = [0, 1, 2].map(|k| m.indices[3 * t + k] as usize);
    let p: Vec3 = (0..3).map(|k| lambda[k] * m.positions[idx[k]]).sum();
    let n = (0..3).map(|k| lambda[k] * m.normals[idx[k]]).sum::<Vec3>().normalize();
    let local: Vec<u32> = idx.iter().map(|&v| topo.pos_group[v]).collect();
    let f = vv::frame(n);
    let (mut agree, mut total, mut occluded) = (0, 0, 0);
    for d in vv::lambert_grid(res, &f) {
        let truth = trace_occluder(tracer, topo, &local, p.as_dvec3(), n.as_dvec3(), d).is_some();
        let ours = vv::occluded_by(loops, d.as_vec3(), n);
        total += 1;
        occluded += truth as usize;
        agree += (truth == ours) as usize;
    }
    (agree as f64 / total as f64, occluded)
}

fn coarse_with_ground(divisions: u32) -> Scene {
    let src = std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/coarse.toml")).unwrap();
    let src = src.replace(
        "mesh = { type = \"plane\", size = 6 }",
        &format!("mesh = {{ type = \"plane\", size = 3, divisions = {divisions} }}"),
    );
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("vv_test_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("coarse_ground.toml");
    std::fs::write(&p, src).unwrap();
    std::fs::copy(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/assets/sunset-dwab.exr"),
        dir.join("sunset-dwab.exr"),
    )
    .ok();
    std::fs::create_dir_all(dir.join("assets")).unwrap();
    std::fs::copy(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/assets/sunset-dwab.exr"),
        dir.join("assets/sunset-dwab.exr"),
    )
    .ok();
    Scene::load(&p).expect("scene")
}

/// Occluded solid angle of loops (clamped to the hemisphere of `n`).
fn solid(loops: &[Vec<Vec3>], n: Vec3) -> f64 {
    loops.iter().map(|l| vv::signed_solid_angle(l, n)).sum()
}

/// The coarse scene with a subdivided ground (374 vertices, 664 triangles) at a small map
/// resolution: eq. 3 and eq. 21 against ray tracing at triangle interior points, and eq. 21 at
/// the vertices against each vertex's own visibility.
#[test]
fn interpolated_visibility_matches_ray_tracing_and_the_vertices() {
    let s = coarse_with_ground(10);
    let m = model_of(&s);
    let params = VvParams { resolution: 32, ..Default::default() };
    let (vdone, cdone) = (AtomicU64::new(0), AtomicU64::new(0));
    let d = vv::compute(&m, &params, &|stage, n| {
        match stage {
            vv::Stage::Visibility => vdone.fetch_add(n, Ordering::Relaxed),
            vv::Stage::Correspondence => cdone.fetch_add(n, Ordering::Relaxed),
        };
    })
    .unwrap();
    // progress reaches the announced totals
    assert_eq!(vdone.into_inner(), vv::Stage::Visibility.total(&m));
    assert_eq!(cdone.into_inner(), vv::Stage::Correspondence.total(&m));
    eprintln!("{} vertices, {} triangles: {:?}", m.positions.len(), m.triangle_count(), d.stats);
    assert!(d.stats.voronoi_triples > 0 && d.stats.propagated_triples > 0, "{:?}", d.stats);
    // file round trip of real data
    let back = VvData::from_bytes(&d.to_bytes(), "mem").unwrap();
    assert_eq!(back.vis, d.vis);
    assert_eq!(back.corr, d.corr);
    back.check_model(&m).unwrap();

    // at the vertices (lambda = e_k) the interpolated visibility is the vertex's own
    let mut verr = Vec::new();
    for t in 0..m.triangle_count() {
        for k in 0..3 {
            let (a, b) = at_corner(&m, &d, t, k);
            verr.push((a - b).abs());
        }
    }
    verr.sort_by(|a, b| a.total_cmp(b));
    let (median, p95) = (verr[verr.len() / 2], verr[verr.len() * 95 / 100]);
    eprintln!("vertex reproduction |dOmega| (sr): median {median:.4} p95 {p95:.4} max {:.4}", verr.last().unwrap());
    assert!(median < 0.005 && p95 < 0.05, "median {median} p95 {p95}");
    // every corner (jumps routed through the poles, corr step 6): before, the worst was 0.85 sr
    // on vv_coarse and 13 sr on the bunny (winding flips on split horizon rings)
    assert!(*verr.last().unwrap() < 0.05, "worst corner {}", verr.last().unwrap());

    // interior points: eq. 21 (interpolated once) vs the eq. 19 blend of the three eq. 3 syntheses
    let topo = Topology::new(&m);
    let tracer = Tracer::new(&m.positions, &m.indices, &m.occluder);
    let (mut s19, mut s21, mut n) = (0.0, 0.0, 0);
    for t in (0..m.triangle_count()).step_by(3) {
        let lambda = [0.2f32, 0.3, 0.5];
        let idx = [0, 1, 2].map(|k| m.indices[3 * t + k] as usize);
        let p: Vec3 = (0..3).map(|k| lambda[k] * m.positions[idx[k]]).sum();
        let nn = (0..3).map(|k| lambda[k] * m.normals[idx[k]]).sum::<Vec3>().normalize();
        let (a21, occ) =
            agreement(&m, &topo, &tracer, t, lambda, &vv::interpolate(&d.vis, &d.corr, t, lambda, p, nn), 32);
        if occ == 0 {
            continue;
        }
        let a19: f64 = (0..3)
            .map(|k| {
                lambda[k] as f64
                    * agreement(&m, &topo, &tracer, t, lambda, &vv::synthesize(&d.vis, idx[k], p, nn), 32).0
            })
            .sum();
        s19 += a19;
        s21 += a21;
        n += 1;
    }
    let (s19, s21) = (s19 / n as f64, s21 / n as f64);
    eprintln!("agreement with ray tracing over {n} occluded interior points: eq. 3 blended (eq. 19) {s19:.4}, interpolated (eq. 21) {s21:.4}");
    assert!(n > 50);
    assert!(s19 > 0.96, "eq. 3 syntheses agree on {s19}");
    assert!(s21 > 0.96 && s21 > s19 - 0.01, "eq. 21 agrees on {s21} (eq. 19 blend {s19})");
}

/// At corner `k` of triangle `t`: the occluded solid angle of the interpolated visibility
/// (eq. 21 at lambda = e_k) and of the vertex's own (eq. 3).
fn at_corner(m: &VvModel, d: &VvData, t: usize, k: usize) -> (f64, f64) {
    let v = m.indices[3 * t + k] as usize;
    let mut l = [0.0f32; 3];
    l[k] = 1.0;
    let (p, n) = (m.positions[v], m.normals[v]);
    (solid(&vv::interpolate(&d.vis, &d.corr, t, l, p, n), n), solid(&vv::synthesize(&d.vis, v, p, n), n))
}

/// Triangles whose vertices see different numbers of sequences (a vertex of the ball that sees
/// the ring next to one that does not): the loops collapse at the empty vertex through a virtual
/// point and are the other vertices' own visibility there.
#[test]
fn vertices_with_different_sequence_counts_and_determinism() {
    let s = scene("coarse.toml");
    let m = model_of(&s);
    let params = VvParams { resolution: 24, ..Default::default() };
    let d = vv::compute(&m, &params, &|_, _| {}).unwrap();
    let count = |v: usize| d.vis.vertex_seqs[v][1];
    let mut mixed = 0;
    let mut with_empty = 0;
    let (mut pairs, mut close) = (0, 0);
    for t in 0..m.triangle_count() {
        let idx = [0, 1, 2].map(|k| m.indices[3 * t + k] as usize);
        let c = idx.map(count);
        if c.iter().all(|&x| x == c[0]) {
            continue;
        }
        mixed += 1;
        for k in 0..3 {
            let (a, b) = at_corner(&m, &d, t, k);
            pairs += 1;
            if (a - b).abs() < 0.05 + 0.05 * b {
                close += 1;
            } else {
                eprintln!("triangle {t} counts {c:?} vertex {k}: interpolated {a:.4} own {b:.4}");
            }
            if c[k] == 0 {
                assert!(a.abs() < 1e-3, "empty vertex {k} of triangle {t}: {a}");
            }
        }
        if c.contains(&0) && c.iter().any(|&x| x > 0) {
            with_empty += 1;
            // some triple of this triangle uses a virtual point for the empty vertex
            let k = c.iter().position(|&x| x == 0).unwrap();
            let virt = d
                .corr
                .triangle_loops(t)
                .flat_map(|l| d.corr.loop_triples(l).to_vec())
                .any(|tr| tr[k] >= d.vis.vertex_points);
            assert!(virt, "triangle {t} {c:?}");
        }
    }
    eprintln!("{mixed} triangles with different sequence counts, {with_empty} with an empty vertex");
    assert!(mixed > 10 && with_empty > 5, "{mixed} {with_empty}");
    // the relaxed stage leaves chords where a region splits: most vertices are still exact
    assert!(close as f64 >= 0.9 * pairs as f64, "{close} of {pairs} vertices reproduced");
    // deterministic for a seed, different for another
    let again = vv::compute(&m, &params, &|_, _| {}).unwrap();
    assert_eq!(again.to_bytes()[80..], d.to_bytes()[80..], "same seed, same data (after the timings)");
    let other = vv::compute(&m, &VvParams { seed: 99, ..params.clone() }, &|_, _| {}).unwrap();
    assert_eq!(other.vis.seq_offsets, d.vis.seq_offsets, "the visibility does not depend on the seed");
    assert_ne!(other.corr, d.corr, "the correspondence does");
}

/// `load_or_compute` writes the cache once and reads it back; a corrupt cache is recomputed.
#[test]
fn cache_is_written_read_and_repaired() {
    let s = scene("coarse.toml");
    let m = model_of(&s);
    let params = VvParams { resolution: 12, ..Default::default() };
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("vv_cache_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (a, path) = vv::load_or_compute(&m, &params, &dir, "coarse scene", &|_, _| {}).unwrap();
    assert!(path.exists() && path.file_name().unwrap().to_string_lossy().starts_with("coarse_scene-"));
    let calls = AtomicU64::new(0);
    let (b, _) = vv::load_or_compute(&m, &params, &dir, "coarse scene", &|_, _| {
        calls.fetch_add(1, Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(calls.load(Ordering::Relaxed), 0, "read from the cache");
    assert_eq!(a, b);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let err = VvData::read_for(&path, &m).unwrap_err();
    assert!(err.contains(&path.display().to_string()) && err.contains("truncated"), "{err}");
    let (c, _) = vv::load_or_compute(&m, &params, &dir, "coarse scene", &|_, _| {}).unwrap();
    assert_eq!(c.corr, a.corr);
    assert_eq!(std::fs::read(&path).unwrap().len(), bytes.len(), "rewritten");
    let _ = std::fs::remove_dir_all(&dir);
}
