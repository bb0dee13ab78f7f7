//! Vectorized visibility (Ho et al. 2015) and its per-triangle correspondence generated with
//! spherical Voronoi diagrams (Leung et al. 2021, "All frequency direct illumination using
//! visibility correspondence generated with spherical Voronoi diagrams"), the offline data of
//! the `vv` technique.
//!
//! # Data
//! * [`VectorizedVisibility`] (section II-B, eq. 1-2): for every vertex of a static model, the
//!   boundary of its *occluded* directions as closed sequences of points `q_ij` on the
//!   occluders. A point is homogeneous, `[x, y, z, w]`: `w = 1` a model-space position on an
//!   occluder (a silhouette point), `w = 0` a model-space unit direction "at infinity" (a point
//!   of the vertex's horizon, where an occluded region is cut by the vertex's tangent plane).
//! * Synthesis at a nearby surface point `s` (eq. 3): `a_ij = normalize(q_ij.xyz - q_ij.w s)`
//!   ([`synth_dir`]), giving closed loops of unit directions ([`synthesize`]). Directions below
//!   the shading point's tangent plane are clamped onto its horizon ([`clamp_to_hemisphere`]):
//!   this keeps the point count (and so the correspondence) and turns each loop into the
//!   boundary of (occluded region) ∩ (upper hemisphere).
//! * [`Correspondence`] (section III): per triangle, an *output triple list* arranged in closed
//!   loops of triples. A triple is three indices into [`VectorizedVisibility::points`], one
//!   point of each vertex of the triangle in index-buffer order (`k = 0, 1, 2` = `indices[3t +
//!   k]`). Interpolated vectorized visibility at barycentrics `lambda` (eq. 21):
//!   `a = normalize(sum_k lambda_k synth_dir(points[triple[k]], s))` per triple, in loop order
//!   ([`interpolate`]). Triples may reference *virtual points*: points appended after the
//!   vertices' own points (index `>= VectorizedVisibility::vertex_points`) where a vertex has
//!   no counterpart of another vertex's region (it sees fewer sequences): a virtual point is a
//!   single point inside the other vertices' region, so the interpolated loop collapses to it
//!   (zero area) at that vertex. A second kind of virtual point is a vertex's *pole* (its unit
//!   normal as a direction, `w = 0`): a loop steps through it where its entities of that
//!   vertex jump along the sequence (see [`corr`], step 6).
//!
//! # Orientation convention
//! Loops go counter-clockwise around the **occluded** region seen from outside the unit sphere
//! (the occluded side is on the left walking along the loop with the outward normal up); for
//! a small loop around a centre `c`, `sum_i (a_i x a_{i+1}) . c > 0`. The occluded solid angle
//! within the hemisphere of `n` is `sum over loops` of [`signed_solid_angle`] (overlapping
//! loops add, a hole in an occluded region is a clockwise loop). So for a lat-long integral
//! of `f`: `int_visible f = int_{hemisphere(n)} f - sum_loops (signed boundary integral of f)`.
//! A vertex with no occluder has **no** sequence (empty visibility); a fully enclosed vertex
//! has one loop of horizon points (`w = 0`) covering its whole hemisphere (`2 pi`).
//! Winding numbers are taken relative to `-n` (the antipode of the shading normal counts as
//! visible): after clamping, every loop lies in the closed hemisphere of `n`, and the fan from
//! `n` ([`signed_solid_angle`]) integrates exactly that winding over the hemisphere.
//!
//! # Precompute choice
//! The boundary is extracted from a fine visibility map traced on the CPU (a closest-hit BVH
//! over the occluder triangles, [`precompute`]): the upper hemisphere of each vertex (about its
//! normal) is sampled on an `N x N` grid in Lambert azimuthal equal-area coordinates (equal
//! solid angle per cell, fine at the horizon), the occluded/visible boundary is traced by
//! marching squares, each boundary crossing is refined by bisection along the cell edge and
//! keeps the 3D hit point on the occluder side (a silhouette point), and the loops are
//! simplified (Douglas-Peucker on the sphere, angle tolerance, segment length cap). The
//! triangles of the vertex's one-ring are not occluders of that vertex (the local surface is its
//! tangent plane); triangles whose object does not cast shadows are never occluders.
//! Vertices with the same position and normal (uv seams) share one visibility.
//!
//! # Files
//! One file per model ([`VvData::to_bytes`] / [`VvData::read`]): magic `PNVV`, format version
//! ([`FORMAT_VERSION`]), a model hash (positions, normals, indices, occluder flags: a file made
//! for another model is rejected), the parameters, counts, then the arrays below, little
//! endian. Truncated, corrupt or mismatched files give errors naming the file.
//!
//! # Caching (agreed with the renderer, part B of issue 9)
//! [`load_or_compute`]`(model, params, cache_dir, progress)` reads
//! `cache_dir/<name>-<hash>.pvv` when it exists and matches, else precomputes both stages and
//! writes it. The renderer builds its [`VvModel`] from the scene's static objects with
//! [`VvModel::from_objects`] (world space, object order), so vertex `v` of object `o` is model
//! vertex `base[o] + v` and triangle `t` of object `o` is model triangle `tbase[o] + t`.

