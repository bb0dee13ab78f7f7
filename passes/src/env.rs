//! The environment map on the GPU: an RGBA32F lat-long image with a solid-angle weighted box
//! mip chain (uploaded once by the `env_upload` transfer pass into a persistent image; the
//! glossy term's lookups, `env_glossy` of `glsl/include/env_shade.glsl`), and its 9-coefficient
//! SH irradiance (Ramamoorthi and Hanrahan 2001; kept for tests: the diffuse term reads the exact
//! irradiance map, `lighting::camera_irradiance`, since SH9 rings under a bright source).
//!
//! Orientation: `penumbra_scene::Environment::direction` (v = 0 is +Y); the scene's `rotation`
//! turns the map about +Y, the shader undoes it per lookup.

use crate::util::bytes_of;
use glam::Vec3;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::{vk, FrameStore, Graph, ImageHandle};
use penumbra_scene::{Environment, EnvironmentState};

/// CPU-side environment data ready for the GPU.
#[derive(Clone, Debug)]
pub struct EnvMapGpu {
    pub width: u32,
    pub height: u32,
    /// RGBA texels of every mip level, level 0 first.
    pub mips: Vec<(u32, u32, Vec<[f32; 4]>)>,
    /// Irradiance SH (already convolved with the clamped cosine), rgb per coefficient, in the world
    /// frame of the loaded rotation: a CPU reference for tests (no shader reads it; the diffuse
    /// term reads the exact irradiance map, `lighting::camera_irradiance`).
    pub sh: [[f32; 3]; 9],
    /// Texels that were NaN/Inf/negative and were replaced by 0.
    pub repaired_texels: usize,
}

/// Real SH basis, bands 0..2, in the order of [`EnvMapGpu::sh`].
pub fn sh9_basis(d: Vec3) -> [f32; 9] {
    [
        0.282095,
        0.488603 * d.y,
        0.488603 * d.z,
        0.488603 * d.x,
        1.092548 * d.x * d.y,
        1.092548 * d.y * d.z,
        0.315392 * (3.0 * d.z * d.z - 1.0),
        1.092548 * d.x * d.z,
        0.546274 * (d.x * d.x - d.y * d.y),
    ]
}

/// Irradiance from the convolved coefficients (CPU twin of the shader).
pub fn sh9_irradiance(sh: &[[f32; 3]; 9], n: Vec3) -> Vec3 {
    let b = sh9_basis(n);
    let mut r = Vec3::ZERO;
    for i in 0..9 {
        r += Vec3::from_array(sh[i]) * b[i];
    }
    r.max(Vec3::ZERO)
}

/// World direction of lat-long (u, v) with the map turned by `rotation` about +Y.
pub fn world_direction(u: f32, v: f32, rotation: f32) -> Vec3 {
    let r = Environment::direction(u, v);
    let (s, c) = rotation.sin_cos();
    Vec3::new(c * r.x + s * r.z, r.y, -s * r.x + c * r.z)
}

/// `env` halved (2x2 box filter) until both sides are at most `max_side` texels (a device's
/// `maxImageDimension2D`); `None` when it fits already.
pub fn fit_to_device(env: &Environment, max_side: u32) -> Option<Environment> {
    let max_side = max_side.max(1);
    if env.width <= max_side && env.height <= max_side {
        return None;
    }
    let mut e = env.clone();
    while e.width > max_side || e.height > max_side {
        let (w, h) = ((e.width / 2).max(1), (e.height / 2).max(1));
        let at = |x: u32, y: u32| e.texels[(y.min(e.height - 1) * e.width + x.min(e.width - 1)) as usize];
        let texels = (0..w * h)
            .map(|i| {
                let (x, y) = (2 * (i % w), 2 * (i / w));
                let q = [at(x, y), at(x + 1, y), at(x, y + 1), at(x + 1, y + 1)];
                [0, 1, 2].map(|c| q.iter().map(|t| t[c]).sum::<f32>() * 0.25)
            })
            .collect();
        e = Environment { width: w, height: h, texels, ..e };
    }
    Some(e)
}

