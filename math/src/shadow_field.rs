//! Precomputed shadow fields (Zhou et al. 2005) with adaptive shell resolution (Tamura et al.,
//! "adaptive shadow fields"): object occlusion fields (OOF) on concentric shells, order-4 SH
//! (16 coefficients), 8-bit quantization with per-shell min/step, per-vertex self-occlusion
//! transfer, and the CPU evaluation used by the `shadow-fields` technique.
//!
//! # Conventions
//! * The field stores *visibility* `V(w) = 1` for unblocked directions (so occluders combine by
//!   the SH triple product of their visibilities). A point inside a closed mesh sees `V = 0`.
//! * Shell `c` (0-based) has radius `0.2 * Vr * (1 + c)` around the bounding-box centre, `Vr`
//!   the bounding-sphere radius about that centre.
//! * Shell sample `(s, t)` of resolution `R`: `theta = pi (s + 0.5) / R` from +z,
//!   `phi = 2 pi t / R` from +x towards +y (the [`crate::sh`] frame). Interpolation is bilinear
//!   (clamped in theta, periodic in phi) inside a shell and linear between the two nearest
//!   shells; inside the innermost shell the innermost shell is used, outside the outermost the
//!   object is ignored (unoccluded). The GPU mirror is `glsl/include/sf.glsl`.
//! * Coefficient `e` of a shell is stored as `u8 q`, value `min[e] + q * step[e]`.

use crate::sh::{eval_basis_into, sh_count, ShRotation, TripleProductTensor};
use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// SH order of the fields (bands 0..3).
pub const ORDER: usize = 4;
/// Coefficients per sample point.
pub const NCOEF: usize = 16;
/// Floats of the block-diagonal SH rotation matrix of order 4 (1 + 9 + 25 + 49).
pub const ROT_FLOATS: usize = 84;
/// Visibility coefficient vector of an unoccluded point (`V = 1`): `sqrt(4 pi)` in band 0.
pub const UNOCCLUDED_DC: f64 = 3.544907701811032;
/// The constant basis function `Y_0 = 1 / sqrt(4 pi)`.
pub const Y0: f64 = 0.28209479177387814;
/// Entities (occluders whose shells contain the point, plus lights) one point combines at most
/// (the GPU's local sort array; the CPU path applies the same cap so both agree).
pub const MAX_ENTITIES: usize = 48;

/// Precomputation parameters (defaults from the paper).
#[derive(Clone, Debug)]
pub struct Params {
    /// Number of concentric shells `C` (paper: 32).
    pub shells: usize,
    /// Initial (fixed) polar resolution `R`: `R x R` samples per shell (paper: 64). Rounded up
    /// to a power of two.
    pub resolution: usize,
    /// Occlusion map resolution per sample point: `map_res x 2 map_res` lat-long directions
    /// (paper: 64x64 maps).
    pub map_res: usize,
    /// Adaptive threshold of eq. 1 (paper: 0.010).
    pub threshold: f64,
    /// Smallest resolution the adaptation may reach.
    pub min_resolution: usize,
}

impl Default for Params {
    fn default() -> Self {
        Params { shells: 32, resolution: 64, map_res: 32, threshold: 0.010, min_resolution: 1 }
    }
}

// ---------------------------------------------------------------------------------------------
// Ray casting (a small binary BVH over the object's triangles, any-hit queries)

/// A BVH node. Inner nodes hold their two children's boxes, so a ray tests both children where
/// it stands and descends only into those it enters, nearer first.
#[derive(Clone, Copy)]
struct Node {
    /// Boxes of child 0 and child 1 (inner nodes); unused in leaves.
    lo: [DVec3; 2],
    hi: [DVec3; 2],
    /// Inner: the children's node indices. Leaf: first triangle and count.
    a: u32,
    b: u32,
    leaf: bool,
}

/// Any-hit ray caster over a triangle soup: binned-SAH BVH in f64. Whether a ray is occluded
/// does not depend on the tree (every triangle a ray can hit lies in boxes it enters: the boxes
/// are padded by a relative 1e-9 against rounding), only the time to find out does.
pub struct RayCaster {
    tris: Vec<[DVec3; 3]>,
    nodes: Vec<Node>,
    /// The root's box (tested before the walk).
    root: (DVec3, DVec3),
}

/// Centroid bins of the SAH build.
const SAH_BINS: usize = 16;
/// Largest leaf.
const LEAF_MAX: usize = 4;

fn tri_box(t: &[DVec3; 3]) -> (DVec3, DVec3) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}

fn boxes_of(tris: &[[DVec3; 3]]) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for t in tris {
        let (a, b) = tri_box(t);
        lo = lo.min(a);
        hi = hi.max(b);
    }
    // conservative against rounding in the slab test
    let pad = (hi - lo).max_element().max(hi.abs().max(lo.abs()).max_element()) * 1e-9;
    (lo - DVec3::splat(pad), hi + DVec3::splat(pad))
}

fn half_area(lo: DVec3, hi: DVec3) -> f64 {
    let e = (hi - lo).max(DVec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl RayCaster {
    /// Builds the BVH (triangles referencing out-of-range vertices are skipped).
    pub fn new(positions: &[Vec3], indices: &[u32]) -> Self {
        let mut tris: Vec<[DVec3; 3]> = indices
            .chunks_exact(3)
            .filter(|t| t.iter().all(|&i| (i as usize) < positions.len()))
            .map(|t| [0, 1, 2].map(|k| positions[t[k] as usize].as_dvec3()))
            .collect();
        let mut nodes = Vec::new();
        let root = boxes_of(&tris);
        if !tris.is_empty() {
            let n = tris.len();
            nodes.push(Node { lo: [DVec3::ZERO; 2], hi: [DVec3::ZERO; 2], a: 0, b: 0, leaf: true });
            Self::build(&mut tris, 0, n, 0, &mut nodes, 0);
        }
        RayCaster { tris, nodes, root }
    }

    /// Splits `tris[start..end]` (binned SAH over centroids; the median on the longest axis
    /// when the centroids coincide along it) and fills node `id`.
    fn build(tris: &mut [[DVec3; 3]], start: usize, end: usize, id: usize, nodes: &mut Vec<Node>, depth: usize) {
        let n = end - start;
        if n <= LEAF_MAX || depth >= 48 {
            nodes[id] = Node { lo: [DVec3::ZERO; 2], hi: [DVec3::ZERO; 2], a: start as u32, b: n as u32, leaf: true };
            return;
        }
        let cen = |t: &[DVec3; 3]| (t[0] + t[1] + t[2]) / 3.0;
        let (mut clo, mut chi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in &tris[start..end] {
            let c = cen(t);
            clo = clo.min(c);
            chi = chi.max(c);
        }
        let ext = chi - clo;
        // best (cost, axis, bin boundary) over the three axes
        let mut best: Option<(f64, usize, usize)> = None;
        for axis in 0..3 {
            if !(ext[axis] > 0.0) {
                continue;
            }
            let scale = SAH_BINS as f64 / ext[axis];
            let bin_of = |t: &[DVec3; 3]| (((cen(t)[axis] - clo[axis]) * scale) as usize).min(SAH_BINS - 1);
            let mut cnt = [0usize; SAH_BINS];
            let mut blo = [DVec3::splat(f64::INFINITY); SAH_BINS];
            let mut bhi = [DVec3::splat(f64::NEG_INFINITY); SAH_BINS];
            for t in &tris[start..end] {
                let b = bin_of(t);
                let (l, h) = tri_box(t);
                cnt[b] += 1;
                blo[b] = blo[b].min(l);
                bhi[b] = bhi[b].max(h);
            }
            // sweep: left areas/counts from the left, right from the right
            let mut right_cost = [0f64; SAH_BINS];
            let (mut lo, mut hi, mut c) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY), 0usize);
            for b in (1..SAH_BINS).rev() {
                lo = lo.min(blo[b]);
                hi = hi.max(bhi[b]);
                c += cnt[b];
                right_cost[b] = if c > 0 { half_area(lo, hi) * c as f64 } else { 0.0 };
            }
            let (mut lo, mut hi, mut c) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY), 0usize);
            for b in 0..SAH_BINS - 1 {
                lo = lo.min(blo[b]);
                hi = hi.max(bhi[b]);
                c += cnt[b];
                if c == 0 || c == n {
                    continue;
                }
                let cost = half_area(lo, hi) * c as f64 + right_cost[b + 1];
                if best.is_none_or(|(bc, _, _)| cost < bc) {
                    best = Some((cost, axis, b + 1));
                }
            }
        }
        let mid = match best {
            Some((_, axis, split)) => {
                let scale = SAH_BINS as f64 / ext[axis];
                let mut i = start;
                for j in start..end {
                    let b = (((cen(&tris[j])[axis] - clo[axis]) * scale) as usize).min(SAH_BINS - 1);
                    if b < split {
                        tris.swap(i, j);
                        i += 1;
                    }
                }
                i
            }
            None => start + n / 2, // every centroid in one point: any halving
        };
        let children = nodes.len();
        nodes.push(Node { lo: [DVec3::ZERO; 2], hi: [DVec3::ZERO; 2], a: 0, b: 0, leaf: true });
        nodes.push(Node { lo: [DVec3::ZERO; 2], hi: [DVec3::ZERO; 2], a: 0, b: 0, leaf: true });
        let (l0, h0) = boxes_of(&tris[start..mid]);
        let (l1, h1) = boxes_of(&tris[mid..end]);
        nodes[id] = Node { lo: [l0, l1], hi: [h0, h1], a: children as u32, b: children as u32 + 1, leaf: false };
        Self::build(tris, start, mid, children, nodes, depth + 1);
        Self::build(tris, mid, end, children + 1, nodes, depth + 1);
    }

    /// Entry distance of the ray into a box, `None` when it misses within `(0, tmax)`.
    #[inline(always)]
    fn enter(lo: DVec3, hi: DVec3, o: DVec3, inv: DVec3, tmax: f64) -> Option<f64> {
        let t0 = (lo - o) * inv;
        let t1 = (hi - o) * inv;
        let tn = t0.min(t1).max_element().max(0.0);
        let tf = t0.max(t1).min_element().min(tmax);
        (tn <= tf && !tf.is_nan()).then_some(tn)
    }

    /// Whether the ray `o + t d`, `t in (0, tmax)`, hits any triangle (both sides).
    pub fn occluded(&self, o: DVec3, d: DVec3, tmax: f64) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let inv = DVec3::ONE / d;
        if Self::enter(self.root.0, self.root.1, o, inv, tmax).is_none() {
            return false;
        }
        let mut stack = [0u32; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if n.leaf {
                for t in &self.tris[n.a as usize..(n.a + n.b) as usize] {
                    if crate::ray::ray_triangle(o, d, t, tmax, 1e-14).is_some() {
                        return true;
                    }
                }
                continue;
            }
            let e0 = Self::enter(n.lo[0], n.hi[0], o, inv, tmax);
            let e1 = Self::enter(n.lo[1], n.hi[1], o, inv, tmax);
            // push the farther first so the nearer is walked first (the depth cap keeps 64 enough)
            match (e0, e1) {
                (Some(t0), Some(t1)) => {
                    let (near, far) = if t0 <= t1 { (n.a, n.b) } else { (n.b, n.a) };
                    stack[sp] = far;
                    stack[sp + 1] = near;
                    sp += 2;
                }
                (Some(_), None) => {
                    stack[sp] = n.a;
                    sp += 1;
                }
                (None, Some(_)) => {
                    stack[sp] = n.b;
                    sp += 1;
                }
                (None, None) => {}
            }
        }
        false
    }
}

