//! Integral spherical Gaussians (Iwasaki et al. 2012, "Real-time rendering of dynamic scenes
//! under all-frequency lighting using integral spherical Gaussian").
//!
//! Local frame: the lobe axis is `+Z`; a direction of the `z >= 0` hemisphere is
//! `Omega(theta, phi) = (sin theta cos phi, cos theta, sin theta sin phi)` with `theta in [0, pi]`
//! the angle from `+Y` and `phi in [0, pi]` the azimuth about `Y` from `+X` (the lobe axis is
//! `theta = phi = pi/2`). The ISG of an SG of sharpness `gamma` is
//!
//! ```text
//! S(theta, phi) = int_0^theta int_0^phi exp(gamma (sin t sin p - 1)) sin t dp dt
//! ```
//!
//! and the normalized ISG is `S / S(pi, pi)` with `S(pi, pi) = 2 pi (1 - exp(-gamma)) / gamma`
//! (the hemisphere integral). The integral over a patch `[t0, t1] x [p0, p1]` is the
//! summed-area-table difference `S(t1,p1) - S(t0,p1) - S(t1,p0) + S(t0,p0)`.
//!
//! Three evaluators:
//! * [`isg_exact`] / [`isg_grid_exact`]: numerical integration (Gauss-Legendre panels refined
//!   around the lobe, accurate to ~1e-12 relative), for `gamma` from `1e-2` to `1e5` and beyond;
//! * [`paper_fit`]: the paper's two-sigmoid fit `f = s(g(gamma)(theta - pi/2)) s(h(gamma)(phi - pi/2))`
//!   with the appendix's quartic polynomials `g`, `h` in `gamma / 100` (fitted for `gamma` in
//!   1..10000; outside that range `gamma` is clamped);
//! * [`IsgTable`]: a tabulated pre-integration (the fit is poor, see the tests and [`fit_error`]),
//!   levels of `log10 gamma` from -2 to 5, each a cumulative grid over warped angles
//!   (`v = atan(k (theta - pi/2)) / atan(k pi/2)`, `k = sqrt(gamma) + 0.5`), bilinear in
//!   `(v_theta, v_phi)` and linear in `log10 gamma` after rescaling the angles about `pi/2` by
//!   `sqrt((gamma + 1) / (gamma_level + 1))` (the lobe's width law). `gamma` beyond the table
//!   uses the last level with the same rescaling (asymptotically exact).
//!
//! [`visible_fraction`] is the paper's visibility integral (section 4.1) on the CPU: the region
//! within the limiting angle is split into `patch_side^2` patches, every blocker sphere whose
//! projected cap meets the cone of the region marks the patches whose centre it covers, and the
//! ISGs of occluded patches are subtracted from 1 (the border patches extend to the hemisphere's
//! boundary, so a blocker covering the whole region blocks the whole lobe; the paper leaves the
//! mass beyond the limiting angle visible). It is the reference for the GPU code
//! (`glsl/include/isg.glsl`).

use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, PI};

/// Smallest sharpness the table stores (smaller ones use this level: the lobe is then nearly
/// constant over the hemisphere).
pub const GAMMA_MIN: f64 = 1e-2;
/// Largest sharpness the table stores (larger ones are rescaled from it).
pub const GAMMA_MAX: f64 = 1e5;

/// Direction `Omega(theta, phi)` of the local frame (lobe axis `+Z`).
pub fn direction(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin())
}

/// `(theta, phi)` of a unit direction of the local frame; `phi` is in `[0, pi]` for `z >= 0` and
/// is clamped to `[0, pi]` (0 or pi) for `z < 0`.
pub fn angles(d: DVec3) -> (f64, f64) {
    let theta = d.y.clamp(-1.0, 1.0).acos();
    let phi = d.z.atan2(d.x);
    let phi = if phi < 0.0 {
        if phi < -FRAC_PI_2 {
            PI
        } else {
            0.0
        }
    } else {
        phi
    };
    (theta, phi)
}

/// `S(pi, pi)`: integral of `exp(gamma (cos - 1))` over the hemisphere about its axis,
/// `2 pi (1 - exp(-gamma)) / gamma` (`2 pi` at `gamma = 0`).
pub fn hemisphere_integral(gamma: f64) -> f64 {
    let g = gamma.max(0.0);
    if g < 1e-8 {
        2.0 * PI * (1.0 - 0.5 * g)
    } else {
        -2.0 * PI * (-g).exp_m1() / g
    }
}