pub mod corr;
pub mod hull;
mod io;
pub mod precompute;
pub mod trace;

pub use io::FORMAT_VERSION;
pub use precompute::{precompute_visibility, Topology};

use glam::{DVec3, Mat4, Vec3};

/// Magic bytes of a vectorized-visibility file.
pub const MAGIC: &[u8; 4] = b"PNVV";

/// Parameters of the precompute and the correspondence (defaults are ours: the papers give no
/// numbers beyond Table 1's sizes and times).
#[derive(Clone, Debug, PartialEq)]
pub struct VvParams {
    /// Visibility map resolution `N` (`N x N` Lambert cells over the hemisphere), 8..=1024.
    pub resolution: u32,
    /// Bisection steps refining each boundary crossing along a cell edge (0..=16).
    pub refine_steps: u32,
    /// Simplification tolerance in degrees (Douglas-Peucker on the sphere); `0` keeps every
    /// marching-squares point.
    pub tolerance_deg: f32,
    /// Longest segment kept after simplification, degrees (long segments are split back).
    pub max_segment_deg: f32,
    /// Largest angle between two linked entities (at the triangle centre), degrees: RGB
    /// tripoints with a wider pair are not candidates, and a vertex without an entity this
    /// close gets a virtual point.
    pub max_link_deg: f32,
    /// Seed of the correspondence (random triangle order, Voronoi symbolic perturbation).
    pub seed: u64,
}

impl Default for VvParams {
    fn default() -> Self {
        VvParams {
            resolution: 64,
            refine_steps: 6,
            tolerance_deg: 1.0,
            max_segment_deg: 20.0,
            max_link_deg: 45.0,
            seed: 1,
        }
    }
}

impl VvParams {
    /// Checks ranges; the message names the parameter.
    pub fn validate(&self) -> Result<(), String> {
        if !(8..=1024).contains(&self.resolution) {
            return Err(format!("vv: resolution {} out of 8..=1024", self.resolution));
        }
        if self.refine_steps > 16 {
            return Err(format!("vv: refine steps {} out of 0..=16", self.refine_steps));
        }
        if !(self.tolerance_deg >= 0.0 && self.tolerance_deg <= 30.0) {
            return Err(format!("vv: tolerance_deg {} out of 0..=30", self.tolerance_deg));
        }
        if !(self.max_segment_deg >= 1.0 && self.max_segment_deg <= 90.0) {
            return Err(format!("vv: max_segment_deg {} out of 1..=90", self.max_segment_deg));
        }
        if !(self.max_link_deg >= 1.0 && self.max_link_deg <= 180.0) {
            return Err(format!("vv: max_link_deg {} out of 1..=180", self.max_link_deg));
        }
        Ok(())
    }
}

/// A static model: triangles in one space (world space for a scene), per-vertex unit normals,
/// and which triangles occlude.
#[derive(Clone, Debug, Default)]
pub struct VvModel {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals (the hemisphere of each vertex).
    pub normals: Vec<Vec3>,
    /// Triangle list.
    pub indices: Vec<u32>,
    /// Per triangle: whether it occludes (objects with `casts_shadow = false` only receive).
    pub occluder: Vec<bool>,
}

