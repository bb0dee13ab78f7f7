//! Radiance integration over regions bounded by loops of unit directions with summed-area tables
//! (vectorized visibility, Ho et al. 2015 as used by Leung et al. 2021, eq. 9-16).
//!
//! The lat-long environment map (conventions of [`crate::envmap::latlong_direction`]: row 0 is
//! +Y, `phi = 2 pi u` from -Z towards +X) is turned into a summed-area table of four RGB
//! channels, `x L_e`, `y L_e`, `z L_e` and `L_e`, each texel holding the exact integral of
//! `l dω` (resp. `dω`) over its cell times its radiance. [`Sat::lookup`] interpolates the
//! corner values bilinearly.
//!
//! **Loops.** A region is given by closed loops of unit directions (consecutive points joined by
//! great arcs). A loop's interior is on its *left as seen from the sphere's centre* (the shading
//! point looking out: counter-clockwise loops are positive); a loop traversed the other way
//! counts negatively (a hole). [`integrate_loops`] sums, over every arc, the *strip* between
//! the north pole and the arc (eq. 10, `vsat`): `E` and `F` are the SAT strips down to the arc's
//! two endpoint latitudes, and the interpolation factor of eq. 11 is `1/2 + 1/2 tanh(alpha' x_c)`
//! where `x_c` is the signed perpendicular distance, in texels, from the luminance centroid of
//! the arc's bounding box to the arc (positive towards the pole: that light is inside the
//! strip). Arcs are split at the `phi` seam, at their latitude extremum (so each piece is
//! monotone in `theta`; an arc over a pole becomes two meridian pieces with no strip) and into
//! pieces of at most [`MAX_DPHI`] of longitude. The strips of a closed loop add up to the
//! integral over its interior up to a multiple of the whole-sphere integral, fixed by the net
//! longitude winding and by a point known to lie outside every loop (loops are clipped to a cap,
//! see [`clip_to_cap`], and a pole outside the cap has winding 0).
//!
//! **Shading.** Diffuse (eq. 9/12): `L_d = albedo/pi * n . ∫_V l L_e dl` over the visible
//! region `V` = hemisphere of `n` minus the occluder loops clipped to it
//! ([`visible_moments`]). Specular (eq. 14-16): the unshadowed glossy radiance times the ratio
//! `gamma` of the cap-weighted (`Cap = l.r - cos xi` inside the cap of radius `xi` around `r`,
//! eq. 16 with the inequality of the cap interior) environment integral over `V ∩ W` and over
//! `W` ([`cap_ratio`]).
//!
//! The GLSL mirror is `glsl/include/vv_sat.glsl` (same splitting, same factor).

use glam::DVec3;
use std::f64::consts::PI;

/// Longest longitude span of one integrated arc piece (radians).
pub const MAX_DPHI: f64 = PI / 8.0;

/// Default `alpha'` of eq. 11 in units of 1/texel of the map (the transition width of the
/// interpolation factor is about one texel / alpha').
pub const DEFAULT_ALPHA: f64 = 2.0;

/// Integrals of `(x, y, z, 1) * L_e` (each RGB) over a region.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Moments(pub [DVec3; 4]);

impl Moments {
    /// `sum_k v_k m_k` for k = x, y, z: the RGB integral of `(v . l) L_e`.
    pub fn dot(&self, v: DVec3) -> DVec3 {
        self.0[0] * v.x + self.0[1] * v.y + self.0[2] * v.z
    }
    /// The RGB integral of `L_e`.
    pub fn radiance(&self) -> DVec3 {
        self.0[3]
    }
    fn add(&mut self, o: &Moments, s: f64) {
        for k in 0..4 {
            self.0[k] += o.0[k] * s;
        }
    }
    fn scaled(&self, s: f64) -> Moments {
        let mut m = Moments::default();
        m.add(self, s);
        m
    }
}

/// A summed-area table over a lat-long map: `(width + 1) x (height + 1)` corners, corner
/// `(i, j)` holding the integral over texels `x < i`, `y < j`.
#[derive(Clone, Debug)]
pub struct Sat {
    /// Map width in texels.
    pub width: usize,
    /// Map height in texels.
    pub height: usize,
    /// Corner values, row-major, `width + 1` per row.
    pub corners: Vec<Moments>,
}

