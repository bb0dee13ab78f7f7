//! SG approximations of specular BRDF lobes as functions of the outgoing direction:
//! Blinn-Phong and Cook-Torrance with one lobe, anisotropic Ashikhmin-Shirley with seven
//! (as in the integral-SG paper, after Wang et al. 2009).
//!
//! # Conventions
//! Local shading frame: normal `n = +Z`, tangent `+X` (Ashikhmin-Shirley exponent `nu`),
//! bitangent `+Y` (`nv`). `wi` (incident, towards the light) and `wo` (outgoing, towards the
//! viewer) are unit vectors in that frame with `z > 0`. BRDF values are in 1/sr, without the
//! cosine. Lobes are SGs in `wi` for a fixed `wo`.
//!
//! # Fits
//! * *Warp* (closed form, GPU friendly; Wang et al. 2009): the half-vector distribution is an
//!   SG about `n` (Blinn-Phong `(n.h)^s ~ exp(s (n.h - 1))`, Beckmann `D ~ exp(2/m^2 (n.h - 1)) /
//!   (pi m^2)`), moved to `wi` space by the spherical warp `axis = reflect(-wo, n)`,
//!   `lambda_i = lambda_h / (4 |wo.n|)`; the remaining factors (Fresnel, shadowing,
//!   `1 / (4 cos cos)`) are evaluated at the lobe axis.
//! * *Optimised* ([`fit_brdf_lobes`]): Levenberg–Marquardt on all lobe parameters (axis as two
//!   tangent offsets, `ln lambda`, `ln mu`) minimising the cosine-weighted L2 error over the
//!   upper hemisphere, started from the warp (one lobe) or from seven warped lobes spread along
//!   the anisotropy (Ashikhmin-Shirley).
//! * The error reported is the relative, cosine-weighted L2 error over the upper hemisphere,
//!   `sqrt(int_{z>0} (f - sum G)^2 cos / int_{z>0} f^2 cos)`, computed with a lobe-aligned
//!   quadrature (test `brdf` prints a table).

use crate::quad::{gauss_legendre, orthonormal_basis};
use crate::sg::Sg;
use glam::DVec3;
use std::f64::consts::PI;

fn schlick(f0: f64, c: f64) -> f64 {
    f0 + (1.0 - f0) * (1.0 - c.clamp(0.0, 1.0)).powi(5)
}

fn reflect_about_n(wo: DVec3) -> DVec3 {
    DVec3::new(-wo.x, -wo.y, wo.z)
}

/// Normalised Blinn-Phong specular lobe `f = (s + 2) / (8 pi) (n.h)^s`.
#[derive(Clone, Copy, Debug)]
pub struct BlinnPhong {
    /// Exponent `s` (glossiness; the paper's figures use 1000).
    pub shininess: f64,
}

impl BlinnPhong {
    /// BRDF value (0 below the horizon).
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        let h = (wi + wo).normalize();
        (self.shininess + 2.0) / (8.0 * PI) * h.z.max(0.0).powf(self.shininess)
    }
    /// One-lobe warp approximation for outgoing direction `wo`.
    pub fn sg_warp(&self, wo: DVec3) -> Sg {
        let c = wo.z.max(1e-4);
        Sg::new(reflect_about_n(wo), self.shininess / (4.0 * c), (self.shininess + 2.0) / (8.0 * PI))
    }
}

/// Cook-Torrance with a Beckmann distribution (roughness `m`), Schlick Fresnel and the
/// separable Smith shadowing of the GGX form with width `m`, `G = G1(n.wi) G1(n.wo)` (as the
/// reference renderer's exact Cook-Torrance): `f = D F G / (4 (n.wi)(n.wo))`.
///
/// The Cook-Torrance V-cavity G used before is 1 at the warp's axis, so the warped lobe's
/// amplitude grew as `1 / (n.wo)^2` at grazing view (single-pixel fireflies at silhouettes);
/// Smith's G1 goes to 0 there and keeps the amplitude below about `1 / (pi m^4)`.
#[derive(Clone, Copy, Debug)]
pub struct CookTorrance {
    /// Beckmann roughness `m` (RMS slope).
    pub roughness: f64,
    /// Fresnel reflectance at normal incidence.
    pub f0: f64,
}

