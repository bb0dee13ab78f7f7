//! A procedural walking figure wearing a hat, written as a glTF 2.0 binary (`.glb`): the
//! stand-in for the adaptive visibility sampling paper's third scene (a skinned man with a hat
//! walking on a textured plane, its Figures 8 and 9d-f, about 32k vertices), for which no rigged
//! character with a licence that allows it was at hand. Everything here is generated, so the
//! file carries the project's own licence.
//!
//! The figure is about 1.75 m tall, stands on y = 0 facing +z at rest and is built from
//! closed capsule-like tubes (torso, neck, head, upper and lower legs, feet, upper arms,
//! forearms, hands) in four materials, skinned to 14 joints with linear-blend weights that
//! blend neighbouring bones over the joints. Its hat is a separate rigid mesh on a child node
//! of the head joint (a lathe: crown and brim), so it moves with the head without being
//! skinned. Every material is rough (roughness 1: the paper's man and hat are diffuse). One
//! animation, `walk`, loops every [`WALK_DURATION`] seconds: the figure walks once around a
//! circle of radius [`WALK_RADIUS`] about the origin, eight strides of [`STRIDE_PERIOD`] (hips
//! lowered so that the lower sole stays 4 mm above the floor, and swaying; legs and arms
//! swinging, knees and elbows bending), keyed 30 times a second.
//!
//! `penumbra asset walker` writes it; `scenes/paper/walker.glb` is its output (a test checks
//! that the file still decodes to what the generator makes, within 1e-5).

use glam::{Mat4, Quat, Vec3};
use serde_json::{json, Value};
use std::f32::consts::{PI, TAU};

/// Length of the animation's loop, seconds: one lap of the circle.
pub const WALK_DURATION: f32 = 8.0;
/// One stride (a step with each foot), seconds.
pub const STRIDE_PERIOD: f32 = 1.0;
/// Radius of the circle the figure walks around the origin, metres.
pub const WALK_RADIUS: f32 = 1.2;
/// Animation keys per second.
const KEYS_PER_SECOND: usize = 30;

// Nodes. 0 is the root (moved around the circle), 1..=14 the skin's joints (joint j = node
// j + 1), 15 the hat, 16 the skinned body.
const ROOT: usize = 0;
const HIPS: usize = 1;
const SPINE: usize = 2;
const CHEST: usize = 3;
const HEAD: usize = 4;
const L_THIGH: usize = 5;
const L_SHIN: usize = 6;
const L_FOOT: usize = 7;
const R_THIGH: usize = 8;
const R_SHIN: usize = 9;
const R_FOOT: usize = 10;
const L_ARM: usize = 11;
const L_FOREARM: usize = 12;
const R_ARM: usize = 13;
const R_FOREARM: usize = 14;
const HAT: usize = 15;
const BODY: usize = 16;
const JOINTS: usize = 14;

/// Rest (bind) position of each node in the figure's space (the root at the origin, no
/// rotations at rest).
fn rest_position(node: usize) -> Vec3 {
    match node {
        ROOT | BODY => Vec3::ZERO,
        HIPS => Vec3::new(0.0, 0.96, 0.0),
        SPINE => Vec3::new(0.0, 1.08, 0.0),
        CHEST => Vec3::new(0.0, 1.30, 0.0),
        HEAD => Vec3::new(0.0, 1.50, 0.0),
        L_THIGH => Vec3::new(0.1, 0.91, 0.0),
        L_SHIN => Vec3::new(0.1, 0.48, 0.0),
        L_FOOT => Vec3::new(0.1, 0.06, 0.0),
        R_THIGH => Vec3::new(-0.1, 0.91, 0.0),
        R_SHIN => Vec3::new(-0.1, 0.48, 0.0),
        R_FOOT => Vec3::new(-0.1, 0.06, 0.0),
        L_ARM => Vec3::new(0.2, 1.45, 0.0),
        L_FOREARM => Vec3::new(0.215, 1.16, 0.0),
        R_ARM => Vec3::new(-0.2, 1.45, 0.0),
        R_FOREARM => Vec3::new(-0.215, 1.16, 0.0),
        HAT => Vec3::new(0.0, 1.70, 0.0),
        _ => Vec3::ZERO,
    }
}

