//! Random numbers, sampling helpers, the alias table and the importance-sampled environment.

use glam::{Vec2, Vec3};
use penumbra_scene::Environment;
use std::f32::consts::{PI, TAU};

/// SplitMix64 finaliser, used to derive per-pixel seeds.
pub fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// PCG32 (O'Neill), one independent stream per pixel.
#[derive(Clone, Debug)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

impl Pcg32 {
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut r = Pcg32 { state: 0, inc: (stream << 1) | 1 };
        r.next_u32();
        r.state = r.state.wrapping_add(seed);
        r.next_u32();
        r
    }
    /// The generator of pixel `index` for a render seed: independent of thread scheduling.
    pub fn for_pixel(seed: u64, index: u64) -> Self {
        Pcg32::new(splitmix64(seed ^ splitmix64(index)), index)
    }
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }
    /// Uniform in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }
    pub fn next_vec2(&mut self) -> Vec2 {
        Vec2::new(self.next_f32(), self.next_f32())
    }
}

/// Rec. 709 luminance.
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// Cosine-weighted direction on the +Z hemisphere (pdf = cos / pi).
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let r = u.x.sqrt();
    let phi = TAU * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt())
}

/// Uniform direction on the +Z hemisphere (pdf = 1 / (2 pi)).
pub fn uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = TAU * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// An orthonormal frame around a unit normal `n` (z axis), tangent `t` as x axis when given.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub t: Vec3,
    pub b: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// Frame from a normal and an optional tangent hint (Gram-Schmidt; arbitrary if degenerate).
    pub fn new(n: Vec3, tangent_hint: Vec3) -> Self {
        let t = tangent_hint - n * n.dot(tangent_hint);
        let t = if t.length_squared() > 1e-12 {
            t.normalize()
        } else {
            // Duff et al. 2017 branchless ONB.
            let s = 1.0f32.copysign(n.z);
            let a = -1.0 / (s + n.z);
            let b = n.x * n.y * a;
            Vec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x)
        };
        let b = n.cross(t);
        Frame { t, b, n }
    }
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }
}

/// Walker/Vose alias table over non-negative weights.
#[derive(Clone, Debug)]
pub struct AliasTable {
    prob: Vec<f32>,
    alias: Vec<u32>,
    /// Normalised probability of each entry.
    pmf: Vec<f32>,
    total: f64,
}