impl CookTorrance {
    fn beckmann(&self, c: f64) -> f64 {
        let m2 = self.roughness * self.roughness;
        let c2 = c * c;
        (-(1.0 - c2) / (c2 * m2)).exp() / (PI * m2 * c2 * c2)
    }
    /// Smith G1 of the GGX form with width `alpha` at cosine `c` (0 at and below the horizon).
    pub fn smith_g1(alpha: f64, c: f64) -> f64 {
        if c <= 0.0 {
            return 0.0;
        }
        let a2 = alpha * alpha;
        2.0 * c / (c + (a2 + (1.0 - a2) * c * c).sqrt())
    }
    fn geometry(&self, wi: DVec3, wo: DVec3) -> f64 {
        Self::smith_g1(self.roughness, wi.z) * Self::smith_g1(self.roughness, wo.z)
    }
    /// BRDF value (0 below the horizon).
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        let h = (wi + wo).normalize();
        self.beckmann(h.z) * schlick(self.f0, wo.dot(h)) * self.geometry(wi, wo) / (4.0 * wi.z * wo.z)
    }
    /// One-lobe warp approximation for outgoing direction `wo` (Wang et al. 2009).
    pub fn sg_warp(&self, wo: DVec3) -> Sg {
        let m2 = self.roughness * self.roughness;
        let c = wo.z.max(1e-4);
        let axis = reflect_about_n(wo);
        let h = DVec3::Z;
        let extra = schlick(self.f0, wo.dot(h)) * self.geometry(axis, wo) / (4.0 * axis.z.max(1e-4) * c);
        Sg::new(axis, 2.0 / m2 / (4.0 * c), extra / (PI * m2))
    }
}

/// Anisotropic Ashikhmin-Shirley specular lobe
/// `f = sqrt((nu+1)(nv+1)) / (8 pi) (n.h)^((nu hx^2 + nv hy^2)/(1 - hz^2)) / ((h.wo) max(n.wi, n.wo)) F(h.wo)`.
#[derive(Clone, Copy, Debug)]
pub struct AshikhminShirley {
    /// Exponent along the tangent `+X`.
    pub nu: f64,
    /// Exponent along the bitangent `+Y`.
    pub nv: f64,
    /// Fresnel reflectance at normal incidence.
    pub f0: f64,
}

impl AshikhminShirley {
    /// BRDF value (0 below the horizon).
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        let h = (wi + wo).normalize();
        let s2 = (1.0 - h.z * h.z).max(0.0);
        let e = if s2 > 1e-300 { (self.nu * h.x * h.x + self.nv * h.y * h.y) / s2 } else { 0.5 * (self.nu + self.nv) };
        let hk = h.dot(wo).max(1e-12);
        ((self.nu + 1.0) * (self.nv + 1.0)).sqrt() / (8.0 * PI) * h.z.max(0.0).powf(e) / (hk * wi.z.max(wo.z))
            * schlick(self.f0, hk)
    }

    /// Seven warped lobes spread along the wider anisotropy direction in half-vector space
    /// (start point of the optimised fit).
    pub fn sg7_initial(&self, wo: DVec3) -> Vec<Sg> {
        let (wide, nwide, nnarrow) =
            if self.nu <= self.nv { (DVec3::X, self.nu, self.nv) } else { (DVec3::Y, self.nv, self.nu) };
        let sigma_wide = 1.0 / nwide.max(1e-6).sqrt();
        (0..7)
            .map(|k| {
                let off = (k as f64 - 3.0) * 0.6 * sigma_wide;
                let h = (DVec3::Z + wide * off.tan().clamp(-10.0, 10.0)).normalize();
                let voh = wo.dot(h).max(1e-3);
                let wi = (2.0 * voh * h - wo).normalize();
                // lobe width in h space ~ narrow exponent; warped to wi space
                let lam_h = (nnarrow + nwide) * 0.5;
                let mu = self.eval(if wi.z > 0.0 { wi } else { reflect_about_n(wo) }, wo).max(1e-6) * 0.5;
                Sg::new(wi, lam_h / (4.0 * voh), mu)
            })
            .collect()
    }
}

