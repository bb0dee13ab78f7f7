//! Spherical Gaussians (SGs).
//!
//! `G(w; p, lambda, mu) = mu * exp(lambda * (dot(p, w) - 1))` with unit lobe axis `p`, sharpness
//! `lambda >= 0` (1/steradian-ish: the lobe's angular standard deviation is about
//! `1/sqrt(lambda)` radians) and amplitude `mu` (radiance, BRDF value, ... at the lobe centre).
//! [`Sg`] is the f64 version, [`Sg32`] the f32 version with the same formulas (the GLSL include
//! `glsl/include/sg.glsl` mirrors `Sg32`).
//!
//! # Numerical formulation (valid for `lambda` in `[0, 1e5]` and beyond, no NaN/Inf)
//! * Evaluation uses `dot(p, w) - 1 = -|p - w|^2 / 2` (exact for unit vectors), which keeps full
//!   relative precision of the exponent near the lobe axis where sharp lobes live.
//! * Product: `G1 G2 = mu1 mu2 exp(lm - l1 - l2) G(w; u/lm, lm, 1)`, `u = l1 p1 + l2 p2`,
//!   `lm = |u|`. The exponent `lm - l1 - l2 = -l1 l2 |p1 - p2|^2 / (lm + l1 + l2)` is computed in
//!   that form (no cancellation, always `<= 0`), `exp(lambda)` is never formed. Exactly opposite
//!   lobes of equal sharpness give `lm = 0`: the product is the constant `mu1 mu2 exp(-2 l)` and
//!   the axis is arbitrary (we keep `p1`).
//! * Sphere integral `2 pi mu (1 - exp(-2 lambda)) / lambda` is evaluated with `expm1`, limit
//!   `4 pi mu` at `lambda = 0`.
//! * Inner product `int G1 G2 = 2 pi mu1 mu2 exp(lm - l1 - l2) (1 - exp(-2 lm)) / lm` with the
//!   combined exponent above.
//!
//! # Hemisphere integral
//! `int_{dot(n,w)>0} G(w) dw` has no elementary closed form. Two versions:
//! * [`Sg::hemisphere_integral`] (f64): exact up to ~1e-12 relative. With `x = 1 - cos t` (t the
//!   angle from the lobe axis) the azimuthal extent of the hemisphere is analytic, the parts of the
//!   `x` range where the circle is fully inside/outside are integrated analytically, and the
//!   remaining band `x in [1 - s, 1 + s]` (s = sine of the angle between axis and normal) is
//!   integrated by adaptive Gauss–Kronrod after the substitution `x = 1 - s cos(psi)`, which
//!   removes the square-root end-point singularities.
//! * [`Sg::hemisphere_integral_approx`] / [`Sg32::hemisphere_integral_approx`] / GLSL: the
//!   approximation of Tokuyoshi 2022 ("Accurate Diffuse Lighting from Spherical Gaussian
//!   Lights"): an interpolation between the exact upper (`2 pi (1 - e)/lambda`, axis = normal) and
//!   lower (`2 pi e (1 - e) / lambda`, axis = -normal, `e = exp(-lambda)`) integrals with factor
//!   `0.5 + 0.5 erf(t c) / erf(t)`, `c = dot(p, n)`,
//!   `t = lambda sqrt((0.5 lambda + A) / ((lambda + B) lambda + C))`, with the paper's fitted
//!   `A = 0.65173, B = 1.34183, C = 7.22167`. It is exact at `c = -1, 0, 1` and for
//!   `lambda -> 0`. Measured against the exact form (test `hemisphere_approx_error`, grid
//!   `lambda in [1e-4, 1e5]` x `c in [-1, 1]`): absolute error at most 0.44% of the full-sphere
//!   integral `2 pi mu (1 - exp(-2 lambda))/lambda`; relative error at most 2.5% where the
//!   hemisphere integral is at least 10% of the full-sphere integral (it grows, up to ~35%, where
//!   the lobe is mostly below the horizon and the integral is only 1-10% of the full one).
//!
//! # Clamped cosine
//! [`clamped_cosine_sg`] approximates `max(0, dot(n, w))` by `G(w; n, 2.133, 1.170)`, the fit of
//! Wang et al. 2009 ("All-frequency rendering of dynamic, spatially-varying reflectance"), used by
//! the integral-SG paper. Its relative L2 error over the sphere is 17.7% (test
//! `clamped_cosine_fit_error`, which also verifies it is within 1% of the L2-optimal single lobe,
//! found at `lambda = 2.144, mu = 1.177`); the irradiance from a constant environment is
//! `3.398 L` instead of `pi L` (+8.2%): the lobe's tail below the horizon counts. Integrating the
//! product lobe over the upper hemisphere only ([`irradiance_sg_cosine_hemisphere`]) removes most
//! of that bias (+0.5%/-0.5%/-3.8% in test `convolution_and_irradiance_vs_quadrature`, against
//! +6%/+24%/+26% for the full-sphere inner product). Both stay far off for sharp lights (14% low
//! 48 degrees off the normal, 17% high at normal incidence); the GPU techniques' diffuse term uses
//! [`cosine_irradiance`] instead (the lobe as a von Mises-Fisher distribution, within 2%).