/// Exact `∫ (l, 1) dω` over the cell `phi in [p0, p1]`, `theta in [t0, t1]`.
pub fn cell_moments(p0: f64, p1: f64, t0: f64, t1: f64) -> [f64; 4] {
    let tt = (t1 / 2.0 - (2.0 * t1).sin() / 4.0) - (t0 / 2.0 - (2.0 * t0).sin() / 4.0);
    let x = tt * (p0.cos() - p1.cos());
    let y = (t1.sin().powi(2) - t0.sin().powi(2)) / 2.0 * (p1 - p0);
    let z = -tt * (p1.sin() - p0.sin());
    let one = (t0.cos() - t1.cos()) * (p1 - p0);
    [x, y, z, one]
}

/// Error of [`Sat::new`].
#[derive(Debug, Clone, PartialEq)]
pub enum SatError {
    /// Width or height zero, or the texel count does not match.
    BadSize {
        /// Given width.
        width: usize,
        /// Given height.
        height: usize,
        /// Texels given.
        texels: usize,
    },
}

impl std::fmt::Display for SatError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SatError::BadSize { width, height, texels } => {
                write!(f, "environment map {width}x{height} with {texels} texels cannot form a summed-area table")
            }
        }
    }
}
impl std::error::Error for SatError {}

impl Sat {
    /// The SAT of a lat-long map (row-major, row 0 = +Y). Non-finite and negative texels count
    /// as 0.
    pub fn new(width: usize, height: usize, texels: &[[f32; 3]]) -> Result<Sat, SatError> {
        if width == 0 || height == 0 || texels.len() != width * height {
            return Err(SatError::BadSize { width, height, texels: texels.len() });
        }
        let cw = width + 1;
        let mut corners = vec![Moments::default(); cw * (height + 1)];
        let dp = 2.0 * PI / width as f64;
        let dt = PI / height as f64;
        for y in 0..height {
            let mut row = Moments::default();
            for x in 0..width {
                let t = texels[y * width + x];
                let c = DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64);
                let c = DVec3::new(clean(c.x), clean(c.y), clean(c.z));
                let m = cell_moments(x as f64 * dp, (x + 1) as f64 * dp, y as f64 * dt, (y + 1) as f64 * dt);
                for (rk, mk) in row.0.iter_mut().zip(m) {
                    *rk += c * mk;
                }
                let above = corners[y * cw + x + 1];
                let mut v = above;
                v.add(&row, 1.0);
                corners[(y + 1) * cw + x + 1] = v;
            }
        }
        Ok(Sat { width, height, corners })
    }

    /// Integral over the whole sphere.
    pub fn total(&self) -> Moments {
        self.corners[self.corners.len() - 1]
    }

    /// The SAT at `(phi, theta)` (radians, `phi in [0, 2 pi]`, `theta in [0, pi]`): integral over
    /// `[0, phi] x [0, theta]`, bilinear between corners.
    pub fn lookup(&self, phi: f64, theta: f64) -> Moments {
        let fx = (phi / (2.0 * PI) * self.width as f64).clamp(0.0, self.width as f64);
        let fy = (theta / PI * self.height as f64).clamp(0.0, self.height as f64);
        let x0 = (fx.floor() as usize).min(self.width - 1);
        let y0 = (fy.floor() as usize).min(self.height - 1);
        let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
        let cw = self.width + 1;
        let c = |x: usize, y: usize| &self.corners[y * cw + x];
        let mut m = Moments::default();
        m.add(c(x0, y0), (1.0 - tx) * (1.0 - ty));
        m.add(c(x0 + 1, y0), tx * (1.0 - ty));
        m.add(c(x0, y0 + 1), (1.0 - tx) * ty);
        m.add(c(x0 + 1, y0 + 1), tx * ty);
        m
    }

    /// Strip `[phi_a, phi_b] x [0, theta]` (signed by the direction of phi).
    fn strip(&self, pa: f64, pb: f64, theta: f64) -> Moments {
        let mut m = self.lookup(pb, theta);
        m.add(&self.lookup(pa, theta), -1.0);
        m
    }
}

fn clean(v: f64) -> f64 {
    if v.is_finite() && v > 0.0 {
        v
    } else {
        0.0
    }
}