/// Nodes of 7-point Gauss-Hermite quadrature (`int exp(-x^2) f(x) dx ~ sum w_k f(x_k)`).
pub const GAUSS_HERMITE_7_NODES: [f64; 7] = [
    -2.651961356835233,
    -1.673551628767471,
    -0.816287882858965,
    0.0,
    0.816287882858965,
    1.673551628767471,
    2.651961356835233,
];
/// Weights of 7-point Gauss-Hermite quadrature (they sum to sqrt(pi)).
pub const GAUSS_HERMITE_7_WEIGHTS: [f64; 7] = [
    0.000971781245099520,
    0.0545155828191270,
    0.425607252610128,
    0.810264617556807,
    0.425607252610128,
    0.0545155828191270,
    0.000971781245099520,
];

impl AshikhminShirley {
    /// Seven lobes in closed form, no optimisation (what `sg_as_lobes` in `glsl/include/sg.glsl`
    /// computes per pixel, so that roughness maps and animated exponents need no table). Near the
    /// normal the half-vector factor `(n.h)^((nu hx^2 + nv hy^2) / (1 - hz^2))` is the anisotropic
    /// Gaussian `exp(-(nu sx^2 + nv sy^2) / 2)` of the half vector's slopes; along the wide
    /// direction (the smaller exponent) it is the narrow Gaussian convolved with a Gaussian of
    /// variance `1/n_wide - 1/n_narrow`, and 7-point Gauss-Hermite quadrature of that convolution
    /// gives seven lobes of sharpness `n_narrow` (about their half vectors) along the wide
    /// direction with weights `w_k sqrt(n_narrow / n_wide / pi)`. Each is warped to incident
    /// directions as the one-lobe warp (axis: `wo` mirrored about the lobe's half vector `h_k`,
    /// sharpness `n_narrow / (4 wo.h_k)`) and scaled by the BRDF's remaining factors at its
    /// centre (normalisation, `1 / (h.wo max(n.wi, n.wo))`, Schlick's Fresnel). A lobe whose centre
    /// is below the horizon gets amplitude 0.
    pub fn sg7_hermite(&self, wo: DVec3) -> Vec<Sg> {
        let nu = self.nu.clamp(1e-3, 1e6);
        let nv = self.nv.clamp(1e-3, 1e6);
        let x_wide = nu <= nv;
        let (n_wide, n_narrow) = (nu.min(nv), nu.max(nv));
        let sp = (1.0 / n_wide - 1.0 / n_narrow).max(0.0).sqrt() * std::f64::consts::SQRT_2;
        let c = (n_narrow / n_wide / PI).sqrt() * ((nu + 1.0) * (nv + 1.0)).sqrt() / (8.0 * PI);
        GAUSS_HERMITE_7_NODES
            .iter()
            .zip(GAUSS_HERMITE_7_WEIGHTS)
            .map(|(xi, wt)| {
                let s = sp * xi;
                let h = if x_wide { DVec3::new(s, 0.0, 1.0) } else { DVec3::new(0.0, s, 1.0) }.normalize();
                let vh = wo.dot(h);
                let wi = 2.0 * vh * h - wo;
                let lambda = n_narrow / (4.0 * vh.max(1e-4));
                let mu = if vh > 0.0 && wi.z > 0.0 && wo.z > 0.0 {
                    schlick(self.f0, vh) * c * wt / (vh * wi.z.max(wo.z))
                } else {
                    0.0
                };
                Sg { axis: wi.normalize(), lambda, mu }
            })
            .collect()
    }
}