impl EnvMapGpu {
    pub fn new(env: Option<&Environment>) -> Self {
        let black;
        let env = match env {
            Some(e) if e.width > 0 && e.height > 0 && e.texels.len() == (e.width * e.height) as usize => e,
            _ => {
                black = Environment { width: 4, height: 2, texels: vec![[0.0; 3]; 8], intensity: 0.0, rotation: 0.0 };
                &black
            }
        };
        let mut repaired = 0;
        let base: Vec<[f32; 4]> = env
            .texels
            .iter()
            .map(|t| {
                let ok = Environment::texel_ok(t);
                if !ok {
                    repaired += 1;
                }
                if ok {
                    [t[0], t[1], t[2], 1.0]
                } else {
                    [0.0, 0.0, 0.0, 1.0]
                }
            })
            .collect();
        // SH projection, weighted by texel solid angle (2 pi / W)(pi / H) sin(theta); f64 sums
        // so a 1e4-bright sun does not swamp the sky's contribution.
        let (w, h) = (env.width, env.height);
        let mut acc = [[0f64; 3]; 9];
        let dw = (2.0 * std::f64::consts::PI / w as f64) * (std::f64::consts::PI / h as f64);
        for j in 0..h {
            let v = (j as f32 + 0.5) / h as f32;
            let sin_t = (std::f64::consts::PI * v as f64).sin();
            for i in 0..w {
                let u = (i as f32 + 0.5) / w as f32;
                let d = world_direction(u, v, env.rotation);
                let b = sh9_basis(d);
                let t = base[(j * w + i) as usize];
                for k in 0..9 {
                    for c in 0..3 {
                        acc[k][c] += t[c] as f64 * b[k] as f64 * dw * sin_t;
                    }
                }
            }
        }
        let band = [std::f64::consts::PI, 2.0 * std::f64::consts::PI / 3.0, std::f64::consts::PI / 4.0];
        let mut sh = [[0f32; 3]; 9];
        for k in 0..9 {
            let l = if k == 0 {
                0
            } else if k < 4 {
                1
            } else {
                2
            };
            for c in 0..3 {
                sh[k][c] = (acc[k][c] * band[l]) as f32;
            }
        }
        // Box-filtered mip chain down to 1x1, each texel the solid-angle-weighted mean of its
        // children (a row's weight is its band's cos(theta_top) - cos(theta_bottom)): an
        // unweighted mean counts the polar rows as much as the equator's, which darkened the
        // glossy reflections of environments bright at the horizon by over a tenth at the
        // coarse levels rough lobes read (a GGX 0.7 sphere under sunset-dwab.exr: 0.77 -> 0.89
        // of the reference).
        let band = |row: u32, rows: u32| {
            let t = |r: u32| (std::f64::consts::PI * r as f64 / rows as f64).cos();
            (t(row) - t(row + 1)).max(0.0) as f32
        };
        let mut mips = vec![(w, h, base)];
        while mips.last().is_some_and(|m| m.0 > 1 || m.1 > 1) {
            let (pw, ph, prev) = mips.last().unwrap();
            let (nw, nh) = ((pw / 2).max(1), (ph / 2).max(1));
            let mut next = vec![[0f32; 4]; (nw * nh) as usize];
            for y in 0..nh {
                for x in 0..nw {
                    let mut s = [0f32; 4];
                    let mut n = 0.0;
                    for dy in 0..2 {
                        for dx in 0..2 {
                            let sx = (x * 2 + dx).min(pw - 1);
                            let sy = (y * 2 + dy).min(ph - 1);
                            let t = prev[(sy * pw + sx) as usize];
                            let wt = band(sy, *ph);
                            for c in 0..4 {
                                s[c] += t[c] * wt;
                            }
                            n += wt;
                        }
                    }
                    next[(y * nw + x) as usize] = if n > 0.0 { s.map(|c| c / n) } else { [0.0; 4] };
                }
            }
            mips.push((nw, nh, next));
        }
        EnvMapGpu { width: w, height: h, mips, sh, repaired_texels: repaired }
    }