fn parent(node: usize) -> Option<usize> {
    match node {
        HIPS => Some(ROOT),
        SPINE | L_THIGH | R_THIGH => Some(HIPS),
        CHEST => Some(SPINE),
        HEAD | L_ARM | R_ARM => Some(CHEST),
        L_SHIN => Some(L_THIGH),
        L_FOOT => Some(L_SHIN),
        R_SHIN => Some(R_THIGH),
        R_FOOT => Some(R_SHIN),
        L_FOREARM => Some(L_ARM),
        R_FOREARM => Some(R_ARM),
        HAT => Some(HEAD),
        _ => None,
    }
}

fn children(node: usize) -> Vec<usize> {
    (0..=BODY).filter(|&c| parent(c) == Some(node)).collect()
}

fn joint(node: usize) -> u8 {
    debug_assert!((HIPS..=R_FOREARM).contains(&node));
    (node - 1) as u8
}

/// One vertex's joints and weights (up to four; weights sum to 1).
type Weights = [(usize, f32); 4];

fn smoothstep(a: f32, b: f32, x: f32) -> f32 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A vertex bound to joint node `j` alone.
fn rigid(j: usize) -> Weights {
    [(j, 1.0), (j, 0.0), (j, 0.0), (j, 0.0)]
}

/// Weights of a point at parameter `s` along a bone (0 at its start joint, 1 at its end) that
/// blends with `before` over its first fifth and with `after` over its last: half and half at
/// the joints themselves and beyond them (the end caps).
fn bone_weights(s: f32, own: usize, before: Option<usize>, after: Option<usize>) -> Weights {
    let mut w = [(own, 1.0), (own, 0.0), (own, 0.0), (own, 0.0)];
    if let Some(b) = before {
        let x = 0.5 * (1.0 - smoothstep(0.0, 0.2, s));
        w[0].1 -= x;
        w[1] = (b, x);
    }
    if let Some(a) = after {
        let x = 0.5 * smoothstep(0.8, 1.0, s);
        w[0].1 -= x;
        w[2] = (a, x);
    }
    w
}

/// A closed tube around the segment a -> b (never along x): rings of an elliptic cross-section
/// (radii along x, made perpendicular to the segment, and along axis x that) from `radii(s)`,
/// closed at both ends by half-ellipsoid caps and poles.
struct Tube<'a> {
    a: Vec3,
    b: Vec3,
    radii: &'a dyn Fn(f32) -> (f32, f32),
    weights: &'a dyn Fn(Vec3, f32) -> Weights,
    around: usize,
    rings: usize,
    cap_rings: usize,
}

/// Triangles of one material: positions, normals, joints, weights, indices.
#[derive(Default)]
struct Part {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    joints: Vec<[u8; 4]>,
    weights: Vec<[f32; 4]>,
    indices: Vec<u32>,
}

impl Part {
    fn push_vertex(&mut self, p: Vec3, w: Weights) {
        self.positions.push(p);
        self.normals.push(Vec3::ZERO);
        let total: f32 = w.iter().map(|x| x.1.max(0.0)).sum();
        let mut j = [0u8; 4];
        let mut ws = [0f32; 4];
        for (k, (n, x)) in w.iter().enumerate() {
            if *x > 0.0 {
                j[k] = joint(*n);
                ws[k] = x.max(0.0) / total;
            }
        }
        self.joints.push(j);
        self.weights.push(ws);
    }

