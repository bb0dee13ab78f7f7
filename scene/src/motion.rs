//! Motion over time: keyframe tracks, rigid motions, procedural deformations, and the glTF
//! rig (node hierarchy, animations, skins, morph targets). Everything is a pure function of
//! the time `t` in seconds, so evaluation is deterministic.

use crate::MeshData;
use glam::{Mat4, Quat, Vec3};
use std::f32::consts::TAU;
use std::sync::Arc;

/// How a [`Track`] interpolates between keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Interp {
    Step,
    #[default]
    Linear,
}

/// Values that can be interpolated.
pub trait Lerp: Clone {
    fn lerp_to(&self, other: &Self, t: f32) -> Self;
}
impl Lerp for f32 {
    fn lerp_to(&self, o: &Self, t: f32) -> Self {
        self + (o - self) * t
    }
}
impl Lerp for Vec3 {
    fn lerp_to(&self, o: &Self, t: f32) -> Self {
        self.lerp(*o, t)
    }
}
impl Lerp for Quat {
    fn lerp_to(&self, o: &Self, t: f32) -> Self {
        self.slerp(*o, t).normalize()
    }
}
impl Lerp for Vec<f32> {
    fn lerp_to(&self, o: &Self, t: f32) -> Self {
        self.iter().zip(o).map(|(a, b)| a + (b - a) * t).collect()
    }
}

/// Keyframes: strictly increasing `times` (seconds), one value per time. Before the first key
/// the first value holds; after the last the last value holds unless `looping`, in which case
/// time wraps modulo the last key's time.
#[derive(Clone, Debug, PartialEq)]
pub struct Track<T> {
    pub times: Vec<f32>,
    pub values: Vec<T>,
    pub interp: Interp,
    pub looping: bool,
}

impl<T: Lerp> Track<T> {
    /// A track; `Err` when empty, lengths differ, or times are not finite and increasing.
    pub fn new(times: Vec<f32>, values: Vec<T>, interp: Interp, looping: bool) -> Result<Self, String> {
        if times.is_empty() {
            return Err("keyframe track has no keys".into());
        }
        if times.len() != values.len() {
            return Err(format!("keyframe track has {} times but {} values", times.len(), values.len()));
        }
        if times.iter().any(|t| !t.is_finite()) {
            return Err("keyframe time is NaN or infinite".into());
        }
        if times.windows(2).any(|w| w[1] <= w[0]) {
            return Err("keyframe times must be strictly increasing".into());
        }
        Ok(Track { times, values, interp, looping })
    }

    pub fn duration(&self) -> f32 {
        *self.times.last().unwrap_or(&0.0)
    }

    pub fn sample(&self, t: f32) -> T {
        let n = self.times.len();
        let mut t = if t.is_finite() { t } else { 0.0 };
        let end = self.times[n - 1];
        if self.looping && end > 0.0 && t > end {
            t = t.rem_euclid(end);
        }
        if n == 1 || t <= self.times[0] {
            return self.values[0].clone();
        }
        if t >= end {
            return self.values[n - 1].clone();
        }
        let k = self.times.partition_point(|&x| x <= t).clamp(1, n - 1);
        let (t0, t1) = (self.times[k - 1], self.times[k]);
        match self.interp {
            Interp::Step => self.values[k - 1].clone(),
            Interp::Linear => self.values[k - 1].lerp_to(&self.values[k], (t - t0) / (t1 - t0)),
        }
    }

    /// True when all values are equal (the track does not change anything).
    pub fn is_constant(&self) -> bool
    where
        T: PartialEq,
    {
        self.values.windows(2).all(|w| w[0] == w[1])
    }
}