impl AliasTable {
    /// `None` when the weights are empty or sum to zero (or are not finite).
    pub fn new(weights: &[f64]) -> Option<Self> {
        let n = weights.len();
        let total: f64 = weights.iter().map(|w| w.max(0.0)).sum();
        if n == 0 || total.is_nan() || total <= 0.0 || !total.is_finite() {
            return None;
        }
        let scaled: Vec<f64> = weights.iter().map(|w| w.max(0.0) * n as f64 / total).collect();
        let mut prob = vec![0.0f32; n];
        let mut alias = vec![0u32; n];
        let (mut small, mut large): (Vec<usize>, Vec<usize>) = (Vec::new(), Vec::new());
        let mut q = scaled.clone();
        for (i, &s) in scaled.iter().enumerate() {
            if s < 1.0 {
                small.push(i)
            } else {
                large.push(i)
            }
        }
        while let (Some(&s), Some(&l)) = (small.last(), large.last()) {
            small.pop();
            prob[s] = q[s] as f32;
            alias[s] = l as u32;
            q[l] = (q[l] + q[s]) - 1.0;
            if q[l] < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        for i in large.into_iter().chain(small) {
            prob[i] = 1.0;
            alias[i] = i as u32;
        }
        let pmf = weights.iter().map(|w| (w.max(0.0) / total) as f32).collect();
        Some(AliasTable { prob, alias, pmf, total })
    }
    pub fn len(&self) -> usize {
        self.prob.len()
    }
    pub fn is_empty(&self) -> bool {
        self.prob.is_empty()
    }
    pub fn total(&self) -> f64 {
        self.total
    }
    pub fn pmf(&self, i: usize) -> f32 {
        self.pmf[i]
    }
    /// Sample an index from two uniforms.
    pub fn sample(&self, u1: f32, u2: f32) -> usize {
        let n = self.prob.len();
        let i = ((u1 * n as f32) as usize).min(n - 1);
        if u2 < self.prob[i] {
            i
        } else {
            self.alias[i] as usize
        }
    }
}

/// The scene environment prepared for rendering: piecewise-constant radiance per texel
/// (nearest lookup, no filtering), rotated by `rotation` about +Y, importance-sampled by an alias
/// table over texels weighted by luminance times the texel's exact solid angle. Within a texel,
/// directions are uniform in solid angle, so the pdf is constant per texel.
///
/// Rotation convention: a map direction `d` (from [`Environment::direction`]) appears at world
/// direction `R_y(rotation) d` (right-handed rotation about +Y).
#[derive(Clone, Debug)]
pub struct EnvLight {
    width: u32,
    height: u32,
    texels: Vec<Vec3>,
    cos_rot: f32,
    sin_rot: f32,
    /// cos(theta) at row boundaries, `height + 1` entries.
    row_cos: Vec<f32>,
    /// Solid angle of one texel of each row.
    row_solid_angle: Vec<f32>,
    table: Option<AliasTable>,
    /// SG lighting (world-space axis, sharpness, RGB amplitude): when set, radiance is the
    /// exact sum of these lobes and `texels` only drive importance sampling.
    sg: Option<Vec<(Vec3, f32, Vec3)>>,
}

/// Sum of SG lobes `mu exp(lambda (dot(axis, d) - 1))` at unit `d`.
pub fn eval_sg_sum(lobes: &[(Vec3, f32, Vec3)], d: Vec3) -> Vec3 {
    lobes.iter().map(|(a, l, mu)| *mu * (-0.5 * *l * (*a - d).length_squared()).exp()).sum()
}

impl EnvLight {
    /// Solid angle of one texel of row `j` (0 outside the map).
    pub fn row_solid_angle(&self, j: usize) -> f32 {
        self.row_solid_angle.get(j).copied().unwrap_or(0.0)
    }

    /// A black environment (no radiance, never sampled).
    pub fn black() -> Self {
        EnvLight {
            width: 1,
            height: 1,
            texels: vec![Vec3::ZERO],
            cos_rot: 1.0,
            sin_rot: 0.0,
            row_cos: vec![1.0, -1.0],
            row_solid_angle: vec![4.0 * PI],
            table: None,
            sg: None,
        }
    }