/// One object of [`VvModel::from_objects`].
pub struct ObjectMesh<'a> {
    /// Object-space positions.
    pub positions: &'a [Vec3],
    /// Object-space normals.
    pub normals: &'a [Vec3],
    /// Triangle list.
    pub indices: &'a [u32],
    /// Object to world.
    pub world: Mat4,
    /// Whether it casts shadows.
    pub casts_shadow: bool,
}

impl VvModel {
    /// Concatenates objects in world space (vertex and triangle ranges in object order).
    pub fn from_objects<'a>(objects: impl IntoIterator<Item = ObjectMesh<'a>>) -> Self {
        let mut m = VvModel::default();
        for o in objects {
            let base = m.positions.len() as u32;
            let nm = glam::Mat3::from_mat4(o.world).inverse().transpose();
            m.positions.extend(o.positions.iter().map(|p| o.world.transform_point3(*p)));
            m.normals.extend(o.normals.iter().map(|n| (nm * *n).normalize_or_zero()));
            m.indices.extend(o.indices.iter().map(|i| base + i));
            m.occluder.extend(std::iter::repeat_n(o.casts_shadow, o.indices.len() / 3));
        }
        m
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Checks sizes, indices and finiteness (the message says what is wrong).
    pub fn validate(&self) -> Result<(), String> {
        if self.positions.is_empty() || self.indices.len() < 3 {
            return Err("vv: empty model (no triangles)".into());
        }
        if !self.indices.len().is_multiple_of(3) {
            return Err(format!("vv: index count {} is not a multiple of 3", self.indices.len()));
        }
        if self.normals.len() != self.positions.len() {
            return Err(format!("vv: {} normals for {} vertices", self.normals.len(), self.positions.len()));
        }
        if self.occluder.len() != self.triangle_count() {
            return Err(format!("vv: {} occluder flags for {} triangles", self.occluder.len(), self.triangle_count()));
        }
        if let Some(i) = self.indices.iter().find(|&&i| i as usize >= self.positions.len()) {
            return Err(format!("vv: index {i} out of range ({} vertices)", self.positions.len()));
        }
        if self.positions.iter().chain(&self.normals).any(|p| !p.is_finite()) {
            return Err("vv: non-finite vertex position or normal".into());
        }
        if self.positions.len() > (1 << 24) {
            return Err(format!("vv: {} vertices (max 2^24)", self.positions.len()));
        }
        Ok(())
    }

    /// FNV-1a hash of positions, normals, indices and occluder flags (stored in files).
    pub fn hash(&self) -> u64 {
        let mut h = 0xcbf29ce484222325u64;
        let mut eat = |b: &[u8]| {
            for &x in b {
                h ^= x as u64;
                h = h.wrapping_mul(0x100000001b3);
            }
        };
        for p in self.positions.iter().chain(&self.normals) {
            for c in p.to_array() {
                eat(&c.to_le_bytes());
            }
        }
        for i in &self.indices {
            eat(&i.to_le_bytes());
        }
        for &o in &self.occluder {
            eat(&[o as u8]);
        }
        h
    }
}

/// Per-vertex vectorized visibility of a model (flat arrays, ready for GPU buffers).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VectorizedVisibility {
    /// Homogeneous points `[x, y, z, w]` (see the module docs): first the vertices' own
    /// sequence points (`..vertex_points`), then the correspondence's virtual points.
    pub points: Vec<[f32; 4]>,
    /// Number of points belonging to vertex sequences (virtual points follow).
    pub vertex_points: u32,
    /// Sequence `k` is `points[seq_offsets[k]..seq_offsets[k + 1]]` (a closed loop: the last
    /// point connects back to the first). Length = sequence count + 1.
    pub seq_offsets: Vec<u32>,
    /// Per model vertex: its sequences `first..first + count` (`[first, count]`); vertices
    /// with the same position and normal share the range.
    pub vertex_seqs: Vec<[u32; 2]>,
}

impl VectorizedVisibility {
    /// Number of sequences.
    pub fn sequence_count(&self) -> usize {
        self.seq_offsets.len().saturating_sub(1)
    }

    /// Points of sequence `k`.
    pub fn sequence(&self, k: usize) -> &[[f32; 4]] {
        &self.points[self.seq_offsets[k] as usize..self.seq_offsets[k + 1] as usize]
    }