/// Result of a BRDF lobe fit.
#[derive(Clone, Debug)]
pub struct BrdfFit {
    /// Lobes in `wi` (local frame) for the given `wo`.
    pub lobes: Vec<Sg>,
    /// Relative cosine-weighted L2 error over the upper hemisphere (module docs).
    pub rel_l2_error: f64,
}

/// Quadrature over the upper hemisphere aligned with `axis` (lobe of sharpness about
/// `lambda`): polar coordinates about `axis` with `x = 1 - cos t` on geometrically growing
/// intervals (8 Gauss–Legendre nodes each) times `nphi` azimuths; directions with `z <= 0` are
/// dropped. Returns `(direction, solid-angle weight)`.
pub fn hemisphere_rule_about(axis: DVec3, lambda: f64, nphi: usize) -> Vec<(DVec3, f64)> {
    let axis = axis.normalize();
    let (t1, t2) = orthonormal_basis(axis);
    let (gx, gw) = gauss_legendre(8);
    let mut breaks = vec![0.0];
    let mut x = (0.02 / lambda.max(1e-6)).min(0.5);
    while x < 2.0 {
        breaks.push(x);
        x *= 2.0;
    }
    breaks.push(2.0);
    let mut out = Vec::new();
    for w in breaks.windows(2) {
        let (a, b) = (w[0], w[1]);
        for (xi, wi) in gx.iter().zip(&gw) {
            let x = 0.5 * (a + b) + 0.5 * (b - a) * xi;
            let wx = 0.5 * (b - a) * wi;
            let ct = 1.0 - x;
            let st = (x * (2.0 - x)).max(0.0).sqrt();
            for j in 0..nphi {
                let phi = 2.0 * PI * (j as f64 + 0.5) / nphi as f64;
                let d = axis * ct + (t1 * phi.cos() + t2 * phi.sin()) * st;
                if d.z > 0.0 {
                    out.push((d, wx * 2.0 * PI / nphi as f64));
                }
            }
        }
    }
    out
}

/// Relative cosine-weighted L2 error of `lobes` against `f(wi)` on the rule `rule`.
pub fn lobe_error(f: &dyn Fn(DVec3) -> f64, lobes: &[Sg], rule: &[(DVec3, f64)]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (d, w) in rule {
        let t = f(*d);
        let g = Sg::eval_sum(lobes, *d);
        num += w * d.z * (g - t) * (g - t);
        den += w * d.z * t * t;
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        0.0
    }
}