fn luminance(c: DVec3) -> f64 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// `(phi, theta)` of a unit direction (phi in [0, 2 pi)).
pub fn angles(d: DVec3) -> (f64, f64) {
    let theta = d.y.clamp(-1.0, 1.0).acos();
    let mut phi = d.x.atan2(-d.z);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    (phi, theta)
}

fn wrap_pi(mut a: f64) -> f64 {
    while a > PI {
        a -= 2.0 * PI;
    }
    while a <= -PI {
        a += 2.0 * PI;
    }
    a
}

/// The integration state of a set of loops.
struct Acc<'a> {
    sat: &'a Sat,
    alpha: f64,
    sum: Moments,
    /// Net longitude travelled (radians).
    dphi: f64,
    /// Arc pieces integrated (cost measure).
    pieces: usize,
}

impl Acc<'_> {
    /// One great arc a -> b (unit vectors).
    fn arc(&mut self, a: DVec3, b: DVec3, depth: u32) {
        let m = a.cross(b);
        let ml = m.length();
        if ml < 1e-12 {
            return; // coincident or antipodal endpoints: no well-defined arc
        }
        let mh = m / ml;
        // latitude extremum inside the arc: split there (monotone theta per piece)
        if depth == 0 {
            let top = DVec3::Y - mh * mh.y;
            if top.length() > 1e-12 {
                let top = top.normalize();
                for p in [top, -top] {
                    if a.cross(p).dot(mh) > 1e-12 && p.cross(b).dot(mh) > 1e-12 {
                        self.arc(a, p, 1);
                        self.arc(p, b, 1);
                        return;
                    }
                }
            }
        }
        let (mut pa, ta) = angles(a);
        let (mut pb, tb) = angles(b);
        // a pole endpoint takes the other endpoint's longitude (meridian piece)
        if ta.sin() < 1e-9 {
            pa = pb;
        }
        if tb.sin() < 1e-9 {
            pb = pa;
        }
        let d = wrap_pi(pb - pa);
        if d.abs() > MAX_DPHI && depth < 12 {
            let mid = (a + b).normalize();
            self.arc(a, mid, depth + 1);
            self.arc(mid, b, depth + 1);
            return;
        }
        self.dphi += d;
        let end = pa + d;
        // (a NaN end takes the plain path)
        if !end.is_nan() && !(0.0..=2.0 * PI).contains(&end) {
            // crosses the seam (x = 0, z < 0): split at the crossing
            let t = a.x / (a.x - b.x);
            let p = (a + (b - a) * t).normalize();
            let (_, tp) = angles(p);
            let (seam_a, seam_b) = if d > 0.0 { (2.0 * PI, 0.0) } else { (0.0, 2.0 * PI) };
            self.piece(pa, ta, seam_a, tp, a, p);
            self.piece(seam_b, tp, seam_b + (end - seam_a), tb, p, b);
        } else {
            self.piece(pa, ta, end, tb, a, b);
        }
    }

    /// A piece monotone in theta within [0, 2 pi] of longitude: eq. 10-11.
    fn piece(&mut self, pa: f64, ta: f64, pb: f64, tb: f64, a: DVec3, b: DVec3) {
        if (pb - pa).abs() < 1e-15 {
            return;
        }
        self.pieces += 1;
        let (tmin, tmax) = if ta <= tb { (ta, tb) } else { (tb, ta) };
        let smin = self.sat.strip(pa, pb, tmin);
        let smax = self.sat.strip(pa, pb, tmax);
        let mut box_ = smax;
        box_.add(&smin, -1.0);
        // luminance centroid of the box (sign of the strip removed)
        let s = (pb - pa).signum();
        let c = DVec3::new(luminance(box_.0[0]), luminance(box_.0[1]), luminance(box_.0[2])) * s;
        let f = if c.length() > 1e-300 && tmax - tmin > 1e-12 {
            let c = c.normalize();
            // signed angular distance from the arc's great circle, positive towards +Y
            let m = a.cross(b);
            let ml = m.length();
            let side = if ml > 1e-15 {
                let mh = m / ml;
                let sgn = if mh.y >= 0.0 { 1.0 } else { -1.0 };
                (c.dot(mh)).clamp(-1.0, 1.0).asin() * sgn
            } else {
                0.0
            };
            let texels = side * self.sat.height as f64 / PI;
            0.5 + 0.5 * (self.alpha * texels).tanh()
        } else {
            0.5
        };
        let mut r = smin;
        r.add(&box_, f);
        self.sum.add(&r, 1.0);
    }

    fn closed_loop(&mut self, pts: &[DVec3]) {
        if pts.len() < 2 {
            return;
        }
        for i in 0..pts.len() {
            self.arc(pts[i], pts[(i + 1) % pts.len()], 0);
        }
    }
}

