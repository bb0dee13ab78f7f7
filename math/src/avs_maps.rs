//! Hemispherical visibility maps and SSDFs of the adaptive-visibility-sampling technique (issue 8):
//! the paper's `(theta, phi)` parameterization, texel directions, solid angles, the tangent frame,
//! the 1-bit visibility packing and the fp16 SSDF layout. `glsl/include/avs_maps.glsl` mirrors every
//! function here with the same formulas (checked on the GPU in `tests/hsdt.rs`).
//!
//! # Parameterization (paper Fig. 2a, Algorithm 1: both angles range over `[0, pi]`)
//! Local frame: `z` = surface normal `n`, `x` = tangent `t`, `y` = bitangent `b = n x t`
//! (right-handed, see [`Frame`]). A local direction is
//!
//! ```text
//! w(theta, phi) = (cos theta, sin theta cos phi, sin theta sin phi)      theta, phi in [0, pi]
//! ```
//!
//! * `theta` is the **polar angle from the tangent axis `+x`** (a "latitude" row of the map is a
//!   circle of constant `theta` around `x`); `phi` is the **azimuth around `x`**, measured from the
//!   bitangent `+y` (`phi = 0`) through the normal `+z` (`phi = pi/2`) to `-y` (`phi = pi`) (a
//!   "longitude" column of constant `phi` is a great half-circle from `+x` to `-x`).
//! * `dot(n, w) = sin theta sin phi >= 0`: the rectangle `[0, pi] x [0, pi]` is exactly the upper
//!   hemisphere, each direction once. The normal is at `(pi/2, pi/2)`, the map centre.
//! * **Poles**: `theta = 0` (`w = +x`) and `theta = pi` (`w = -x`); both lie ON the horizon
//!   (grazing directions, cosine weight 0). Each is one point that the whole first (last) row
//!   shrinks to.
//! * **The phi "seam"**: `phi = 0` and `phi = pi` are the two halves of the horizon great circle
//!   (`+y` side and `-y` side). They are NOT adjacent on the hemisphere (the lower hemisphere lies
//!   between them): the map does not wrap in `phi`, and a distance transform must not wrap either.
//!   Near the poles the two edges approach each other (they meet at the poles).
//! * Resolution `r x r`: row `i` (theta) covers `[i, i+1] pi / r`, column `j` (phi) covers
//!   `[j, j+1] pi / r`; the texel's direction is its centre `((i + 0.5) pi / r, (j + 0.5) pi / r)`,
//!   strictly above the horizon, so **no texel is below the horizon** and no ray of a map goes
//!   below it (rays of the first and last column graze it at `phi = pi / (2r)`). Texel solid angle
//!   `(cos(i pi/r) - cos((i+1) pi/r)) pi / r` (independent of `j`), summing to `2 pi`.
//!
//! Why this parameterization (rather than the normal as pole): the latitude scans of the HSDT are
//! then exact (the point of a row closest to ANY direction on a column is the one closest in `phi`,
//! since `cos(dphi)` is monotone on `[0, pi]` and `sin theta >= 0`), there is no wrap-around, and the
//! distortion (small texels) sits at the grazing poles where the cosine term vanishes.
//!
//! # Visibility bits
//! A map of resolution `r` is `r * r / 32` u32 words ([`words_per_map`]); texel `(i, j)` (row `i` =
//! theta index, column `j` = phi index) is bit `k = i * r + j`: word `k / 32`, bit `k % 32` (LSB
//! first). **1 = visible (the ray escapes, unoccluded), 0 = occluded.** N maps are concatenated, map
//! `p` starting at word `p * words_per_map(r)` (2 KB per map at 128). `r` must be a multiple of 8 in
//! `[8, 256]` ([`check_res`]), so maps are whole words.
//!
//! # SSDF
//! The signed spherical distance of each texel centre (eq. 4), in **radians**: positive in the
//! visible region (distance to the nearest occluded texel centre), negative in the occluded region
//! (minus the distance to the nearest visible texel centre). All-visible maps store `+pi`, all-occluded
//! maps `-pi` (no boundary on the hemisphere; `pi` exceeds every distance between two hemisphere
//! directions, which is at most `pi`). Stored as fp16, `r * r` halves per map ([`ssdf_words_per_map`]
//! = `r * r / 2` u32 words, 32 KB at 128): texel `k = i * r + j` is word `k / 2`, the low half
//! (`unpackHalf2x16(..).x`) for even `k`. Map `p` starts at word `p * ssdf_words_per_map(r)`.
//!
//! Note on the distance convention: the SSDF measures centre-to-centre distances, so the true zero
//! crossing lies about halfway between a positive and a negative texel; consumers that need the
//! boundary position (the SSDF integrals) use `d - sign(d) * h / 2` style corrections or
//! interpolate, as documented in `ssdf_integrate`.