    pub fn desc(&self) -> ImageDesc {
        ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, self.width, self.height).with_mips(self.mips.len() as u32)
    }

    /// Declares the persistent `env_map` image; on its first frame adds the `env_upload` pass.
    /// Returns the handle to sample.
    pub fn add(&self, engine: &mut FrameStore<'_>, graph: &mut Graph) -> ImageHandle {
        let img = engine.persistent_image(graph, "env_map", self.desc());
        if !graph.persistent_is_new(img) {
            return img;
        }
        let bytes: Vec<Vec<u8>> = self.mips.iter().map(|(_, _, texels)| bytes_of(texels)).collect();
        let parts = self.mips.iter().zip(&bytes).enumerate().map(|(level, ((w, h, _), bytes))| {
            crate::util::Subresource { mip: level as u32, layer: 0, width: *w, height: *h, bytes }
        });
        crate::util::add_image_upload(graph, "env", img, parts)
    }
}

// ---- Importance tables of the environment (mc, shadowmaps): texel distribution proportional to
// luminance x solid angle, as the CPU reference's alias table.

/// Environment sampling tables (CPU side), in the map's own frame at unit intensity: the
/// environment's state (rotation, intensity; animated per frame, [`EnvTables::set_state`]) is
/// applied when sampling, so the tables are built once.
pub struct EnvTables {
    pub width: u32,
    pub height: u32,
    /// rgb radiance (at intensity 1), w = probability of the texel.
    pub texels: Vec<[f32; 4]>,
    /// Marginal CDF over rows (height + 1), then each row's conditional CDF (width + 1).
    pub cdf: Vec<f32>,
    pub can_sample: bool,
    /// The current state: cos and sin of the rotation, and the intensity.
    pub cos_rot: f32,
    pub sin_rot: f32,
    pub intensity: f32,
}

fn luminance(c: Vec3) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