    /// Sequence indices of vertex `v`.
    pub fn vertex_sequences(&self, v: usize) -> std::ops::Range<usize> {
        let [f, c] = self.vertex_seqs[v];
        f as usize..(f + c) as usize
    }

    /// Total number of points of vertex `v`'s sequences.
    pub fn vertex_point_count(&self, v: usize) -> usize {
        self.vertex_sequences(v).map(|k| self.sequence(k).len()).sum()
    }
}

/// Per-triangle output triple lists (section III), flat.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Correspondence {
    /// Triangle `t`'s loops are `tri_offsets[t]..tri_offsets[t + 1]` (length = triangles + 1).
    pub tri_offsets: Vec<u32>,
    /// Loop `l` is `triples[loop_offsets[l]..loop_offsets[l + 1]]` (closed; length = loops + 1).
    pub loop_offsets: Vec<u32>,
    /// Triples: one index into [`VectorizedVisibility::points`] per triangle vertex (index
    /// buffer order).
    pub triples: Vec<[u32; 3]>,
}

impl Correspondence {
    /// Loop index range of triangle `t`.
    pub fn triangle_loops(&self, t: usize) -> std::ops::Range<usize> {
        self.tri_offsets[t] as usize..self.tri_offsets[t + 1] as usize
    }

    /// Triples of loop `l`.
    pub fn loop_triples(&self, l: usize) -> &[[u32; 3]] {
        &self.triples[self.loop_offsets[l] as usize..self.loop_offsets[l + 1] as usize]
    }

    /// Bytes of the triple lists as the paper counts them (6 ints per triple would be ours 3).
    pub fn triple_bytes(&self) -> usize {
        self.triples.len() * 12 + self.loop_offsets.len() * 4 + self.tri_offsets.len() * 4
    }
}

/// Statistics of a precompute (sizes in bytes, times in seconds).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VvStats {
    /// Vectorized-visibility points and offsets.
    pub visibility_bytes: usize,
    /// Output triple lists.
    pub triple_bytes: usize,
    /// Wall time of the visibility precompute.
    pub visibility_seconds: f64,
    /// Wall time of the correspondence.
    pub correspondence_seconds: f64,
    /// Triples that needed the relaxed constraints (Rule 1 ignored, no propagation).
    pub relaxed_triples: usize,
    /// Triples selected from RGB tripoints (before propagation).
    pub voronoi_triples: usize,
    /// Triples completed from propagated partial triples.
    pub propagated_triples: usize,
    /// Triples added to route jumps through a vertex's pole (step 6 of [`corr`]).
    pub pole_triples: usize,
}

/// Everything one model file holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VvData {
    /// [`VvModel::hash`] of the model it was made for.
    pub model_hash: u64,
    /// Vertex count of that model.
    pub vertex_count: u32,
    /// Triangle count of that model.
    pub triangle_count: u32,
    /// Parameters used.
    pub params: VvParams,
    /// Per-vertex visibility (+ virtual points).
    pub vis: VectorizedVisibility,
    /// Per-triangle triple lists.
    pub corr: Correspondence,
    /// Sizes and times (times are those of the run that wrote the file).
    pub stats: VvStats,
}

// ---------------------------------------------------------------------------------------------
// Synthesis (eq. 3) and interpolation (eq. 21)

/// Eq. 3 for one point: `normalize(q.xyz - q.w * s)`; `None` when `q` is (numerically) `s`.
pub fn synth_dir(q: [f32; 4], s: Vec3) -> Option<Vec3> {
    let d = Vec3::new(q[0], q[1], q[2]) - q[3] * s;
    let l = d.length();
    (l > 1e-12 && l.is_finite()).then(|| d / l)
}

/// Clamps `d` onto the hemisphere of the unit normal `n`: a direction below the tangent plane
/// is projected onto the horizon (any horizon direction for `d = -n`).
pub fn clamp_to_hemisphere(d: Vec3, n: Vec3) -> Vec3 {
    let c = d.dot(n);
    if c >= 0.0 {
        return d;
    }
    let t = d - c * n;
    let l = t.length();
    if l > 1e-6 {
        t / l
    } else {
        n.any_orthonormal_vector()
    }
}