use glam::{DVec3, Vec3};
use std::f64::consts::PI;

/// Smallest supported map resolution.
pub const MIN_RES: u32 = 8;
/// Largest supported map resolution (the GPU HSDT keeps one column in shared memory).
pub const MAX_RES: u32 = 256;
/// SSDF value of a map without any boundary (all visible: `+NO_BOUNDARY`, all occluded: `-`).
pub const NO_BOUNDARY: f64 = PI;

/// `Ok` if `r` is a supported resolution (multiple of 8 in `[8, 256]`), else a message naming it.
pub fn check_res(r: u32) -> Result<(), String> {
    if !(MIN_RES..=MAX_RES).contains(&r) || !r.is_multiple_of(8) {
        Err(format!("visibility map resolution {r} is not a multiple of 8 in [{MIN_RES}, {MAX_RES}]"))
    } else {
        Ok(())
    }
}

/// u32 words of one packed visibility map (`r * r / 32`).
pub fn words_per_map(r: u32) -> usize {
    (r * r / 32) as usize
}

/// u32 words of one fp16 SSDF (`r * r / 2`).
pub fn ssdf_words_per_map(r: u32) -> usize {
    (r * r / 2) as usize
}

/// Angular size of one texel edge, `pi / r` (radians).
pub fn texel_angle(r: u32) -> f64 {
    PI / r as f64
}

/// `theta` of row `i`'s centre.
pub fn texel_theta(i: u32, r: u32) -> f64 {
    (i as f64 + 0.5) * PI / r as f64
}

/// `phi` of column `j`'s centre.
pub fn texel_phi(j: u32, r: u32) -> f64 {
    (j as f64 + 0.5) * PI / r as f64
}

/// Local direction of `(theta, phi)`: `(cos theta, sin theta cos phi, sin theta sin phi)`.
pub fn angles_to_local(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(ct, st * cp, st * sp)
}

/// `(theta, phi)` of a unit local direction; `None` below the horizon (`z < 0`). At the poles
/// (`y = z = 0`) `phi` is `0` or `pi` (depending on the sign of the zero `y`; any column is right). Horizon directions (`z = 0`) give `phi = 0` (`y > 0`) or `pi`.
pub fn local_to_angles(w: DVec3) -> Option<(f64, f64)> {
    if w.z < 0.0 {
        return None;
    }
    let theta = w.x.clamp(-1.0, 1.0).acos();
    let z = if w.z > 0.0 { w.z } else { 0.0 }; // -0.0 would give phi = -pi
    let phi = z.atan2(w.y); // in [0, pi]
    Some((theta, phi))
}

/// Local direction of texel `(i, j)`'s centre (row `i` = theta, column `j` = phi).
pub fn texel_dir(i: u32, j: u32, r: u32) -> DVec3 {
    angles_to_local(texel_theta(i, r), texel_phi(j, r))
}

/// f32 version of [`texel_dir`] (the GLSL function computes the same in f32).
pub fn texel_dir_f32(i: u32, j: u32, r: u32) -> Vec3 {
    let h = std::f32::consts::PI / r as f32;
    let theta = (i as f32 + 0.5) * h;
    let phi = (j as f32 + 0.5) * h;
    Vec3::new(theta.cos(), theta.sin() * phi.cos(), theta.sin() * phi.sin())
}

/// Texel `(i, j)` containing the unit local direction `w`; `None` below the horizon. Directions
/// on the texel edges go to the higher index, clamped to `r - 1` (so `theta = pi` is row `r - 1`).
pub fn dir_to_texel(w: DVec3, r: u32) -> Option<(u32, u32)> {
    let (theta, phi) = local_to_angles(w)?;
    let f = r as f64 / PI;
    let i = ((theta * f) as i64).clamp(0, r as i64 - 1) as u32;
    let j = ((phi * f) as i64).clamp(0, r as i64 - 1) as u32;
    Some((i, j))
}