/// A rigid world-space motion `M(t)`; an object's world transform is `M(t) * base`.
#[derive(Clone, Debug, PartialEq, Default)]
pub enum RigidMotion {
    #[default]
    Static,
    /// Keyframed translation / rotation / scale (each optional), composed as T * R * S.
    Keyframes { translation: Option<Track<Vec3>>, rotation: Option<Track<Quat>>, scale: Option<Track<Vec3>> },
    /// Spin about `axis` through `center` at `speed` radians per second.
    Spin { axis: Vec3, center: Vec3, speed: f32 },
    /// Rolling without slipping along a circle of radius `radius` around `center` (in the
    /// plane y = center.y), ball radius `ball_radius`, one lap per `period` seconds, starting
    /// at angle `phase` (radians). The object's base should be centred at the origin.
    Roll { center: Vec3, radius: f32, ball_radius: f32, period: f32, phase: f32 },
    /// Drop from `height` above the rest pose under `gravity` (m/s^2) after `delay`
    /// seconds, bouncing with coefficient of restitution `restitution`; tumbles about `axis`
    /// by `spin` radians during the first fall and lands in the rest orientation.
    Fall { height: f32, gravity: f32, restitution: f32, delay: f32, axis: Vec3, spin: f32 },
    /// Oscillate: translation `amplitude * sin(2 pi t / period + phase)`.
    Oscillate { amplitude: Vec3, period: f32, phase: f32 },
}

impl RigidMotion {
    pub fn is_static(&self) -> bool {
        match self {
            RigidMotion::Static => true,
            RigidMotion::Keyframes { translation, rotation, scale } => {
                translation.as_ref().is_none_or(|t| t.is_constant())
                    && rotation.as_ref().is_none_or(|t| t.is_constant())
                    && scale.as_ref().is_none_or(|t| t.is_constant())
            }
            RigidMotion::Spin { speed, .. } => *speed == 0.0,
            RigidMotion::Roll { period, .. } => !period.is_finite() || *period == 0.0,
            RigidMotion::Fall { height, spin, .. } => *height == 0.0 && *spin == 0.0,
            RigidMotion::Oscillate { amplitude, period, .. } => *amplitude == Vec3::ZERO || *period == 0.0,
        }
    }

    /// `M(t)`.
    pub fn eval(&self, t: f32) -> Mat4 {
        match self {
            RigidMotion::Static => Mat4::IDENTITY,
            RigidMotion::Keyframes { translation, rotation, scale } => Mat4::from_scale_rotation_translation(
                scale.as_ref().map_or(Vec3::ONE, |s| s.sample(t)),
                rotation.as_ref().map_or(Quat::IDENTITY, |r| r.sample(t)),
                translation.as_ref().map_or(Vec3::ZERO, |p| p.sample(t)),
            ),
            RigidMotion::Spin { axis, center, speed } => {
                let axis = axis.try_normalize().unwrap_or(Vec3::Y);
                Mat4::from_translation(*center)
                    * Mat4::from_axis_angle(axis, speed * t)
                    * Mat4::from_translation(-*center)
            }
            RigidMotion::Roll { center, radius, ball_radius, period, phase } => {
                let w = TAU / period;
                let a = phase + w * t;
                let pos = *center + Vec3::new(a.cos(), 0.0, -a.sin()) * *radius;
                // Rolling without slipping: angular velocity (up x v) / b. In the frame that
                // turns with the path (rate w about Y) it is the constant
                // omega = -(R w / b) r0 - w Y, so O(t) = Ry(w t) * exp(t omega).
                let r0 = Vec3::new(phase.cos(), 0.0, -phase.sin());
                let omega = -r0 * (radius * w / ball_radius.max(1e-6)) - Vec3::Y * w;
                let spin = match omega.try_normalize() {
                    Some(axis) => Mat4::from_axis_angle(axis, omega.length() * t),
                    None => Mat4::IDENTITY,
                };
                Mat4::from_translation(pos) * Mat4::from_rotation_y(w * t) * spin
            }
            RigidMotion::Fall { height, gravity, restitution, delay, axis, spin } => {
                let (y, first_fall_left) = fall_offset(t - delay, *height, *gravity, *restitution);
                let t_land = (2.0 * height / gravity.max(1e-6)).sqrt();
                let frac = if t_land > 0.0 { first_fall_left / t_land } else { 0.0 };
                let axis = axis.try_normalize().unwrap_or(Vec3::X);
                Mat4::from_translation(Vec3::Y * y) * Mat4::from_axis_angle(axis, spin * frac)
            }
            RigidMotion::Oscillate { amplitude, period, phase } => {
                Mat4::from_translation(*amplitude * (TAU * t / period + phase).sin())
            }
        }
    }
}