use crate::quad;
use crate::special::{erf, one_minus_exp_neg_over_x, one_minus_exp_neg_over_x_f32};
use glam::{DVec3, Vec3};

/// Sharpness of the clamped-cosine SG fit of Wang et al. 2009 (see module docs).
pub const CLAMPED_COSINE_LAMBDA: f64 = 2.133;
/// Amplitude of the clamped-cosine SG fit of Wang et al. 2009 (see module docs).
pub const CLAMPED_COSINE_MU: f64 = 1.170;

/// Tokuyoshi 2022 hemispherical-integral steepness constants (see module docs).
const TOKU_A: f64 = 0.651_732_882_690_705_6;
const TOKU_B: f64 = 1.341_828_003_314_128_8;
const TOKU_C: f64 = 7.221_668_779_895_671;

macro_rules! sg_common {
    ($Sg:ident, $F:ty, $V:ty, $pi:expr, $omeox:path) => {
        /// A spherical Gaussian `mu * exp(lambda * (dot(axis, w) - 1))`; see the module docs.
        #[derive(Clone, Copy, Debug, PartialEq)]
        pub struct $Sg {
            /// Unit lobe axis.
            pub axis: $V,
            /// Sharpness `lambda >= 0`.
            pub lambda: $F,
            /// Amplitude (value at the lobe axis).
            pub mu: $F,
        }

        impl $Sg {
            /// New lobe; `axis` is normalised (a zero/non-finite axis becomes +Z) and `lambda`
            /// is clamped to `>= 0` (NaN becomes 0).
            pub fn new(axis: $V, lambda: $F, mu: $F) -> Self {
                let axis = axis.try_normalize().unwrap_or(<$V>::Z);
                let lambda = if lambda > 0.0 { lambda } else { 0.0 };
                Self { axis, lambda, mu }
            }

            /// Value at unit direction `w`.
            #[inline]
            pub fn eval(&self, w: $V) -> $F {
                let d = self.axis - w;
                self.mu * (-0.5 * self.lambda * d.length_squared()).exp()
            }

            /// The product of two SGs as one SG (exact). See the module docs for the stable form.
            pub fn product(&self, o: &Self) -> Self {
                let (axis, lm, log_scale) = Self::product_parts(self, o);
                Self { axis, lambda: lm, mu: self.mu * o.mu * log_scale.exp() }
            }

            /// `(axis, lambda, log_scale)` of the product: `G1 G2 = mu1 mu2 exp(log_scale)
            /// exp(lambda (dot(axis, w) - 1))`, `log_scale <= 0`.
            pub fn product_parts(a: &Self, b: &Self) -> ($V, $F, $F) {
                let u = a.axis * a.lambda + b.axis * b.lambda;
                let lm = u.length();
                let d2 = (a.axis - b.axis).length_squared();
                let denom = lm + a.lambda + b.lambda;
                let log_scale = if denom > 0.0 { -a.lambda * b.lambda * d2 / denom } else { 0.0 };
                let axis = if lm > 0.0 { u / lm } else { a.axis };
                (axis, lm, log_scale)
            }

            /// Integral over the whole sphere: `2 pi mu (1 - exp(-2 lambda)) / lambda`
            /// (`4 pi mu` at `lambda = 0`).
            #[inline]
            pub fn sphere_integral(&self) -> $F {
                4.0 * $pi * self.mu * $omeox(2.0 * self.lambda)
            }

            /// Inner product `int_S2 G1(w) G2(w) dw` (exact, combined exponents).
            pub fn inner_product(&self, o: &Self) -> $F {
                let (_, lm, log_scale) = Self::product_parts(self, o);
                4.0 * $pi * self.mu * o.mu * log_scale.exp() * $omeox(2.0 * lm)
            }

            /// Convolution with a lighting made of SGs: `int_S2 L(w) G(w) dw`, `L = sum lights`
            /// (the SG-lighting version of the paper's `mu Gamma_L(a, lambda)`).
            pub fn convolve(&self, lights: &[Self]) -> $F {
                lights.iter().map(|l| self.inner_product(l)).sum()
            }

            /// Approximate integral over the hemisphere `dot(normal, w) > 0` (Tokuyoshi 2022;
            /// error in the module docs). `normal` must be unit length.
            pub fn hemisphere_integral_approx(&self, normal: $V) -> $F {
                let l = self.lambda;
                let c = self.axis.dot(normal).clamp(-1.0, 1.0);
                let e = (-l).exp();
                let f = Self::hemisphere_lerp_factor(c, l);
                // lerp(e, 1, f) * 2 pi (1 - e) / lambda
                2.0 * $pi * self.mu * (e + (1.0 - e) * f) * $omeox(l)
            }

            /// Normalised-erf interpolation factor of Tokuyoshi 2022; limit `(1 + c)/2` at
            /// `lambda -> 0`.
            fn hemisphere_lerp_factor(c: $F, l: $F) -> $F {
                let a = TOKU_A as $F;
                let b = TOKU_B as $F;
                let cc = TOKU_C as $F;
                let t = l * ((0.5 * l + a) / ((l + b) * l + cc)).sqrt();
                let et = erf(t as f64) as $F;
                if et > 0.0 {
                    (0.5 + 0.5 * (erf((t * c) as f64) as $F) / et).clamp(0.0, 1.0)
                } else {
                    0.5 + 0.5 * c
                }
            }
        }
    };
}