fn sanitize_gamma(gamma: f64) -> f64 {
    if gamma.is_nan() || gamma < 0.0 {
        0.0
    } else {
        gamma.min(1e12)
    }
}

/// A composite Gauss-Legendre rule on `[0, pi]` with breakpoints at every `cuts` value and at
/// `pi/2 +- w 2^k` (`w = 0.5 / sqrt(gamma)`), panels at most 0.25 wide.
fn rule(gamma: f64, cuts: &[f64], order: usize) -> (Vec<f64>, Vec<f64>, Vec<usize>) {
    let (gx, gw) = crate::quad::gauss_legendre(order);
    let mut bp: Vec<f64> = vec![0.0, PI];
    bp.extend(cuts.iter().map(|c| c.clamp(0.0, PI)));
    if gamma > 1.0 {
        let mut w = 0.25 / gamma.sqrt();
        while w < FRAC_PI_2 {
            bp.push(FRAC_PI_2 - w);
            bp.push(FRAC_PI_2 + w);
            w *= 1.6;
        }
        bp.push(FRAC_PI_2);
    }
    bp.sort_by(|a, b| a.total_cmp(b));
    bp.dedup_by(|a, b| (*a - *b).abs() < 1e-15);
    // Split panels wider than 0.25.
    let mut fine = vec![bp[0]];
    for win in bp.windows(2) {
        let n = ((win[1] - win[0]) / 0.25).ceil().max(1.0) as usize;
        for k in 1..n {
            fine.push(win[0] + (win[1] - win[0]) * k as f64 / n as f64);
        }
        fine.push(win[1]);
    }
    let mut x = Vec::new();
    let mut w = Vec::new();
    // panel_end[i]: number of nodes before breakpoint i (so cumulative sums can be read at cuts).
    let mut panel_end = vec![0usize];
    for win in fine.windows(2) {
        let (a, b) = (win[0], win[1]);
        let h = 0.5 * (b - a);
        for (xi, wi) in gx.iter().zip(&gw) {
            x.push(a + h * (xi + 1.0));
            w.push(h * wi);
        }
        panel_end.push(x.len());
    }
    // Map every cut to the node count before it.
    let ends: Vec<usize> = cuts
        .iter()
        .map(|c| {
            let c = c.clamp(0.0, PI);
            let i = fine.iter().position(|f| (*f - c).abs() < 1e-12).unwrap_or(fine.len() - 1);
            panel_end[i]
        })
        .collect();
    (x, w, ends)
}

/// Exact (numerically integrated) **unnormalized** ISG `S(theta_i, phi_j)` on a grid, row-major
/// in `theta` (`out[i * phis.len() + j]`). Angles are clamped to `[0, pi]`.
pub fn isg_grid_exact(gamma: f64, thetas: &[f64], phis: &[f64]) -> Vec<f64> {
    let gamma = sanitize_gamma(gamma);
    let (tx, tw, tcut) = rule(gamma, thetas, 8);
    let (px, pw, pcut) = rule(gamma, phis, 8);
    let sin_p: Vec<f64> = px.iter().map(|p| p.sin()).collect();
    // Cumulative-in-phi inner integrals at the phi cuts, accumulated over theta nodes; the theta
    // cut positions are visited in node order.
    let mut order: Vec<usize> = (0..thetas.len()).collect();
    order.sort_by_key(|&i| tcut[i]);
    let mut out = vec![0.0; thetas.len() * phis.len()];
    let mut acc = vec![0.0; phis.len()];
    let mut pord: Vec<usize> = (0..phis.len()).collect();
    pord.sort_by_key(|&j| pcut[j]);
    let mut next = 0;
    let mut row = vec![0.0; phis.len()];
    for (k, (&t, &wt)) in tx.iter().zip(&tw).enumerate() {
        while next < order.len() && tcut[order[next]] == k {
            let i = order[next];
            out[i * phis.len()..(i + 1) * phis.len()].copy_from_slice(&acc);
            next += 1;
        }
        let st = t.sin();
        // inner cumulative integral over phi
        let mut s = 0.0;
        let mut jn = 0;
        for (m, (&sp, &wp)) in sin_p.iter().zip(&pw).enumerate() {
            while jn < pord.len() && pcut[pord[jn]] == m {
                row[pord[jn]] = s;
                jn += 1;
            }
            s += wp * (gamma * (st * sp - 1.0)).exp();
        }
        while jn < pord.len() {
            row[pord[jn]] = s;
            jn += 1;
        }
        for j in 0..phis.len() {
            acc[j] += wt * st * row[j];
        }
    }
    while next < order.len() {
        let i = order[next];
        out[i * phis.len()..(i + 1) * phis.len()].copy_from_slice(&acc);
        next += 1;
    }
    out
}