/// Height above rest of a body dropped from `h` at time 0 (t < 0: still at `h`), and the
/// time left until the first landing (0 after it).
fn fall_offset(t: f32, h: f32, g: f32, e: f32) -> (f32, f32) {
    let g = g.max(1e-6);
    let t1 = (2.0 * h.max(0.0) / g).sqrt();
    if t <= 0.0 {
        return (h, t1);
    }
    if t < t1 {
        return (h - 0.5 * g * t * t, t1 - t);
    }
    // Bounces: launch speed v_k = e^k * v0, each flight lasts 2 v_k / g.
    let e = e.clamp(0.0, 0.95);
    let mut v = g * t1 * e;
    let mut start = t1;
    for _ in 0..64 {
        let dur = 2.0 * v / g;
        if v < 1e-3 {
            break;
        }
        if t < start + dur {
            let s = t - start;
            return ((v * s - 0.5 * g * s * s).max(0.0), 0.0);
        }
        start += dur;
        v *= e;
    }
    (0.0, 0.0)
}

/// Procedural and glTF-driven vertex deformations, applied in object space.
#[derive(Clone, Debug, PartialEq)]
pub enum Deformation {
    /// A travelling wave along `direction` (in XZ) displacing vertices along +Y:
    /// `dy = amplitude * sin(2 pi (d.p / wavelength - t / period)) * pin(p)` where `pin` ramps
    /// from 0 at the minimum of `d.p` over the mesh to 1 at the maximum when `pinned` (a cloth
    /// held at one edge), else 1. Normals are recomputed.
    Wave { amplitude: f32, wavelength: f32, period: f32, direction: Vec3, pinned: bool },
    /// Squash and stretch along Y about the mesh's lowest point, volume preserving:
    /// `s(t) = 1 - amount * (0.5 - 0.5 cos(2 pi t / period))`, y scaled by s, x and z by
    /// 1/sqrt(s). Normals are recomputed.
    Squash { amount: f32, period: f32 },
    /// glTF morph targets of a mesh, weights from the rig's animation (or the defaults).
    Morph { rig: Arc<Rig>, node: usize, targets: Vec<MorphTarget>, default_weights: Vec<f32> },
    /// glTF linear-blend skinning; the result is in the rig's root space.
    Skin { rig: Arc<Rig>, skin: usize, joints: Vec<[u16; 4]>, weights: Vec<[f32; 4]> },
}

/// One morph target: per-vertex deltas.
#[derive(Clone, Debug, PartialEq)]
pub struct MorphTarget {
    pub positions: Vec<Vec3>,
    pub normals: Option<Vec<Vec3>>,
}

impl Deformation {
    /// Whether the deformation changes over time.
    pub fn is_animated(&self) -> bool {
        match self {
            Deformation::Wave { amplitude, period, .. } => *amplitude != 0.0 && *period != 0.0,
            Deformation::Squash { amount, period } => *amount != 0.0 && *period != 0.0,
            Deformation::Morph { rig, node, .. } => rig.animation.is_some_and(|a| {
                rig.animations[a].channels.iter().any(|c| c.node == *node && matches!(c.target, Channel::Weights(_)))
            }),
            Deformation::Skin { rig, skin, .. } => rig.animation.is_some_and(|a| {
                let anim = &rig.animations[a];
                rig.skins[*skin]
                    .joints
                    .iter()
                    .any(|&j| anim.channels.iter().any(|c| rig.is_ancestor_or_self(c.node, j)))
            }),
        }
    }