/// Result of [`integrate_loops`].
#[derive(Clone, Copy, Debug, Default)]
pub struct LoopIntegral {
    /// The integrals.
    pub moments: Moments,
    /// Arc pieces evaluated (four SAT lookups each).
    pub pieces: usize,
}

/// Signed integral over the loops' interiors (see the module docs), all loops lying in a region
/// that excludes the south pole (`south_outside`) or the north pole (otherwise).
pub fn integrate_loops(sat: &Sat, loops: &[Vec<DVec3>], south_outside: bool, alpha: f64) -> LoopIntegral {
    let mut acc = Acc { sat, alpha, sum: Moments::default(), dphi: 0.0, pieces: 0 };
    for l in loops {
        acc.closed_loop(l);
    }
    let w = (acc.dphi / (2.0 * PI)).round();
    let mut m = acc.sum;
    if !south_outside {
        // winding(N) = 0, winding(S) = -w: add -w times the whole sphere
        m.add(&sat.total(), -w);
    }
    LoopIntegral { moments: m, pieces: acc.pieces }
}

/// Points on the circle of the cap (`axis`, `cos_r`) from `from` to `to`, turning
/// counter-clockwise as seen from the centre (left-hand about `axis`... i.e. keeping the cap on
/// the left seen from the centre), excluding both ends, at most `step` radians apart.
fn circle_walk(axis: DVec3, cos_r: f64, from: DVec3, to: DVec3, step: f64, out: &mut Vec<DVec3>) {
    let (u, v) = basis(axis);
    let ang = |p: DVec3| {
        let q = p - axis * p.dot(axis);
        q.dot(v).atan2(q.dot(u))
    };
    let a0 = ang(from);
    let a1 = ang(to);
    // counter-clockwise seen from the centre = clockwise about +axis seen from outside =
    // decreasing angle in the right-handed (u, v, axis) frame
    let mut span = a0 - a1;
    while span < 0.0 {
        span += 2.0 * PI;
    }
    while span >= 2.0 * PI {
        span -= 2.0 * PI;
    }
    let sin_r = (1.0 - cos_r * cos_r).max(0.0).sqrt();
    let n = (span / step).ceil() as usize;
    for i in 1..n {
        let a = a0 - span * i as f64 / n as f64;
        out.push((axis * cos_r + (u * a.cos() + v * a.sin()) * sin_r).normalize());
    }
}

/// An orthonormal pair perpendicular to `a` with `u x v = a`.
pub fn basis(a: DVec3) -> (DVec3, DVec3) {
    let t = if a.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = t.cross(a).normalize();
    let v = a.cross(u);
    (u, v)
}

/// The full circle of the cap (`axis`, `cos_r`) as a positive loop (cap interior on the left
/// seen from the centre), `n` points.
pub fn cap_loop(axis: DVec3, cos_r: f64, n: usize) -> Vec<DVec3> {
    let (u, v) = basis(axis);
    let sin_r = (1.0 - cos_r * cos_r).max(0.0).sqrt();
    (0..n)
        .map(|i| {
            let a = -2.0 * PI * i as f64 / n as f64;
            (axis * cos_r + (u * a.cos() + v * a.sin()) * sin_r).normalize()
        })
        .collect()
}