/// Exact unnormalized ISG `S(theta, phi)` for one point.
pub fn isg_exact(theta: f64, phi: f64, gamma: f64) -> f64 {
    isg_grid_exact(gamma, &[theta], &[phi])[0]
}

/// Exact normalized ISG `S(theta, phi) / S(pi, pi)`.
pub fn isg_normalized_exact(theta: f64, phi: f64, gamma: f64) -> f64 {
    isg_exact(theta, phi, gamma) / hemisphere_integral(sanitize_gamma(gamma))
}

/// Appendix polynomial coefficients `(g4, g3, g2, g1, g0)`.
pub const PAPER_G: [f64; 5] = [-2.6856e-6, 7e-4, -0.0571, 3.9529, 17.6028];
/// Appendix polynomial coefficients `(h4, h3, h2, h1, h0)`.
pub const PAPER_H: [f64; 5] = [-2.6875e-6, 7e-4, -0.0592, 3.9900, 17.5003];

fn quartic(c: &[f64; 5], gamma: f64) -> f64 {
    let x = gamma.clamp(1.0, 1e4) / 100.0;
    (((c[0] * x + c[1]) * x + c[2]) * x + c[3]) * x + c[4]
}

/// The paper's `g(gamma)` (sigmoid slope in theta); `gamma` clamped to the fit range 1..1e4.
pub fn paper_g(gamma: f64) -> f64 {
    quartic(&PAPER_G, sanitize_gamma(gamma))
}

/// The paper's `h(gamma)` (sigmoid slope in phi); `gamma` clamped to the fit range 1..1e4.
pub fn paper_h(gamma: f64) -> f64 {
    quartic(&PAPER_H, sanitize_gamma(gamma))
}

fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// The integral over `[t0, t1] x [p0, p1]` of a normalized ISG `s(theta, phi)` (its summed-area
/// difference, never negative).
pub fn summed_area_patch(s: impl Fn(f64, f64) -> f64, t0: f64, t1: f64, p0: f64, p1: f64) -> f64 {
    (s(t1, p1) - s(t0, p1) - s(t1, p0) + s(t0, p0)).max(0.0)
}

/// The paper's two-sigmoid fit of the normalized ISG (eq. 14).
pub fn paper_fit(theta: f64, phi: f64, gamma: f64) -> f64 {
    sigmoid(paper_g(gamma) * (theta - FRAC_PI_2)) * sigmoid(paper_h(gamma) * (phi - FRAC_PI_2))
}

/// Max and RMS absolute error of a normalized-ISG model against the exact one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitError {
    /// Largest absolute error over all sharpness values and grid points.
    pub max: f64,
    /// RMS over all sharpness values and grid points.
    pub rms: f64,
    /// Sharpness at which `max` occurs.
    pub worst_gamma: f64,
}

/// Error of `model(theta, phi, gamma)` (normalized ISG) against [`isg_grid_exact`] over
/// `gammas` and an `n x n` grid on `[0, pi]^2` refined around the lobe (half the points within
/// four lobe widths of `pi/2`).
pub fn fit_error(model: &dyn Fn(f64, f64, f64) -> f64, gammas: &[f64], n: usize) -> FitError {
    let mut max: f64 = 0.0;
    let mut worst = f64::NAN;
    let mut sum = 0.0;
    let mut count = 0usize;
    let n = n.max(2);
    for &g in gammas {
        let width = (4.0 / g.max(1e-3).sqrt()).min(FRAC_PI_2);
        let mut pts: Vec<f64> = (0..n).map(|i| PI * i as f64 / (n - 1) as f64).collect();
        pts.extend((0..n).map(|i| FRAC_PI_2 - width + 2.0 * width * i as f64 / (n - 1) as f64));
        let exact = isg_grid_exact(g, &pts, &pts);
        let norm = hemisphere_integral(g);
        for (i, &t) in pts.iter().enumerate() {
            for (j, &p) in pts.iter().enumerate() {
                let e = (model(t, p, g) - exact[i * pts.len() + j] / norm).abs();
                let e = if e.is_finite() { e } else { f64::INFINITY };
                if e > max {
                    max = e;
                    worst = g;
                }
                sum += e * e;
                count += 1;
            }
        }
    }
    FitError { max, rms: (sum / count.max(1) as f64).sqrt(), worst_gamma: worst }
}