    /// Apply to `mesh` (which holds the result of the previous deformations) at time `t`.
    pub fn apply(&self, mesh: &mut MeshData, rest: &MeshData, t: f32) {
        match self {
            Deformation::Wave { amplitude, wavelength, period, direction, pinned } => {
                let d = Vec3::new(direction.x, 0.0, direction.z).try_normalize().unwrap_or(Vec3::X);
                let (lo, hi) = rest
                    .positions
                    .iter()
                    .fold((f32::MAX, f32::MIN), |(lo, hi), p| (lo.min(p.dot(d)), hi.max(p.dot(d))));
                let span = (hi - lo).max(1e-6);
                for (i, p) in mesh.positions.iter_mut().enumerate() {
                    let x = rest.positions[i].dot(d);
                    let pin = if *pinned { ((x - lo) / span).clamp(0.0, 1.0) } else { 1.0 };
                    let ph = TAU * (x / wavelength.max(1e-6) - t / period);
                    p.y += amplitude * ph.sin() * pin;
                }
                mesh.recompute_normals();
            }
            Deformation::Squash { amount, period } => {
                let base = rest.positions.iter().fold(f32::MAX, |m, p| m.min(p.y));
                let s = (1.0 - amount * (0.5 - 0.5 * (TAU * t / period).cos())).max(0.05);
                let sx = 1.0 / s.sqrt();
                for p in mesh.positions.iter_mut() {
                    *p = Vec3::new(p.x * sx, base + (p.y - base) * s, p.z * sx);
                }
                mesh.recompute_normals();
            }
            Deformation::Morph { rig, node, targets, default_weights } => {
                let w = rig.morph_weights(*node, t).unwrap_or_else(|| default_weights.clone());
                for (k, tgt) in targets.iter().enumerate() {
                    let wk = w.get(k).copied().unwrap_or(0.0);
                    if wk == 0.0 {
                        continue;
                    }
                    for (p, d) in mesh.positions.iter_mut().zip(&tgt.positions) {
                        *p += *d * wk;
                    }
                    if let Some(nd) = &tgt.normals {
                        for (n, d) in mesh.normals.iter_mut().zip(nd) {
                            *n += *d * wk;
                        }
                    }
                }
                for n in &mut mesh.normals {
                    *n = n.try_normalize().unwrap_or(Vec3::Y);
                }
            }
            Deformation::Skin { rig, skin, joints, weights } => {
                let mats = rig.joint_matrices(*skin, t);
                for i in 0..mesh.positions.len() {
                    let (j, w) = (joints[i], weights[i]);
                    let mut m = Mat4::ZERO;
                    let mut total = 0.0;
                    for k in 0..4 {
                        if w[k] != 0.0 {
                            if let Some(jm) = mats.get(j[k] as usize) {
                                m += *jm * w[k];
                                total += w[k];
                            }
                        }
                    }
                    if total <= 0.0 {
                        continue;
                    }
                    let m = m * (1.0 / total);
                    mesh.positions[i] = m.transform_point3(mesh.positions[i]);
                    mesh.normals[i] = m.transform_vector3(mesh.normals[i]).try_normalize().unwrap_or(Vec3::Y);
                }
            }
        }
    }
}

/// What an animation channel drives.
#[derive(Clone, Debug, PartialEq)]
pub enum Channel {
    Translation(Track<Vec3>),
    Rotation(Track<Quat>),
    Scale(Track<Vec3>),
    Weights(Track<Vec<f32>>),
}

#[derive(Clone, Debug, PartialEq)]
pub struct AnimChannel {
    pub node: usize,
    pub target: Channel,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Animation {
    pub name: String,
    pub channels: Vec<AnimChannel>,
    /// Length in seconds; playback loops with this period.
    pub duration: f32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Skin {
    /// Node index of each joint.
    pub joints: Vec<usize>,
    pub inverse_bind: Vec<Mat4>,
}

/// A glTF node hierarchy with its animations and skins, shared by every object made from the
/// file. `animation` selects the animation that plays (looping).
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    pub parent: Vec<Option<usize>>,
    /// Rest local transform (translation, rotation, scale) of each node.
    pub rest: Vec<(Vec3, Quat, Vec3)>,
    pub animations: Vec<Animation>,
    pub skins: Vec<Skin>,
    pub animation: Option<usize>,
}

impl Rig {
    fn is_ancestor_or_self(&self, anc: usize, mut n: usize) -> bool {
        for _ in 0..self.parent.len() + 1 {
            if n == anc {
                return true;
            }
            match self.parent.get(n).copied().flatten() {
                Some(p) => n = p,
                None => return false,
            }
        }
        false
    }