sg_common!(Sg, f64, DVec3, std::f64::consts::PI, one_minus_exp_neg_over_x);
sg_common!(Sg32, f32, Vec3, std::f32::consts::PI, one_minus_exp_neg_over_x_f32);

impl Sg {
    /// f32 copy.
    pub fn to_f32(&self) -> Sg32 {
        Sg32 { axis: self.axis.as_vec3(), lambda: self.lambda as f32, mu: self.mu as f32 }
    }

    /// Integral over the hemisphere `dot(normal, w) > 0`, exact to ~1e-12 relative (adaptive
    /// quadrature of a smooth 1-D integrand; see the module docs). Cost: a few hundred `exp`.
    pub fn hemisphere_integral(&self, normal: DVec3) -> f64 {
        let n = normal.try_normalize().unwrap_or(DVec3::Z);
        let l = self.lambda;
        let c = self.axis.dot(n).clamp(-1.0, 1.0);
        let s = self.axis.cross(n).length().min(1.0);
        let two_pi = 2.0 * std::f64::consts::PI;
        // int_a^b exp(-l x) dx = exp(-l a) (b - a) (1 - exp(-l (b - a)))/(l (b - a))
        let seg = |a: f64, b: f64| (-l * a).exp() * (b - a) * one_minus_exp_neg_over_x(l * (b - a));
        let x1 = 1.0 - s;
        let x2 = 1.0 + s;
        let mut total = 0.0;
        if c > 0.0 {
            total += two_pi * seg(0.0, x1);
        } else if c < 0.0 {
            total += two_pi * seg(x2, 2.0);
        }
        if s > 0.0 {
            // band: x = 1 - s cos(psi), exp(-l x) = exp(-l x1) exp(-l s (1 - cos psi))
            let band = |psi: f64| -> f64 {
                let cp = psi.cos();
                let sp = psi.sin();
                let denom = (1.0 - s * s * cp * cp).max(0.0).sqrt();
                let q = if denom > 0.0 { (-c * cp / denom).clamp(-1.0, 1.0) } else { 0.0 };
                let arc = 2.0 * q.acos();
                (-l * s * (1.0 - cp)).exp() * arc * s * sp
            };
            // breakpoints where the exponential decays: psi ~ k / sqrt(l s)
            let scale = 1.0 / (l * s).max(1e-300).sqrt();
            let breaks: Vec<f64> = (0..12).map(|k| scale * 2f64.powi(k - 3)).collect();
            let v = quad::integrate_adaptive(band, 0.0, std::f64::consts::PI, &breaks, 0.0, 1e-13, 400);
            total += (-l * x1).exp() * v;
        }
        self.mu * total
    }

