//! Local lights of a frame ([`penumbra_scene::LightInstance`]) for direct lighting.
//!
//! - Point: radiant intensity `power` (W/sr), irradiance `power cos / d^2`.
//! - Spot: a point light times `smoothstep(cos(outer), cos(inner), cos(angle to the axis))`
//!   (hard cut-off when outer <= inner).
//! - Sphere: a sphere of `radius` emitting uniform radiance `power`, sampled uniformly in the
//!   cone it subtends. Lights are emitters only: they are invisible to camera rays and do not
//!   block other light.
//! - Directional: irradiance `power` (W/m^2 at normal incidence) arriving along `-direction`
//!   from infinitely far (a delta light; its shadow rays are unbounded).

use glam::{Vec2, Vec3};
use penumbra_scene::{LightInstance, LightKind};
use std::f32::consts::TAU;

#[derive(Clone, Copy, Debug)]
pub enum LocalLight {
    Point {
        pos: Vec3,
        intensity: Vec3,
    },
    Spot {
        pos: Vec3,
        axis: Vec3,
        cos_inner: f32,
        cos_outer: f32,
        intensity: Vec3,
    },
    Sphere {
        center: Vec3,
        radius: f32,
        radiance: Vec3,
    },
    /// `to_light`: the unit direction towards the light (minus the scene's `direction`).
    Directional {
        to_light: Vec3,
        irradiance: Vec3,
    },
}

/// A sampled light direction from a point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub wi: Vec3,
    /// Distance to the light along `wi` (for the shadow ray).
    pub dist: f32,
    /// Radiance (area lights) or `intensity / d^2` (delta lights) arriving along `wi`.
    pub li: Vec3,
    /// Solid-angle pdf, `None` for delta lights.
    pub pdf: Option<f32>,
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    if e1 <= e0 {
        return if x >= e0 { 1.0 } else { 0.0 };
    }
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl LocalLight {
    /// `None` for lights that cannot emit (zero or non-finite power, zero radius).
    pub fn new(l: &LightInstance) -> Option<Self> {
        let p = l.power;
        if !p.is_finite() || p.max_element() <= 0.0 || !l.position.is_finite() {
            return None;
        }
        match l.kind {
            LightKind::Directional => {
                let d = l.direction.normalize_or_zero();
                (d != Vec3::ZERO && d.is_finite())
                    .then_some(LocalLight::Directional { to_light: -d, irradiance: p.max(Vec3::ZERO) })
            }
            LightKind::Point => Some(LocalLight::Point { pos: l.position, intensity: p.max(Vec3::ZERO) }),
            LightKind::Spot { inner_deg, outer_deg } => {
                let axis = l.direction.normalize_or_zero();
                if axis == Vec3::ZERO || !axis.is_finite() {
                    return None;
                }
                let ci = inner_deg.clamp(0.0, 180.0).to_radians().cos();
                let co = outer_deg.clamp(0.0, 180.0).to_radians().cos();
                Some(LocalLight::Spot {
                    pos: l.position,
                    axis,
                    cos_inner: ci,
                    cos_outer: co,
                    intensity: p.max(Vec3::ZERO),
                })
            }
            LightKind::Sphere { radius } => (radius.is_finite() && radius > 0.0).then_some(LocalLight::Sphere {
                center: l.position,
                radius,
                radiance: p.max(Vec3::ZERO),
            }),
        }
    }

    /// The light's position (sphere: its centre), for equiangular distance sampling; `None` for
    /// a directional light.
    pub fn position(&self) -> Option<Vec3> {
        match self {
            LocalLight::Point { pos, .. } | LocalLight::Spot { pos, .. } => Some(*pos),
            LocalLight::Sphere { center, .. } => Some(*center),
            LocalLight::Directional { .. } => None,
        }
    }

    pub fn is_delta(&self) -> bool {
        !matches!(self, LocalLight::Sphere { .. })
    }

    /// Sample the light as seen from `x`.
    pub fn sample(&self, x: Vec3, u: Vec2) -> Option<LightSample> {
        match *self {
            LocalLight::Directional { to_light, irradiance } => {
                Some(LightSample { wi: to_light, dist: f32::MAX, li: irradiance, pdf: None })
            }
            LocalLight::Point { pos, intensity } => {
                let v = pos - x;
                let d2 = v.length_squared();
                (d2 > 0.0).then(|| {
                    let d = d2.sqrt();
                    LightSample { wi: v / d, dist: d, li: intensity / d2, pdf: None }
                })
            }
            LocalLight::Spot { pos, axis, cos_inner, cos_outer, intensity } => {
                let v = pos - x;
                let d2 = v.length_squared();
                if d2 <= 0.0 {
                    return None;
                }
                let d = d2.sqrt();
                let wi = v / d;
                let f = smoothstep(cos_outer, cos_inner, (-wi).dot(axis));
                (f > 0.0).then_some(LightSample { wi, dist: d, li: intensity * (f / d2), pdf: None })
            }
            LocalLight::Sphere { center, radius, radiance } => {
                let v = center - x;
                let d2 = v.length_squared();
                let r2 = radius * radius;
                if d2 <= r2 {
                    return None; // inside the light
                }
                let d = d2.sqrt();
                let axis = v / d;
                let sin2 = r2 / d2;
                // 1 - cos(theta_max), stable for small lights.
                let one_minus = sin2 / (1.0 + (1.0 - sin2).max(0.0).sqrt());
                let cos_t = 1.0 - u.x * one_minus;
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                let phi = TAU * u.y;
                let f = crate::sampling::Frame::new(axis, Vec3::ZERO);
                let wi = f.to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)).normalize();
                let t = self.hit(x, wi).unwrap_or(d - radius);
                Some(LightSample { wi, dist: t, li: radiance, pdf: Some(1.0 / (TAU * one_minus)) })
            }
        }
    }

    /// Distance along `wi` from `x` to the sphere light's surface (area lights only).
    pub fn hit(&self, x: Vec3, wi: Vec3) -> Option<f32> {
        let LocalLight::Sphere { center, radius, .. } = *self else { return None };
        let oc = x - center;
        let b = oc.dot(wi);
        let c = oc.length_squared() - radius * radius;
        if c <= 0.0 {
            return None;
        }
        let disc = b * b - c;
        if disc < 0.0 {
            return None;
        }
        let t = -b - disc.sqrt();
        (t > 0.0).then_some(t)
    }

    /// Radiance of an area light along `wi` from `x` and its sampling pdf, if `wi` hits it.
    pub fn hit_radiance_pdf(&self, x: Vec3, wi: Vec3) -> Option<(f32, Vec3, f32)> {
        let LocalLight::Sphere { center, radius, radiance } = *self else { return None };
        let t = self.hit(x, wi)?;
        let sin2 = radius * radius / (center - x).length_squared();
        let one_minus = sin2 / (1.0 + (1.0 - sin2).max(0.0).sqrt());
        Some((t, radiance, 1.0 / (TAU * one_minus)))
    }
}