/// Tabulated pre-integration of the normalized ISG (see the module docs).
#[derive(Clone, Debug)]
pub struct IsgTable {
    /// Levels per decade of `gamma`.
    pub per_decade: usize,
    /// Samples per angle axis (odd, centred on `pi/2`).
    pub n: usize,
    /// `log10` of the first level's sharpness.
    pub log_min: f64,
    /// Number of levels.
    pub levels: usize,
    /// `levels * n * n` normalized ISG values, `[level][theta][phi]`.
    pub data: Vec<f32>,
}

fn warp_k(gamma: f64) -> f64 {
    gamma.sqrt() + 0.5
}

/// Warped coordinate in `[-1, 1]` of angle `x` for a level of sharpness `gamma`.
fn warp(x: f64, k: f64) -> f64 {
    (k * (x - FRAC_PI_2)).atan() / (k * FRAC_PI_2).atan()
}

fn unwarp(v: f64, k: f64) -> f64 {
    FRAC_PI_2 + (v * (k * FRAC_PI_2).atan()).tan() / k
}

impl IsgTable {
    /// Builds the table: `per_decade` levels per decade of sharpness over `[GAMMA_MIN, GAMMA_MAX]`,
    /// `n` samples per angle (made odd, at least 5).
    pub fn build(per_decade: usize, n: usize) -> IsgTable {
        let per_decade = per_decade.max(1);
        let n = (n.max(5)) | 1;
        let log_min = GAMMA_MIN.log10();
        let levels = ((GAMMA_MAX.log10() - log_min) * per_decade as f64).round() as usize + 1;
        let mut data = Vec::with_capacity(levels * n * n);
        for l in 0..levels {
            let gamma = 10f64.powf(log_min + l as f64 / per_decade as f64);
            let k = warp_k(gamma);
            let pts: Vec<f64> =
                (0..n).map(|i| unwarp(-1.0 + 2.0 * i as f64 / (n - 1) as f64, k).clamp(0.0, PI)).collect();
            let s = isg_grid_exact(gamma, &pts, &pts);
            let norm = hemisphere_integral(gamma);
            data.extend(s.iter().map(|v| (v / norm).clamp(0.0, 1.0) as f32));
        }
        IsgTable { per_decade, n, log_min, levels, data }
    }

    /// The default table (16 levels per decade, 65 x 65 samples: 113 levels, 1.9 MB as f32).
    pub fn default_table() -> IsgTable {
        IsgTable::build(16, 65)
    }

    fn level_gamma(&self, l: usize) -> f64 {
        10f64.powf(self.log_min + l as f64 / self.per_decade as f64)
    }

    fn lookup_level(&self, l: usize, theta: f64, phi: f64) -> f64 {
        let k = warp_k(self.level_gamma(l));
        let n = self.n;
        let f = |x: f64| {
            let v = (warp(x.clamp(0.0, PI), k) + 1.0) * 0.5 * (n - 1) as f64;
            let i = (v.floor() as usize).min(n - 2);
            (i, (v - i as f64).clamp(0.0, 1.0))
        };
        let (i, a) = f(theta);
        let (j, b) = f(phi);
        let base = l * n * n;
        let d = |ii: usize, jj: usize| self.data[base + ii * n + jj] as f64;
        let top = d(i, j) * (1.0 - b) + d(i, j + 1) * b;
        let bot = d(i + 1, j) * (1.0 - b) + d(i + 1, j + 1) * b;
        top * (1.0 - a) + bot * a
    }