    fn add_tube(&mut self, t: &Tube) {
        let first = self.positions.len() as u32;
        let axis = t.b - t.a;
        let len = axis.length();
        let dir = axis / len;
        debug_assert!(dir.x.abs() < 0.9, "a tube along x has no cross-section frame from x");
        let u = (Vec3::X - dir * dir.x).normalize();
        let v = dir.cross(u);
        // (centre, radius scale, s) per ring, from the start pole's first ring to the end's last
        let mut rings: Vec<(Vec3, f32, f32)> = Vec::new();
        let (r0u, r0v) = (t.radii)(0.0);
        let (r1u, r1v) = (t.radii)(1.0);
        let d0 = r0u.min(r0v);
        let d1 = r1u.min(r1v);
        for k in 1..t.cap_rings {
            let beta = 0.5 * PI * k as f32 / t.cap_rings as f32;
            rings.push((t.a - dir * d0 * beta.cos(), beta.sin(), -d0 * beta.cos() / len));
        }
        for k in 0..=t.rings {
            let s = k as f32 / t.rings as f32;
            rings.push((t.a + axis * s, 1.0, s));
        }
        for k in (1..t.cap_rings).rev() {
            let beta = 0.5 * PI * k as f32 / t.cap_rings as f32;
            rings.push((t.b + dir * d1 * beta.cos(), beta.sin(), 1.0 + d1 * beta.cos() / len));
        }
        let pole0 = t.a - dir * d0;
        self.push_vertex(pole0, (t.weights)(pole0, -d0 / len));
        for &(c, scale, s) in &rings {
            let (ru, rv) = (t.radii)(s.clamp(0.0, 1.0));
            for i in 0..t.around {
                let phi = TAU * i as f32 / t.around as f32;
                let p = c + (u * ru * phi.cos() + v * rv * phi.sin()) * scale;
                self.push_vertex(p, (t.weights)(p, s));
            }
        }
        let pole1 = t.b + dir * d1;
        self.push_vertex(pole1, (t.weights)(pole1, 1.0 + d1 / len));
        let n = t.around as u32;
        let ring = |r: usize, i: u32| first + 1 + r as u32 * n + i % n;
        let last = first + 1 + rings.len() as u32 * n;
        for i in 0..n {
            self.indices.extend([first, ring(0, i + 1), ring(0, i)]);
            self.indices.extend([last, ring(rings.len() - 1, i), ring(rings.len() - 1, i + 1)]);
        }
        for r in 0..rings.len() - 1 {
            for i in 0..n {
                let (a, b, c, d) = (ring(r, i), ring(r, i + 1), ring(r + 1, i), ring(r + 1, i + 1));
                self.indices.extend([a, b, d, a, d, c]);
            }
        }
        self.orient_outwards(first as usize, (t.a + t.b) * 0.5);
    }

    /// A round limb from joint node `own` to `end`, its radius `r` at the start shrinking by
    /// `taper` to the end, weighted to `own` and blended with `before` and `after` over its
    /// joints ([`bone_weights`]).
    fn add_limb(
        &mut self,
        own: usize,
        end: Vec3,
        (r, taper): (f32, f32),
        before: Option<usize>,
        after: Option<usize>,
        around: usize,
        rings: usize,
    ) {
        let radii = |s: f32| {
            let x = r - taper * s;
            (x, x)
        };
        let weights = |_q: Vec3, s: f32| bone_weights(s, own, before, after);
        self.add_tube(&Tube {
            a: rest_position(own),
            b: end,
            radii: &radii,
            weights: &weights,
            around,
            rings,
            cap_rings: 6,
        });
    }