// ---------------------------------------------------------------------------------------------
// Sphere directions

/// Direction of polar angles in the SH frame.
pub fn polar_dir(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

/// A lat-long direction table `(direction, solid angle, basis values)` with `n x 2n` cells.
pub struct DirTable {
    /// `(direction, weight, Y_0..Y_15)`; weights sum to 4 pi.
    pub dirs: Vec<(DVec3, f64, [f64; NCOEF])>,
}

impl DirTable {
    /// `n` rings in theta, `2n` cells in phi, cell centres.
    pub fn new(n: usize) -> Self {
        let n = n.max(2);
        let (dt, dp) = (PI / n as f64, PI / n as f64);
        let mut dirs = Vec::with_capacity(2 * n * n);
        for i in 0..n {
            let th = (i as f64 + 0.5) * dt;
            // exact solid angle of the ring cell
            let w = ((i as f64 * dt).cos() - ((i + 1) as f64 * dt).cos()) * dp;
            for j in 0..2 * n {
                let d = polar_dir(th, (j as f64 + 0.5) * dp);
                let mut y = [0.0; NCOEF];
                eval_basis_into(ORDER, d, &mut y);
                dirs.push((d, w, y));
            }
        }
        DirTable { dirs }
    }
}

// ---------------------------------------------------------------------------------------------
// Grids

/// Bilinear sample of an `r x r` grid of coefficient vectors at polar angles (see module docs).
pub fn sample_grid(grid: &[[f32; NCOEF]], r: usize, theta: f64, phi: f64) -> [f64; NCOEF] {
    let (s0, s1, fs, t0, t1, ft) = grid_weights(r, theta, phi);
    let mut out = [0.0; NCOEF];
    for (idx, w) in [
        (s0 * r + t0, (1.0 - fs) * (1.0 - ft)),
        (s0 * r + t1, (1.0 - fs) * ft),
        (s1 * r + t0, fs * (1.0 - ft)),
        (s1 * r + t1, fs * ft),
    ] {
        for e in 0..NCOEF {
            out[e] += w * grid[idx][e] as f64;
        }
    }
    out
}

/// Indices and weights of the bilinear lookup: `(s0, s1, fs, t0, t1, ft)`.
pub fn grid_weights(r: usize, theta: f64, phi: f64) -> (usize, usize, f64, usize, usize, f64) {
    let r = r.max(1);
    let rf = r as f64;
    let u = (theta / PI * rf - 0.5).clamp(0.0, rf - 1.0);
    let s0 = (u.floor() as usize).min(r - 1);
    let s1 = (s0 + 1).min(r - 1);
    let fs = u - s0 as f64;
    let v = (phi / (2.0 * PI)).rem_euclid(1.0) * rf;
    let t0 = (v.floor() as usize) % r;
    let t1 = (t0 + 1) % r;
    let ft = v - v.floor();
    (s0, s1, fs, t0, t1, ft)
}

/// Polar angles `(theta, phi)` of sample `(s, t)` at resolution `r`.
pub fn sample_angles(r: usize, s: usize, t: usize) -> (f64, f64) {
    (PI * (s as f64 + 0.5) / r as f64, 2.0 * PI * t as f64 / r as f64)
}

/// Polar angles of a (non-zero) vector.
pub fn angles_of(d: DVec3) -> (f64, f64) {
    let len = d.length();
    if !(len > 0.0) {
        return (0.0, 0.0);
    }
    let theta = (d.z / len).clamp(-1.0, 1.0).acos();
    let phi = d.y.atan2(d.x).rem_euclid(2.0 * PI);
    (theta, phi)
}

/// Eq. 1: `1/(4 pi) int |sum (a_g - b_g) Y_g|`, by the table's quadrature.
pub fn eq1_error(a: &[f64; NCOEF], b: &[f32; NCOEF], table: &DirTable) -> f64 {
    let mut diff = [0.0; NCOEF];
    for e in 0..NCOEF {
        diff[e] = a[e] - b[e] as f64;
    }
    let mut s = 0.0;
    for (_, w, y) in &table.dirs {
        let v: f64 = diff.iter().zip(y).map(|(x, y)| x * y).sum();
        s += w * v.abs();
    }
    s / (4.0 * PI)
}

// ---------------------------------------------------------------------------------------------
// Raw and quantized fields

/// Unquantized field at the initial resolution on every shell (output of [`precompute`]).
#[derive(Clone, Debug)]
pub struct RawField {
    /// Shell centre (object space).
    pub center: Vec3,
    /// Bounding-sphere radius about `center`.
    pub bound_radius: f32,
    /// Initial resolution `R` (power of two).
    pub resolution: usize,
    /// Per shell, `R * R` coefficient vectors, row `s` (theta) major.
    pub shells: Vec<Vec<[f32; NCOEF]>>,
    /// Per vertex self-occlusion diffuse transfer `V_self(w) max(n.w, 0) / pi` (object space).
    pub self_transfer: Vec<[f32; NCOEF]>,
    /// Seconds spent in the ray casting.
    pub seconds: f64,
    /// Directions tested (an upper bound of the rays cast: outside the bounding sphere only the
    /// directions inside its cone are cast).
    pub rays: u64,
}

/// One quantized shell.
#[derive(Clone, Debug, PartialEq)]
pub struct Shell {
    /// Polar resolution `R_c` (`R_c x R_c` samples).
    pub resolution: u32,
    /// Per coefficient minimum.
    pub min: [f32; NCOEF],
    /// Per coefficient quantization step (`(max - min) / 255`).
    pub step: [f32; NCOEF],
    /// `R_c * R_c * 16` bytes, sample-major.
    pub data: Vec<u8>,
    /// Largest eq. 1 error of the re-interpolated samples against the initial ones (0 if not
    /// reduced).
    pub adapt_error: f32,
}

/// A quantized object occlusion field with self-transfer: what is stored in one file per object.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectField {
    /// Shell centre (object space).
    pub center: Vec3,
    /// Bounding-sphere radius `Vr`.
    pub bound_radius: f32,
    /// The shells, innermost first.
    pub shells: Vec<Shell>,
    /// Per vertex self-transfer (object space, not quantized).
    pub self_transfer: Vec<[f32; NCOEF]>,
}

fn quantize(grid: &[[f32; NCOEF]], r: usize, adapt_error: f32) -> Shell {
    let mut min = [f32::INFINITY; NCOEF];
    let mut max = [f32::NEG_INFINITY; NCOEF];
    for v in grid {
        for e in 0..NCOEF {
            min[e] = min[e].min(v[e]);
            max[e] = max[e].max(v[e]);
        }
    }
    let mut step = [0.0f32; NCOEF];
    for e in 0..NCOEF {
        if !min[e].is_finite() || !max[e].is_finite() {
            min[e] = 0.0;
            max[e] = 0.0;
        }
        step[e] = (max[e] - min[e]) / 255.0;
    }
    let mut data = Vec::with_capacity(grid.len() * NCOEF);
    for v in grid {
        for e in 0..NCOEF {
            let q = if step[e] > 0.0 { ((v[e] - min[e]) / step[e]).round().clamp(0.0, 255.0) } else { 0.0 };
            data.push(q as u8);
        }
    }
    Shell { resolution: r as u32, min, step, data, adapt_error }
}

impl RawField {
    /// The original (fixed-resolution) field: every shell at `R`, quantized.
    pub fn to_fixed(&self) -> ObjectField {
        ObjectField {
            center: self.center,
            bound_radius: self.bound_radius,
            shells: self.shells.iter().map(|g| quantize(g, self.resolution, 0.0)).collect(),
            self_transfer: self.self_transfer.clone(),
        }
    }

    /// The adaptive field (section 4): per shell, halve `R` while every initial sample,
    /// re-interpolated from the coarser grid (whose samples are bilinear from the initial
    /// grid), stays within `threshold` of eq. 1. The error is always measured against the
    /// initial samples (not the previous level), so it does not accumulate.
    pub fn to_adaptive(&self, threshold: f64, min_resolution: usize) -> ObjectField {
        self.adapt(threshold, min_resolution, false)
    }

    /// The adaptive source radiance field: as [`RawField::to_adaptive`] with the threshold
    /// relative to each shell's peak radiance (the largest value over the shell's samples and
    /// directions of the radiance they reconstruct), since radiance has units and falls off as
    /// `1/r^2` across shells: the peak plays the part of visibility's 1 in an OOF's threshold
    /// (relative to the mean, `c_0 Y_0`, a small light's field, whose order-4 lobe peaks about
    /// 16 times above its mean, would need 16 times an OOF's accuracy and keep every sample).
    /// A shell without radiance collapses to the minimum resolution.
    pub fn to_adaptive_relative(&self, threshold: f64, min_resolution: usize) -> ObjectField {
        self.adapt(threshold, min_resolution, true)
    }

    fn adapt(&self, threshold: f64, min_resolution: usize, relative: bool) -> ObjectField {
        let table = DirTable::new(12);
        let r0 = self.resolution;
        let shells = self
            .shells
            .par_iter()
            .map(|g| {
                let scale = if relative {
                    g.iter()
                        .map(|v| {
                            table.dirs.iter().fold(0.0f64, |m, (_, _, y)| {
                                m.max(v.iter().zip(y).map(|(a, b)| *a as f64 * b).sum::<f64>().abs())
                            })
                        })
                        .fold(0.0, f64::max)
                } else {
                    1.0
                };
                // tiny absolute floor: a zero shell adapts all the way down
                let (r, grid, err) =
                    adapt_shell(g, r0, threshold * scale + if relative { 1e-30 } else { 0.0 }, min_resolution, &table);
                quantize(&grid, r, (err / scale.max(1e-30)) as f32)
            })
            .collect();
        ObjectField {
            center: self.center,
            bound_radius: self.bound_radius,
            shells,
            self_transfer: self.self_transfer.clone(),
        }
    }
}