/// Synthesized visibility of model vertex `v` at the surface point `s` with unit normal `n`
/// (eq. 3 + [`clamp_to_hemisphere`]): one loop of unit directions per sequence. A point equal
/// to `s` takes its neighbours' direction (or `n`).
pub fn synthesize(vis: &VectorizedVisibility, v: usize, s: Vec3, n: Vec3) -> Vec<Vec<Vec3>> {
    vis.vertex_sequences(v)
        .map(|k| {
            let seq = vis.sequence(k);
            let mut out: Vec<Option<Vec3>> = seq.iter().map(|q| synth_dir(*q, s)).collect();
            fill_missing(&mut out, n);
            out.into_iter().map(|d| clamp_to_hemisphere(d.unwrap(), n)).collect()
        })
        .collect()
}

fn fill_missing(v: &mut [Option<Vec3>], n: Vec3) {
    let Some(first) = v.iter().position(|d| d.is_some()) else {
        v.iter_mut().for_each(|d| *d = Some(n));
        return;
    };
    let len = v.len();
    for i in 1..=len {
        let j = (first + i) % len;
        if v[j].is_none() {
            v[j] = v[(j + len - 1) % len];
        }
    }
}

/// Interpolated vectorized visibility of triangle `t` (eq. 21) at barycentrics `lambda`, surface
/// point `s` and unit normal `n`: one loop of unit directions per triple loop.
pub fn interpolate(
    vis: &VectorizedVisibility,
    corr: &Correspondence,
    t: usize,
    lambda: [f32; 3],
    s: Vec3,
    n: Vec3,
) -> Vec<Vec<Vec3>> {
    corr.triangle_loops(t)
        .map(|l| {
            corr.loop_triples(l)
                .iter()
                .map(|tr| {
                    let mut a = Vec3::ZERO;
                    for k in 0..3 {
                        if let Some(d) = synth_dir(vis.points[tr[k] as usize], s) {
                            a += lambda[k] * d;
                        }
                    }
                    clamp_to_hemisphere(a.try_normalize().unwrap_or(n), n)
                })
                .collect()
        })
        .collect()
}

/// Signed solid angle enclosed by a closed loop of unit directions, counter-clockwise seen from
/// outside positive, measured as a fan of spherical triangles from the pole `n` (exact for
/// loops in the closed hemisphere of `n`, which synthesized and interpolated loops are).
pub fn signed_solid_angle(loop_dirs: &[Vec3], n: Vec3) -> f64 {
    let c = n.as_dvec3();
    let m = loop_dirs.len();
    let mut sum = 0.0;
    for i in 0..m {
        let a = loop_dirs[i].as_dvec3();
        let b = loop_dirs[(i + 1) % m].as_dvec3();
        sum += tri_solid_angle(c, a, b);
    }
    sum
}

/// Signed solid angle of the spherical triangle `(a, b, c)` (Van Oosterom-Strackee).
pub fn tri_solid_angle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let num = a.dot(b.cross(c));
    let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
    2.0 * num.atan2(den)
}

/// Lambert azimuthal equal-area coordinates of `d` about the frame `(t, b, n)`: the hemisphere
/// maps onto the unit disk (horizon at radius 1, pole at 0). Below the horizon `r > 1`.
pub fn lambert(d: DVec3, frame: &[DVec3; 3]) -> (f64, f64) {
    let (x, y, z) = (d.dot(frame[0]), d.dot(frame[1]), d.dot(frame[2]));
    let r = (1.0 - z).max(0.0).sqrt();
    let rxy = (x * x + y * y).sqrt();
    if rxy < 1e-15 {
        return (r, 0.0);
    }
    (r * x / rxy, r * y / rxy)
}

/// Inverse of [`lambert`] for `r <= sqrt(2)`.
pub fn lambert_inv(u: f64, v: f64, frame: &[DVec3; 3]) -> DVec3 {
    let r2 = u * u + v * v;
    let z = 1.0 - r2;
    let s = (2.0 - r2).max(0.0).sqrt();
    (frame[0] * (u * s) + frame[1] * (v * s) + frame[2] * z).normalize()
}