    /// A closed solid of revolution about +y through `origin`: `profile` (radius, height) from
    /// the top of the axis down the outside to the bottom of the axis; each profile segment its
    /// own strip (a crease between segments), subdivided into `steps` rings.
    fn add_lathe(&mut self, origin: Vec3, profile: &[(f32, f32)], around: usize, steps: usize, w: Weights) {
        let centre = origin + Vec3::Y * profile.iter().map(|p| p.1).sum::<f32>() / profile.len() as f32;
        let first = self.positions.len();
        let n = around as u32;
        for seg in profile.windows(2) {
            // rings of the segment (a point on the axis is a single pole vertex)
            let mut rings: Vec<(u32, bool)> = Vec::new();
            for k in 0..=steps {
                let f = k as f32 / steps as f32;
                let (r, y) = (seg[0].0 + (seg[1].0 - seg[0].0) * f, seg[0].1 + (seg[1].1 - seg[0].1) * f);
                let base = self.positions.len() as u32;
                if r <= 0.0 {
                    self.push_vertex(origin + Vec3::Y * y, w);
                    rings.push((base, true));
                    continue;
                }
                for i in 0..around {
                    let phi = TAU * i as f32 / around as f32;
                    self.push_vertex(origin + Vec3::new(r * phi.cos(), y, r * phi.sin()), w);
                }
                rings.push((base, false));
            }
            for pair in rings.windows(2) {
                let ((p, p_pole), (q, q_pole)) = (pair[0], pair[1]);
                for i in 0..n {
                    let j = (i + 1) % n;
                    match (p_pole, q_pole) {
                        (false, false) => self.indices.extend([p + i, p + j, q + j, p + i, q + j, q + i]),
                        (true, false) => self.indices.extend([p, q + j, q + i]),
                        (false, true) => self.indices.extend([p + i, p + j, q]),
                        (true, true) => {}
                    }
                }
            }
        }
        self.orient_outwards(first, centre);
    }

    /// Area-weighted vertex normals of the triangles from the first that uses vertex `first`,
    /// every triangle turned so that its normal points away from `centre` on the whole (the
    /// pieces are closed and star-shaped about it).
    fn orient_outwards(&mut self, first: usize, centre: Vec3) {
        let tri0 = self.indices.iter().position(|&i| i as usize >= first).unwrap_or(self.indices.len()) / 3;
        let mut outward = 0.0;
        for t in self.indices[tri0 * 3..].chunks(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| self.positions[i as usize]);
            outward += (b - a).cross(c - a).dot((a + b + c) / 3.0 - centre);
        }
        if outward < 0.0 {
            for t in self.indices[tri0 * 3..].chunks_mut(3) {
                t.swap(1, 2);
            }
        }
        for t in self.indices[tri0 * 3..].chunks(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| self.positions[i as usize]);
            let n = (b - a).cross(c - a);
            for &i in t {
                self.normals[i as usize] += n;
            }
        }
        for n in &mut self.normals[first..] {
            *n = n.try_normalize().unwrap_or(Vec3::Y);
        }
    }
}

/// Piecewise-linear interpolation of `(x, y)` stations at `x`.
fn stations(st: &[(f32, f32)], x: f32) -> f32 {
    if x <= st[0].0 {
        return st[0].1;
    }
    for w in st.windows(2) {
        if x <= w[1].0 {
            let f = (x - w[0].0) / (w[1].0 - w[0].0);
            return w[0].1 + (w[1].1 - w[0].1) * f;
        }
    }
    st[st.len() - 1].1
}