    /// Normalized ISG `S(theta, phi) / S(pi, pi)` for any sharpness (NaN sharpness counts as 0,
    /// NaN angles as 0). Result in `[0, 1]`.
    pub fn eval(&self, theta: f64, phi: f64, gamma: f64) -> f64 {
        let theta = if theta.is_nan() { 0.0 } else { theta };
        let phi = if phi.is_nan() { 0.0 } else { phi };
        let gamma = sanitize_gamma(gamma);
        let lg = gamma.max(GAMMA_MIN).log10();
        let x = ((lg - self.log_min) * self.per_decade as f64).clamp(0.0, (self.levels - 1) as f64);
        let l0 = (x.floor() as usize).min(self.levels.saturating_sub(2));
        let t = if self.levels > 1 { (x - l0 as f64).clamp(0.0, 1.0) } else { 0.0 };
        let mut out = 0.0;
        for (l, w) in [(l0, 1.0 - t), ((l0 + 1).min(self.levels - 1), t)] {
            if w == 0.0 {
                continue;
            }
            let gl = self.level_gamma(l);
            let s = ((gamma.max(GAMMA_MIN) + 1.0) / (gl + 1.0)).sqrt();
            let th = FRAC_PI_2 + (theta - FRAC_PI_2) * s;
            let ph = FRAC_PI_2 + (phi - FRAC_PI_2) * s;
            out += w * self.lookup_level(l, th, ph);
        }
        out.clamp(0.0, 1.0)
    }

    /// Normalized integral over the patch `[t0, t1] x [p0, p1]` (summed-area difference).
    pub fn patch(&self, t0: f64, t1: f64, p0: f64, p1: f64, gamma: f64) -> f64 {
        summed_area_patch(|t, p| self.eval(t, p, gamma), t0, t1, p0, p1)
    }

    /// Limiting angle `Delta`: half-width about `pi/2` such that the normalized ISG marginal
    /// `S(pi/2 - Delta, pi) / S(pi, pi) <= epsilon` (bisection; `pi/2` for broad lobes).
    pub fn limiting_angle(&self, gamma: f64, epsilon: f64) -> f64 {
        let eps = if epsilon.is_nan() { 0.01 } else { epsilon.clamp(1e-6, 0.5) };
        if self.eval(0.0, PI, gamma) >= eps || self.eval(1e-6, PI, gamma) >= eps {
            return FRAC_PI_2;
        }
        let (mut lo, mut hi) = (0.0, FRAC_PI_2);
        for _ in 0..50 {
            let mid = 0.5 * (lo + hi);
            if self.eval(FRAC_PI_2 - mid, PI, gamma) > eps {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }

    /// Limiting angles of every level (for the GPU, which interpolates them in `log10 gamma`).
    pub fn level_limiting_angles(&self, epsilon: f64) -> Vec<f32> {
        (0..self.levels).map(|l| self.limiting_angle(self.level_gamma(l), epsilon) as f32).collect()
    }

    /// Layout for the GPU (`glsl/include/isg.glsl`): header `[per_decade, n, log_min, levels]` as
    /// f32, then `levels` limiting angles for `epsilon`, then the data, then the paper's fit
    /// ([`PAPER_G`], [`PAPER_H`]: 10 values).
    pub fn to_gpu(&self, epsilon: f64) -> Vec<f32> {
        let mut v = vec![self.per_decade as f32, self.n as f32, self.log_min as f32, self.levels as f32];
        v.extend(self.level_limiting_angles(epsilon));
        v.extend_from_slice(&self.data);
        // the paper's fit (`isg_paper_poly` in glsl/include/isg.glsl): g's then h's coefficients
        v.extend(PAPER_G.iter().chain(&PAPER_H).map(|&c| c as f32));
        v
    }
}

/// A blocker sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre (world space).
    pub center: DVec3,
    /// Radius.
    pub radius: f64,
}

/// How the normalized ISG of a patch's corners is evaluated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum IsgModel {
    /// [`IsgTable::eval`], the tabulated pre-integration (default: the fit's error, see
    /// [`fit_error`], is what the table removes).
    #[default]
    Table,
    /// [`paper_fit`], eq. 14's two sigmoids with the appendix polynomials (the paper's).
    PaperFit,
}