    /// Checks that every node's global transform (and every skin joint matrix) is finite at
    /// rest and at each key time of each animation (and halfway between keys), so that
    /// huge-but-finite input cannot overflow into NaN/Inf during playback.
    pub fn check_finite(&self) -> Result<(), String> {
        let mut times = vec![0.0f32];
        for a in &self.animations {
            for c in &a.channels {
                let ts: &[f32] = match &c.target {
                    Channel::Translation(k) | Channel::Scale(k) => &k.times,
                    Channel::Rotation(k) => &k.times,
                    Channel::Weights(k) => &k.times,
                };
                for w in ts.windows(2) {
                    times.push(0.5 * (w[0] + w[1]));
                }
                times.extend_from_slice(ts);
            }
        }
        times.sort_by(f32::total_cmp);
        times.dedup();
        let anims: Vec<Option<usize>> = std::iter::once(None).chain((0..self.animations.len()).map(Some)).collect();
        for anim in anims {
            let rig = Rig { animation: anim, ..self.clone() };
            for &t in &times {
                for n in 0..self.parent.len() {
                    if !rig.global(n, t).is_finite() {
                        return Err(format!("node {n} has a non-finite (overflowing) transform at t = {t}"));
                    }
                }
                for (s, _) in self.skins.iter().enumerate() {
                    if rig.joint_matrices(s, t).iter().any(|m| !m.is_finite()) {
                        return Err(format!("skin {s} has a non-finite (overflowing) joint matrix at t = {t}"));
                    }
                }
                for a in &rig.animations {
                    for c in &a.channels {
                        if let Channel::Weights(_) = c.target {
                            if rig.morph_weights(c.node, t).is_some_and(|w| w.iter().any(|x| !x.is_finite())) {
                                return Err(format!("node {} has non-finite morph weights at t = {t}", c.node));
                            }
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// Whether node `n`'s global transform changes over time.
    pub fn node_animated(&self, n: usize) -> bool {
        self.animation.is_some_and(|a| {
            self.animations[a]
                .channels
                .iter()
                .any(|c| !matches!(c.target, Channel::Weights(_)) && self.is_ancestor_or_self(c.node, n))
        })
    }

    fn local(&self, n: usize, t: f32) -> Mat4 {
        let (mut tr, mut r, mut s) = self.rest[n];
        if let Some(a) = self.animation {
            let anim = &self.animations[a];
            let tt = if anim.duration > 0.0 { t.rem_euclid(anim.duration) } else { 0.0 };
            // The end of a loop maps to its start; evaluate exactly `duration` as the end.
            let tt = if t > 0.0 && tt == 0.0 { anim.duration } else { tt };
            for c in anim.channels.iter().filter(|c| c.node == n) {
                match &c.target {
                    Channel::Translation(k) => tr = k.sample(tt),
                    Channel::Rotation(k) => r = k.sample(tt),
                    Channel::Scale(k) => s = k.sample(tt),
                    Channel::Weights(_) => {}
                }
            }
        }
        Mat4::from_scale_rotation_translation(s, r, tr)
    }

    /// Global (root-space) transform of node `n` at time `t`.
    pub fn global(&self, n: usize, t: f32) -> Mat4 {
        let mut m = self.local(n, t);
        let mut p = self.parent[n];
        let mut guard = 0;
        while let Some(q) = p {
            m = self.local(q, t) * m;
            p = self.parent[q];
            guard += 1;
            if guard > self.parent.len() {
                break;
            }
        }
        m
    }

    /// Morph weights of node `n` from the playing animation, if it drives them.
    pub fn morph_weights(&self, n: usize, t: f32) -> Option<Vec<f32>> {
        let anim = &self.animations[self.animation?];
        let tt = if anim.duration > 0.0 { t.rem_euclid(anim.duration) } else { 0.0 };
        let tt = if t > 0.0 && tt == 0.0 { anim.duration } else { tt };
        anim.channels.iter().find_map(|c| match (&c.target, c.node == n) {
            (Channel::Weights(k), true) => Some(k.sample(tt)),
            _ => None,
        })
    }

    /// Joint matrices `global(joint) * inverse_bind` of skin `s` at time `t`.
    pub fn joint_matrices(&self, s: usize, t: f32) -> Vec<Mat4> {
        let skin = &self.skins[s];
        skin.joints.iter().zip(&skin.inverse_bind).map(|(&j, ib)| self.global(j, t) * *ib).collect()
    }
}