/// Adapts one shell: returns `(R_c, grid, largest error of the accepted level)`.
pub fn adapt_shell(
    g: &[[f32; NCOEF]],
    r0: usize,
    threshold: f64,
    min_resolution: usize,
    table: &DirTable,
) -> (usize, Vec<[f32; NCOEF]>, f64) {
    let mut r = r0;
    let mut grid = g.to_vec();
    let mut err_acc = 0.0;
    while r / 2 >= min_resolution.max(1) && r >= 2 {
        let r2 = r / 2;
        let mut coarse = Vec::with_capacity(r2 * r2);
        for s in 0..r2 {
            for t in 0..r2 {
                let (th, ph) = sample_angles(r2, s, t);
                let v = sample_grid(g, r0, th, ph);
                coarse.push(v.map(|x| x as f32));
            }
        }
        let mut worst = 0.0f64;
        'outer: for s in 0..r0 {
            for t in 0..r0 {
                let (th, ph) = sample_angles(r0, s, t);
                let rec = sample_grid(&coarse, r2, th, ph);
                worst = worst.max(eq1_error(&rec, &g[s * r0 + t], table));
                if worst >= threshold {
                    break 'outer;
                }
            }
        }
        if worst >= threshold {
            break;
        }
        r = r2;
        grid = coarse;
        err_acc = worst;
    }
    (r, grid, err_acc)
}

/// Bounding-box centre and bounding-sphere radius about it.
pub fn bounds(positions: &[Vec3]) -> (Vec3, f32) {
    if positions.is_empty() {
        return (Vec3::ZERO, 0.0);
    }
    let (lo, hi) = positions
        .iter()
        .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(l, h), p| (l.min(*p), h.max(*p)));
    let c = (lo + hi) * 0.5;
    let r = positions.iter().map(|p| (*p - c).length()).fold(0.0f32, f32::max);
    (c, r)
}

/// Computes the object occlusion field at the initial resolution on every shell, and the
/// per-vertex self-transfer. `progress(n)` is called with finished-sample
/// increments (shell samples, then vertices; total `shells * R^2 + vertex count`), from any thread.
pub fn precompute(
    positions: &[Vec3],
    normals: &[Vec3],
    indices: &[u32],
    params: &Params,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<RawField, String> {
    if positions.is_empty() || indices.len() < 3 {
        return Err("shadow field: empty mesh".into());
    }
    if params.shells == 0 || params.shells > 1024 {
        return Err(format!("shadow field: shell count {} out of 1..=1024", params.shells));
    }
    if params.resolution == 0 || params.resolution > 1024 || params.map_res == 0 || params.map_res > 1024 {
        return Err("shadow field: resolution and map resolution must be in 1..=1024".into());
    }
    if positions.iter().any(|p| !p.is_finite()) {
        return Err("shadow field: non-finite vertex position".into());
    }
    let start = std::time::Instant::now();
    let r = params.resolution.next_power_of_two();
    let (center, vr) = bounds(positions);
    if !(vr > 0.0) {
        return Err("shadow field: degenerate mesh (zero bounding radius)".into());
    }
    let caster = RayCaster::new(positions, indices);
    let table = DirTable::new(params.map_res);
    let c = center.as_dvec3();
    let eps = 1e-4 * vr as f64;
    let far = 1e3 * vr as f64;
    let ndir = table.dirs.len() as u64;
    let mut full = [0.0f64; NCOEF];
    for (_, w, y) in &table.dirs {
        for e in 0..NCOEF {
            full[e] += w * y[e];
        }
    }
    let shells: Vec<Vec<[f32; NCOEF]>> = (0..params.shells)
        .map(|sh| {
            let radius = 0.2 * vr as f64 * (1.0 + sh as f64);
            (0..r * r)
                .into_par_iter()
                .map(|i| {
                    let (th, ph) = sample_angles(r, i / r, i % r);
                    let p = c + radius * polar_dir(th, ph);
                    // Start unoccluded and subtract the blocked directions; outside the
                    // bounding sphere only directions inside its cone can be blocked.
                    let mut o = full;
                    let to_c = c - p;
                    let dist = to_c.length();
                    let cone = if dist > 1.0001 * vr as f64 {
                        (1.0 - (vr as f64 / dist).powi(2)).max(0.0).sqrt() - 1e-3
                    } else {
                        -2.0
                    };
                    let axis = if dist > 0.0 { to_c / dist } else { DVec3::Z };
                    for (d, w, y) in &table.dirs {
                        if d.dot(axis) >= cone && caster.occluded(p + *d * eps, *d, far) {
                            for e in 0..NCOEF {
                                o[e] -= w * y[e];
                            }
                        }
                    }
                    progress(1);
                    o.map(|x| x as f32)
                })
                .collect()
        })
        .collect();
    let self_transfer: Vec<[f32; NCOEF]> = positions
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let n = normals.get(i).copied().unwrap_or(Vec3::ZERO).as_dvec3();
            let n = if n.length_squared() > 0.0 { n.normalize() } else { DVec3::Z };
            let p = p.as_dvec3() + n * (10.0 * eps);
            let mut o = [0.0f64; NCOEF];
            for (d, w, y) in &table.dirs {
                let cs = n.dot(*d);
                if cs > 0.0 && !caster.occluded(p, *d, far) {
                    for e in 0..NCOEF {
                        o[e] += w * cs / PI * y[e];
                    }
                }
            }
            progress(1);
            o.map(|x| x as f32)
        })
        .collect();
    // upper bound (directions outside the bounding cone are not cast)
    let rays = (params.shells as u64 * (r * r) as u64 + positions.len() as u64) * ndir;
    Ok(RawField {
        center,
        bound_radius: vr,
        resolution: r,
        shells,
        self_transfer,
        seconds: start.elapsed().as_secs_f64(),
        rays,
    })
}

// ---------------------------------------------------------------------------------------------
// Evaluation

impl ObjectField {
    /// Shell radius step `0.2 Vr` (the radius of shell `c` is `(c + 1)` times this).
    pub fn shell_step(&self) -> f64 {
        0.2 * self.bound_radius as f64
    }

    /// Dequantized coefficient vector of sample `idx` of shell `c`.
    pub fn sample(&self, c: usize, idx: usize) -> [f64; NCOEF] {
        let sh = &self.shells[c];
        std::array::from_fn(|e| sh.min[e] as f64 + sh.data[idx * NCOEF + e] as f64 * sh.step[e] as f64)
    }

    /// Dequantized whole shell grid.
    pub fn shell_grid(&self, c: usize) -> Vec<[f32; NCOEF]> {
        let r = self.shells[c].resolution as usize;
        (0..r * r).map(|i| self.sample(c, i).map(|x| x as f32)).collect()
    }

    fn shell_lookup(&self, c: usize, theta: f64, phi: f64) -> [f64; NCOEF] {
        let r = self.shells[c].resolution as usize;
        let (s0, s1, fs, t0, t1, ft) = grid_weights(r, theta, phi);
        let mut out = [0.0; NCOEF];
        for (idx, w) in [
            (s0 * r + t0, (1.0 - fs) * (1.0 - ft)),
            (s0 * r + t1, (1.0 - fs) * ft),
            (s1 * r + t0, fs * (1.0 - ft)),
            (s1 * r + t1, fs * ft),
        ] {
            let v = self.sample(c, idx);
            for e in 0..NCOEF {
                out[e] += w * v[e];
            }
        }
        out
    }

    /// Visibility coefficients (object frame) at object-space point `p`, or `None` outside the
    /// outermost shell (the object is ignored there) or for an empty field.
    pub fn ocv(&self, p: DVec3) -> Option<[f64; NCOEF]> {
        let nc = self.shells.len();
        if nc == 0 || !(self.bound_radius > 0.0) {
            return None;
        }
        let q = p - self.center.as_dvec3();
        let x = q.length() / self.shell_step() - 1.0;
        if !x.is_finite() || x > (nc - 1) as f64 {
            return None;
        }
        let (theta, phi) = angles_of(q);
        let x = x.max(0.0);
        let c0 = (x.floor() as usize).min(nc - 1);
        let c1 = (c0 + 1).min(nc - 1);
        let w = x - c0 as f64;
        let a = self.shell_lookup(c0, theta, phi);
        if w <= 0.0 || c1 == c0 {
            return Some(a);
        }
        let b = self.shell_lookup(c1, theta, phi);
        let mut out = [0.0; NCOEF];
        for e in 0..NCOEF {
            out[e] = (1.0 - w) * a[e] + w * b[e];
        }
        Some(out)
    }

    /// Bytes of the coefficient data (`sum R_c^2 * 16`), without tables.
    pub fn data_bytes(&self) -> usize {
        self.shells.iter().map(|s| s.data.len()).sum()
    }

    /// Bytes of the file [`ObjectField::to_bytes`] writes.
    pub fn file_bytes(&self) -> usize {
        self.to_bytes().len()
    }

    /// Per-shell resolutions, innermost first.
    pub fn resolutions(&self) -> Vec<u32> {
        self.shells.iter().map(|s| s.resolution).collect()
    }