/// Which patches a blocker sphere occludes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PatchRule {
    /// A patch whose centre direction lies in the sphere's projected cap (default).
    #[default]
    Centre,
    /// The paper's rule (section 4.1): a patch whose angular extent overlaps the cap's
    /// occluded ranges (rows meeting `theta_l +- psi_l`, in each row the cap's `phi` range at its
    /// widest over the row), so every patch the cap touches counts as wholly occluded
    /// (conservative: shadows grow by up to a patch). Thin-shell triangles keep the centre rule
    /// (the paper rasterizes them).
    Paper,
}

/// Parameters of the visibility integral (paper defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsgParams {
    /// Threshold of the limiting angle (paper: 0.01).
    pub epsilon: f64,
    /// Patches per side of the discretized region (paper: 100 to 400 patches, i.e. 10 to 20).
    pub patch_side: usize,
    /// The corners' normalized ISG: the table or the paper's sigmoid fit.
    pub model: IsgModel,
    /// Which patches a sphere occludes.
    pub rule: PatchRule,
}

impl Default for IsgParams {
    fn default() -> Self {
        IsgParams { epsilon: 0.01, patch_side: 16, model: IsgModel::Table, rule: PatchRule::Centre }
    }
}

/// The `phi` half-width of the cap (local centre `cl`, cosine radius `cos_psi`) at polar angle
/// `theta`: `Some(pi)` when the whole circle of latitude is inside, `None` when none of it is.
fn cap_half_width(theta: f64, cl: DVec3, cos_psi: f64) -> Option<f64> {
    let rhs = cos_psi - theta.cos() * cl.y;
    let den = theta.sin() * DVec3::new(cl.x, 0.0, cl.z).length();
    if den <= 1e-7 {
        return (rhs <= 0.0).then_some(PI);
    }
    let q = rhs / den;
    if q <= -1.0 {
        Some(PI)
    } else if q <= 1.0 {
        Some(q.acos())
    } else {
        None
    }
}

/// The paper's rule ([`PatchRule::Paper`]): marks in `occluded` (`side x side`, rows `theta`)
/// every patch of the region `pi/2 +- delta` whose extent overlaps the cap; true if any.
/// Mirror of `isg_mark_cap_paper` in `glsl/include/isg.glsl`.
fn mark_cap_paper(occluded: &mut [bool], side: usize, delta: f64, cl: DVec3, psi: f64) -> bool {
    let step = 2.0 * delta / side as f64;
    let phi0 = FRAC_PI_2 - delta;
    let thc = cl.y.clamp(-1.0, 1.0).acos();
    let phc = cl.z.atan2(cl.x);
    let cos_psi = psi.cos();
    let mut any = false;
    let r0 = ((thc - psi - phi0) / step).floor().max(0.0) as usize;
    let r1 = ((thc + psi - phi0) / step).ceil() - 1.0;
    if r1 < 0.0 {
        return false;
    }
    let r1 = (r1 as usize).min(side - 1);
    for i in r0..=r1 {
        let (t0, t1) = (phi0 + step * i as f64, phi0 + step * (i + 1) as f64);
        // the widest the cap gets over the row: at its edges or nearest the cap's centre
        let w =
            [t0, t1, thc.clamp(t0, t1)].into_iter().filter_map(|t| cap_half_width(t, cl, cos_psi)).fold(-1.0, f64::max);
        if w < 0.0 {
            continue;
        }
        for k in -1..=1 {
            let a = phc + std::f64::consts::TAU * k as f64 - w;
            let b = phc + std::f64::consts::TAU * k as f64 + w;
            let j0 = ((a - phi0) / step).floor().max(0.0);
            let j1 = (((b - phi0) / step).ceil() - 1.0).min((side - 1) as f64);
            if j1 < j0 {
                continue;
            }
            for j in j0 as usize..=j1 as usize {
                occluded[i * side + j] = true;
                any = true;
            }
        }
    }
    any
}

/// Orthonormal frame whose `z` is `axis` (the SG lobe axis); the same frame as
/// `isg_visible` in `glsl/include/isg.glsl` (so the patches coincide):
/// `x = normalize(X x z)` (`Y x z` when `|z.x| >= 0.9`), `y = z x x`.
pub fn local_frame(axis: DVec3) -> (DVec3, DVec3, DVec3) {
    let z = axis.try_normalize().unwrap_or(DVec3::Z);
    let x = if z.x.abs() < 0.9 { DVec3::X.cross(z) } else { DVec3::Y.cross(z) }.normalize();
    (x, z.cross(x), z)
}