/// Clips a loop to the spherically convex cap `{l : l . axis >= cos_r}` (`cos_r >= 0`),
/// following the cap's circle (points at most `step` radians apart) between exit and re-entry
/// points. Returns an empty loop when nothing is inside.
pub fn clip_to_cap(pts: &[DVec3], axis: DVec3, cos_r: f64, step: f64) -> Vec<DVec3> {
    let n = pts.len();
    if n < 3 {
        return Vec::new();
    }
    let inside = |p: DVec3| p.dot(axis) >= cos_r;
    // crossing of the great arc a -> b with the circle (first root in (0, 1) of the direction)
    let cross = |a: DVec3, b: DVec3| -> DVec3 {
        // p(t) = a + t (b - a); (p . axis)^2 = cos_r^2 |p|^2 with p . axis >= 0, sign change
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        let g = |t: f64| {
            let p = (a + (b - a) * t).normalize();
            p.dot(axis) - cos_r
        };
        let glo = g(lo);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if (g(mid) >= 0.0) == (glo >= 0.0) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (a + (b - a) * (0.5 * (lo + hi))).normalize()
    };
    let start = match (0..n).find(|&i| inside(pts[i])) {
        Some(i) => i,
        None => {
            // no vertex inside: the loop may still cut the cap with an arc; treat the loop as
            // outside unless it surrounds the cap (then the whole cap is inside)
            if arcs_cut_cap(pts, axis, cos_r) {
                return densify_clip(pts, axis, cos_r, step);
            }
            return if winding_about(pts, axis) != 0 {
                cap_loop(axis, cos_r, ((2.0 * PI / step).ceil() as usize).max(8))
            } else {
                Vec::new()
            };
        }
    };
    let mut out = Vec::with_capacity(n + 8);
    let mut exit: Option<DVec3> = None;
    for k in 0..n {
        let a = pts[(start + k) % n];
        let b = pts[(start + k + 1) % n];
        let (ia, ib) = (inside(a), inside(b));
        if ia {
            out.push(a);
        }
        if ia && !ib {
            exit = Some(cross(a, b));
            out.push(exit.unwrap());
        } else if !ia && ib {
            let entry = cross(a, b);
            if let Some(x) = exit.take() {
                circle_walk(axis, cos_r, x, entry, step, &mut out);
            }
            out.push(entry);
        } else if !ia && !ib {
            // both ends outside: the arc may still dip into the cap (entry, then exit)
            if let Some(p) = arc_point_in_cap(a, b, axis, cos_r) {
                let entry = cross(a, p);
                if let Some(x) = exit.take() {
                    circle_walk(axis, cos_r, x, entry, step, &mut out);
                }
                out.push(entry);
                let x = cross(p, b);
                out.push(x);
                exit = Some(x);
            }
        }
    }
    out
}

/// The point of the great arc `a -> b` closest to `axis` when it lies strictly inside the cap.
fn arc_point_in_cap(a: DVec3, b: DVec3, axis: DVec3, cos_r: f64) -> Option<DVec3> {
    let m = a.cross(b);
    if m.length() < 1e-15 {
        return None;
    }
    let mh = m.normalize();
    let p = axis - mh * mh.dot(axis);
    if p.length() < 1e-15 {
        return None;
    }
    let p = p.normalize();
    (a.cross(p).dot(mh) > 0.0 && p.cross(b).dot(mh) > 0.0 && p.dot(axis) > cos_r).then_some(p)
}

/// True if some arc between two outside points dips into the cap.
fn arcs_cut_cap(pts: &[DVec3], axis: DVec3, cos_r: f64) -> bool {
    (0..pts.len()).any(|i| arc_point_in_cap(pts[i], pts[(i + 1) % pts.len()], axis, cos_r).is_some())
}

/// Clip after inserting each arc's point closest to the axis (so some vertex is inside).
fn densify_clip(pts: &[DVec3], axis: DVec3, cos_r: f64, step: f64) -> Vec<DVec3> {
    let mut d = Vec::with_capacity(pts.len() * 2);
    for i in 0..pts.len() {
        let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
        d.push(a);
        let m = a.cross(b);
        if m.length() > 1e-15 {
            let mh = m.normalize();
            let p = axis - mh * mh.dot(axis);
            if p.length() > 1e-15 {
                let p = p.normalize();
                if a.cross(p).dot(mh) > 0.0 && p.cross(b).dot(mh) > 0.0 {
                    d.push(p);
                }
            }
        }
    }
    if d.iter().any(|p| p.dot(axis) >= cos_r) {
        clip_to_cap(&d, axis, cos_r, step)
    } else {
        Vec::new()
    }
}