/// The figure's four skinned parts (skin, shirt, trousers, shoes) and its hat.
fn build_meshes() -> (Vec<Part>, Part) {
    let mut skin = Part::default();
    let mut shirt = Part::default();
    let mut trousers = Part::default();
    let mut shoes = Part::default();
    let p = rest_position;

    // torso: an elliptic tube from the hips to the shoulders, weighted hips -> spine -> chest
    let (y0, y1) = (0.86, 1.47);
    let rx = [(0.86, 0.165), (0.96, 0.17), (1.08, 0.145), (1.3, 0.18), (1.42, 0.175), (1.47, 0.15)];
    let rz = [(0.86, 0.11), (0.96, 0.115), (1.08, 0.10), (1.3, 0.12), (1.42, 0.11), (1.47, 0.09)];
    let torso_r = |s: f32| {
        let y = y0 + (y1 - y0) * s;
        (stations(&rx, y), stations(&rz, y))
    };
    let torso_w = |q: Vec3, _s: f32| -> Weights {
        let a = smoothstep(0.98, 1.18, q.y);
        let b = smoothstep(1.18, 1.36, q.y);
        [(HIPS, 1.0 - a), (SPINE, a - b), (CHEST, b), (CHEST, 0.0)]
    };
    shirt.add_tube(&Tube {
        a: Vec3::new(0.0, y0, 0.0),
        b: Vec3::new(0.0, y1, 0.0),
        radii: &torso_r,
        weights: &torso_w,
        around: 48,
        rings: 30,
        cap_rings: 6,
    });
    // neck and head
    let neck_r = |_s: f32| (0.055, 0.055);
    let neck_w = |_q: Vec3, s: f32| -> Weights {
        let x = smoothstep(0.2, 0.8, s);
        [(CHEST, 1.0 - x), (HEAD, x), (HEAD, 0.0), (HEAD, 0.0)]
    };
    skin.add_tube(&Tube {
        a: Vec3::new(0.0, 1.42, 0.0),
        b: Vec3::new(0.0, 1.56, 0.0),
        radii: &neck_r,
        weights: &neck_w,
        around: 28,
        rings: 6,
        cap_rings: 4,
    });
    let head_r = |_s: f32| (0.1, 0.108);
    let head_w = |_q: Vec3, _s: f32| rigid(HEAD);
    skin.add_tube(&Tube {
        a: Vec3::new(0.0, 1.6, 0.005),
        b: Vec3::new(0.0, 1.64, 0.005),
        radii: &head_r,
        weights: &head_w,
        around: 48,
        rings: 4,
        cap_rings: 16,
    });

    for (sx, thigh, shin, foot, arm, forearm) in
        [(1.0f32, L_THIGH, L_SHIN, L_FOOT, L_ARM, L_FOREARM), (-1.0, R_THIGH, R_SHIN, R_FOOT, R_ARM, R_FOREARM)]
    {
        // legs
        trousers.add_limb(thigh, p(shin), (0.075, 0.02), Some(HIPS), Some(shin), 36, 26);
        trousers.add_limb(shin, p(foot) + Vec3::Y * 0.01, (0.055, 0.015), Some(thigh), Some(foot), 36, 26);
        let foot_r = |_s: f32| (0.045, 0.04);
        let foot_w = move |_q: Vec3, _s: f32| rigid(foot);
        shoes.add_tube(&Tube {
            a: Vec3::new(0.1 * sx, 0.045, -0.04),
            b: Vec3::new(0.1 * sx, 0.045, 0.15),
            radii: &foot_r,
            weights: &foot_w,
            around: 32,
            rings: 12,
            cap_rings: 6,
        });
        // arms
        shirt.add_limb(arm, p(forearm), (0.05, 0.008), Some(CHEST), Some(forearm), 32, 18);
        shirt.add_limb(forearm, Vec3::new(0.23 * sx, 0.92, 0.0), (0.042, 0.009), Some(arm), None, 32, 16);
        let hand_r = |_s: f32| (0.022, 0.042);
        let hand_w = move |_q: Vec3, _s: f32| rigid(forearm);
        skin.add_tube(&Tube {
            a: Vec3::new(0.23 * sx, 0.9, 0.0),
            b: Vec3::new(0.23 * sx, 0.83, 0.0),
            radii: &hand_r,
            weights: &hand_w,
            around: 24,
            rings: 6,
            cap_rings: 5,
        });
    }

    // the hat in its node's space (its origin on top of the head)
    let mut hat = Part::default();
    let profile = [
        (0.0, 0.16),
        (0.10, 0.16),
        (0.12, 0.145),
        (0.122, 0.02),
        (0.215, 0.012),
        (0.225, 0.0),
        (0.215, -0.012),
        (0.10, -0.014),
        (0.0, -0.014),
    ];
    hat.add_lathe(Vec3::ZERO, &profile, 72, 3, rigid(HEAD));
    (vec![skin, shirt, trousers, shoes], hat)
}