/// Fraction of the hemisphere integral of the SG `exp(gamma (dot(axis, w) - 1))` that is visible
/// from `p` (normal `n`) through `spheres`, by the paper's patch method (section 4.1).
///
/// Spheres that contain or touch `p` (`|c - p| <= r (1 + 1e-4)`) are skipped: they are the
/// receiver's own proxy (a surface point lies on its own sphere set); spheres entirely below the
/// tangent plane of `n` are skipped (the surface itself hides them). Returns a value in `[0, 1]`;
/// 1 with no spheres.
pub fn visible_fraction(
    table: &IsgTable,
    p: DVec3,
    n: DVec3,
    axis: DVec3,
    gamma: f64,
    spheres: &[Sphere],
    params: &IsgParams,
) -> f64 {
    visible_fraction_with_triangles(table, p, n, axis, gamma, spheres, &[], params)
}

/// A thin-shell triangle (world space), an occluder from both sides.
pub type Triangle = [DVec3; 3];

/// Whether the direction `d` from `p` passes through the triangle (its projection on the
/// sphere of directions about `p`); `None` when the triangle is skipped: its plane contains `p`
/// or it lies entirely below the tangent plane of `n`.
pub fn triangle_projection(p: DVec3, n: DVec3, t: &Triangle) -> Option<impl Fn(DVec3) -> bool> {
    let (a, b, c) = (t[0] - p, t[1] - p, t[2] - p);
    if a.dot(n).max(b.dot(n)).max(c.dot(n)) <= 0.0 {
        return None;
    }
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    if !(la > 0.0 && lb > 0.0 && lc > 0.0 && (la * lb * lc).is_finite()) {
        return None;
    }
    let (nab, nbc, nca) = (a.cross(b), b.cross(c), c.cross(a));
    let det = a.dot(nbc);
    if det.abs() <= 1e-7 * la * lb * lc {
        return None;
    }
    let s = det.signum();
    Some(move |d: DVec3| s * d.dot(nab) >= 0.0 && s * d.dot(nbc) >= 0.0 && s * d.dot(nca) >= 0.0)
}

/// [`visible_fraction`] with thin-shell occluders too: every patch whose centre direction
/// passes through a triangle ([`triangle_projection`]) is occluded (the paper's projected
/// triangle meshes, section 5).
pub fn visible_fraction_with_triangles(
    table: &IsgTable,
    p: DVec3,
    n: DVec3,
    axis: DVec3,
    gamma: f64,
    spheres: &[Sphere],
    triangles: &[Triangle],
    params: &IsgParams,
) -> f64 {
    let side = params.patch_side.clamp(1, 64);
    let delta = table.limiting_angle(gamma, params.epsilon);
    let (fx, fy, fz) = local_frame(axis);
    let cone = (delta * std::f64::consts::SQRT_2).min(PI);
    let mut occluded = vec![false; side * side];
    let mut any = false;
    let n = n.try_normalize().unwrap_or(fz);
    for s in spheres {
        let d = s.center - p;
        let dist = d.length();
        if !(dist.is_finite() && s.radius.is_finite()) || s.radius <= 0.0 || dist <= s.radius * (1.0 + 1e-4) {
            continue;
        }
        if d.dot(n) < -s.radius {
            continue;
        }
        let c = d / dist;
        let psi = (s.radius / dist).clamp(0.0, 1.0).asin();
        let ang = c.dot(fz).clamp(-1.0, 1.0).acos();
        if ang - psi > cone {
            continue;
        }
        let cos_psi = psi.cos();
        let cl = DVec3::new(c.dot(fx), c.dot(fy), c.dot(fz));
        if params.rule == PatchRule::Paper {
            any = mark_cap_paper(&mut occluded, side, delta, cl, psi) || any;
            continue;
        }
        for i in 0..side {
            let t = FRAC_PI_2 - delta + 2.0 * delta * (i as f64 + 0.5) / side as f64;
            for j in 0..side {
                let ph = FRAC_PI_2 - delta + 2.0 * delta * (j as f64 + 0.5) / side as f64;
                if direction(t, ph).dot(cl) >= cos_psi {
                    occluded[i * side + j] = true;
                    any = true;
                }
            }
        }
    }
    for t in triangles {
        let Some(inside) = triangle_projection(p, n, t) else { continue };
        for i in 0..side {
            let th = FRAC_PI_2 - delta + 2.0 * delta * (i as f64 + 0.5) / side as f64;
            for j in 0..side {
                if occluded[i * side + j] {
                    continue;
                }
                let ph = FRAC_PI_2 - delta + 2.0 * delta * (j as f64 + 0.5) / side as f64;
                let dl = direction(th, ph);
                if inside(fx * dl.x + fy * dl.y + fz * dl.z) {
                    occluded[i * side + j] = true;
                    any = true;
                }
            }
        }
    }
    if !any {
        return 1.0;
    }
    let mut occ = 0.0;
    // The outer edges of the border patches extend to the hemisphere's boundary so that the
    // lobe's mass beyond the limiting angle (about 2 epsilon per axis) is attributed to them.
    let mut edges: Vec<f64> = (0..=side).map(|i| FRAC_PI_2 - delta + 2.0 * delta * i as f64 / side as f64).collect();
    edges[0] = 0.0;
    edges[side] = PI;
    for i in 0..side {
        for j in 0..side {
            if occluded[i * side + j] {
                let (t0, t1, p0, p1) = (edges[i], edges[i + 1], edges[j], edges[j + 1]);
                occ += match params.model {
                    IsgModel::Table => table.patch(t0, t1, p0, p1, gamma),
                    IsgModel::PaperFit => summed_area_patch(|t, p| paper_fit(t, p, gamma), t0, t1, p0, p1),
                };
            }
        }
    }
    (1.0 - occ).clamp(0.0, 1.0)
}