/// Winding number of a loop about `axis` (positive counter-clockwise seen from the centre).
pub fn winding_about(pts: &[DVec3], axis: DVec3) -> i32 {
    let mut s = 0.0;
    for i in 0..pts.len() {
        let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
        let y = axis.dot(a.cross(b));
        let x = a.dot(b) - a.dot(axis) * b.dot(axis);
        s += y.atan2(x);
    }
    // counter-clockwise seen from the centre = clockwise about +axis seen from outside
    (-s / (2.0 * PI)).round() as i32
}

/// Options of the shading integrals.
#[derive(Clone, Copy, Debug)]
pub struct IntegrateOptions {
    /// `alpha'` of eq. 11 (1/texel).
    pub alpha: f64,
    /// Longest step of the arcs that follow a clipping circle (radians).
    pub circle_step: f64,
    /// Clip the occluder loops to the cap (true), or take them as lying inside it already
    /// (false: loops synthesized with the hemisphere clamp of `penumbra_math::vv`, as the GPU
    /// does).
    pub clip: bool,
}

impl Default for IntegrateOptions {
    fn default() -> Self {
        IntegrateOptions { alpha: DEFAULT_ALPHA, circle_step: PI / 16.0, clip: true }
    }
}

/// `∫_V (l, 1) L_e dl` over `V` = the cap (`axis`, `cos_r`) minus the occluder loops (each
/// positive = occluded interior on its left seen from the centre), loops clipped to the cap
/// first; `clip2` optionally intersects everything with a second cap (`axis2`, `cos2`) first.
pub fn region_moments(
    sat: &Sat,
    axis: DVec3,
    cos_r: f64,
    occluders: &[Vec<DVec3>],
    clip2: Option<(DVec3, f64)>,
    o: &IntegrateOptions,
) -> LoopIntegral {
    let axis = nudge_axis(axis, cos_r);
    let clip2 = clip2.map(|(a, c)| (nudge_axis(a, c), c));
    let mut loops = Vec::with_capacity(occluders.len() + 1);
    let steps = ((2.0 * PI / o.circle_step).ceil() as usize).max(8);
    let mut outer = cap_loop(axis, cos_r, steps);
    if let Some((a2, c2)) = clip2 {
        outer = clip_to_cap(&outer, a2, c2, o.circle_step);
    }
    if !outer.is_empty() {
        loops.push(outer);
    }
    for l in occluders {
        let mut c = if o.clip { clip_to_cap(l, axis, cos_r, o.circle_step) } else { l.clone() };
        if let Some((a2, c2)) = clip2 {
            c = clip_to_cap(&c, a2, c2, o.circle_step);
        }
        if c.len() >= 3 {
            c.reverse();
            loops.push(c);
        }
    }
    // a pole outside the (first) cap has winding 0
    let south_outside = -axis.y < cos_r || clip2.is_some_and(|(a2, c2)| -a2.y < c2);
    let north_outside = axis.y < cos_r || clip2.is_some_and(|(a2, c2)| a2.y < c2);
    let south = south_outside || !north_outside;
    integrate_loops(sat, &loops, south, o.alpha)
}

/// A cap axis moved by ~2e-3 rad when a pole lies within 1e-3 (in `y`) of the cap's circle, so
/// that each pole is clearly inside or outside (a horizon through both poles is otherwise
/// ambiguous). Mirrored in GLSL, where it must exceed fp32's angular resolution next to a pole
/// (`acos` of a `y` within one ulp of 1 is ~3.5e-4 rad): with the former 2e-6 rad the shader
/// put the circle's points exactly on the poles and lost the whole hemisphere of horizontal
/// normals (tests/vv.rs, GLSL-vs-CPU parity). The tilt changes such a normal's integral by at
/// most ~2e-3 of its value.
pub fn nudge_axis(axis: DVec3, cos_r: f64) -> DVec3 {
    if (axis.y - cos_r).abs() < 1e-3 || (-axis.y - cos_r).abs() < 1e-3 {
        let s = if axis.y >= 0.0 { 1.0 } else { -1.0 };
        (axis + DVec3::new(0.0, 2e-3 * s, 0.0)).normalize()
    } else {
        axis
    }
}