/// Solid angle of a texel of row `i`: `(cos(i pi/r) - cos((i+1) pi/r)) * pi / r` steradians.
pub fn texel_solid_angle(i: u32, r: u32) -> f64 {
    let h = PI / r as f64;
    // cos a - cos b = 2 sin((a+b)/2) sin((b-a)/2): no cancellation for thin rows.
    2.0 * ((i as f64 + 0.5) * h).sin() * (0.5 * h).sin() * h
}

/// Great-circle angle between two unit vectors, accurate for tiny and near-`pi` angles
/// (`2 atan2(|a - b|, |a + b|)`).
pub fn angle_between(a: DVec3, b: DVec3) -> f64 {
    2.0 * (a - b).length().atan2((a + b).length())
}

/// Great-circle distance between `(theta1, phi1)` and `(theta2, phi2)`, radians. Uses
/// `sin^2(d/2) = sin^2(dtheta/2) + sin t1 sin t2 sin^2(dphi/2)` (haversine; exact for small
/// distances).
pub fn angular_distance(theta1: f64, phi1: f64, theta2: f64, phi2: f64) -> f64 {
    let a = (0.5 * (theta1 - theta2)).sin();
    let b = (0.5 * (phi1 - phi2)).sin();
    let h = a * a + theta1.sin() * theta2.sin() * b * b;
    2.0 * h.clamp(0.0, 1.0).sqrt().asin()
}

/// The local frame of a sample point: `x` = tangent (the map's pole axis), `y` = bitangent, `z` =
/// normal; right-handed (`y = z x x`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Tangent, the pole axis of the map (`theta = 0`).
    pub t: DVec3,
    /// Bitangent `n x t` (`phi = 0`).
    pub b: DVec3,
    /// Normal (`phi = pi/2` at `theta = pi/2`).
    pub n: DVec3,
}

impl Frame {
    /// Frame from the normal alone (Duff et al. 2017 branchless basis, the same in GLSL
    /// `avs_frame`): deterministic and continuous in `n` except across `n.z = 0`, where the
    /// tangent flips. Sample points whose SSDFs are interpolated should share the same rule.
    pub fn from_normal(n: DVec3) -> Frame {
        let n = n.normalize();
        let sign = 1f64.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let bb = n.x * n.y * a;
        let t = DVec3::new(1.0 + sign * n.x * n.x * a, sign * bb, -sign * n.x);
        Frame { t, b: n.cross(t), n }
    }

    /// Frame whose tangent is `hint` made orthogonal to `n` (Gram-Schmidt); falls back to
    /// [`Frame::from_normal`] when `hint` is (nearly) parallel to `n`. Use a fixed world hint
    /// (e.g. the up axis) to give nearby sample points nearly identical frames everywhere but
    /// where `n` is parallel to the hint (GLSL `avs_frame_hint`).
    pub fn from_normal_hint(n: DVec3, hint: DVec3) -> Frame {
        let n = n.normalize();
        let t = hint - n * n.dot(hint);
        let l = t.length();
        if !(l > 1e-4 * hint.length().max(1e-300)) {
            return Frame::from_normal(n);
        }
        let t = t / l;
        Frame { t, b: n.cross(t), n }
    }

    /// Local coordinates of a world direction.
    pub fn to_local(&self, w: DVec3) -> DVec3 {
        DVec3::new(self.t.dot(w), self.b.dot(w), self.n.dot(w))
    }

    /// World direction of local coordinates.
    pub fn to_world(&self, l: DVec3) -> DVec3 {
        self.t * l.x + self.b * l.y + self.n * l.z
    }
}

/// One packed visibility map (bits as documented in the module docs).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VisMap {
    /// Resolution.
    pub r: u32,
    /// `words_per_map(r)` words, bit `i * r + j` = texel `(i, j)`, 1 = visible.
    pub bits: Vec<u32>,
}

impl VisMap {
    /// All texels visible (`true`) or occluded.
    pub fn filled(r: u32, visible: bool) -> VisMap {
        check_res(r).expect("resolution");
        VisMap { r, bits: vec![if visible { u32::MAX } else { 0 }; words_per_map(r)] }
    }