/// Local rotation and translation of every node at time `t` of the walk (nodes without a key
/// keep their rest transform: translation from the parent, no rotation).
fn pose(node: usize, t: f32) -> (Vec3, Quat) {
    pose_with(node, t, true)
}

/// Height of the lower foot's sole above the floor with the hips at their rest height: the
/// lower of each foot's ends (the centres of its tube's end circles) less the tube's vertical
/// radius.
fn sole_height(t: f32) -> f32 {
    [L_FOOT, R_FOOT]
        .iter()
        .flat_map(|&f| {
            let g = global_with(f, t, false);
            [-0.04, 0.15].map(move |z| g.transform_point3(Vec3::new(0.0, -0.015, z)).y - 0.04)
        })
        .fold(f32::MAX, f32::min)
}

fn global_with(node: usize, t: f32, bob: bool) -> Mat4 {
    let (tr, r) = pose_with(node, t, bob);
    let local = Mat4::from_rotation_translation(r, tr);
    match parent(node) {
        Some(p) => global_with(p, t, bob) * local,
        None => local,
    }
}

/// [`pose`]; `bob = false` keeps the hips at their rest height (the hips are lowered so that
/// the lower sole stays 4 mm above the floor).
fn pose_with(node: usize, t: f32, bob: bool) -> (Vec3, Quat) {
    let rest = rest_position(node) - parent(node).map(rest_position).unwrap_or(Vec3::ZERO);
    let phase = TAU * t / STRIDE_PERIOD;
    let deg = |d: f32| d.to_radians();
    // a leg's swing forward (towards +z) and its knee's bend, at phase `ph`
    let hip = |ph: f32| deg(24.0) * ph.sin();
    let knee = |ph: f32| deg(6.0) + deg(48.0) * ph.cos().max(0.0).powf(1.5);
    let leg_phase = |left: bool| if left { phase } else { phase + PI };
    match node {
        ROOT => {
            let theta = TAU * t / WALK_DURATION;
            let pos = Vec3::new(WALK_RADIUS * theta.cos(), 0.0, WALK_RADIUS * theta.sin());
            (pos, Quat::from_rotation_y(-theta))
        }
        HIPS => {
            let dy = if bob { 0.004 - sole_height(t) } else { 0.0 };
            (
                rest + Vec3::Y * dy,
                Quat::from_rotation_y(deg(6.0) * phase.sin()) * Quat::from_rotation_z(deg(2.5) * phase.cos()),
            )
        }
        SPINE => (rest, Quat::from_rotation_x(deg(4.0))),
        CHEST => (rest, Quat::from_rotation_y(-deg(9.0) * phase.sin())),
        HEAD => (rest, Quat::from_rotation_y(deg(4.0) * phase.sin()) * Quat::from_rotation_x(-deg(4.0))),
        L_THIGH | R_THIGH => (rest, Quat::from_rotation_x(-hip(leg_phase(node == L_THIGH)))),
        L_SHIN | R_SHIN => (rest, Quat::from_rotation_x(knee(leg_phase(node == L_SHIN)))),
        L_FOOT | R_FOOT => {
            let ph = leg_phase(node == L_FOOT);
            (rest, Quat::from_rotation_x(hip(ph) - knee(ph)))
        }
        L_ARM | R_ARM => {
            // an arm swings against its own side's leg
            let ph = leg_phase(node == L_ARM) + PI;
            let side = if node == L_ARM { 1.0 } else { -1.0 };
            (rest, Quat::from_rotation_x(-deg(20.0) * ph.sin()) * Quat::from_rotation_z(side * deg(4.0)))
        }
        L_FOREARM | R_FOREARM => {
            let ph = leg_phase(node == L_FOREARM) + PI;
            (rest, Quat::from_rotation_x(-deg(14.0) - deg(16.0) * ph.sin().max(0.0)))
        }
        _ => (rest, Quat::IDENTITY),
    }
}