/// Stratified equal-area directions of the hemisphere of `frame`: the centres of an `res x res`
/// grid over the Lambert disk that fall inside it, mapped by [`lambert_inv`]. Each stands for a
/// solid angle of `2 pi (2 / res)^2 / pi`.
pub fn lambert_grid(res: u32, frame: &[DVec3; 3]) -> impl Iterator<Item = DVec3> + '_ {
    let cell = move |i: u32| -1.0 + (i as f64 + 0.5) * 2.0 / res as f64;
    (0..res)
        .flat_map(move |i| (0..res).map(move |j| (cell(i), cell(j))))
        .filter(|(u, w)| u * u + w * w < 1.0)
        .map(|(u, w)| lambert_inv(u, w, frame))
}

/// Orthonormal frame `(t, b, n)` with `t x b = n`.
pub fn frame(n: Vec3) -> [DVec3; 3] {
    let n = n.as_dvec3().normalize();
    let t = n.any_orthonormal_vector();
    [t, n.cross(t), n]
}

/// Whether direction `d` (in the hemisphere of `n`) is occluded by the loops: their total
/// winding number about `d` is positive. Loops are projected with [`lambert`] about `n`
/// (segments become straight in the disk: exact at the vertices, approximate in between).
pub fn occluded_by(loops: &[Vec<Vec3>], d: Vec3, n: Vec3) -> bool {
    let f = frame(n);
    let (px, py) = lambert(d.as_dvec3(), &f);
    let mut wn = 0i32;
    for l in loops {
        let pts: Vec<(f64, f64)> = l.iter().map(|a| lambert(a.as_dvec3(), &f)).collect();
        for i in 0..pts.len() {
            let (ax, ay) = pts[i];
            let (bx, by) = pts[(i + 1) % pts.len()];
            let side = (bx - ax) * (py - ay) - (px - ax) * (by - ay);
            if ay <= py {
                if by > py && side > 0.0 {
                    wn += 1;
                }
            } else if by <= py && side < 0.0 {
                wn -= 1;
            }
        }
    }
    wn > 0
}

// ---------------------------------------------------------------------------------------------
// Both stages

/// Stage of [`compute`] reported to the progress callback.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Per-vertex visibility: total = model vertex count.
    Visibility,
    /// Correspondence: total = 2 x triangle count.
    Correspondence,
}

impl Stage {
    /// Progress total of this stage for `model`.
    pub fn total(self, model: &VvModel) -> u64 {
        match self {
            Stage::Visibility => model.positions.len() as u64,
            Stage::Correspondence => 2 * model.triangle_count() as u64,
        }
    }
}

/// Precomputes the vectorized visibility and the correspondence of `model` (both stages,
/// timed). `progress(stage, n)` receives finished-work increments, from any thread.
pub fn compute(model: &VvModel, params: &VvParams, progress: &(dyn Fn(Stage, u64) + Sync)) -> Result<VvData, String> {
    model.validate()?;
    params.validate()?;
    let t0 = std::time::Instant::now();
    let mut vis = precompute_visibility(model, params, &|n| progress(Stage::Visibility, n))?;
    let visibility_seconds = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let topo = Topology::new(model);
    let (corr, stats) = corr::correspondence(model, &topo, &mut vis, params, &|n| progress(Stage::Correspondence, n))?;
    let correspondence_seconds = t1.elapsed().as_secs_f64();
    Ok(VvData {
        model_hash: model.hash(),
        vertex_count: model.positions.len() as u32,
        triangle_count: model.triangle_count() as u32,
        params: params.clone(),
        vis,
        corr,
        stats: VvStats { visibility_seconds, correspondence_seconds, ..stats },
    }
    .with_sizes())
}

/// Cache file of `model` under `dir`: `<dir>/<name>-<model hash>-<params hash>.pvv` (`name`
/// sanitized).
pub fn cache_path(dir: &std::path::Path, name: &str, model: &VvModel, params: &VvParams) -> std::path::PathBuf {
    let clean: String =
        name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
    let ph = {
        let m = VvModel {
            positions: vec![
                Vec3::new(params.resolution as f32, params.refine_steps as f32, params.tolerance_deg),
                Vec3::new(params.max_segment_deg, params.max_link_deg, params.seed as f32),
            ],
            ..Default::default()
        };
        m.hash() ^ params.seed
    };
    dir.join(format!("{clean}-{:016x}-{:08x}.pvv", model.hash(), ph as u32))
}