    /// Lighting made of SG lobes given in the map's frame (axes before `rotation`, amplitudes
    /// before `intensity`, as fitted to `env`'s texels); rotation and intensity of `env` are
    /// applied. Importance sampling uses the lobes tabulated at `env`'s resolution.
    pub fn from_sg(env: &Environment, lobes: &[(Vec3, f32, Vec3)]) -> Result<Self, String> {
        let mut e = EnvLight::new(env)?;
        let world: Vec<(Vec3, f32, Vec3)> = lobes
            .iter()
            .map(|(a, l, mu)| (e.to_world(a.normalize_or_zero()), l.max(0.0), *mu * env.intensity))
            .collect();
        if world.iter().any(|(a, l, mu)| !a.is_finite() || !l.is_finite() || !mu.is_finite()) {
            return Err("SG lighting has non-finite lobes".into());
        }
        let (w, h) = (env.width as usize, env.height as usize);
        let mut weights = Vec::with_capacity(w * h);
        let mut texels = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let d_map = Environment::direction((i as f32 + 0.5) / w as f32, (j as f32 + 0.5) / h as f32);
                let v = eval_sg_sum(&world, e.to_world(d_map));
                texels.push(v);
                weights.push(luminance(v.max(Vec3::ZERO)) as f64 * e.row_solid_angle[j] as f64);
            }
        }
        e.texels = texels;
        e.table = AliasTable::new(&weights);
        e.sg = Some(world);
        Ok(e)
    }

    pub fn new(env: &Environment) -> Result<Self, String> {
        let (w, h) = (env.width, env.height);
        if w == 0 || h == 0 || env.texels.len() != w as usize * h as usize {
            return Err(format!("environment has {} texels for a {}x{} map", env.texels.len(), w, h));
        }
        if !env.intensity.is_finite() || !env.rotation.is_finite() {
            return Err("environment intensity or rotation is not finite".into());
        }
        // Texels are read exactly as the GPU path reads them (`passes::env::EnvMapGpu`): a texel
        // with a NaN, infinite or negative channel is black (whole texel), then scaled by the
        // intensity. A reference that passed them through would differ from every technique
        // (studio.exr holds texels down to -149: 0.68 % darker images, negative pixels).
        let texels: Vec<Vec3> = env
            .texels
            .iter()
            .map(|t| {
                if Environment::texel_ok(t) {
                    let v = Vec3::from_array(*t) * env.intensity;
                    if v.is_finite() {
                        v
                    } else {
                        Vec3::ZERO
                    }
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        let row_cos: Vec<f32> = (0..=h).map(|j| (PI * j as f32 / h as f32).cos()).collect::<Vec<_>>();
        let row_solid_angle: Vec<f32> = (0..h as usize)
            .map(|j| {
                let d = ((j as f64 * std::f64::consts::PI / h as f64).cos()
                    - ((j + 1) as f64 * std::f64::consts::PI / h as f64).cos())
                    * std::f64::consts::TAU
                    / w as f64;
                d as f32
            })
            .collect();
        let weights: Vec<f64> = texels
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let j = i / w as usize;
                (luminance(t.max(Vec3::ZERO)) as f64) * row_solid_angle[j] as f64
            })
            .collect();
        let table = AliasTable::new(&weights);
        Ok(EnvLight {
            width: w,
            height: h,
            texels,
            cos_rot: env.rotation.cos(),
            sin_rot: env.rotation.sin(),
            row_cos,
            row_solid_angle,
            table,
            sg: None,
        })
    }

    fn to_map(&self, d: Vec3) -> Vec3 {
        // R_y(-rotation) d
        let (c, s) = (self.cos_rot, self.sin_rot);
        Vec3::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z)
    }
    fn to_world(&self, d: Vec3) -> Vec3 {
        let (c, s) = (self.cos_rot, self.sin_rot);
        Vec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
    }

    fn texel_index(&self, d_world: Vec3) -> usize {
        let (u, v) = Environment::uv(self.to_map(d_world));
        let i = ((u * self.width as f32) as i64).clamp(0, self.width as i64 - 1) as usize;
        let j = ((v * self.height as f32) as i64).clamp(0, self.height as i64 - 1) as usize;
        j * self.width as usize + i
    }

    /// Radiance arriving from world direction `d` (unit).
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        if let Some(sg) = &self.sg {
            return eval_sg_sum(sg, d);
        }
        self.texels[self.texel_index(d)]
    }

    /// Whether importance sampling is possible (some positive radiance).
    pub fn can_sample(&self) -> bool {
        self.table.is_some()
    }

    /// Solid-angle pdf of [`EnvLight::sample`] for world direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        match &self.table {
            None => 0.0,
            Some(t) => {
                let i = self.texel_index(d);
                let j = i / self.width as usize;
                t.pmf(i) / self.row_solid_angle[j]
            }
        }
    }

    /// Sample a world direction: returns (direction, radiance, solid-angle pdf).
    pub fn sample(&self, u: [f32; 4]) -> Option<(Vec3, Vec3, f32)> {
        let t = self.table.as_ref()?;
        let i = t.sample(u[0], u[1]);
        let (w, _) = (self.width as usize, self.height as usize);
        let (ix, j) = (i % w, i / w);
        let phi = TAU * (ix as f32 + u[2]) / self.width as f32;
        let (c0, c1) = (self.row_cos[j], self.row_cos[j + 1]);
        let cos_t = (c0 + (c1 - c0) * u[3]).clamp(-1.0, 1.0);
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let d_map = Vec3::new(sin_t * phi.sin(), cos_t, -sin_t * phi.cos());
        let d = self.to_world(d_map).normalize();
        // Use the texel actually looked up for this direction, so that sample() and pdf() agree
        // even at texel borders.
        let k = self.texel_index(d);
        let pdf = t.pmf(k) / self.row_solid_angle[k / w];
        if pdf <= 0.0 {
            return None;
        }
        let l = match &self.sg {
            Some(sg) => eval_sg_sum(sg, d),
            None => self.texels[k],
        };
        Some((d, l, pdf))
    }
}