impl EnvTables {
    pub fn new(env: Option<&Environment>) -> Self {
        let black = Environment { width: 1, height: 1, texels: vec![[0.0; 3]], intensity: 0.0, rotation: 0.0 };
        let env = match env {
            Some(e) if e.width > 0 && e.height > 0 && e.texels.len() == (e.width * e.height) as usize => e,
            _ => &black,
        };
        let (w, h) = (env.width as usize, env.height as usize);
        let rad: Vec<Vec3> = env
            .texels
            .iter()
            .map(|t| {
                // as the environment texture and the reference read it: a texel with a NaN,
                // infinite or negative channel is black (studio.exr holds texels down to -149,
                // which gave `mc` negative pixels)
                let ok = Environment::texel_ok(t);
                let v = if ok { Vec3::from_array(*t) } else { Vec3::ZERO };
                if v.is_finite() {
                    v
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        let pi = std::f64::consts::PI;
        let row_sa: Vec<f64> = (0..h)
            .map(|j| ((j as f64 * pi / h as f64).cos() - ((j + 1) as f64 * pi / h as f64).cos()) * 2.0 * pi / w as f64)
            .collect();
        let weights: Vec<f64> =
            rad.iter().enumerate().map(|(i, t)| luminance(t.max(Vec3::ZERO)) * row_sa[i / w]).collect();
        let total: f64 = weights.iter().sum();
        let can_sample = total.is_finite() && total > 0.0;
        let mut cdf = Vec::with_capacity(h + 1 + h * (w + 1));
        let row_tot: Vec<f64> = (0..h).map(|j| weights[j * w..(j + 1) * w].iter().sum()).collect();
        let mut acc = 0.0;
        cdf.push(0.0);
        for (j, rt) in row_tot.iter().enumerate() {
            acc += rt;
            cdf.push(if j + 1 == h { 1.0 } else { (acc / total.max(1e-300)) as f32 });
        }
        for j in 0..h {
            let mut a = 0.0;
            cdf.push(0.0);
            for i in 0..w {
                a += weights[j * w + i];
                cdf.push(if i + 1 == w {
                    1.0
                } else if row_tot[j] > 0.0 {
                    (a / row_tot[j]) as f32
                } else {
                    (i + 1) as f32 / w as f32
                });
            }
        }
        let texels = rad
            .iter()
            .zip(&weights)
            .map(|(r, wt)| [r.x, r.y, r.z, if can_sample { (wt / total) as f32 } else { 0.0 }])
            .collect();
        let mut t = EnvTables {
            width: w as u32,
            height: h as u32,
            texels,
            cdf,
            can_sample,
            cos_rot: 1.0,
            sin_rot: 0.0,
            intensity: 0.0,
        };
        t.set_state(env.state());
        t
    }

    /// Turns and scales the environment to `state` (a frame's, `Frame::environment`); a value
    /// that is not finite reads as 0. Returns whether anything changed.
    pub fn set_state(&mut self, state: EnvironmentState) -> bool {
        let rot = if state.rotation.is_finite() { state.rotation } else { 0.0 };
        let intensity = if state.intensity.is_finite() { state.intensity.max(0.0) } else { 0.0 };
        let (sin_rot, cos_rot) = rot.sin_cos();
        let changed = (cos_rot, sin_rot, intensity) != (self.cos_rot, self.sin_rot, self.intensity);
        (self.cos_rot, self.sin_rot, self.intensity) = (cos_rot, sin_rot, intensity);
        changed
    }
}

impl EnvTables {
    fn search(cdf: &[f32], u: f32) -> usize {
        // first i with cdf[i + 1] > u, as the shader's binary search
        let n = cdf.len() - 1;
        let (mut lo, mut hi) = (0usize, n);
        while lo + 1 < hi {
            let mid = (lo + hi) / 2;
            if cdf[mid] <= u {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }

    fn texel_of(&self, dw: Vec3) -> usize {
        let (c, s) = (self.cos_rot, self.sin_rot);
        let d = Vec3::new(c * dw.x - s * dw.z, dw.y, s * dw.x + c * dw.z);
        let (u, v) = penumbra_scene::Environment::uv(d);
        let i = ((u * self.width as f32) as i64).clamp(0, self.width as i64 - 1) as usize;
        let j = ((v * self.height as f32) as i64).clamp(0, self.height as i64 - 1) as usize;
        j * self.width as usize + i
    }

    /// Samples a world direction from four uniforms: (direction, radiance, solid-angle pdf), at
    /// the current state.
    pub fn sample(&self, u: [f32; 4]) -> Option<(Vec3, Vec3, f32)> {
        if !self.can_sample {
            return None;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let j = Self::search(&self.cdf[0..h + 1], u[0]);
        let base = h + 1 + j * (w + 1);
        let ix = Self::search(&self.cdf[base..base + w + 1], u[1]);
        let pi = std::f32::consts::PI;
        let phi = std::f32::consts::TAU * (ix as f32 + u[2]) / w as f32;
        let (c0, c1) = ((pi * j as f32 / h as f32).cos(), (pi * (j + 1) as f32 / h as f32).cos());
        let cos_t = (c0 + (c1 - c0) * u[3]).clamp(-1.0, 1.0);
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let dm = Vec3::new(sin_t * phi.sin(), cos_t, -sin_t * phi.cos());
        let (c, s) = (self.cos_rot, self.sin_rot);
        let d = Vec3::new(c * dm.x + s * dm.z, dm.y, -s * dm.x + c * dm.z).normalize();
        let k = self.texel_of(d);
        let row = k / w;
        let sa = ((pi * row as f32 / h as f32).cos() - (pi * (row + 1) as f32 / h as f32).cos())
            * std::f32::consts::TAU
            / w as f32;
        let pdf = self.texels[k][3] / sa;
        (pdf > 0.0 && pdf.is_finite())
            .then(|| (d, Vec3::new(self.texels[k][0], self.texels[k][1], self.texels[k][2]) * self.intensity, pdf))
    }
}