/// Visible moments of eq. 9/12: hemisphere of `n` minus the occluders.
pub fn visible_moments(sat: &Sat, n: DVec3, occluders: &[Vec<DVec3>], o: &IntegrateOptions) -> LoopIntegral {
    region_moments(sat, n, 0.0, occluders, None, o)
}

/// Diffuse radiance (eq. 9/12) for an albedo: `albedo / pi * n . ∫_V l L_e`.
pub fn diffuse(sat: &Sat, n: DVec3, occluders: &[Vec<DVec3>], albedo: DVec3, o: &IntegrateOptions) -> DVec3 {
    let m = visible_moments(sat, n, occluders, o).moments;
    (albedo / PI * m.dot(n)).max(DVec3::ZERO)
}

/// Cap radius `xi` (cosine) of a Phong lobe `cos^shininess`: the cone holding 95% of the
/// normalised lobe's energy, at most 90 degrees.
pub fn phong_cap_cos(shininess: f64) -> f64 {
    0.05f64.powf(1.0 / (shininess.max(0.0) + 1.0)).clamp(0.0, 1.0)
}

/// Visibility ratio `gamma` of eq. 15 for reflection direction `r`, cap cosine `cos_xi`, normal
/// `n` (per RGB channel, in [0, 1]; 1 where the cap carries no light).
pub fn cap_ratio(sat: &Sat, n: DVec3, r: DVec3, cos_xi: f64, occluders: &[Vec<DVec3>], o: &IntegrateOptions) -> DVec3 {
    // denominator over W; numerator over W ∩ H(n) minus the occluders
    let den = region_moments(sat, r, cos_xi, &[], None, o).moments;
    let num = region_moments(sat, r, cos_xi, occluders, Some((n, 0.0)), o).moments;
    let capw = |m: &Moments| m.dot(r) - m.radiance() * cos_xi;
    let (nu, de) = (capw(&num), capw(&den));
    let ratio = |a: f64, b: f64| if b > 1e-12 { (a / b).clamp(0.0, 1.0) } else { 1.0 };
    DVec3::new(ratio(nu.x, de.x), ratio(nu.y, de.y), ratio(nu.z, de.z))
}

/// Brute-force reference: `∫ (l, 1) L_e` over the directions inside `inside(l)`, each texel
/// split into `sub x sub` cells with exact cell moments (the map is piecewise constant).
pub fn brute_force(
    width: usize,
    height: usize,
    texels: &[[f32; 3]],
    sub: usize,
    inside: impl Fn(DVec3) -> bool + Sync,
) -> Moments {
    use rayon::prelude::*;
    let dp = 2.0 * PI / (width * sub) as f64;
    let dt = PI / (height * sub) as f64;
    let rows: Vec<Moments> = (0..height * sub)
        .into_par_iter()
        .map(|yy| {
            let mut m = Moments::default();
            let y = yy / sub;
            let t0 = yy as f64 * dt;
            for xx in 0..width * sub {
                let p0 = xx as f64 * dp;
                let d = crate::envmap::latlong_direction((p0 + 0.5 * dp) / (2.0 * PI), (t0 + 0.5 * dt) / PI);
                if !inside(d) {
                    continue;
                }
                let t = texels[y * width + xx / sub];
                let c = DVec3::new(clean(t[0] as f64), clean(t[1] as f64), clean(t[2] as f64));
                let cm = cell_moments(p0, p0 + dp, t0, t0 + dt);
                for (mk, cmk) in m.0.iter_mut().zip(cm) {
                    *mk += c * cmk;
                }
            }
            m
        })
        .collect();
    let mut m = Moments::default();
    for r in &rows {
        m.add(r, 1.0);
    }
    m
}

/// True if `d` is inside the loop (winding about `d` non-zero), for small loops not
/// surrounding `-d`.
pub fn inside_loop(pts: &[DVec3], d: DVec3) -> bool {
    winding_about(pts, d) != 0
}

/// Relative error `|a - b| / |b|` over all channels (Frobenius).
pub fn rel_error(a: &Moments, b: &Moments) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..4 {
        num += (a.0[k] - b.0[k]).length_squared();
        den += b.0[k].length_squared();
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    }
}

#[allow(dead_code)]
fn _scaled(m: &Moments) -> Moments {
    m.scaled(1.0)
}