    /// Serializes the field (little endian): `"PSF1"`, shell count, vertex count, centre,
    /// `Vr`, then per shell `R`, adapt error, `min[16]`, `step[16]`, `R*R*16` bytes, then the
    /// self-transfer as f32.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend_from_slice(b"PSF1");
        b.extend_from_slice(&(self.shells.len() as u32).to_le_bytes());
        b.extend_from_slice(&(self.self_transfer.len() as u32).to_le_bytes());
        for v in self.center.to_array().iter().chain([self.bound_radius].iter()) {
            b.extend_from_slice(&v.to_le_bytes());
        }
        for s in &self.shells {
            b.extend_from_slice(&s.resolution.to_le_bytes());
            b.extend_from_slice(&s.adapt_error.to_le_bytes());
            for v in s.min.iter().chain(s.step.iter()) {
                b.extend_from_slice(&v.to_le_bytes());
            }
            b.extend_from_slice(&s.data);
        }
        for t in &self.self_transfer {
            for v in t {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        b
    }

    /// Parses [`ObjectField::to_bytes`]; errors (never panics) on truncated or corrupt input.
    pub fn from_bytes(b: &[u8]) -> Result<Self, String> {
        let mut rd = ByteReader::new(b, "shadow field file");
        if rd.take(4)? != b"PSF1" {
            return Err("shadow field file: bad magic (expected PSF1)".into());
        }
        let nshell = rd.shell_count()?;
        let nvert = rd.u32()? as usize;
        let hdr = rd.centre_radius()?;
        let mut shells = Vec::with_capacity(nshell);
        for _ in 0..nshell {
            let r = rd.shell_resolution()? as u32;
            let adapt_error = rd.f32()?;
            let mut min = [0f32; NCOEF];
            let mut step = [0f32; NCOEF];
            for v in min.iter_mut().chain(step.iter_mut()) {
                *v = rd.f32()?;
            }
            if !min.iter().chain(step.iter()).all(|x| x.is_finite()) {
                return Err("shadow field file: non-finite quantization table".into());
            }
            let data = rd.take(r as usize * r as usize * NCOEF)?.to_vec();
            shells.push(Shell { resolution: r, min, step, data, adapt_error });
        }
        if nvert.checked_mul(NCOEF * 4).is_none_or(|n| n > b.len()) {
            return Err("shadow field file: truncated self-transfer".into());
        }
        let mut self_transfer = Vec::with_capacity(nvert);
        for _ in 0..nvert {
            let mut t = [0f32; NCOEF];
            for v in &mut t {
                *v = rd.f32()?;
            }
            self_transfer.push(t);
        }
        if !rd.done() {
            return Err("shadow field file: trailing bytes".into());
        }
        Ok(ObjectField { center: Vec3::new(hdr[0], hdr[1], hdr[2]), bound_radius: hdr[3], shells, self_transfer })
    }
}

/// Block-diagonal order-4 SH rotation matrix of `r` (bands 0..3, row-major blocks, 84 floats):
/// `rotated[l^2 + k] = sum_j M_l[k][j] c[l^2 + j]` is the coefficient vector of `f(R^T w)`.
pub fn rotation_blocks(r: DMat3) -> [f64; ROT_FLOATS] {
    let rot = ShRotation::new(ORDER, r);
    let mut out = [0.0; ROT_FLOATS];
    let mut off = 0;
    for l in 0..ORDER {
        let s = l * l;
        let bw = 2 * l + 1;
        for j in 0..bw {
            let mut e = vec![0.0; sh_count(ORDER)];
            e[s + j] = 1.0;
            let col = rot.apply(&e);
            for k in 0..bw {
                out[off + k * bw + j] = col[s + k];
            }
        }
        off += bw * bw;
    }
    out
}

/// Applies [`rotation_blocks`] to a coefficient vector.
pub fn rotate(blocks: &[f64; ROT_FLOATS], c: &[f64; NCOEF]) -> [f64; NCOEF] {
    let mut out = [0.0; NCOEF];
    let mut off = 0;
    for l in 0..ORDER {
        let s = l * l;
        let bw = 2 * l + 1;
        for k in 0..bw {
            out[s + k] = (0..bw).map(|j| blocks[off + k * bw + j] * c[s + j]).sum();
        }
        off += bw * bw;
    }
    out
}

/// Sparse triple product with a tensor of order 4: `h_k = sum C_ijk f_i g_j`.
pub fn triple(t: &TripleProductTensor, f: &[f64; NCOEF], g: &[f64; NCOEF]) -> [f64; NCOEF] {
    let mut h = [0.0; NCOEF];
    for &(i, j, k, c) in &t.entries {
        h[k as usize] += c * f[i as usize] * g[j as usize];
    }
    h
}

/// Order-4 SH of the clamped cosine lobe about unit `n`, divided by pi (the diffuse transfer
/// without self-occlusion): zonal coefficients `A_l / pi` rotated to `n`.
pub fn cosine_transfer(n: DVec3) -> [f64; NCOEF] {
    // c_lm = A_l Y_lm(n) with A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4, A_3 = 0 (then / pi)
    let a = [1.0, 2.0 / 3.0, 0.25, 0.0];
    let mut y = [0.0; NCOEF];
    let n = if n.length_squared() > 0.0 { n.normalize() } else { DVec3::Z };
    eval_basis_into(ORDER, n, &mut y);
    let mut out = [0.0; NCOEF];
    for l in 0..ORDER {
        let k = a[l];
        for m in 0..2 * l + 1 {
            out[l * l + m] = k * y[l * l + m];
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Per-point shading (the CPU rendering path)

/// One instance of a frame as seen by the shading: its field (if it casts shadows), the
/// world-to-object transform and the object-to-world SH rotation.
#[derive(Clone, Copy, Debug)]
pub struct InstanceFrame<'a> {
    /// The object's field; `None` = casts no shadow.
    pub field: Option<&'a ObjectField>,
    /// World to object space (inverse of the instance's world matrix).
    pub world_to_local: glam::DMat4,
    /// [`rotation_blocks`] of the instance's rotation (object to world).
    pub rot: [f64; ROT_FLOATS],
    /// World position of the field's shell centre (the entity sort key of [`shade_point`]).
    pub center_world: DVec3,
    /// Added to the distance that sorts this occluder among the entities of [`shade_point`]:
    /// a light's fixture sorts at its light's position plus [`FIXTURE_SORT_BIAS`], just after
    /// its light, whose source radiance field holds the fixture's occlusion already (0 for
    /// every other object).
    pub sort_bias: f64,
}

/// [`InstanceFrame::sort_bias`] of a light's fixture (scene units).
pub const FIXTURE_SORT_BIAS: f64 = 1e-4;

impl<'a> InstanceFrame<'a> {
    /// From an instance world matrix (rigid, optionally uniformly scaled).
    pub fn new(field: Option<&'a ObjectField>, world: glam::DMat4) -> Self {
        let (_, q, _) = world.to_scale_rotation_translation();
        let q = if q.is_finite() { q.normalize() } else { glam::DQuat::IDENTITY };
        let inv = world.inverse();
        let world_to_local = if inv.is_finite() { inv } else { glam::DMat4::IDENTITY };
        let c = field.map_or(glam::Vec3::ZERO, |f| f.center).as_dvec3();
        InstanceFrame {
            field,
            world_to_local,
            rot: rotation_blocks(DMat3::from_quat(q)),
            center_world: world.transform_point3(c),
            sort_bias: 0.0,
        }
    }
}

/// A point to shade: world position, receiver instance, albedo, object-space transfer.
#[derive(Clone, Copy, Debug)]
pub struct ShadePoint {
    /// World position.
    pub pos: DVec3,
    /// Index of the receiving instance (excluded from the occluders).
    pub inst: usize,
    /// Diffuse albedo.
    pub albedo: DVec3,
    /// Transfer (self-occluded clamped cosine / pi) in the instance's object space.
    pub transfer: [f64; NCOEF],
}

/// Occluded transfer in world space: `T (x) O_1 (x) O_2 ...` over the other instances whose
/// shells contain the point; returns it and the number of occluders applied.
pub fn occluded_transfer(
    p: &ShadePoint,
    insts: &[InstanceFrame],
    tensor: &TripleProductTensor,
) -> ([f64; NCOEF], usize) {
    let Some(me) = insts.get(p.inst) else {
        return (p.transfer, 0);
    };
    let mut u = rotate(&me.rot, &p.transfer);
    let mut applied = 0;
    for (j, inst) in insts.iter().enumerate() {
        if j == p.inst {
            continue;
        }
        let Some(field) = inst.field else { continue };
        let local = inst.world_to_local.transform_point3(p.pos);
        let Some(o) = field.ocv(local) else { continue };
        let o = rotate(&inst.rot, &o);
        u = triple(tensor, &o, &u);
        applied += 1;
    }
    (u, applied)
}

/// Radiance of each point (`albedo * int L U`, clamped at 0) and the unclamped minimum channel,
/// in parallel, without local lights (see [`shade_points_with`]). `light[e]` is the rgb SH coefficient `e` of the environment radiance.
pub fn shade_points(
    points: &[ShadePoint],
    insts: &[InstanceFrame],
    light: &[[f64; 3]; NCOEF],
    tensor: &TripleProductTensor,
) -> Vec<(DVec3, f64)> {
    shade_points_with(points, insts, &[], light, tensor, &ShadeOptions::default())
}

// ---------------------------------------------------------------------------------------------
// Source radiance fields (local lights)

/// A local light as its source radiance field describes it, for unit power, in the light's
/// frame: the light at the origin, a spot pointing along `+z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightSource {
    /// Radiant intensity 1 in every direction.
    Point,
    /// Intensity `smoothstep(cos_outer, cos_inner, s.z)` in direction `s` from the light (a
    /// hard cut-off at `cos_outer` when `cos_inner <= cos_outer`), as the reference renderer.
    Spot {
        /// Cosine of the full-intensity half-angle.
        cos_inner: f64,
        /// Cosine of the cut-off half-angle.
        cos_outer: f64,
    },
    /// A sphere of `radius` emitting radiance 1.
    Sphere {
        /// Sphere radius.
        radius: f64,
    },
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    if e1 <= e0 {
        return if x >= e0 { 1.0 } else { 0.0 };
    }
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// `int_t^1 P_l(x) dx` for `l = 0..3` (zonal SH of a cap of half-angle `acos t`, up to
/// `2 pi`).
fn cap_legendre(t: f64) -> [f64; 4] {
    [1.0 - t, (1.0 - t * t) / 2.0, (t - t * t * t) / 2.0, (-0.25 - 1.25 * t.powi(4) + 1.5 * t * t) / 2.0]
}

impl LightSource {
    /// Order-4 SH of the radiance arriving at light-frame point `p` from the light (unit
    /// power), as a function of the incident direction (pointing towards the light): a point
    /// or spot light is the projection of `delta(w - w_l) / r^2`, `Y(w_l) / r^2`; a sphere light
    /// the projection of its radiance over the cap it subtends. Zero at the light and inside a
    /// sphere light (as the reference: no light there).
    pub fn rcv(&self, p: DVec3) -> [f64; NCOEF] {
        let r2 = p.length_squared();
        let mut out = [0.0; NCOEF];
        if !(r2 > 0.0) || !r2.is_finite() {
            return out;
        }
        let r = r2.sqrt();
        let s = p / r; // from the light to p
        let mut y = [0.0; NCOEF];
        eval_basis_into(ORDER, -s, &mut y);
        match *self {
            LightSource::Point | LightSource::Spot { .. } => {
                let f = match *self {
                    LightSource::Spot { cos_inner, cos_outer } => smoothstep(cos_outer, cos_inner, s.z),
                    _ => 1.0,
                };
                for e in 0..NCOEF {
                    out[e] = f / r2 * y[e];
                }
            }
            LightSource::Sphere { radius } => {
                if !(r > radius) {
                    return out;
                }
                let t = (1.0 - (radius / r).powi(2)).max(0.0).sqrt();
                let ip = cap_legendre(t);
                for l in 0..ORDER {
                    for m in 0..2 * l + 1 {
                        out[l * l + m] = 2.0 * PI * ip[l] * y[l * l + m];
                    }
                }
            }
        }
        out
    }
}

/// Directions per sphere light's cap sampled by [`LightSource::rcv_through`] (8 rings of 16).
pub const CAP_SAMPLES: usize = 128;

impl LightSource {
    /// [`LightSource::rcv`] through the light's fixture (a shade or housing, in the light frame):
    /// a point or spot light's radiance is zero where the fixture lies between `p` and the
    /// light; a sphere light's cap loses the projection of its occluded part, from
    /// [`CAP_SAMPLES`] stratified directions uniform in solid angle over the cap (the closed
    /// form stays exact where nothing is occluded). `None` is [`LightSource::rcv`].
    pub fn rcv_through(&self, p: DVec3, fixture: Option<&RayCaster>) -> [f64; NCOEF] {
        let mut out = self.rcv(p);
        let Some(caster) = fixture else { return out };
        let r = p.length();
        if !(r > 0.0) || !r.is_finite() || out.iter().all(|&x| x == 0.0) {
            return out;
        }
        let toward = -p / r;
        match *self {
            LightSource::Point | LightSource::Spot { .. } => {
                if caster.occluded(p, toward, r * (1.0 - 1e-9)) {
                    out = [0.0; NCOEF];
                }
            }
            LightSource::Sphere { radius } => {
                let t = (1.0 - (radius / r).powi(2)).max(0.0).sqrt();
                let (b1, b2) = orthonormal_pair(toward);
                let (rings, per) = (8, CAP_SAMPLES / 8);
                let w = 2.0 * PI * (1.0 - t) / CAP_SAMPLES as f64;
                let mut y = [0.0; NCOEF];
                for a in 0..rings {
                    for b in 0..per {
                        // stratified: cos theta uniform in [t, 1], phi uniform, cell centres
                        let u = (a as f64 + 0.5) / rings as f64;
                        let ct = 1.0 - u * (1.0 - t);
                        let st = (1.0 - ct * ct).max(0.0).sqrt();
                        let ph = 2.0 * PI * (b as f64 + 0.5 + 0.25 * (a % 2) as f64) / per as f64;
                        let d = toward * ct + (b1 * ph.cos() + b2 * ph.sin()) * st;
                        // distance to the sphere's near surface along d
                        let disc = radius * radius - r * r * st * st;
                        let thit = r * ct - disc.max(0.0).sqrt();
                        if caster.occluded(p, d, thit.max(0.0)) {
                            eval_basis_into(ORDER, d, &mut y);
                            for e in 0..NCOEF {
                                out[e] -= w * y[e];
                            }
                        }
                    }
                }
            }
        }
        out
    }
}

/// Two unit vectors completing `n` (unit) to an orthonormal basis.
fn orthonormal_pair(n: DVec3) -> (DVec3, DVec3) {
    let a = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let b1 = n.cross(a).normalize();
    (b1, n.cross(b1))
}

/// Computes the source radiance field of `src` (unit power) on `params.shells` shells around
/// the light whose outermost radius is `reach` (shell `c` at `reach (c + 1) / C`, i.e. the
/// object convention `0.2 Vr (1 + c)` with `Vr = reach / (0.2 C)`), `R x R` samples each. No
/// self-transfer. `progress(n)` as for [`precompute`].
pub fn precompute_srf(
    src: LightSource,
    reach: f64,
    params: &Params,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<RawField, String> {
    precompute_srf_through(src, None, reach, params, progress)
}

/// [`precompute_srf`] of a real emitter: the light seen through its `fixture` (a shade or
/// housing as triangles in the light frame; [`LightSource::rcv_through`]), the paper's source
/// radiance field of a light with its fixture. `rays` counts the fixture's shadow rays.
pub fn precompute_srf_through(
    src: LightSource,
    fixture: Option<&RayCaster>,
    reach: f64,
    params: &Params,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<RawField, String> {
    if params.shells == 0 || params.shells > 1024 {
        return Err(format!("source radiance field: shell count {} out of 1..=1024", params.shells));
    }
    if params.resolution == 0 || params.resolution > 1024 {
        return Err("source radiance field: resolution must be in 1..=1024".into());
    }
    if !(reach > 0.0) || !reach.is_finite() {
        return Err(format!("source radiance field: reach {reach} must be finite and > 0"));
    }
    let start = std::time::Instant::now();
    let r = params.resolution.next_power_of_two();
    let vr = reach / (0.2 * params.shells as f64);
    let shells = (0..params.shells)
        .map(|sh| {
            let radius = 0.2 * vr * (1.0 + sh as f64);
            let g: Vec<[f32; NCOEF]> = (0..r * r)
                .into_par_iter()
                .map(|i| {
                    let (th, ph) = sample_angles(r, i / r, i % r);
                    src.rcv_through(radius * polar_dir(th, ph), fixture).map(|x| x as f32)
                })
                .collect();
            progress((r * r) as u64);
            g
        })
        .collect();
    Ok(RawField {
        center: Vec3::ZERO,
        bound_radius: vr as f32,
        resolution: r,
        shells,
        self_transfer: Vec::new(),
        seconds: start.elapsed().as_secs_f64(),
        rays: match (fixture, src) {
            (None, _) => 0,
            (Some(_), LightSource::Sphere { .. }) => (params.shells * r * r * CAP_SAMPLES) as u64,
            (Some(_), _) => (params.shells * r * r) as u64,
        },
    })
}

impl ObjectField {
    /// Radiance coefficients (light frame) of a source radiance field at light-frame point
    /// `p`, or `None` outside the outermost shell (the caller evaluates the light analytically
    /// there). Between shells the interpolation is linear in `r^2 RCV` (exact for the `1/r^2`
    /// falloff of a point light, where plain linear interpolation errs by up to 40% between the
    /// two innermost shells); inside the innermost shell the innermost shell is scaled by
    /// `r_0^2 / r^2`.
    pub fn rcv(&self, p: DVec3) -> Option<[f64; NCOEF]> {
        self.rcv_beyond(p, false)
    }

    /// [`ObjectField::rcv`], and with `extrapolate` beyond the outermost shell too: the
    /// outermost shell scaled by `r_N^2 / r^2` (exact for a point or spot light seen through a
    /// fixture inside the shells, whose shadow is a cone from the light).
    pub fn rcv_beyond(&self, p: DVec3, extrapolate: bool) -> Option<[f64; NCOEF]> {
        let nc = self.shells.len();
        if nc == 0 || !(self.bound_radius > 0.0) {
            return None;
        }
        let q = p - self.center.as_dvec3();
        let len = q.length();
        let step = self.shell_step();
        let x = len / step - 1.0;
        if !x.is_finite() || x > (nc - 1) as f64 && !extrapolate {
            return None;
        }
        if !(len > 0.0) {
            return Some([0.0; NCOEF]);
        }
        let (theta, phi) = angles_of(q);
        let xc = x.clamp(0.0, (nc - 1) as f64);
        let c0 = (xc.floor() as usize).min(nc - 1);
        let c1 = (c0 + 1).min(nc - 1);
        let w = if c1 == c0 { 0.0 } else { xc - c0 as f64 };
        let r0 = step * (c0 as f64 + 1.0);
        let r1 = step * (c1 as f64 + 1.0);
        let a = self.shell_lookup(c0, theta, phi);
        let b = if w > 0.0 { self.shell_lookup(c1, theta, phi) } else { [0.0; NCOEF] };
        let inv = 1.0 / (len * len);
        let mut out = [0.0; NCOEF];
        for e in 0..NCOEF {
            out[e] = ((1.0 - w) * r0 * r0 * a[e] + w * r1 * r1 * b[e]) * inv;
        }
        Some(out)
    }
}

// ---------------------------------------------------------------------------------------------
// Windowing of the occluders' visibility (ringing of order-4 products)

/// Per-band window applied to every occluder's visibility vector before the triple products
/// (Sloan, "Stupid spherical harmonics tricks"), with window width = the SH order (4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Window {
    /// No windowing (the paper).
    #[default]
    None,
    /// `(1 + cos(pi l / 4)) / 2`: 1, 0.854, 0.5, 0.146.
    Hanning,
    /// `sinc(pi l / 4)`: 1, 0.900, 0.637, 0.300.
    Lanczos,
}

impl Window {
    /// Band factors `sigma_l`, `l = 0..3`.
    pub fn sigma(self) -> [f64; ORDER] {
        let mut s = [1.0; ORDER];
        for (l, v) in s.iter_mut().enumerate().skip(1) {
            let x = PI * l as f64 / ORDER as f64;
            *v = match self {
                Window::None => 1.0,
                Window::Hanning => 0.5 * (1.0 + x.cos()),
                Window::Lanczos => x.sin() / x,
            };
        }
        s
    }

    /// Applies the window to a coefficient vector.
    pub fn apply(self, c: &mut [f64; NCOEF]) {
        if self == Window::None {
            return;
        }
        let s = self.sigma();
        for l in 1..ORDER {
            for m in 0..2 * l + 1 {
                c[l * l + m] *= s[l];
            }
        }
    }

    /// Parses `none`, `hanning`, `lanczos`.
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim() {
            "none" => Some(Window::None),
            "hanning" | "hann" => Some(Window::Hanning),
            "lanczos" => Some(Window::Lanczos),
            _ => None,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Per-point shading with local lights (Fig. 3)

/// The rotation of a light's frame (light to world): `+z` turned to `direction` by the
/// shortest arc (`+z` itself for a zero or non-finite direction).
pub fn light_rotation(direction: DVec3) -> glam::DQuat {
    let dir = if direction.is_finite() && direction.length_squared() > 0.0 { direction.normalize() } else { DVec3::Z };
    glam::DQuat::from_rotation_arc(DVec3::Z, dir)
}

/// One local light of a frame: its source radiance field (or `None`: the analytic radiance
/// everywhere), its frame and its rgb power.
#[derive(Clone, Copy, Debug)]
pub struct LightFrame<'a> {
    /// The light's source radiance field (`None`: analytic radiance everywhere).
    pub field: Option<&'a ObjectField>,
    /// What the light is.
    pub source: LightSource,
    /// World to light frame.
    pub world_to_local: glam::DMat4,
    /// [`rotation_blocks`] of the light frame's rotation (light to world).
    pub rot: [f64; ROT_FLOATS],
    /// World position.
    pub position: DVec3,
    /// rgb power (colour times intensity).
    pub power: DVec3,
    /// Beyond the field's outermost shell: the outermost shell extrapolated
    /// ([`ObjectField::rcv_beyond`]; a light with a fixture) rather than the analytic radiance.
    pub extrapolate: bool,
}

impl<'a> LightFrame<'a> {
    /// A light whose frame (light to world, rigid) is `world`: a light with a fixture, whose
    /// frame moves with the fixture's motion ([`LightFrame::new`] would turn it by the shortest
    /// arc to its direction, which does not follow a spin about the direction). Its field, if
    /// any, is extrapolated beyond the outermost shell.
    pub fn with_world(field: Option<&'a ObjectField>, source: LightSource, world: glam::DMat4, power: DVec3) -> Self {
        let (_, q, t) = world.to_scale_rotation_translation();
        let q = if q.is_finite() { q.normalize() } else { glam::DQuat::IDENTITY };
        Self::from_rotation(field, source, q, t, power, true)
    }

    /// A light at `position`; a spot's `+z` is turned to `direction`.
    pub fn new(
        field: Option<&'a ObjectField>,
        source: LightSource,
        position: DVec3,
        direction: DVec3,
        power: DVec3,
    ) -> Self {
        Self::from_rotation(field, source, light_rotation(direction), position, power, false)
    }

    fn from_rotation(
        field: Option<&'a ObjectField>,
        source: LightSource,
        q: glam::DQuat,
        position: DVec3,
        power: DVec3,
        extrapolate: bool,
    ) -> Self {
        let world = glam::DMat4::from_rotation_translation(q, position);
        LightFrame {
            field,
            source,
            world_to_local: world.inverse(),
            rot: rotation_blocks(DMat3::from_quat(q)),
            position,
            power,
            extrapolate,
        }
    }

    /// World-frame radiance coefficients (unit power) at world point `p`: the SRF inside its
    /// outermost shell, the analytic radiance outside.
    pub fn rcv_world(&self, p: DVec3) -> [f64; NCOEF] {
        let local = self.world_to_local.transform_point3(p);
        let c =
            self.field.and_then(|f| f.rcv_beyond(local, self.extrapolate)).unwrap_or_else(|| self.source.rcv(local));
        rotate(&self.rot, &c)
    }
}

/// Options of [`shade_points_with`].
#[derive(Clone, Copy, Debug, Default)]
pub struct ShadeOptions {
    /// Window of the occluders' visibility.
    pub window: Window,
}

/// Radiance of one point (before the albedo) by Fig. 3 of the paper: the entities (other
/// objects whose shells contain the point, and lights) sorted by the distance from the point
/// to their centres; the transfer `U` (self-transfer rotated to world) is multiplied by each
/// occluder's visibility in turn (triple product), and each light adds its power times the
/// double product of its radiance with the current `U` (so only occluders nearer than the
/// light shadow it); the environment adds the double product with the final `U`. At most
/// [`MAX_ENTITIES`] nearest entities are used.
pub fn shade_point(
    p: &ShadePoint,
    insts: &[InstanceFrame],
    lights: &[LightFrame],
    env: &[[f64; 3]; NCOEF],
    tensor: &TripleProductTensor,
    opts: &ShadeOptions,
) -> DVec3 {
    let mut u = match insts.get(p.inst) {
        Some(me) => rotate(&me.rot, &p.transfer),
        None => p.transfer,
    };
    // (distance, occluder index | light index + insts.len(), local coefficients)
    let mut ents: Vec<(f64, usize, [f64; NCOEF])> = Vec::new();
    for (j, inst) in insts.iter().enumerate() {
        if j == p.inst {
            continue;
        }
        let Some(field) = inst.field else { continue };
        let local = inst.world_to_local.transform_point3(p.pos);
        let Some(o) = field.ocv(local) else { continue };
        ents.push(((p.pos - inst.center_world).length() + inst.sort_bias, j, o));
    }
    for (i, l) in lights.iter().enumerate() {
        ents.push(((p.pos - l.position).length(), insts.len() + i, [0.0; NCOEF]));
    }
    ents.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    ents.truncate(MAX_ENTITIES);
    let mut c = DVec3::ZERO;
    for (_, idx, o) in &ents {
        if *idx < insts.len() {
            let mut o = rotate(&insts[*idx].rot, o);
            opts.window.apply(&mut o);
            u = triple(tensor, &o, &u);
        } else {
            let l = &lights[*idx - insts.len()];
            let s = l.rcv_world(p.pos);
            let d: f64 = s.iter().zip(&u).map(|(a, b)| a * b).sum();
            c += l.power * d;
        }
    }
    for e in 0..NCOEF {
        c += DVec3::from_array(env[e]) * u[e];
    }
    c
}

/// [`shade_point`] for every point in parallel, times the albedo: the radiance clamped at 0
/// and the unclamped minimum channel.
pub fn shade_points_with(
    points: &[ShadePoint],
    insts: &[InstanceFrame],
    lights: &[LightFrame],
    env: &[[f64; 3]; NCOEF],
    tensor: &TripleProductTensor,
    opts: &ShadeOptions,
) -> Vec<(DVec3, f64)> {
    points
        .par_iter()
        .map(|p| {
            let c = shade_point(p, insts, lights, env, tensor, opts) * p.albedo;
            (c.max(DVec3::ZERO), c.min_element())
        })
        .collect()
}

/// A little-endian reader over a precomputed file's bytes: every read is bounds-checked and
/// fails with "`<what>`: truncated" (the field files' parsers never panic on corrupt input).
struct ByteReader<'a> {
    b: &'a [u8],
    pos: usize,
    what: &'static str,
}

impl<'a> ByteReader<'a> {
    fn new(b: &'a [u8], what: &'static str) -> Self {
        ByteReader { b, pos: 0, what }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| format!("{}: truncated", self.what))?;
        let s = &self.b[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn u16(&mut self) -> Result<u16, String> {
        let s = self.take(2)?;
        Ok(u16::from_le_bytes([s[0], s[1]]))
    }

    fn u32(&mut self) -> Result<u32, String> {
        let s = self.take(4)?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }

    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32()?))
    }

    /// A field's shell count (at most 1024).
    fn shell_count(&mut self) -> Result<usize, String> {
        let n = self.u32()? as usize;
        if n > 1024 {
            return Err(format!("{}: {n} shells (max 1024)", self.what));
        }
        Ok(n)
    }

    /// A field's centre and bounding radius (finite, the radius not negative).
    fn centre_radius(&mut self) -> Result<[f32; 4], String> {
        let hdr = [self.f32()?, self.f32()?, self.f32()?, self.f32()?];
        if !hdr.iter().all(|x| x.is_finite()) || !(hdr[3] >= 0.0) {
            return Err(format!("{}: non-finite centre or radius", self.what));
        }
        Ok(hdr)
    }

    /// A shell's resolution (1..=4096).
    fn shell_resolution(&mut self) -> Result<usize, String> {
        let r = self.u32()? as usize;
        if r == 0 || r > 4096 {
            return Err(format!("{}: shell resolution {r} out of 1..=4096", self.what));
        }
        Ok(r)
    }

    /// Every byte read.
    fn done(&self) -> bool {
        self.pos == self.b.len()
    }
}

// ---------------------------------------------------------------------------------------------
// All-frequency variant: Haar wavelets on a cube map (CPU)

/// All-frequency occlusion fields (Zhou et al. / Ng et al. 2004 style, CPU only): per sample
/// point a binary visibility cube map (`6 x n x n`), each face transformed by the orthonormal
/// 2D (non-standard) Haar transform, the largest `keep` fraction of coefficients kept (the
/// paper: 5%) and quantized to 8 bits per shell (index `u16` + value `u8` per kept
/// coefficient). Products of fields are taken in the pixel domain, which for Haar at the map
/// resolution equals the wavelet triple product exactly (the product of two piecewise-constant
/// maps is piecewise constant on the same pixels); see [`haar::HaarField::product_map`].
pub mod haar {
    use super::{angles_of, polar_dir, sample_angles, ByteReader, RayCaster};
    use glam::{DVec3, Vec3};
    use rayon::prelude::*;

    /// Cube-map directions and solid angles (`6 n^2` pixels, faces +x -x +y -y +z -z).
    pub struct CubeTable {
        /// Face resolution (power of two).
        pub n: usize,
        /// Unit direction of each pixel centre.
        pub dirs: Vec<DVec3>,
        /// Solid angle of each pixel (sums to 4 pi).
        pub w: Vec<f64>,
    }

    impl CubeTable {
        /// The (unnormalized) point of face `f` at face coordinates `u, v` in [-1, 1]: faces
        /// +x -x +y -y +z -z, the convention of every map (and of the shaders' cube lookups).
        pub fn face_point(f: usize, u: f64, v: f64) -> DVec3 {
            match f {
                0 => DVec3::new(1.0, v, -u),
                1 => DVec3::new(-1.0, v, u),
                2 => DVec3::new(u, 1.0, -v),
                3 => DVec3::new(u, -1.0, v),
                4 => DVec3::new(u, v, 1.0),
                _ => DVec3::new(-u, v, -1.0),
            }
        }

        /// A table of face resolution `n` (rounded up to a power of two, at least 2).
        pub fn new(n: usize) -> Self {
            let n = n.max(2).next_power_of_two();
            let mut dirs = Vec::with_capacity(6 * n * n);
            let mut w = Vec::with_capacity(6 * n * n);
            for f in 0..6 {
                for i in 0..n {
                    for j in 0..n {
                        let u = 2.0 * (j as f64 + 0.5) / n as f64 - 1.0;
                        let v = 2.0 * (i as f64 + 0.5) / n as f64 - 1.0;
                        let d = Self::face_point(f, u, v);
                        let l = d.length();
                        // solid angle of the pixel ~ area / r^3 (midpoint rule)
                        w.push((2.0 / n as f64).powi(2) / (l * l * l));
                        dirs.push(d / l);
                    }
                }
            }
            let s: f64 = w.iter().sum();
            let k = 4.0 * std::f64::consts::PI / s;
            for x in &mut w {
                *x *= k;
            }
            CubeTable { n, dirs, w }
        }
    }

    /// Orthonormal non-standard 2D Haar transform of every `n x n` face of `m`, in place.
    pub fn forward(m: &mut [f32], n: usize) {
        let mut tmp = vec![0f32; n * n];
        for face in m.chunks_exact_mut(n * n) {
            let mut size = n;
            while size > 1 {
                let h = size / 2;
                for i in 0..h {
                    for j in 0..h {
                        let a = face[(2 * i) * n + 2 * j];
                        let b = face[(2 * i) * n + 2 * j + 1];
                        let c = face[(2 * i + 1) * n + 2 * j];
                        let d = face[(2 * i + 1) * n + 2 * j + 1];
                        tmp[i * n + j] = (a + b + c + d) * 0.5;
                        tmp[i * n + j + h] = (a - b + c - d) * 0.5;
                        tmp[(i + h) * n + j] = (a + b - c - d) * 0.5;
                        tmp[(i + h) * n + j + h] = (a - b - c + d) * 0.5;
                    }
                }
                for i in 0..size {
                    face[i * n..i * n + size].copy_from_slice(&tmp[i * n..i * n + size]);
                }
                size = h;
            }
        }
    }

    /// Inverse of [`forward`].
    pub fn inverse(m: &mut [f32], n: usize) {
        let mut tmp = vec![0f32; n * n];
        for face in m.chunks_exact_mut(n * n) {
            let mut size = 2;
            while size <= n {
                let h = size / 2;
                for i in 0..h {
                    for j in 0..h {
                        let s = face[i * n + j];
                        let hh = face[i * n + j + h];
                        let v = face[(i + h) * n + j];
                        let d = face[(i + h) * n + j + h];
                        tmp[(2 * i) * n + 2 * j] = (s + hh + v + d) * 0.5;
                        tmp[(2 * i) * n + 2 * j + 1] = (s - hh + v - d) * 0.5;
                        tmp[(2 * i + 1) * n + 2 * j] = (s + hh - v - d) * 0.5;
                        tmp[(2 * i + 1) * n + 2 * j + 1] = (s - hh - v + d) * 0.5;
                    }
                }
                for i in 0..size {
                    face[i * n..i * n + size].copy_from_slice(&tmp[i * n..i * n + size]);
                }
                size *= 2;
            }
        }
    }

    /// Keeps the `keep` fraction (at least the 6 face averages) of largest-magnitude
    /// coefficients: `(index, value)` sorted by index.
    pub fn truncate(c: &[f32], n: usize, keep: f64) -> Vec<(u16, f32)> {
        let count = ((c.len() as f64 * keep).ceil() as usize).clamp(6, c.len());
        // face averages first (always kept), then the largest magnitudes (a selection, not a
        // sort: this runs for every sample of every shell)
        let is_avg = |i: usize| i.is_multiple_of(n * n);
        let mut idx: Vec<usize> = (0..c.len()).filter(|&i| is_avg(i)).collect();
        // zeros are never kept (filtered below) and rank last: leaving them out of the selection
        // keeps the same set (most detail coefficients of a binary map are zero)
        let mut rest: Vec<usize> = (0..c.len()).filter(|&i| !is_avg(i) && c[i] != 0.0).collect();
        let more = count.saturating_sub(idx.len()).min(rest.len());
        if more > 0 && more < rest.len() {
            rest.select_nth_unstable_by(more - 1, |&a, &b| c[b].abs().total_cmp(&c[a].abs()).then(a.cmp(&b)));
        }
        idx.extend_from_slice(&rest[..more]);
        let mut out: Vec<(u16, f32)> = idx.iter().map(|&i| (i as u16, c[i])).filter(|(_, v)| *v != 0.0).collect();
        out.sort_by_key(|x| x.0);
        out
    }

    /// Dense map of sparse coefficients (inverse transform).
    pub fn reconstruct(sparse: &[(u16, f32)], n: usize) -> Vec<f32> {
        let mut m = vec![0f32; 6 * n * n];
        for &(i, v) in sparse {
            if let Some(x) = m.get_mut(i as usize) {
                *x = v;
            }
        }
        inverse(&mut m, n);
        m
    }

    /// `1/(4 pi) int |a - b|` of two maps (eq. 1 in the pixel domain).
    pub fn l1(a: &[f32], b: &[f32], t: &CubeTable) -> f64 {
        a.iter().zip(b).zip(&t.w).map(|((x, y), w)| w * (*x as f64 - *y as f64).abs()).sum::<f64>()
            / (4.0 * std::f64::consts::PI)
    }

    /// One quantized all-frequency shell: per sample the kept coefficients (u16 index, u8
    /// value with the shell's min/step).
    #[derive(Clone, Debug)]
    pub struct HaarShell {
        /// Polar resolution `R_c`.
        pub resolution: usize,
        /// Value quantization of the shell.
        pub min: f32,
        /// Quantization step.
        pub step: f32,
        /// Per sample `(index, quantized value)`.
        pub samples: Vec<Vec<(u16, u8)>>,
    }

    /// An all-frequency object occlusion field.
    #[derive(Clone, Debug)]
    pub struct HaarField {
        /// Cube face resolution of the maps.
        pub n: usize,
        /// Shell centre and bounding radius (as [`super::ObjectField`]).
        pub center: Vec3,
        /// Bounding-sphere radius `Vr`.
        pub bound_radius: f32,
        /// Shells, innermost first.
        pub shells: Vec<HaarShell>,
    }

    fn quantize(r: usize, samples: &[Vec<(u16, f32)>]) -> HaarShell {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for s in samples {
            for &(_, v) in s {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        if !lo.is_finite() {
            lo = 0.0;
            hi = 0.0;
        }
        let step = (hi - lo) / 255.0;
        let samples = samples
            .iter()
            .map(|s| {
                s.iter()
                    .map(|&(i, v)| (i, if step > 0.0 { ((v - lo) / step).round().clamp(0.0, 255.0) as u8 } else { 0 }))
                    .collect()
            })
            .collect();
        HaarShell { resolution: r, min: lo, step, samples }
    }

    /// Raw (dense) visibility maps of every shell sample at resolution `r` (power of two).
    pub fn raw_maps(
        positions: &[Vec3],
        indices: &[u32],
        shells: usize,
        r: usize,
        table: &CubeTable,
    ) -> (Vec3, f32, Vec<Vec<Vec<f32>>>) {
        let (center, vr) = super::bounds(positions);
        let caster = RayCaster::new(positions, indices);
        let c = center.as_dvec3();
        let eps = 1e-4 * vr as f64;
        let far = 1e3 * vr as f64;
        let maps = (0..shells)
            .map(|sh| {
                let radius = 0.2 * vr as f64 * (1.0 + sh as f64);
                (0..r * r)
                    .into_par_iter()
                    .map(|i| {
                        let (th, ph) = sample_angles(r, i / r, i % r);
                        let p = c + radius * polar_dir(th, ph);
                        // directions outside the bounding sphere's cone from p cannot hit
                        // (1e-6 of slack against rounding at its rim)
                        let to_c = c - p;
                        let dc = to_c.length();
                        let rb = vr as f64 * (1.0 + 1e-6);
                        let cone =
                            if dc > rb { Some((to_c / dc, (1.0 - (rb / dc).powi(2)).max(0.0).sqrt())) } else { None };
                        table
                            .dirs
                            .iter()
                            .map(|d| {
                                if cone.is_some_and(|(axis, cos)| d.dot(axis) < cos) {
                                    return 1.0;
                                }
                                if caster.occluded(p + *d * eps, *d, far) {
                                    0.0
                                } else {
                                    1.0
                                }
                            })
                            .collect()
                    })
                    .collect()
            })
            .collect();
        (center, vr, maps)
    }

    /// Start of the self-visibility rays past the vertex, in bounding radii.
    pub const SELF_SKIP: f64 = 0.05;

    /// Self-visibility of every vertex of a mesh as binary cube maps (object frame, one bit
    /// per pixel, pixel `k` at bit `k % 32` of the vertex's word `k / 32`, `6 n^2 / 32` words
    /// per vertex): 1 where a ray from the vertex (lifted off the surface by 1e-3 of the
    /// bounding radius along its normal and started [`SELF_SKIP`] bounding radii along the
    /// ray) escapes the mesh, 0 where it hits it or points below the vertex's tangent plane. Rigid objects keep it for good (the paper's per-vertex
    /// self-visibility).
    pub fn self_maps(positions: &[Vec3], normals: &[Vec3], indices: &[u32], table: &CubeTable) -> Vec<u32> {
        let (_, vr) = super::bounds(positions);
        let caster = RayCaster::new(positions, indices);
        let per = table.dirs.len().div_ceil(32);
        let lift = 1e-3 * vr.max(1e-12) as f64;
        let far = 1e3 * vr.max(1e-12) as f64;
        // Hits nearer than this along the ray are the vertex's own neighbourhood (a concave
        // crease between coarse triangles), which per-vertex values would smear over whole
        // triangles: skipped.
        let skip = SELF_SKIP * vr.max(1e-12) as f64;
        let words: Vec<Vec<u32>> = (0..positions.len())
            .into_par_iter()
            .map(|v| {
                let mut w = vec![0u32; per];
                let n = normals.get(v).copied().unwrap_or(Vec3::ZERO).as_dvec3();
                let n = if n.length_squared() > 0.0 && n.is_finite() { n.normalize() } else { DVec3::ZERO };
                let p = positions[v].as_dvec3() + lift * n;
                for (k, d) in table.dirs.iter().enumerate() {
                    let open = if n == DVec3::ZERO {
                        true
                    } else {
                        d.dot(n) >= 0.0 && !caster.occluded(p + *d * skip, *d, far)
                    };
                    if open {
                        w[k / 32] |= 1 << (k % 32);
                    }
                }
                w
            })
            .collect();
        words.concat()
    }

    fn bilinear_map(maps: &[Vec<f32>], r: usize, theta: f64, phi: f64) -> Vec<f32> {
        let (s0, s1, fs, t0, t1, ft) = super::grid_weights(r, theta, phi);
        let mut out = vec![0f32; maps[0].len()];
        for (idx, w) in [
            (s0 * r + t0, (1.0 - fs) * (1.0 - ft)),
            (s0 * r + t1, (1.0 - fs) * ft),
            (s1 * r + t0, fs * (1.0 - ft)),
            (s1 * r + t1, fs * ft),
        ] {
            if w > 0.0 {
                for (o, x) in out.iter_mut().zip(&maps[idx]) {
                    *o += (w as f32) * x;
                }
            }
        }
        out
    }

    impl HaarField {
        /// Builds the fixed (`adaptive = false`) or adaptive field from raw maps: per shell the
        /// maps are transformed and truncated to `keep`; adaptively, `R` is halved while every
        /// initial sample's truncated map, re-interpolated from the coarser grid, stays within
        /// `threshold` of eq. 1 (L1 in the pixel domain) of its own truncated map.
        pub fn build(
            center: Vec3,
            vr: f32,
            maps: &[Vec<Vec<f32>>],
            r0: usize,
            table: &CubeTable,
            keep: f64,
            adaptive: bool,
            threshold: f64,
        ) -> Self {
            Self::build_sized(center, vr, maps, r0, table, keep, adaptive, threshold).0
        }

        /// [`HaarField::build`] and the [`HaarField::bytes`] the fixed field (every shell at
        /// `r0`) would take, from the same truncation (no second build for the size).
        pub fn build_sized(
            center: Vec3,
            vr: f32,
            maps: &[Vec<Vec<f32>>],
            r0: usize,
            table: &CubeTable,
            keep: f64,
            adaptive: bool,
            threshold: f64,
        ) -> (Self, usize) {
            let n = table.n;
            let built: Vec<(HaarShell, usize)> = maps
                .par_iter()
                .map(|g| {
                    let trunc = |m: &Vec<f32>| {
                        let mut c = m.clone();
                        forward(&mut c, n);
                        truncate(&c, n, keep)
                    };
                    let base: Vec<Vec<(u16, f32)>> = g.iter().map(trunc).collect();
                    let fixed_bytes = 8 + base.iter().map(|c| 2 + 3 * c.len()).sum::<usize>();
                    let dense: Vec<Vec<f32>> = base.iter().map(|s| reconstruct(s, n)).collect();
                    let mut r = r0;
                    let mut cur = base;
                    while adaptive && r >= 2 {
                        let r2 = r / 2;
                        let coarse: Vec<Vec<f32>> = (0..r2 * r2)
                            .map(|i| {
                                let (th, ph) = sample_angles(r2, i / r2, i % r2);
                                bilinear_map(&dense, r0, th, ph)
                            })
                            .collect();
                        let coarse_t: Vec<Vec<(u16, f32)>> = coarse.iter().map(trunc).collect();
                        let coarse_d: Vec<Vec<f32>> = coarse_t.iter().map(|s| reconstruct(s, n)).collect();
                        let mut ok = true;
                        'outer: for s in 0..r0 {
                            for t in 0..r0 {
                                let (th, ph) = sample_angles(r0, s, t);
                                if l1(&bilinear_map(&coarse_d, r2, th, ph), &dense[s * r0 + t], table) >= threshold {
                                    ok = false;
                                    break 'outer;
                                }
                            }
                        }
                        if !ok {
                            break;
                        }
                        r = r2;
                        cur = coarse_t;
                    }
                    (quantize(r, &cur), fixed_bytes)
                })
                .collect();
            let fixed_bytes = built.iter().map(|b| b.1).sum();
            let shells = built.into_iter().map(|b| b.0).collect();
            (HaarField { n, center, bound_radius: vr, shells }, fixed_bytes)
        }

        /// Bytes: per kept coefficient a `u16` index and a `u8` value, plus per sample a `u16`
        /// count and per shell min/step.
        pub fn bytes(&self) -> usize {
            self.shells.iter().map(|s| 8 + s.samples.iter().map(|c| 2 + 3 * c.len()).sum::<usize>()).sum()
        }

        /// Every sample's map of shell `c` decoded and thresholded at 1/2 back to binary
        /// visibility, one bit per pixel (pixel `k` of a sample is bit `k % 32` of its word
        /// `k / 32`), samples in order: what the GPU reads (`6 n^2 / 32` words per sample, about
        /// the compressed size: 5 % of `6 n^2` coefficients at 3 bytes is 0.9 bits per pixel).
        pub fn shell_bits(&self, c: usize) -> Vec<u32> {
            let sh = &self.shells[c];
            let per = (6 * self.n * self.n).div_ceil(32);
            let mut out = vec![0u32; sh.samples.len() * per];
            for idx in 0..sh.samples.len() {
                for (k, v) in self.sample_map(c, idx).iter().enumerate() {
                    if *v >= 0.5 {
                        out[idx * per + k / 32] |= 1 << (k % 32);
                    }
                }
            }
            out
        }

        /// Per-shell resolutions.
        pub fn resolutions(&self) -> Vec<usize> {
            self.shells.iter().map(|s| s.resolution).collect()
        }

        /// Serializes the field (little endian): `"PSW1"`, cube face resolution `n`, shell
        /// count, centre, `Vr`, then per shell `R`, min, step, and per sample (`R^2`, in order)
        /// its coefficient count (`u16`) and coefficients (`u16` index, `u8` value).
        pub fn to_bytes(&self) -> Vec<u8> {
            let mut b = Vec::with_capacity(self.bytes() + 64);
            b.extend_from_slice(b"PSW1");
            b.extend_from_slice(&(self.n as u32).to_le_bytes());
            b.extend_from_slice(&(self.shells.len() as u32).to_le_bytes());
            for v in self.center.to_array().iter().chain([self.bound_radius].iter()) {
                b.extend_from_slice(&v.to_le_bytes());
            }
            for s in &self.shells {
                b.extend_from_slice(&(s.resolution as u32).to_le_bytes());
                b.extend_from_slice(&s.min.to_le_bytes());
                b.extend_from_slice(&s.step.to_le_bytes());
                for c in &s.samples {
                    b.extend_from_slice(&(c.len() as u16).to_le_bytes());
                    for &(i, q) in c {
                        b.extend_from_slice(&i.to_le_bytes());
                        b.push(q);
                    }
                }
            }
            b
        }

        /// Parses [`HaarField::to_bytes`]; errors (never panics, never allocates more than the
        /// input's size allows) on truncated or corrupt input.
        pub fn from_bytes(b: &[u8]) -> Result<Self, String> {
            let mut rd = ByteReader::new(b, "wavelet field file");
            if rd.take(4)? != b"PSW1" {
                return Err("wavelet field file: bad magic (expected PSW1)".into());
            }
            let n = rd.u32()? as usize;
            if !(2..=256).contains(&n) || !n.is_power_of_two() {
                return Err(format!("wavelet field file: cube resolution {n} (a power of two 2..=256)"));
            }
            let pixels = 6 * n * n;
            let nshell = rd.shell_count()?;
            let hdr = rd.centre_radius()?;
            let mut shells = Vec::with_capacity(nshell);
            for _ in 0..nshell {
                let r = rd.shell_resolution()?;
                let (min, step) = (rd.f32()?, rd.f32()?);
                if !(min.is_finite() && step.is_finite()) {
                    return Err("wavelet field file: non-finite quantization".into());
                }
                // every sample takes at least its 2-byte count: checked before allocating
                if r * r * 2 > b.len() {
                    return Err("wavelet field file: truncated".into());
                }
                let mut samples = Vec::with_capacity(r * r);
                for _ in 0..r * r {
                    let count = rd.u16()? as usize;
                    let data = rd.take(3 * count)?;
                    let mut c = Vec::with_capacity(count);
                    for e in data.chunks_exact(3) {
                        let i = u16::from_le_bytes([e[0], e[1]]);
                        if i as usize >= pixels {
                            return Err(format!("wavelet field file: coefficient {i} of a {pixels}-pixel map"));
                        }
                        c.push((i, e[2]));
                    }
                    samples.push(c);
                }
                shells.push(HaarShell { resolution: r, min, step, samples });
            }
            if !rd.done() {
                return Err("wavelet field file: trailing bytes".into());
            }
            Ok(HaarField { n, center: Vec3::new(hdr[0], hdr[1], hdr[2]), bound_radius: hdr[3], shells })
        }

        /// The truncated, dequantized map of sample `idx` of shell `c` (pixel domain, object
        /// frame, cube faces as [`CubeTable`]).
        pub fn sample_map(&self, c: usize, idx: usize) -> Vec<f32> {
            let sh = &self.shells[c];
            let sparse: Vec<(u16, f32)> =
                sh.samples[idx].iter().map(|&(i, q)| (i, sh.min + q as f32 * sh.step)).collect();
            reconstruct(&sparse, self.n)
        }

        /// Visibility cube map (object frame) at object-space point `p` (bilinear in the shell,
        /// linear between shells, as [`super::ObjectField::ocv`]); `None` outside.
        pub fn map_at(&self, p: DVec3) -> Option<Vec<f32>> {
            let nc = self.shells.len();
            let q = p - self.center.as_dvec3();
            let x = q.length() / (0.2 * self.bound_radius as f64) - 1.0;
            if nc == 0 || !x.is_finite() || x > (nc - 1) as f64 {
                return None;
            }
            let (theta, phi) = angles_of(q);
            let x = x.max(0.0);
            let c0 = (x.floor() as usize).min(nc - 1);
            let c1 = (c0 + 1).min(nc - 1);
            let w = (x - c0 as f64) as f32;
            let shell = |c: usize| {
                let r = self.shells[c].resolution;
                let maps: Vec<Vec<f32>> = {
                    let (s0, s1, _, t0, t1, _) = super::grid_weights(r, theta, phi);
                    let mut m = vec![Vec::new(); r * r];
                    for idx in [s0 * r + t0, s0 * r + t1, s1 * r + t0, s1 * r + t1] {
                        if m[idx].is_empty() {
                            m[idx] = self.sample_map(c, idx);
                        }
                    }
                    for v in m.iter_mut() {
                        if v.is_empty() {
                            *v = vec![0.0; 6 * self.n * self.n];
                        }
                    }
                    m
                };
                bilinear_map(&maps, r, theta, phi)
            };
            let a = shell(c0);
            if c1 == c0 || w <= 0.0 {
                return Some(a);
            }
            let b = shell(c1);
            Some(a.iter().zip(&b).map(|(x, y)| (1.0 - w) * x + w * y).collect())
        }

        /// The product of the visibility maps of several (translated, unrotated) occluders at
        /// world point `p` (`(field, centre offset)` pairs: the field's object origin in world
        /// space): the wavelet triple product, evaluated in the pixel domain.
        pub fn product_map(occluders: &[(&HaarField, DVec3)], p: DVec3, n: usize) -> Vec<f32> {
            let mut v = vec![1f32; 6 * n * n];
            for (f, origin) in occluders {
                if let Some(m) = f.map_at(p - *origin) {
                    for (a, b) in v.iter_mut().zip(&m) {
                        *a *= b;
                    }
                }
            }
            v
        }
    }
}