    /// Evaluation of an SG sum (e.g. an SG lighting) at `w`.
    pub fn eval_sum(lobes: &[Sg], w: DVec3) -> f64 {
        lobes.iter().map(|g| g.eval(w)).sum()
    }
}

impl Sg32 {
    /// f64 copy.
    pub fn to_f64(&self) -> Sg {
        Sg { axis: self.axis.as_dvec3(), lambda: self.lambda as f64, mu: self.mu as f64 }
    }
}

/// SG approximation of the clamped cosine `max(0, dot(n, w))` about the unit normal `n`
/// (Wang et al. 2009: `lambda = 2.133`, `mu = 1.170`; error in the module docs).
pub fn clamped_cosine_sg(n: DVec3) -> Sg {
    Sg::new(n, CLAMPED_COSINE_LAMBDA, CLAMPED_COSINE_MU)
}

/// f32 version of [`clamped_cosine_sg`].
pub fn clamped_cosine_sg32(n: Vec3) -> Sg32 {
    Sg32::new(n, CLAMPED_COSINE_LAMBDA as f32, CLAMPED_COSINE_MU as f32)
}

/// Irradiance `int L(w) max(0, dot(n, w)) dw` of an SG lighting, with the clamped cosine replaced
/// by [`clamped_cosine_sg`] (full-sphere inner products; the paper's `L_d` without visibility).
pub fn irradiance_sg_cosine(lights: &[Sg], n: DVec3) -> f64 {
    clamped_cosine_sg(n).convolve(lights)
}

/// Irradiance of an SG lighting with the product `G_k * G_cos` integrated over the upper
/// hemisphere only (exact hemisphere integral): removes the light that the cosine SG's tail
/// picks up from below the horizon.
pub fn irradiance_sg_cosine_hemisphere(lights: &[Sg], n: DVec3) -> f64 {
    let c = clamped_cosine_sg(n);
    lights.iter().map(|l| l.product(&c).hemisphere_integral(n)).sum()
}

/// Quadrature points of [`cosine_irradiance`] (and of `sg_cosine_integral` in
/// `glsl/include/sg.glsl`, which mirrors it).
pub const COSINE_IRRADIANCE_POINTS: usize = 8;

