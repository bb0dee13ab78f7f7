//! BRDFs of [`penumbra_scene::BrdfKind`], evaluated and sampled in a local shading frame
//! (normal = +Z, tangent = +X). All functions take unit `wo` (towards the viewer) and `wi`
//! (towards the light) and return the BRDF value without the cosine factor.
//!
//! Definitions (the ground truth the GPU techniques are compared with):
//! - **Diffuse**: `albedo / pi`.
//! - **BlinnPhong** (normalized): `albedo / pi + specular * (s + 2) / (8 pi) * (n.h)^s`,
//!   `s = shininess`, the lobe of `penumbra_math::brdf::BlinnPhong` (so the SG mode differs only
//!   by the SG fit). Its directional albedo at normal incidence is exactly
//!   `(s + 2^(-s/2)) / (s + 4) < 1` (and lower elsewhere), so it never creates energy. No
//!   Fresnel term.
//! - **CookTorrance**: `albedo / pi + D G F / (4 cos_i cos_o)` with the GGX/Trowbridge-Reitz `D`,
//!   `alpha = roughness^2` (perceptual roughness, clamped to >= 1e-3), separable Smith GGX
//!   `G = G1(wi) G1(wo)` and Schlick's Fresnel with `F0 = specular`.
//! - **AshikhminShirley** (2000): specular
//!   `sqrt((nu+1)(nv+1)) / (8 pi) * (n.h)^((nu h_x^2 + nv h_y^2)/(1 - h_z^2)) / ((h.wi) max(cos_i, cos_o)) * F(h.wi)`
//!   with Schlick `F` (`Rs = specular`), plus the paper's coupled diffuse term
//!   `28 Rd / (23 pi) (1 - Rs) (1 - (1 - cos_i/2)^5) (1 - (1 - cos_o/2)^5)`, `Rd = albedo`.
//!   The exponents are `nu = shininess`, `nv = shininess` (isotropic) unless the material provides
//!   anisotropy; the tangent is dP/du of the mesh UVs.
//!
//! Each BRDF is sampled by a mixture of a cosine-weighted diffuse lobe and the specular lobe's
//! half-vector distribution, chosen with probability proportional to the luminance of
//! `albedo` and `specular`.

use crate::sampling::{cosine_hemisphere, luminance};
use glam::{Vec2, Vec3};
use penumbra_scene::{BrdfKind, Material};
use std::f32::consts::{FRAC_1_PI, PI, TAU};

/// A material's BRDF with precomputed parameters.
#[derive(Clone, Copy, Debug)]
pub struct Brdf {
    pub kind: BrdfKind,
    pub albedo: Vec3,
    pub specular: Vec3,
    /// GGX alpha (Cook-Torrance).
    pub alpha: f32,
    /// Blinn-Phong exponent.
    pub shininess: f32,
    /// Ashikhmin-Shirley exponents along the tangent and bitangent.
    pub nu: f32,
    pub nv: f32,
    /// Probability of sampling the specular lobe.
    pub p_spec: f32,
}

fn sanitize(v: Vec3) -> Vec3 {
    if v.is_finite() {
        v.max(Vec3::ZERO)
    } else {
        Vec3::ZERO
    }
}

fn finite_or(x: f32, d: f32) -> f32 {
    if x.is_finite() {
        x
    } else {
        d
    }
}

/// Schlick's Fresnel.
pub fn schlick(f0: Vec3, cos: f32) -> Vec3 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    f0 + (Vec3::ONE - f0) * (m2 * m2 * m)
}

/// Normalization of the Blinn-Phong lobe `(n.h)^s`: `(s + 2) / (8 pi)`.
pub fn blinn_phong_norm(s: f32) -> f32 {
    (s + 2.0) / (8.0 * PI)
}

/// Directional albedo of the white Blinn-Phong lobe at normal incidence:
/// `integral (s+2)/(8 pi) (n.h)^s cos dwi = (s + 2^(-s/2)) / (s + 4)`.
pub fn blinn_phong_normal_albedo(s: f64) -> f64 {
    (s + (-s / 2.0).exp2()) / (s + 4.0)
}