/// Brute-force reference of [`visible_fraction`]'s quantity (same sphere skipping rules):
/// visible fraction of the hemisphere integral by a `res x res` midpoint rule over `(theta, phi)`.
pub fn visible_fraction_brute(p: DVec3, n: DVec3, axis: DVec3, gamma: f64, spheres: &[Sphere], res: usize) -> f64 {
    visible_fraction_brute_with_triangles(p, n, axis, gamma, spheres, &[], res)
}

/// [`visible_fraction_brute`] with thin-shell triangles (same skipping rules as
/// [`visible_fraction_with_triangles`]).
pub fn visible_fraction_brute_with_triangles(
    p: DVec3,
    n: DVec3,
    axis: DVec3,
    gamma: f64,
    spheres: &[Sphere],
    triangles: &[Triangle],
    res: usize,
) -> f64 {
    let (fx, fy, fz) = local_frame(axis);
    let n = n.try_normalize().unwrap_or(fz);
    let kept: Vec<(DVec3, f64)> = spheres
        .iter()
        .filter_map(|s| {
            let d = s.center - p;
            let dist = d.length();
            if dist <= s.radius * (1.0 + 1e-4) || s.radius <= 0.0 || d.dot(n) < -s.radius {
                return None;
            }
            Some((d / dist, (1.0 - (s.radius / dist).powi(2)).max(0.0).sqrt()))
        })
        .collect();
    let tris: Vec<_> = triangles.iter().filter_map(|t| triangle_projection(p, n, t)).collect();
    let gamma = sanitize_gamma(gamma);
    // Midpoint rule refined about the lobe through a warp, as in the table.
    let k = warp_k(gamma);
    let (mut tot, mut vis) = (0.0, 0.0);
    let xs: Vec<(f64, f64)> = (0..res)
        .map(|i| {
            let v = -1.0 + 2.0 * (i as f64 + 0.5) / res as f64;
            let x = unwarp(v, k);
            // dx/dv
            let a = (k * FRAC_PI_2).atan();
            let dxdv = a / k / (v * a).cos().powi(2);
            (x, dxdv * 2.0 / res as f64)
        })
        .collect();
    for &(t, wt) in &xs {
        for &(ph, wp) in &xs {
            let dl = direction(t, ph);
            let w = (gamma * (dl.z - 1.0)).exp() * t.sin() * wt * wp;
            tot += w;
            let dw = fx * dl.x + fy * dl.y + fz * dl.z;
            if !kept.iter().any(|(c, cp)| dw.dot(*c) >= *cp) && !tris.iter().any(|inside| inside(dw)) {
                vis += w;
            }
        }
    }
    if tot > 0.0 {
        vis / tot
    } else {
        1.0
    }
}