    /// Map from a predicate on `(i, j)`.
    pub fn from_fn(r: u32, mut visible: impl FnMut(u32, u32) -> bool) -> VisMap {
        let mut m = VisMap::filled(r, false);
        for i in 0..r {
            for j in 0..r {
                if visible(i, j) {
                    m.set(i, j, true);
                }
            }
        }
        m
    }

    /// Map from a predicate on the local texel-centre direction.
    pub fn from_dir_fn(r: u32, mut visible: impl FnMut(DVec3) -> bool) -> VisMap {
        VisMap::from_fn(r, |i, j| visible(texel_dir(i, j, r)))
    }

    /// Visibility of texel `(i, j)`.
    pub fn get(&self, i: u32, j: u32) -> bool {
        let k = (i * self.r + j) as usize;
        (self.bits[k / 32] >> (k % 32)) & 1 == 1
    }

    /// Sets texel `(i, j)`.
    pub fn set(&mut self, i: u32, j: u32, visible: bool) {
        let k = (i * self.r + j) as usize;
        if visible {
            self.bits[k / 32] |= 1 << (k % 32);
        } else {
            self.bits[k / 32] &= !(1 << (k % 32));
        }
    }

    /// Number of visible texels.
    pub fn count_visible(&self) -> u32 {
        self.bits.iter().map(|w| w.count_ones()).sum()
    }

    /// Visible solid angle (sum of visible texels' solid angles), steradians.
    pub fn visible_solid_angle(&self) -> f64 {
        let mut s = 0.0;
        for i in 0..self.r {
            let row = (0..self.r).filter(|&j| self.get(i, j)).count();
            s += row as f64 * texel_solid_angle(i, self.r);
        }
        s
    }
}

/// Index of the u32 word holding fp16 SSDF texel `(i, j)` of map `p`, and whether it is the high
/// half (odd texel index).
pub fn ssdf_word(p: usize, i: u32, j: u32, r: u32) -> (usize, bool) {
    let k = (i * r + j) as usize;
    (p * ssdf_words_per_map(r) + k / 2, k % 2 == 1)
}

/// Packs f32 SSDF values (`r * r` per map, texel order) as fp16 pairs like GLSL `packHalf2x16`
/// (round to nearest even).
pub fn pack_ssdf_f16(values: &[f32]) -> Vec<u32> {
    values
        .chunks(2)
        .map(|c| {
            let lo = f32_to_f16(c[0]) as u32;
            let hi = c.get(1).map(|&v| f32_to_f16(v)).unwrap_or(0) as u32;
            lo | (hi << 16)
        })
        .collect()
}

/// Unpacks fp16 pairs (GLSL `unpackHalf2x16`) to f32, `2 * words.len()` values.
pub fn unpack_ssdf_f16(words: &[u32]) -> Vec<f32> {
    words.iter().flat_map(|&w| [f16_to_f32(w as u16), f16_to_f32((w >> 16) as u16)]).collect()
}

/// IEEE binary16 of `x`, round to nearest even, overflow to infinity, subnormals kept.
pub fn f32_to_f16(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x7f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = 1u32 << (shift - 1);
        let mut v = m >> shift;
        let rem = m & ((1 << shift) - 1);
        if rem > half || (rem == half && v & 1 == 1) {
            v += 1;
        }
        return sign | v as u16;
    }
    let mut v = ((e as u32) << 10) | (man >> 13);
    let rem = man & 0x1fff;
    if rem > 0x1000 || (rem == 0x1000 && v & 1 == 1) {
        v += 1; // may carry into the exponent: correct rounding up to the next binade / inf
    }
    sign | v as u16
}

/// f32 of an IEEE binary16.
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h & 0x8000) as u32) << 16;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    let bits = if exp == 0 {
        if man == 0 {
            sign
        } else {
            // subnormal: value = man * 2^-24
            let v = man as f32 * (1.0 / 16_777_216.0);
            return if sign != 0 { -v } else { v };
        }
    } else if exp == 0x1f {
        sign | 0x7f80_0000 | (man << 13)
    } else {
        sign | ((exp + 127 - 15) << 23) | (man << 13)
    };
    f32::from_bits(bits)
}