/// Levenberg–Marquardt fit of `init.len()` SGs to `f(wi)` (cosine-weighted L2 over the upper
/// hemisphere, on `rule`), `iterations` at most. Non-finite steps are rejected, so the result
/// is never worse than `init`.
pub fn fit_brdf_lobes(f: &dyn Fn(DVec3) -> f64, init: &[Sg], rule: &[(DVec3, f64)], iterations: usize) -> BrdfFit {
    let j = init.len();
    let frames: Vec<(DVec3, DVec3, DVec3)> = init
        .iter()
        .map(|g| {
            let (a, b) = orthonormal_basis(g.axis);
            (g.axis, a, b)
        })
        .collect();
    let np = 4 * j;
    let unpack = |p: &[f64]| -> Vec<Sg> {
        (0..j)
            .map(|k| {
                let (a0, t1, t2) = frames[k];
                let axis = (a0 + t1 * p[4 * k] + t2 * p[4 * k + 1]).normalize();
                Sg { axis, lambda: p[4 * k + 2].clamp(-20.0, 25.0).exp(), mu: p[4 * k + 3].clamp(-60.0, 60.0).exp() }
            })
            .collect()
    };
    let targets: Vec<f64> = rule.iter().map(|(d, _)| f(*d)).collect();
    let sw: Vec<f64> = rule.iter().map(|(d, w)| (w * d.z).sqrt()).collect();
    let resid = |p: &[f64]| -> Vec<f64> {
        let lobes = unpack(p);
        rule.iter().enumerate().map(|(i, (d, _))| sw[i] * (Sg::eval_sum(&lobes, *d) - targets[i])).collect()
    };
    let cost = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let mut p: Vec<f64> = init.iter().flat_map(|g| [0.0, 0.0, g.lambda.max(1e-8).ln(), g.mu.max(1e-30).ln()]).collect();
    let mut r = resid(&p);
    let mut c = cost(&r);
    let mut damping = 1e-3;
    let n = rule.len();
    for _ in 0..iterations {
        // forward-difference Jacobian
        let mut jac = vec![0.0; n * np];
        for q in 0..np {
            let h = 1e-6 * (1.0 + p[q].abs());
            let mut pp = p.clone();
            pp[q] += h;
            let rp = resid(&pp);
            for i in 0..n {
                jac[i * np + q] = (rp[i] - r[i]) / h;
            }
        }
        let mut jtj = vec![0.0; np * np];
        let mut jtr = vec![0.0; np];
        for i in 0..n {
            let row = &jac[i * np..(i + 1) * np];
            for a in 0..np {
                if row[a] == 0.0 {
                    continue;
                }
                jtr[a] += row[a] * r[i];
                for b in a..np {
                    jtj[a * np + b] += row[a] * row[b];
                }
            }
        }
        for a in 0..np {
            for b in 0..a {
                jtj[a * np + b] = jtj[b * np + a];
            }
        }
        let mut improved = false;
        for _ in 0..8 {
            let mut m = jtj.clone();
            for a in 0..np {
                m[a * np + a] += damping * (jtj[a * np + a] + 1e-12);
            }
            let Some(delta) = solve_dense(&m, &jtr, np) else {
                damping *= 10.0;
                continue;
            };
            let pn: Vec<f64> = p.iter().zip(&delta).map(|(a, d)| a - d).collect();
            let rn = resid(&pn);
            let cn = cost(&rn);
            if cn.is_finite() && cn < c {
                p = pn;
                r = rn;
                let rel = (c - cn) / c.max(1e-300);
                c = cn;
                damping = (damping / 3.0).max(1e-9);
                improved = rel > 1e-10;
                break;
            }
            damping *= 4.0;
        }
        if !improved {
            break;
        }
    }
    let lobes = unpack(&p);
    let rel_l2_error = lobe_error(f, &lobes, rule);
    BrdfFit { lobes, rel_l2_error }
}

fn solve_dense(m: &[f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    // Cholesky (m is SPD after damping)
    let y = crate::nnls::cholesky_solve(&mut m.to_vec(), n, b.to_vec(), None)?;
    y.iter().all(|v| v.is_finite()).then_some(y)
}

/// One optimised lobe for Blinn-Phong at `wo` (started from the warp).
pub fn blinn_phong_sg(b: &BlinnPhong, wo: DVec3) -> BrdfFit {
    let init = b.sg_warp(wo);
    let rule = hemisphere_rule_about(init.axis, init.lambda, 48);
    fit_brdf_lobes(&|wi| b.eval(wi, wo), &[init], &rule, 40)
}

/// One optimised lobe for Cook-Torrance at `wo` (started from the warp).
pub fn cook_torrance_sg(c: &CookTorrance, wo: DVec3) -> BrdfFit {
    let init = c.sg_warp(wo);
    let rule = hemisphere_rule_about(init.axis, init.lambda, 48);
    fit_brdf_lobes(&|wi| c.eval(wi, wo), &[init], &rule, 40)
}

/// Seven optimised lobes for Ashikhmin-Shirley at `wo`.
pub fn ashikhmin_shirley_sg7(a: &AshikhminShirley, wo: DVec3) -> BrdfFit {
    let init = a.sg7_initial(wo);
    let lam = init.iter().map(|g| g.lambda).fold(0.0, f64::max);
    let rule = hemisphere_rule_about(reflect_about_n(wo), lam, 64);
    fit_brdf_lobes(&|wi| a.eval(wi, wo), &init, &rule, 60)
}