/// Reads the cached data of `model` from [`cache_path`] when it exists, was made for this model
/// with these parameters and this format version; else computes it ([`compute`]) and writes
/// the file (creating `dir`). Returns the data and the path. A stale or corrupt cache file is
/// recomputed; I/O errors name the file.
pub fn load_or_compute(
    model: &VvModel,
    params: &VvParams,
    dir: &std::path::Path,
    name: &str,
    progress: &(dyn Fn(Stage, u64) + Sync),
) -> Result<(VvData, std::path::PathBuf), String> {
    let path = cache_path(dir, name, model, params);
    if path.exists() {
        if let Ok(d) = VvData::read_for(&path, model) {
            if d.params == *params {
                return Ok((d, path));
            }
        }
    }
    let d = compute(model, params, progress)?;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    d.write(&path)?;
    Ok((d, path))
}

// ---------------------------------------------------------------------------------------------
// Accuracy against ray tracing

/// Accuracy of a model's data against ray-traced visibility ([`evaluate`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Evaluation {
    /// Interior points evaluated (points with some traced occlusion).
    pub points: usize,
    /// Mean fraction of hemisphere directions where the eq. 19 blend of the three eq. 3
    /// syntheses (weighted by the barycentrics) agrees with the traced visibility.
    pub agreement_eq19: f64,
    /// Same for the interpolated vectorized visibility (eq. 21).
    pub agreement_eq21: f64,
    /// `|occluded solid angle of eq. 21 at a vertex - the vertex's own|` (sr) over every
    /// (triangle, vertex): median, 95th percentile, max.
    pub vertex_error: [f64; 3],
    /// Triangles with a corner error ([`corner_errors`]) above 0.1, 1 and 3 sr.
    pub triangles_over: [usize; 3],
    /// Triangle count.
    pub triangles: usize,
}

/// Eq. 21 at each triangle's own vertices (barycentrics `(1,0,0)` etc., the vertex's position
/// and normal) against that vertex's own visibility (eq. 3 there): per triangle, the three
/// `|occluded solid angle of the interpolated loops - the vertex's own|` (sr). Exact
/// reproduction gives zeros (up to relaxed-stage chords).
pub fn corner_errors(model: &VvModel, d: &VvData) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    let solid = |l: &[Vec<Vec3>], n: Vec3| l.iter().map(|x| signed_solid_angle(x, n)).sum::<f64>();
    (0..model.triangle_count())
        .into_par_iter()
        .map(|t| {
            let idx = [0, 1, 2].map(|k| model.indices[3 * t + k] as usize);
            [0, 1, 2].map(|k| {
                let mut l = [0.0f32; 3];
                l[k] = 1.0;
                let (p, n) = (model.positions[idx[k]], model.normals[idx[k]]);
                (solid(&interpolate(&d.vis, &d.corr, t, l, p, n), n) - solid(&synthesize(&d.vis, idx[k], p, n), n))
                    .abs()
            })
        })
        .collect()
}

/// Per triangle, the largest disagreement (sr) between eq. 21 and eq. 19 in occluded solid
/// angle, over the centroid and three interior points (barycentrics 0.6 / 0.2 / 0.2): eq. 21's
/// interpolated loops against the barycentric blend of the three vertices' synthesized
/// visibilities (eq. 19's blend, as a solid angle). Both describe the same visibility; a sound
/// correspondence keeps them close, while crossing or mis-ordered triples (loops that turn
/// inside out between the corners) give a far larger or a negative occluded angle: black specks
/// under eq. 21. An interpolated angle outside `[0, 2 pi]` counts as its distance to the range
/// plus the disagreement.
pub fn interpolation_disagreement(model: &VvModel, vis: &VectorizedVisibility, corr: &Correspondence) -> Vec<f32> {
    use rayon::prelude::*;
    let solid = |l: &[Vec<Vec3>], n: Vec3| l.iter().map(|x| signed_solid_angle(x, n)).sum::<f64>();
    const POINTS: [[f32; 3]; 4] =
        [[1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0], [0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6]];
    (0..model.triangle_count())
        .into_par_iter()
        .map(|t| {
            let idx = [0, 1, 2].map(|k| model.indices[3 * t + k] as usize);
            let mut worst = 0.0f64;
            for l in POINTS {
                let s: Vec3 = (0..3).map(|k| model.positions[idx[k]] * l[k]).sum();
                let n = (0..3)
                    .map(|k| model.normals[idx[k]] * l[k])
                    .sum::<Vec3>()
                    .try_normalize()
                    .unwrap_or(model.normals[idx[0]]);
                let w21 = solid(&interpolate(vis, corr, t, l, s, n), n);
                let w19: f64 = (0..3).map(|k| l[k] as f64 * solid(&synthesize(vis, idx[k], s, n), n)).sum();
                let out = (-w21).max(w21 - 2.0 * std::f64::consts::PI).max(0.0);
                worst = worst.max((w21 - w19).abs() + out);
            }
            worst as f32
        })
        .collect()
}