/// The figure's world matrix of `node` at time `t` (for tests: the loader computes the same
/// from the file's keys).
pub fn node_global(node: usize, t: f32) -> Mat4 {
    global_with(node, t, true)
}

/// Node index of the hat in the file (a child of [`HEAD_NODE`]).
pub const HAT_NODE: usize = HAT;
/// Node index of the head joint in the file.
pub const HEAD_NODE: usize = HEAD;

/// Builds the file: binary chunk layout, accessors and the JSON document.
struct Writer {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Writer {
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({ "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    fn accessor(
        &mut self,
        bytes: &[u8],
        target: Option<u32>,
        component: u32,
        count: usize,
        ty: &str,
        minmax: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        let view = self.view(bytes, target);
        let mut a = json!({ "bufferView": view, "componentType": component, "count": count, "type": ty });
        if let Some((lo, hi)) = minmax {
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    fn vec3s(&mut self, v: &[Vec3], target: Option<u32>, bounds: bool) -> usize {
        let bytes: Vec<u8> = v.iter().flat_map(|p| p.to_array()).flat_map(f32::to_le_bytes).collect();
        let minmax = bounds.then(|| {
            let lo = v.iter().fold(Vec3::splat(f32::MAX), |m, p| m.min(*p));
            let hi = v.iter().fold(Vec3::splat(f32::MIN), |m, p| m.max(*p));
            (lo.to_array().to_vec(), hi.to_array().to_vec())
        });
        self.accessor(&bytes, target, 5126, v.len(), "VEC3", minmax)
    }

    fn part(&mut self, p: &Part, material: usize, skinned: bool) -> Value {
        let pos = self.vec3s(&p.positions, Some(34962), true);
        let nrm = self.vec3s(&p.normals, Some(34962), false);
        let idx: Vec<u8> = p.indices.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect();
        let ind = self.accessor(&idx, Some(34963), 5123, p.indices.len(), "SCALAR", None);
        let mut attrs = json!({ "POSITION": pos, "NORMAL": nrm });
        if skinned {
            let j: Vec<u8> = p.joints.iter().flatten().copied().collect();
            let w: Vec<u8> = p.weights.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
            attrs["JOINTS_0"] = json!(self.accessor(&j, Some(34962), 5121, p.joints.len(), "VEC4", None));
            attrs["WEIGHTS_0"] = json!(self.accessor(&w, Some(34962), 5126, p.weights.len(), "VEC4", None));
        }
        json!({ "attributes": attrs, "indices": ind, "material": material, "mode": 4 })
    }
}

/// Vertex count of the figure (body and hat).
pub fn vertex_count() -> usize {
    let (parts, hat) = build_meshes();
    parts.iter().map(|p| p.positions.len()).sum::<usize>() + hat.positions.len()
}

/// The figure as a `.glb` file's bytes (deterministic).
pub fn walker_glb() -> Vec<u8> {
    let (parts, hat) = build_meshes();
    let mut w = Writer { bin: Vec::new(), views: Vec::new(), accessors: Vec::new() };
    let body_prims: Vec<Value> = parts.iter().enumerate().map(|(m, p)| w.part(p, m, true)).collect();
    let hat_prim = w.part(&hat, 4, false);

    // inverse bind matrices: the joints' rest transforms are translations
    let ibm: Vec<u8> = (HIPS..=R_FOREARM)
        .flat_map(|n| Mat4::from_translation(-rest_position(n)).to_cols_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    let ibm = w.accessor(&ibm, None, 5126, JOINTS, "MAT4", None);

    // the walk: every animated node's translation (root and hips) and rotation, keyed
    let keys = (WALK_DURATION * KEYS_PER_SECOND as f32).round() as usize;
    let times: Vec<f32> = (0..=keys).map(|k| k as f32 / KEYS_PER_SECOND as f32).collect();
    let tb: Vec<u8> = times.iter().flat_map(|x| x.to_le_bytes()).collect();
    let time_acc = w.accessor(&tb, None, 5126, times.len(), "SCALAR", Some((vec![0.0], vec![WALK_DURATION])));
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    for node in ROOT..=R_FOREARM {
        if matches!(node, ROOT | HIPS) {
            let tr: Vec<Vec3> = times.iter().map(|&t| pose(node, t).0).collect();
            let acc = w.vec3s(&tr, None, false);
            samplers.push(json!({ "input": time_acc, "output": acc, "interpolation": "LINEAR" }));
            channels.push(json!({ "sampler": samplers.len() - 1, "target": { "node": node, "path": "translation" } }));
        }
        let mut prev = Quat::IDENTITY;
        let rot: Vec<u8> = times
            .iter()
            .flat_map(|&t| {
                let mut q = pose(node, t).1.normalize();
                if q.dot(prev) < 0.0 {
                    q = -q;
                }
                prev = q;
                q.to_array()
            })
            .flat_map(f32::to_le_bytes)
            .collect();
        let acc = w.accessor(&rot, None, 5126, times.len(), "VEC4", None);
        samplers.push(json!({ "input": time_acc, "output": acc, "interpolation": "LINEAR" }));
        channels.push(json!({ "sampler": samplers.len() - 1, "target": { "node": node, "path": "rotation" } }));
    }

    let names = [
        "root",
        "hips",
        "spine",
        "chest",
        "head",
        "thigh_l",
        "shin_l",
        "foot_l",
        "thigh_r",
        "shin_r",
        "foot_r",
        "arm_l",
        "forearm_l",
        "arm_r",
        "forearm_r",
        "hat",
        "body",
    ];
    let nodes: Vec<Value> = (0..=BODY)
        .map(|n| {
            let mut v = json!({ "name": names[n] });
            if n == BODY {
                v["mesh"] = json!(0);
                v["skin"] = json!(0);
                return v;
            }
            let local = rest_position(n) - parent(n).map(rest_position).unwrap_or(Vec3::ZERO);
            if local != Vec3::ZERO {
                v["translation"] = json!(local.to_array());
            }
            let c = children(n);
            if !c.is_empty() {
                v["children"] = json!(c);
            }
            if n == HAT {
                v["mesh"] = json!(1);
            }
            v
        })
        .collect();
    let material = |name: &str, c: [f32; 3], rough: f32| json!({ "name": name, "pbrMetallicRoughness": { "baseColorFactor": [c[0], c[1], c[2], 1.0], "metallicFactor": 0.0, "roughnessFactor": rough } });
    let doc = json!({
        "asset": { "version": "2.0", "generator": "penumbra scene::walker (procedural)", "copyright": "generated by penumbra; the project's licence" },
        "scene": 0,
        "scenes": [{ "name": "walker", "nodes": [ROOT, BODY] }],
        "nodes": nodes,
        "meshes": [{ "name": "body", "primitives": body_prims }, { "name": "hat", "primitives": [hat_prim] }],
        "materials": [
            material("skin", [0.78, 0.55, 0.45], 1.0),
            material("shirt", [0.18, 0.32, 0.62], 1.0),
            material("trousers", [0.24, 0.21, 0.19], 1.0),
            material("shoes", [0.07, 0.05, 0.04], 1.0),
            material("hat", [0.55, 0.12, 0.08], 1.0),
        ],
        "skins": [{ "name": "figure", "joints": (HIPS..=R_FOREARM).collect::<Vec<_>>(), "inverseBindMatrices": ibm, "skeleton": HIPS }],
        "animations": [{ "name": "walk", "samplers": samplers, "channels": channels }],
        "accessors": w.accessors,
        "bufferViews": w.views,
        "buffers": [{ "byteLength": w.bin.len() }],
    });
    crate::gltf_load::glb_bytes(&serde_json::to_vec(&doc).expect("a JSON value serializes"), &w.bin)
}