/// GGX normal distribution (`cos_h = n.h`).
pub fn ggx_d(alpha: f32, cos_h: f32) -> f32 {
    if cos_h <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let c2 = cos_h * cos_h;
    let d = c2 * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

/// Smith G1 for GGX.
pub fn ggx_g1(alpha: f32, cos: f32) -> f32 {
    if cos <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    2.0 * cos / (cos + (a2 + (1.0 - a2) * cos * cos).sqrt())
}

impl Brdf {
    pub fn from_material(m: &Material) -> Self {
        Self::new(m.kind, m.albedo, m.specular, m.roughness, m.shininess, None)
    }

    /// From raw parameters; `shininess_v` is the Ashikhmin-Shirley exponent along the
    /// bitangent (`None` = isotropic). Non-finite or negative inputs are sanitized.
    pub fn new(
        kind: BrdfKind,
        albedo: Vec3,
        specular: Vec3,
        roughness: f32,
        shininess: f32,
        shininess_v: Option<f32>,
    ) -> Self {
        let albedo = sanitize(albedo);
        let specular = sanitize(specular).min(Vec3::ONE);
        let roughness = finite_or(roughness, 1.0).clamp(0.0, 1.0);
        let shininess = finite_or(shininess, 1.0).clamp(0.0, 1e6);
        let alpha = (roughness * roughness).max(1e-3);
        let nu = shininess;
        let nv = shininess_v.map_or(shininess, |v| finite_or(v, shininess).clamp(0.0, 1e6));
        let (ld, ls) = (luminance(albedo), luminance(specular));
        let p_spec = match kind {
            BrdfKind::Diffuse => 0.0,
            _ if ls <= 0.0 => 0.0,
            _ if ld <= 0.0 => 1.0,
            _ => (ls / (ld + ls)).clamp(0.05, 0.95),
        };
        Brdf { kind, albedo, specular, alpha, shininess, nu, nv, p_spec }
    }

    /// BRDF value (no cosine). Zero unless both directions are above the surface.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let (co, ci) = (wo.z, wi.z);
        if co <= 0.0 || ci <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (wo + wi).normalize_or_zero();
        if h == Vec3::ZERO {
            return Vec3::ZERO;
        }
        match self.kind {
            BrdfKind::Diffuse => self.albedo * FRAC_1_PI,
            BrdfKind::BlinnPhong => {
                self.albedo * FRAC_1_PI
                    + self.specular * (blinn_phong_norm(self.shininess) * h.z.max(0.0).powf(self.shininess))
            }
            BrdfKind::CookTorrance => {
                let d = ggx_d(self.alpha, h.z);
                let g = ggx_g1(self.alpha, ci) * ggx_g1(self.alpha, co);
                let f = schlick(self.specular, wi.dot(h));
                self.albedo * FRAC_1_PI + f * (d * g / (4.0 * ci * co))
            }
            BrdfKind::AshikhminShirley => {
                let hdk = wi.dot(h).max(1e-6);
                let spec = as_norm(self.nu, self.nv) / (8.0 * PI) * as_lobe(self.nu, self.nv, h) / (hdk * ci.max(co));
                let f = schlick(self.specular, hdk);
                let p5 = |x: f32| {
                    let m = 1.0 - x / 2.0;
                    let m2 = m * m;
                    1.0 - m2 * m2 * m
                };
                let diff = self.albedo * (Vec3::ONE - self.specular) * (28.0 / (23.0 * PI) * p5(ci) * p5(co));
                diff + f * spec
            }
        }
    }

    /// The diffuse (Lambertian) part alone, for Diffuse, BlinnPhong and CookTorrance.
    pub fn eval_lambert(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        self.albedo * FRAC_1_PI
    }

    /// Solid-angle pdf of [`Brdf::sample`].
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let pd = wi.z * FRAC_1_PI;
        if self.p_spec <= 0.0 {
            return pd;
        }
        let h = (wo + wi).normalize_or_zero();
        let odh = wo.dot(h);
        if odh <= 0.0 {
            return (1.0 - self.p_spec) * pd;
        }
        let ph = match self.kind {
            BrdfKind::Diffuse => 0.0,
            BrdfKind::BlinnPhong => {
                let s = self.shininess;
                (s + 2.0) / TAU * h.z.max(0.0).powf(s + 1.0)
            }
            BrdfKind::CookTorrance => ggx_d(self.alpha, h.z) * h.z,
            BrdfKind::AshikhminShirley => as_norm(self.nu, self.nv) / TAU * as_lobe(self.nu, self.nv, h),
        };
        (1.0 - self.p_spec) * pd + self.p_spec * ph / (4.0 * odh)
    }

    /// Sample `wi` from three uniforms; `None` if the sample falls below the surface.
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<Vec3> {
        if wo.z <= 0.0 {
            return None;
        }
        if u_lobe >= self.p_spec {
            return Some(cosine_hemisphere(u)).filter(|w| w.z > 0.0);
        }
        let h = match self.kind {
            BrdfKind::Diffuse => return None,
            BrdfKind::BlinnPhong => {
                let cos_t = (1.0 - u.x).powf(1.0 / (self.shininess + 2.0));
                spherical(cos_t, TAU * u.y)
            }
            BrdfKind::CookTorrance => {
                let a2 = self.alpha * self.alpha;
                let cos2 = (1.0 - u.x) / (1.0 + (a2 - 1.0) * u.x);
                spherical(cos2.clamp(0.0, 1.0).sqrt(), TAU * u.y)
            }
            BrdfKind::AshikhminShirley => {
                let (nu, nv) = (self.nu, self.nv);
                let r = ((nu + 1.0) / (nv + 1.0)).sqrt();
                let first = |x: f32| (r * (std::f32::consts::FRAC_PI_2 * x).tan()).atan();
                let a = u.y;
                let phi = if a < 0.25 {
                    first(4.0 * a)
                } else if a < 0.5 {
                    PI - first(4.0 * (0.5 - a))
                } else if a < 0.75 {
                    PI + first(4.0 * (a - 0.5))
                } else {
                    TAU - first(4.0 * (1.0 - a))
                };
                let (s, c) = phi.sin_cos();
                let e = nu * c * c + nv * s * s;
                let cos_t = (1.0 - u.x).powf(1.0 / (e + 1.0));
                spherical(cos_t, phi)
            }
        };
        let wi = 2.0 * wo.dot(h) * h - wo;
        (wi.z > 0.0 && wo.dot(h) > 0.0).then_some(wi.normalize())
    }
}

fn spherical(cos_t: f32, phi: f32) -> Vec3 {
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)
}

fn as_norm(nu: f32, nv: f32) -> f32 {
    ((nu + 1.0) * (nv + 1.0)).sqrt()
}

/// `(n.h)^((nu h_x^2 + nv h_y^2) / (1 - h_z^2))`.
fn as_lobe(nu: f32, nv: f32, h: Vec3) -> f32 {
    if h.z <= 0.0 {
        return 0.0;
    }
    let s2 = h.x * h.x + h.y * h.y;
    let e = if s2 > 1e-12 { (nu * h.x * h.x + nv * h.y * h.y) / s2 } else { 0.5 * (nu + nv) };
    h.z.powf(e)
}