/// `int_S2 G(w) max(0, dot(n, w)) dw` of one SG lobe: its sphere integral times the expected
/// clamped cosine under the lobe read as a von Mises-Fisher distribution. With `t = dot(w, axis)`
/// (density `exp(lambda t)` on [-1, 1]) and `c = dot(axis, n)`, `dot(w, n) = c t + sqrt(1 - c^2)
/// sqrt(1 - t^2) cos(phi)` with `phi` uniform, whose clamped mean over `phi` is closed-form
/// (`(u phi0 + v sin phi0) / pi`, `u = c t`, `v` the second term's amplitude, `cos phi0 = -u / v`);
/// the mean over `t` is a midpoint rule in the CDF of `t` with [`COSINE_IRRADIANCE_POINTS`]
/// points. Error at most 2% of the lobe's irradiance at normal incidence for every sharpness
/// (test `cosine_irradiance_vs_quadrature`), where the clamped-cosine SG
/// ([`irradiance_sg_cosine_hemisphere`]) is 14% low for a sharp light 48 degrees off the normal
/// and 17% high at normal incidence: the diffuse term of every SG technique under a studio or sun
/// environment was that far off.
pub fn cosine_irradiance(lobe: &Sg, n: DVec3) -> f64 {
    let n = n.try_normalize().unwrap_or(DVec3::Z);
    let l = lobe.lambda.max(1e-3);
    let c = lobe.axis.dot(n).clamp(-1.0, 1.0);
    let sc = (1.0 - c * c).max(0.0).sqrt();
    let e2 = (-2.0 * l).exp();
    let k = COSINE_IRRADIANCE_POINTS;
    let mut mean = 0.0;
    for i in 0..k {
        let s = (i as f64 + 0.5) / k as f64;
        let t = (1.0 + (s * (1.0 - e2) + e2).ln() / l).clamp(-1.0, 1.0);
        mean += clamped_mean(c * t, sc * (1.0 - t * t).max(0.0).sqrt());
    }
    lobe.sphere_integral() * mean / k as f64
}

/// Mean of `max(0, u + v cos(phi))` over `phi` uniform in [0, 2 pi), `v >= 0`.
fn clamped_mean(u: f64, v: f64) -> f64 {
    if v <= u.abs() {
        return u.max(0.0);
    }
    let q = (-u / v).clamp(-1.0, 1.0);
    let phi0 = q.acos();
    (u * phi0 + v * (1.0 - q * q).max(0.0).sqrt()) / std::f64::consts::PI
}

/// An SG with RGB amplitude (shared axis and sharpness), e.g. one lobe of a fitted environment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SgRgb {
    /// Unit lobe axis.
    pub axis: DVec3,
    /// Sharpness.
    pub lambda: f64,
    /// Linear RGB amplitude.
    pub mu: DVec3,
}

impl SgRgb {
    /// Value at unit direction `w`.
    pub fn eval(&self, w: DVec3) -> DVec3 {
        self.mu * (-0.5 * self.lambda * (self.axis - w).length_squared()).exp()
    }
    /// The scalar lobe of channel `c` (0 = R, 1 = G, 2 = B).
    pub fn channel(&self, c: usize) -> Sg {
        Sg { axis: self.axis, lambda: self.lambda, mu: self.mu[c] }
    }
    /// The lobe with unit amplitude.
    pub fn unit(&self) -> Sg {
        Sg { axis: self.axis, lambda: self.lambda, mu: 1.0 }
    }
    /// Sum of a lobe set at `w`.
    pub fn eval_sum(lobes: &[SgRgb], w: DVec3) -> DVec3 {
        lobes.iter().map(|g| g.eval(w)).sum()
    }
    /// `int_S2 L(w) G(w) dw` for an RGB lighting `L` and a scalar lobe `g`.
    pub fn convolve(lights: &[SgRgb], g: &Sg) -> DVec3 {
        lights.iter().map(|l| l.mu * g.inner_product(&l.unit())).sum()
    }
}