/// Compares `d` with ray tracing at `samples` interior points (deterministic barycentrics from
/// `seed`, triangles spread over the model) on `map_res x map_res` Lambert directions, and the
/// interpolation at every triangle's vertices with the vertices' own visibility.
pub fn evaluate(model: &VvModel, d: &VvData, samples: usize, map_res: u32, seed: u64) -> Evaluation {
    use rayon::prelude::*;
    let topo = Topology::new(model);
    let tracer = trace::Tracer::new(&model.positions, &model.indices, &model.occluder);
    let ntri = model.triangle_count();
    let corners = corner_errors(model, d);
    let triangles_over = [0.1, 1.0, 3.0].map(|x| corners.iter().filter(|c| c.iter().any(|&e| e > x)).count());
    let mut verr: Vec<f64> = corners.iter().flatten().copied().collect();
    verr.sort_by(|a, b| a.total_cmp(b));
    let q =
        |f: f64| verr.get(((verr.len() as f64 * f) as usize).min(verr.len().saturating_sub(1))).copied().unwrap_or(0.0);
    let per: Vec<Option<(f64, f64)>> = (0..samples)
        .into_par_iter()
        .map(|i| {
            let h = |s: u64| {
                let mut z = seed.wrapping_add((i as u64 * 4 + s).wrapping_mul(0x9e3779b97f4a7c15));
                z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
                z ^ (z >> 31)
            };
            let t = (h(0) % ntri as u64) as usize;
            let (mut a, mut b) = ((h(1) >> 11) as f32 / (1u64 << 53) as f32, (h(2) >> 11) as f32 / (1u64 << 53) as f32);
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let lambda = [1.0 - a - b, a, b];
            let idx = [0, 1, 2].map(|k| model.indices[3 * t + k] as usize);
            let p: Vec3 = (0..3).map(|k| lambda[k] * model.positions[idx[k]]).sum();
            let n = (0..3).map(|k| lambda[k] * model.normals[idx[k]]).sum::<Vec3>().try_normalize()?;
            let local: Vec<u32> = idx.iter().map(|&v| topo.pos_group[v]).collect();
            let f = frame(n);
            let syn: Vec<Vec<Vec<Vec3>>> = (0..3).map(|k| synthesize(&d.vis, idx[k], p, n)).collect();
            let interp = interpolate(&d.vis, &d.corr, t, lambda, p, n);
            let (mut a19, mut a21, mut total, mut occ) = (0.0, 0.0, 0usize, 0usize);
            for dir in lambert_grid(map_res, &f) {
                let truth =
                    precompute::trace_occluder(&tracer, &topo, &local, p.as_dvec3(), n.as_dvec3(), dir).is_some();
                total += 1;
                occ += truth as usize;
                let dv = dir.as_vec3();
                a21 += (occluded_by(&interp, dv, n) == truth) as u32 as f64;
                for k in 0..3 {
                    a19 += lambda[k] as f64 * (occluded_by(&syn[k], dv, n) == truth) as u32 as f64;
                }
            }
            (occ > 0 && total > 0).then(|| (a19 / total as f64, a21 / total as f64))
        })
        .collect();
    let ok: Vec<(f64, f64)> = per.into_iter().flatten().collect();
    let m = ok.len().max(1) as f64;
    Evaluation {
        points: ok.len(),
        agreement_eq19: ok.iter().map(|x| x.0).sum::<f64>() / m,
        agreement_eq21: ok.iter().map(|x| x.1).sum::<f64>() / m,
        vertex_error: [q(0.5), q(0.95), verr.last().copied().unwrap_or(0.0)],
        triangles_over,
        triangles: ntri,
    }
}
