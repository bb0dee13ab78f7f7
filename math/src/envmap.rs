//! Lat-long HDR environment maps: SG-prefiltered maps (`Gamma_L`) and fitting K spherical
//! Gaussians to a map.
//!
//! # Map convention
//! Same as `penumbra_scene::Environment::direction`: `width x height` linear-RGB texels, row 0 is
//! the +Y pole; the pixel centre `(u, v) = ((x + 0.5)/width, (y + 0.5)/height)` maps to
//! `phi = 2 pi u`, `theta = pi v`, `d = (sin(theta) sin(phi), cos(theta), -sin(theta) cos(phi))`.
//! Texel `(x, y)` is treated as constant over its solid angle
//! `(cos(theta_top) - cos(theta_bottom)) 2 pi / width`.
//!
//! # SG fit ([`SgEnvFitter`], [`fit_sg_lighting`])
//! Least squares on solid-angle-weighted texels,
//! `min sum_i w_i |L_i - sum_k G_k(d_i)|^2` with non-negative RGB amplitudes:
//! 0. *Sun/sky split* ([`SgFitOptions::sun_cap`]): texels brighter than 100 x the median
//!    luminance are split into a sky part (clamped) and an excess part; each part is fit by
//!    steps 1-3 with its own lobes and the lobe sets are joined; matching pursuit gives each
//!    next lobe to the part whose relative energy decrease is largest.
//!    Maps without such texels are fit in one part. By default ([`SunLobes::Moments`]) the
//!    excess is not fit by least squares but grouped by angle, one lobe per group matching its
//!    energy, mean direction and angular spread (see [`SunLobes`]).
//! 1. *Selection* (matching pursuit on luminance): for a ladder of sharpness values
//!    (`lambda_min` .. the map's resolution limit, ratio `ladder_ratio`) the correlation maps
//!    `C_lambda(a) = sum_i w_i Y_i G(d_i; a, lambda)` are computed once (a sharpness-matched
//!    mip level and output grid, with culling of the lobe support). Each step picks the
//!    `(a, lambda)` maximising the energy decrease `max(R, 0)^2 / |G|^2` of the residual
//!    correlation `R = C - sum_k mu_k <G_k, G_(a,lambda)>` (analytic SG inner products, so the
//!    residual is updated without re-convolving), refines the axis by a parabolic fit on the
//!    score grid, and subtracts the lobe with its optimal amplitude.
//! 2. *Refinement*: passes of coordinate search over each lobe's sharpness (factor `2^(+-s)`)
//!    and axis (`+-s/sqrt(lambda)` along two tangents), `s = 1/2, 1/4, ...` per pass, each trial
//!    re-solving the RGB NNLS with an incrementally updated Gram matrix, on a reduced map (at most
//!    64 rows; lobes sharper than it resolves are left alone).
//! 3. *Amplitudes*: exact discrete NNLS per RGB channel at full resolution (Gram matrix
//!    `sum_i w_i G_k G_l` and right-hand side `sum_i w_i G_k L_i`; [`crate::nnls`]).
//!
//! The reported error is the relative L2 error over the sphere at full resolution,
//! `sqrt(sum_i w_i |L_i - fit_i|^2 / sum_i w_i |L_i|^2)` (RGB summed).
//!
//! # Prefiltered maps ([`prefilter`])
//! `Gamma_L(a, lambda) = int L(w) G(w; a, lambda, 1) dw` (paper eq. 10). We store the normalised
//! value `Gamma_L(a, lambda) / int G(w; a, lambda, 1) dw` (the average of `L` under the lobe; the
//! normalisation uses the discrete weights, so a constant map stays exactly constant), in
//! lat-long maps of the same convention. Multiply by `Sg::sphere_integral` to get `Gamma_L`.

use crate::nnls::nnls_gram;
use crate::sg::{Sg, SgRgb};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Errors for environment-map input.
#[derive(Debug, Clone, PartialEq)]
pub enum EnvError {
    /// Width or height is zero.
    Empty,
    /// `texels.len() != width * height`.
    SizeMismatch {
        /// `width * height`.
        expected: usize,
        /// Number of texels given.
        got: usize,
    },
    /// A texel is NaN or infinite (negative values are clamped to 0 instead).
    NonFinite {
        /// Row-major index of the first bad texel.
        index: usize,
    },
    /// Invalid option (message says which).
    BadOption(&'static str),
}

impl std::fmt::Display for EnvError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EnvError::Empty => write!(f, "environment map is empty"),
            EnvError::SizeMismatch { expected, got } => {
                write!(f, "environment map has {got} texels, expected {expected}")
            }
            EnvError::NonFinite { index } => write!(f, "environment map texel {index} is not finite"),
            EnvError::BadOption(m) => write!(f, "invalid option: {m}"),
        }
    }
}
impl std::error::Error for EnvError {}

/// Direction of lat-long coordinates `(u, v)` in `[0,1]^2` (see the module docs).
pub fn latlong_direction(u: f64, v: f64) -> DVec3 {
    let phi = u * 2.0 * PI;
    let theta = v * PI;
    DVec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos())
}

/// Inverse of [`latlong_direction`].
pub fn latlong_uv(d: DVec3) -> (f64, f64) {
    let theta = d.y.clamp(-1.0, 1.0).acos();
    let mut phi = d.x.atan2(-d.z);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    (phi / (2.0 * PI), theta / PI)
}

/// A lat-long map in f64 with precomputed texel directions and solid angles.
#[derive(Clone, Debug)]
pub struct LatLong {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// Linear RGB, row-major, row 0 = +Y pole.
    pub rgb: Vec<DVec3>,
    dirs: Vec<DVec3>,
    row_weight: Vec<f64>,
}

impl LatLong {
    /// Validates and converts `[f32; 3]` texels. Negative components are clamped to 0.
    pub fn new(width: usize, height: usize, texels: &[[f32; 3]]) -> Result<Self, EnvError> {
        if width == 0 || height == 0 {
            return Err(EnvError::Empty);
        }
        if texels.len() != width * height {
            return Err(EnvError::SizeMismatch { expected: width * height, got: texels.len() });
        }
        let mut rgb = Vec::with_capacity(texels.len());
        for (i, t) in texels.iter().enumerate() {
            if !t.iter().all(|c| c.is_finite()) {
                return Err(EnvError::NonFinite { index: i });
            }
            rgb.push(DVec3::new(t[0].max(0.0) as f64, t[1].max(0.0) as f64, t[2].max(0.0) as f64));
        }
        Ok(Self::from_rgb(width, height, rgb))
    }

    fn from_rgb(width: usize, height: usize, rgb: Vec<DVec3>) -> Self {
        let mut dirs = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                dirs.push(latlong_direction((x as f64 + 0.5) / width as f64, (y as f64 + 0.5) / height as f64));
            }
        }
        let row_weight = (0..height)
            .map(|y| {
                let t0 = PI * y as f64 / height as f64;
                let t1 = PI * (y + 1) as f64 / height as f64;
                (t0.cos() - t1.cos()) * 2.0 * PI / width as f64
            })
            .collect();
        Self { width, height, rgb, dirs, row_weight }
    }

    /// Direction of texel `i` (row-major index).
    pub fn dir(&self, i: usize) -> DVec3 {
        self.dirs[i]
    }

    /// Solid angle of a texel of row `y`.
    pub fn solid_angle(&self, y: usize) -> f64 {
        self.row_weight[y]
    }

    /// Relative L2 error over the sphere of an RGB SG lighting against this map.
    pub fn relative_l2_error(&self, lobes: &[SgRgb]) -> f64 {
        let (num, den) = (0..self.height)
            .into_par_iter()
            .map(|y| {
                let w = self.row_weight[y];
                let mut n = 0.0;
                let mut d = 0.0;
                for x in 0..self.width {
                    let i = y * self.width + x;
                    let f = SgRgb::eval_sum(lobes, self.dirs[i]);
                    n += w * (f - self.rgb[i]).length_squared();
                    d += w * self.rgb[i].length_squared();
                }
                (n, d)
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        if den > 0.0 {
            (num / den).sqrt()
        } else if num > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    }

    /// 2x2 solid-angle-weighted box downsample (requires even width and height).
    pub fn downsample(&self) -> Option<LatLong> {
        if !self.width.is_multiple_of(2) || !self.height.is_multiple_of(2) || self.height < 2 {
            return None;
        }
        let (w2, h2) = (self.width / 2, self.height / 2);
        let mut rgb = vec![DVec3::ZERO; w2 * h2];
        for y in 0..h2 {
            let (wa, wb) = (self.row_weight[2 * y], self.row_weight[2 * y + 1]);
            for x in 0..w2 {
                let a = self.rgb[2 * y * self.width + 2 * x] + self.rgb[2 * y * self.width + 2 * x + 1];
                let b = self.rgb[(2 * y + 1) * self.width + 2 * x] + self.rgb[(2 * y + 1) * self.width + 2 * x + 1];
                rgb[y * w2 + x] = (a * wa + b * wb) / (2.0 * (wa + wb));
            }
        }
        Some(LatLong::from_rgb(w2, h2, rgb))
    }

    /// Total `int L dw` (RGB).
    pub fn integral(&self) -> DVec3 {
        let mut s = DVec3::ZERO;
        for y in 0..self.height {
            for x in 0..self.width {
                s += self.rgb[y * self.width + x] * self.row_weight[y];
            }
        }
        s
    }
}

/// Truncation of the SG support: texels with `lambda (1 - cos) > SUPPORT_CUTOFF` are skipped
/// (relative contribution below `exp(-30) ~ 1e-13`).
const SUPPORT_CUTOFF: f64 = 30.0;

/// Calls `f(i, g)` with `g = G(d_i; a, lambda, 1)` for the texels `i` of `grid` in the support
/// `lambda (1 - dot(a, d_i)) <= cutoff` of a lobe about `a` (rows by angular distance, then the
/// azimuth range of the cap per row, with a one-texel margin).
fn for_each_in_support(grid: &LatLong, a: DVec3, lambda: f64, cutoff: f64, mut f: impl FnMut(usize, f64)) {
    let (h, w) = (grid.height, grid.width);
    let cos_cut = 1.0 - cutoff / lambda.max(1e-300);
    let mut visit_row = |y: usize, x0: isize, n: usize| {
        for k in 0..n {
            let x = (x0 + k as isize).rem_euclid(w as isize) as usize;
            let i = y * w + x;
            let om = 1.0 - a.dot(grid.dirs[i]);
            f(i, (-lambda * om.max(0.0)).exp());
        }
    };
    if cos_cut <= -1.0 {
        for y in 0..h {
            visit_row(y, 0, w);
        }
        return;
    }
    let big_theta = cos_cut.acos();
    let ta = a.y.clamp(-1.0, 1.0).acos();
    let (ua, _) = latlong_uv(a);
    let dtheta = PI / h as f64;
    let dphi = 2.0 * PI / w as f64;
    let y0 = (((ta - big_theta) / dtheta).floor() - 1.0).max(0.0) as usize;
    let y1 = ((((ta + big_theta) / dtheta).ceil() + 1.0) as usize).min(h);
    let (sa, ca) = (ta.sin(), ta.cos());
    for y in y0..y1 {
        let t = (y as f64 + 0.5) * dtheta;
        let (st, ct) = (t.sin(), t.cos());
        let denom = sa * st;
        let half = if denom < 1e-12 {
            PI
        } else {
            let q = (cos_cut - ca * ct) / denom;
            if q <= -1.0 {
                PI
            } else if q >= 1.0 {
                // ring centre misses the cap; its texels may still touch it: one texel margin
                2.0 * dphi
            } else {
                q.acos() + 2.0 * dphi
            }
        };
        if half >= PI {
            visit_row(y, 0, w);
        } else {
            let xc = ua * w as f64 - 0.5;
            let x0 = (xc - half / dphi).floor() as isize;
            let x1 = (xc + half / dphi).ceil() as isize;
            let n = ((x1 - x0 + 1) as usize).min(w);
            visit_row(y, x0, n);
        }
    }
}

/// `(sum_i w_i L_i G(d_i; a, lambda), sum_i w_i G(d_i; a, lambda))` for lobe axis `a` over
/// `src`, visiting only the lobe's support.
fn convolve_at(src: &LatLong, a: DVec3, lambda: f64, cutoff: f64, values: &dyn Fn(usize) -> DVec3) -> (DVec3, f64) {
    let mut acc = DVec3::ZERO;
    let mut wsum = 0.0;
    let w = src.width;
    for_each_in_support(src, a, lambda, cutoff, |i, g| {
        let gw = g * src.row_weight[i / w];
        acc += values(i) * gw;
        wsum += gw;
    });
    (acc, wsum)
}

/// One level of a prefiltered environment: the map convolved with a normalised SG of
/// sharpness `lambda`.
#[derive(Clone, Debug)]
pub struct PrefilteredLevel {
    /// SG sharpness of this level.
    pub lambda: f64,
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// `Gamma_L(a, lambda) / int G(.; a, lambda, 1)` per texel (linear RGB, same lat-long
    /// convention as the input).
    pub texels: Vec<[f32; 3]>,
}

/// Mip pyramid of a map (level 0 = full resolution).
fn pyramid(map: &LatLong) -> Vec<LatLong> {
    let mut levels = vec![map.clone()];
    while levels.last().unwrap().height > 4 {
        match levels.last().unwrap().downsample() {
            Some(l) => levels.push(l),
            None => break,
        }
    }
    levels
}

/// Coarsest pyramid level whose texels are at most `frac` of the lobe's angular width.
fn level_for(levels: &[LatLong], lambda: f64, frac: f64) -> &LatLong {
    let sigma = 1.0 / lambda.max(1e-300).sqrt();
    let mut best = &levels[0];
    for l in levels {
        if PI / l.height as f64 <= frac * sigma {
            best = l;
        }
    }
    best
}

/// Output height used for sharpness `lambda`: texel at most `1/density` of the lobe width, at
/// least 8, at most `max_height`.
fn out_height(lambda: f64, max_height: usize, density: f64) -> usize {
    let need = (density * PI * lambda.max(0.0).sqrt()).ceil() as usize;
    need.next_power_of_two().max(8).min(max_height.max(1))
}

/// Convolves `src` with a normalised SG of sharpness `lambda` onto an `ow x oh` lat-long grid.
fn convolve_map(
    src: &LatLong,
    lambda: f64,
    ow: usize,
    oh: usize,
    cutoff: f64,
    values: &(dyn Fn(usize) -> DVec3 + Sync),
) -> Vec<(DVec3, f64)> {
    (0..oh)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..ow).map(move |x| {
                let a = latlong_direction((x as f64 + 0.5) / ow as f64, (y as f64 + 0.5) / oh as f64);
                convolve_at(src, a, lambda, cutoff, values)
            })
        })
        .collect()
}

/// Prefiltered environment maps for each sharpness in `lambdas` (paper's `Gamma_L`, normalised;
/// see the module docs). The output of level `lambda` has height
/// `min(max_height, pow2(1.5 pi sqrt(lambda)))` (at least 8) and twice that width; the source is
/// the coarsest mip level that still resolves the lobe.
pub fn prefilter(
    width: usize,
    height: usize,
    texels: &[[f32; 3]],
    lambdas: &[f64],
    max_height: usize,
) -> Result<Vec<PrefilteredLevel>, EnvError> {
    let map = LatLong::new(width, height, texels)?;
    if lambdas.iter().any(|l| !(l.is_finite() && *l >= 0.0)) {
        return Err(EnvError::BadOption("lambdas must be finite and >= 0"));
    }
    let levels = pyramid(&map);
    Ok(lambdas
        .iter()
        .map(|&lambda| {
            let src = level_for(&levels, lambda, 0.5);
            let oh = out_height(lambda, max_height.min(height), 1.5);
            let ow = (oh * width / height).max(1);
            let vals = |i: usize| src.rgb[i];
            let conv = convolve_map(src, lambda, ow, oh, SUPPORT_CUTOFF, &vals);
            let texels = conv
                .iter()
                .map(|(v, w)| {
                    let c = if *w > 0.0 { *v / *w } else { DVec3::ZERO };
                    [c.x as f32, c.y as f32, c.z as f32]
                })
                .collect();
            PrefilteredLevel { lambda, width: ow, height: oh, texels }
        })
        .collect())
}

/// Options of the SG environment fit.
#[derive(Clone, Debug)]
pub struct SgFitOptions {
    /// Smallest sharpness of the selection ladder (default 0.5: a lobe covering the sphere).
    pub lambda_min: f64,
    /// Largest sharpness; `None` = the map's resolution limit `2 (height/pi)^2`.
    pub lambda_max: Option<f64>,
    /// Ratio between consecutive ladder sharpness values (default 2).
    pub ladder_ratio: f64,
    /// Sharpness-refinement passes over the sky lobes (default 2; 0 disables).
    pub refine_passes: usize,
    /// Sun/sky split (default `Some(100.0)`; `None` = one plain least-squares fit of the whole
    /// map). Texels whose luminance `Y` exceeds `cap = sun_cap x median luminance` are split into
    /// a sky part `L min(1, cap/Y)` and an excess part `L (1 - cap/Y)` (they sum to `L`). The
    /// excess (a sun, studio lights) is fit by its own lobes, the sky part by the rest (each
    /// lobe goes to the part with the largest relative energy decrease). Without the split a sun 1e4 x brighter than the sky dominates the L2
    /// norm: every lobe goes to the sun's disk-vs-Gaussian residual and broad lobes are bent to
    /// patch it, so the sky is lost.
    pub sun_cap: Option<f64>,
    /// How the excess part (the sun, studio lights) becomes lobes (default
    /// [`SunLobes::Moments`]).
    pub sun_lobes: SunLobes,
}

/// How [`SgEnvFitter`] fits the excess part of a map split by [`SgFitOptions::sun_cap`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SunLobes {
    /// Matching pursuit and NNLS, as the sky (least squares): a light of a few degrees with a
    /// bright core (studio.exr's ring-shaped softbox, about 10 degrees across) becomes a lobe as
    /// sharp as its core (lambda 1024, 2.5 degrees) plus spikes, so its shadows come out hard and
    /// their umbrae black.
    Pursuit,
    /// The excess texels (whole texels over the cap) grouped by angle (brightest first, a texel
    /// farther than [`SUN_GROUP_ANGLE`] from every group's mean direction starts a group, then
    /// each texel goes to the nearest; at most a quarter of the lobes, a weaker group giving its
    /// energy to the nearest), each group one lobe with the group's
    /// energy (RGB), its mean direction as axis, and the sharpness whose mean cosine
    /// `coth(lambda) - 1/lambda` equals the group's: the light's angular extent, which sets its
    /// shadows' penumbrae, rather than its core's L2 fit. The lobes left go to the sky.
    Moments,
}

/// Angle (radians, 15 degrees) from every group's mean direction beyond which an excess texel
/// starts a group of its own in [`SunLobes::Moments`].
pub const SUN_GROUP_ANGLE: f64 = 0.2618;

impl Default for SgFitOptions {
    fn default() -> Self {
        Self {
            lambda_min: 0.5,
            lambda_max: None,
            ladder_ratio: 2.0,
            refine_passes: 2,
            sun_cap: Some(100.0),
            sun_lobes: SunLobes::Moments,
        }
    }
}

/// The sharpness of an SG whose mean cosine about its axis over the sphere,
/// `coth(lambda) - 1/lambda`, is `r` (in `[lo, hi]`).
fn lambda_of_mean_cosine(r: f64, lo: f64, hi: f64) -> f64 {
    let f = |l: f64| 1.0 / l.tanh() - 1.0 / l;
    if !(r > f(lo)) {
        return lo;
    }
    if r >= f(hi) {
        return hi;
    }
    let (mut a, mut b) = (lo.ln(), hi.ln());
    for _ in 0..80 {
        let m = 0.5 * (a + b);
        if f(m.exp()) < r {
            a = m;
        } else {
            b = m;
        }
    }
    (0.5 * (a + b)).exp()
}

/// [`SunLobes::Moments`]: at most `max_lobes` (>= 1) lobes for the excess map `map`, sharpness
/// within `[lambda_lo, lambda_hi]`.
fn moment_lobes(map: &LatLong, max_lobes: usize, lambda_lo: f64, lambda_hi: f64) -> Vec<SgRgb> {
    struct Group {
        /// The mean direction of the texels joined so far.
        seed: DVec3,
        rgb: DVec3,
        weight: f64,
        moment: DVec3,
    }
    let mut texels: Vec<(f64, usize)> = (0..map.rgb.len())
        .map(|i| (luminance(map.rgb[i]) * map.solid_angle(i / map.width), i))
        .filter(|(w, _)| *w > 0.0 && w.is_finite())
        .collect();
    texels.sort_by(|a, b| b.0.total_cmp(&a.0));
    // seeds: brightest first, a texel farther than SUN_GROUP_ANGLE from every group's mean
    // direction so far starts a group; then one Lloyd step: every texel to the group whose
    // mean direction is nearest (texels of equal brightness, a uniform disk, arrive in no
    // particular order)
    let cos_join = SUN_GROUP_ANGLE.cos();
    let mut groups: Vec<Group> = Vec::new();
    for &(w, i) in &texels {
        let d = map.dir(i);
        let g = match groups.iter().position(|g| g.seed.dot(d) >= cos_join) {
            Some(j) => j,
            None => {
                groups.push(Group { seed: d, rgb: DVec3::ZERO, weight: 0.0, moment: DVec3::ZERO });
                groups.len() - 1
            }
        };
        let g = &mut groups[g];
        g.weight += w;
        g.moment += d * w;
        g.seed = g.moment.normalize_or(d);
    }
    for g in &mut groups {
        (g.rgb, g.weight, g.moment) = (DVec3::ZERO, 0.0, DVec3::ZERO);
    }
    for &(w, i) in &texels {
        let d = map.dir(i);
        let g = groups.iter_mut().max_by(|a, b| a.seed.dot(d).total_cmp(&b.seed.dot(d))).unwrap();
        g.rgb += map.rgb[i] * map.solid_angle(i / map.width);
        g.weight += w;
        g.moment += d * w;
    }
    groups.retain(|g| g.weight > 0.0);
    // too many groups: the weakest gives its energy to the group whose mean direction is
    // nearest, which keeps its own direction and spread (joining their moments would put a
    // broad lobe between two distant lights)
    while groups.len() > max_lobes.max(1) {
        let (j, _) = groups.iter().enumerate().min_by(|a, b| a.1.weight.total_cmp(&b.1.weight)).unwrap();
        let weak = groups.swap_remove(j);
        let dir = weak.moment.normalize_or_zero();
        let near = groups
            .iter_mut()
            .max_by(|a, b| a.moment.normalize_or_zero().dot(dir).total_cmp(&b.moment.normalize_or_zero().dot(dir)))
            .unwrap();
        near.moment *= (near.weight + weak.weight) / near.weight;
        near.rgb += weak.rgb;
        near.weight += weak.weight;
    }
    groups
        .iter()
        .filter_map(|g| {
            let len = g.moment.length();
            if !(len > 0.0 && g.weight > 0.0) {
                return None;
            }
            let lambda = lambda_of_mean_cosine(len / g.weight, lambda_lo, lambda_hi);
            let unit = Sg { axis: g.moment / len, lambda, mu: 1.0 }.sphere_integral();
            Some(SgRgb { axis: g.moment / len, lambda, mu: g.rgb / unit })
        })
        .collect()
}

/// Result of an SG environment fit.
#[derive(Clone, Debug)]
pub struct SgEnvFit {
    /// Fitted lobes (RGB amplitudes >= 0, in radiance units of the map). Lobes whose amplitude
    /// came out zero are removed, so there may be fewer than requested.
    pub lobes: Vec<SgRgb>,
    /// Relative L2 error over the sphere at full resolution (see the module docs).
    pub rel_l2_error: f64,
}

struct CorrLevel {
    lambda: f64,
    ow: usize,
    oh: usize,
    axes: Vec<DVec3>,
    corr: Vec<f64>, // luminance correlation with the map
}

/// One part (sky or sun excess) of the map with its selection correlation maps.
struct Part {
    map: LatLong,
    reduced: LatLong,
    levels: Vec<CorrLevel>,
}

impl Part {
    fn new(map: LatLong, lambdas: &[f64]) -> Self {
        let (width, height) = (map.width, map.height);
        let lum = LatLong::from_rgb(width, height, map.rgb.iter().map(|c| DVec3::splat(luminance(*c))).collect());
        let pyr = pyramid(&lum);
        let levels = lambdas
            .iter()
            .map(|&lambda| {
                // selection only needs ~1e-6 accuracy and a grid of about one lobe width
                let src = level_for(&pyr, lambda, 1.0);
                let nonzero: Vec<usize> = (0..src.rgb.len()).filter(|&i| src.rgb[i].x > 0.0).collect();
                let sparse = nonzero.len() * 20 < src.rgb.len();
                // dense maps: grid of at most 128 rows (sharper lobes are placed by the parabolic
                // refinement); sparse maps (a sun's excess) are scattered onto the full-resolution
                // grid, which costs only (non-zero texels x lobe support)
                let oh = out_height(lambda, if sparse { height } else { height.min(128) }, 1.0);
                let ow = (oh * width / height).max(1);
                let grid = LatLong::from_rgb(ow, oh, vec![DVec3::ZERO; ow * oh]);
                let corr = if sparse {
                    let mut c = vec![0.0; ow * oh];
                    for &i in &nonzero {
                        let v = src.rgb[i].x * src.row_weight[i / src.width];
                        for_each_in_support(&grid, src.dirs[i], lambda, 14.0, |j, g| c[j] += v * g);
                    }
                    c
                } else {
                    let vals = |i: usize| src.rgb[i];
                    convolve_map(src, lambda, ow, oh, 14.0, &vals).iter().map(|c| c.0.x).collect()
                };
                CorrLevel { lambda, ow, oh, axes: grid.dirs, corr }
            })
            .collect();
        // reduced map for the refinement passes: at most 64 rows
        let mut reduced = map.clone();
        while reduced.height > 64 {
            match reduced.downsample() {
                Some(r) => reduced = r,
                None => break,
            }
        }
        Self { map, reduced, levels }
    }

    /// Luminance energy `sum_i w_i Y_i^2` of this part.
    fn energy(&self) -> f64 {
        (0..self.map.rgb.len())
            .map(|i| self.map.solid_angle(i / self.map.width) * luminance(self.map.rgb[i]).powi(2))
            .sum()
    }

    /// Best next matching-pursuit lobe for the residual correlations `resid`:
    /// `(energy decrease, lobe with its optimal amplitude)`.
    fn best_step(&self, resid: &[Vec<f64>]) -> Option<(f64, Sg)> {
        let best = self
            .levels
            .par_iter()
            .zip(resid.par_iter())
            .enumerate()
            .map(|(li, (lv, rs))| {
                let unit_norm2 = Sg::new(DVec3::Z, lv.lambda, 1.0).inner_product(&Sg::new(DVec3::Z, lv.lambda, 1.0));
                let mut best = (f64::NEG_INFINITY, 0usize, 0.0);
                for (i, &r) in rs.iter().enumerate() {
                    if r > 0.0 {
                        let score = r * r / unit_norm2;
                        if score > best.0 {
                            best = (score, i, r);
                        }
                    }
                }
                (best.0, li, best.1, best.2, unit_norm2)
            })
            .reduce(|| (f64::NEG_INFINITY, 0, 0, 0.0, 1.0), |a, b| if b.0 > a.0 { b } else { a });
        if !best.0.is_finite() || best.0 <= 0.0 {
            return None; // nothing left to explain
        }
        let (score, li, idx, r, n2) = best;
        let lv = &self.levels[li];
        let axis = refine_axis(lv, &resid[li], idx);
        Some((score, Sg { axis, lambda: lv.lambda, mu: r / n2 }))
    }

    /// Subtracts lobe `g` from the residual correlations.
    fn subtract(&self, resid: &mut [Vec<f64>], g: &Sg) {
        self.levels.par_iter().zip(resid.par_iter_mut()).for_each(|(lv, rs)| {
            // <G_k, G_a> ~ exp(-l l' (1 - a.a') / (l + l')): skip where below exp(-40)
            let c = lv.lambda * g.lambda / (lv.lambda + g.lambda);
            for (i, a) in lv.axes.iter().enumerate() {
                if c * (1.0 - a.dot(g.axis)) < 40.0 {
                    rs[i] -= Sg { axis: *a, lambda: lv.lambda, mu: 1.0 }.inner_product(g);
                }
            }
        });
    }

    /// Coordinate-search refinement of every lobe's sharpness and axis on the reduced map (each
    /// trial re-solves the RGB NNLS with an incrementally updated Gram matrix), then
    /// full-resolution NNLS.
    fn fit_shapes(&self, mut shapes: Vec<Sg>, passes: usize) -> Vec<SgRgb> {
        let m = &self.reduced;
        let n = m.rgb.len();
        let k = shapes.len();
        if passes > 0 && k > 0 {
            let lim = 2.0 * (m.height as f64 / PI).powi(2);
            let w: Vec<f64> = (0..n).map(|i| m.solid_angle(i / m.width)).collect();
            let col = |g: &Sg| -> Vec<f64> { (0..n).map(|i| g.eval(m.dir(i))).collect() };
            let mut cols: Vec<Vec<f64>> = shapes.iter().map(col).collect();
            let dotw = |a: &[f64], b: &[f64]| -> f64 { (0..n).map(|i| w[i] * a[i] * b[i]).sum() };
            let rhs = |a: &[f64]| -> DVec3 { (0..n).map(|i| m.rgb[i] * (w[i] * a[i])).sum() };
            let mut q = vec![0.0; k * k];
            for a in 0..k {
                for c in a..k {
                    let v = dotw(&cols[a], &cols[c]);
                    q[a * k + c] = v;
                    q[c * k + a] = v;
                }
            }
            let mut b: Vec<DVec3> = cols.iter().map(|c| rhs(c)).collect();
            let ll: f64 = (0..n).map(|i| w[i] * m.rgb[i].length_squared()).sum();
            let err = |q: &[f64], b: &[DVec3]| -> f64 {
                let mut e = ll;
                for ch in 0..3 {
                    let bc: Vec<f64> = b.iter().map(|v| v[ch]).collect();
                    let x = nnls_gram(q, &bc);
                    let qx: f64 = (0..k).map(|i| x[i] * (0..k).map(|j| q[i * k + j] * x[j]).sum::<f64>()).sum();
                    e += qx - 2.0 * bc.iter().zip(&x).map(|(u, v)| u * v).sum::<f64>();
                }
                e
            };
            let mut best = err(&q, &b);
            for pass in 0..passes {
                let step = 0.5f64.powi(pass as i32 + 1);
                for j in 0..k {
                    if shapes[j].lambda > lim {
                        continue; // sharper than the reduced map resolves
                    }
                    let g = shapes[j];
                    let (t1, t2) = crate::quad::orthonormal_basis(g.axis);
                    let da = step / g.lambda.max(0.25).sqrt();
                    let fl = 2f64.powf(step);
                    let trials = [
                        Sg { lambda: g.lambda * fl, ..g },
                        Sg { lambda: g.lambda / fl, ..g },
                        Sg { axis: (g.axis + t1 * da).normalize(), ..g },
                        Sg { axis: (g.axis - t1 * da).normalize(), ..g },
                        Sg { axis: (g.axis + t2 * da).normalize(), ..g },
                        Sg { axis: (g.axis - t2 * da).normalize(), ..g },
                    ];
                    for t in trials {
                        if t.lambda > lim {
                            continue;
                        }
                        let c = col(&t);
                        let mut q2 = q.clone();
                        for a in 0..k {
                            let v = if a == j { dotw(&c, &c) } else { dotw(&c, &cols[a]) };
                            q2[a * k + j] = v;
                            q2[j * k + a] = v;
                        }
                        let mut b2 = b.clone();
                        b2[j] = rhs(&c);
                        let e = err(&q2, &b2);
                        if e < best * (1.0 - 1e-9) {
                            best = e;
                            q = q2;
                            b = b2;
                            cols[j] = c;
                            shapes[j] = t;
                        }
                    }
                }
            }
        }
        nnls_rgb(&self.map, &vec![1.0; self.map.rgb.len()], &shapes).0
    }
}

/// Reusable fitter: validates the map and precomputes the selection correlation maps once, then
/// fits any number of lobes with [`SgEnvFitter::fit`].
pub struct SgEnvFitter {
    map: LatLong,
    sky: Part,
    sun: Option<Part>,
    opts: SgFitOptions,
}

fn luminance(c: DVec3) -> f64 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

impl SgEnvFitter {
    /// Prepares the fit of a `width x height` map (see the module docs for the convention).
    pub fn new(width: usize, height: usize, texels: &[[f32; 3]], opts: SgFitOptions) -> Result<Self, EnvError> {
        let map = LatLong::new(width, height, texels)?;
        if !(opts.lambda_min > 0.0 && opts.lambda_min.is_finite()) {
            return Err(EnvError::BadOption("lambda_min must be > 0"));
        }
        if !(opts.ladder_ratio > 1.0 && opts.ladder_ratio.is_finite()) {
            return Err(EnvError::BadOption("ladder_ratio must be > 1"));
        }
        let lmax = opts.lambda_max.unwrap_or(2.0 * (height as f64 / PI).powi(2)).max(opts.lambda_min);
        let mut lambdas = vec![];
        let mut l = opts.lambda_min;
        while l <= lmax * (1.0 + 1e-9) {
            lambdas.push(l);
            l *= opts.ladder_ratio;
        }
        let cap = match opts.sun_cap {
            None => f64::INFINITY,
            Some(f) if f > 0.0 => {
                let mut sorted: Vec<f64> = map.rgb.iter().map(|c| luminance(*c)).collect();
                sorted.sort_by(|a, b| a.total_cmp(b));
                let m = sorted[sorted.len() / 2];
                if m > 0.0 {
                    f * m
                } else {
                    f64::INFINITY
                }
            }
            Some(_) => return Err(EnvError::BadOption("sun_cap must be > 0")),
        };
        let scale = |c: DVec3| -> f64 {
            let y = luminance(c);
            if y > cap {
                cap / y
            } else {
                1.0
            }
        };
        let has_sun = map.rgb.iter().any(|c| scale(*c) < 1.0);
        // Moments: a texel over the cap goes to the excess whole (its light's energy in its
        // lobe), not its part over the cap (a plateau at the cap left in the sky, which the sky's
        // lobes would spend themselves on)
        let whole = opts.sun_lobes == SunLobes::Moments;
        let scale = |c: DVec3| -> f64 {
            let f = scale(c);
            if whole && f < 1.0 {
                0.0
            } else {
                f
            }
        };
        let sky_rgb: Vec<DVec3> = map.rgb.iter().map(|c| *c * scale(*c)).collect();
        let sky = Part::new(LatLong::from_rgb(width, height, sky_rgb), &lambdas);
        // the excess is made of compact bright sources: only sharp lobes (lambda >= 16)
        // and up to 4x the dense limit (angular width ~0.35 texel) so that a sun of one or two
        // texels can be matched
        let mut sun_lambdas: Vec<f64> = lambdas.iter().copied().filter(|&l| l >= 16.0).collect();
        if opts.lambda_max.is_none() {
            let mut l = *lambdas.last().unwrap();
            while l * opts.ladder_ratio <= 4.0 * lmax * (1.0 + 1e-9) {
                l *= opts.ladder_ratio;
                sun_lambdas.push(l);
            }
        }
        let sun_lambdas = if sun_lambdas.is_empty() { vec![*lambdas.last().unwrap()] } else { sun_lambdas };
        let sun = has_sun.then(|| {
            let ex: Vec<DVec3> = map.rgb.iter().map(|c| *c * (1.0 - scale(*c))).collect();
            Part::new(LatLong::from_rgb(width, height, ex), &sun_lambdas)
        });
        Ok(Self { map, sky, sun, opts })
    }

    /// The validated map.
    pub fn map(&self) -> &LatLong {
        &self.map
    }

    /// Fits `k` lobes (`k >= 1`).
    pub fn fit(&self, k: usize) -> Result<SgEnvFit, EnvError> {
        if k == 0 {
            return Err(EnvError::BadOption("need at least one lobe"));
        }
        // SunLobes::Moments: the excess part's lobes from its groups' moments (at most a
        // quarter of them), the rest to the sky
        let mut moment = Vec::new();
        let sun = match (&self.sun, self.opts.sun_lobes) {
            (Some(sun), SunLobes::Moments) if k >= 2 => {
                let hi = sun.levels.last().map_or(self.opts.lambda_min, |l| l.lambda);
                moment = moment_lobes(&sun.map, (k / 4).max(1), self.opts.lambda_min, hi);
                None
            }
            (sun, _) => sun.as_ref(),
        };
        let k = k - moment.len().min(k - 1);
        // matching pursuit over the parts left: each lobe goes to the part whose *relative*
        // energy decrease is largest (a sun cannot take every lobe, the sky cannot starve it)
        let parts: Vec<&Part> = std::iter::once(&self.sky).chain(sun).collect();
        let energies: Vec<f64> = parts.iter().map(|p| p.energy().max(1e-300)).collect();
        let mut resid: Vec<Vec<Vec<f64>>> =
            parts.iter().map(|p| p.levels.iter().map(|l| l.corr.clone()).collect()).collect();
        let mut shapes: Vec<Vec<Sg>> = vec![vec![]; parts.len()];
        for _ in 0..k {
            let mut best: Option<(f64, usize, Sg)> = None;
            for (pi, part) in parts.iter().enumerate() {
                if let Some((score, g)) = part.best_step(&resid[pi]) {
                    let rel = score / energies[pi];
                    if best.as_ref().is_none_or(|b| rel > b.0) {
                        best = Some((rel, pi, g));
                    }
                }
            }
            let Some((_, pi, g)) = best else { break };
            parts[pi].subtract(&mut resid[pi], &g);
            shapes[pi].push(Sg { mu: 1.0, ..g });
        }
        let mut lobes = Vec::new();
        for (pi, part) in parts.iter().enumerate() {
            if !shapes[pi].is_empty() {
                lobes.extend(part.fit_shapes(std::mem::take(&mut shapes[pi]), self.opts.refine_passes));
            }
        }
        lobes.extend(moment);
        let lobes: Vec<SgRgb> = lobes.into_iter().filter(|l| l.mu.max_element() > 0.0).collect();
        let rel_l2_error = self.map.relative_l2_error(&lobes);
        Ok(SgEnvFit { lobes, rel_l2_error })
    }
}

/// Parabolic sub-texel refinement of the argmax `idx` of the residual correlation `rs`.
fn refine_axis(lv: &CorrLevel, rs: &[f64], idx: usize) -> DVec3 {
    let (x, y) = ((idx % lv.ow) as isize, (idx / lv.ow) as isize);
    let r = |xi: isize, yi: isize| -> f64 { rs[yi as usize * lv.ow + xi.rem_euclid(lv.ow as isize) as usize] };
    let c0 = r(x, y);
    let vertex = |m: f64, p: f64| -> f64 {
        let d = m - 2.0 * c0 + p;
        if d < 0.0 {
            (0.5 * (m - p) / d).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let dx = vertex(r(x - 1, y), r(x + 1, y));
    let dy = if y >= 1 && y + 1 < lv.oh as isize { vertex(r(x, y - 1), r(x, y + 1)) } else { 0.0 };
    latlong_direction((x as f64 + dx + 0.5) / lv.ow as f64, (y as f64 + dy + 0.5) / lv.oh as f64)
}

/// NNLS of RGB amplitudes for fixed lobe shapes over `map`; returns the lobes and the squared
/// residual norm (RGB summed, solid-angle weighted).
fn nnls_rgb(map: &LatLong, rw: &[f64], shapes: &[Sg]) -> (Vec<SgRgb>, f64) {
    let k = shapes.len();
    let (q, b, ll) = (0..map.height)
        .into_par_iter()
        .map(|y| {
            let w0 = map.solid_angle(y);
            let mut q = vec![0.0; k * k];
            let mut b = vec![DVec3::ZERO; k];
            let mut ll = 0.0;
            let mut g = vec![0.0; k];
            for x in 0..map.width {
                let i = y * map.width + x;
                let w = w0 * rw[i];
                let d = map.dir(i);
                for (j, s) in shapes.iter().enumerate() {
                    g[j] = s.eval(d);
                }
                let l = map.rgb[i];
                ll += w * l.length_squared();
                for a in 0..k {
                    if g[a] == 0.0 {
                        continue;
                    }
                    let wa = w * g[a];
                    b[a] += l * wa;
                    for c in a..k {
                        q[a * k + c] += wa * g[c];
                    }
                }
            }
            (q, b, ll)
        })
        .reduce(
            || (vec![0.0; k * k], vec![DVec3::ZERO; k], 0.0),
            |mut a, b| {
                for (x, y) in a.0.iter_mut().zip(&b.0) {
                    *x += y;
                }
                for (x, y) in a.1.iter_mut().zip(&b.1) {
                    *x += *y;
                }
                (a.0, a.1, a.2 + b.2)
            },
        );
    let mut q = q;
    for a in 0..k {
        for c in 0..a {
            q[a * k + c] = q[c * k + a];
        }
    }
    let mut mus = vec![DVec3::ZERO; k];
    let mut resid = ll;
    for ch in 0..3 {
        let bc: Vec<f64> = b.iter().map(|v| v[ch]).collect();
        let x = nnls_gram(&q, &bc);
        // |L - A x|^2 = |L|^2 - 2 b.x + x^T Q x
        let qx: f64 = (0..k).map(|i| x[i] * (0..k).map(|j| q[i * k + j] * x[j]).sum::<f64>()).sum();
        resid += qx - 2.0 * bc.iter().zip(&x).map(|(u, v)| u * v).sum::<f64>();
        for i in 0..k {
            mus[i][ch] = x[i];
        }
    }
    let lobes = shapes.iter().zip(mus).map(|(s, mu)| SgRgb { axis: s.axis, lambda: s.lambda, mu }).collect();
    (lobes, resid.max(0.0))
}

/// One-shot convenience: fit `k` SGs to a `width x height` lat-long map with default options.
pub fn fit_sg_lighting(width: usize, height: usize, texels: &[[f32; 3]], k: usize) -> Result<SgEnvFit, EnvError> {
    SgEnvFitter::new(width, height, texels, SgFitOptions::default())?.fit(k)
}

/// Diffuse irradiance `E(n) = int L(w) max(0, dot(n, w)) dw` of a lat-long map on a grid of
/// `out_width x out_height` directions, row-major RGB: row `j` at `v = j / (out_height - 1)` (the
/// first and last rows on the poles, where a texel-centred grid would leave the irradiance's
/// steepest region to extrapolation), column `i` at `u = i / out_width` (same convention as the
/// map, [`latlong_direction`]), by direct summation over the map box-downsampled (solid-angle weighted, energy kept) to
/// at most `max_source_rows` rows. Irradiance is smooth (the cosine kernel is 180 degrees wide),
/// so a 64 x 32 result interpolated bilinearly is within a fraction of a percent, where nine SH
/// coefficients miss a studio map's irradiance by 4% on average and 14% at worst.
pub fn irradiance_map(
    width: usize,
    height: usize,
    texels: &[[f32; 3]],
    out_width: usize,
    out_height: usize,
    max_source_rows: usize,
) -> Result<Vec<[f32; 3]>, EnvError> {
    let mut src = LatLong::new(width, height, texels)?;
    while src.height > max_source_rows.max(1) {
        match src.downsample() {
            Some(d) => src = d,
            None => break,
        }
    }
    let weighted: Vec<(DVec3, DVec3)> = (0..src.rgb.len())
        .map(|i| (src.dir(i), src.rgb[i] * src.solid_angle(i / src.width)))
        .filter(|(_, c)| c.max_element() > 0.0)
        .collect();
    if out_width == 0 || out_height < 2 {
        return Err(EnvError::Empty);
    }
    Ok((0..out_width * out_height)
        .into_par_iter()
        .map(|j| {
            let n = latlong_direction(
                (j % out_width) as f64 / out_width as f64,
                (j / out_width) as f64 / (out_height - 1) as f64,
            );
            let e = weighted.iter().fold(DVec3::ZERO, |acc, (d, c)| acc + *c * d.dot(n).max(0.0));
            [e.x as f32, e.y as f32, e.z as f32]
        })
        .collect())
}

/// A default sharpness stack for [`prefilter`]: `1, 4, 16, ..., 4096` (glossy to near-mirror;
/// a lobe of sharpness `lambda` has an angular width of about `1/sqrt(lambda)` rad).
pub const DEFAULT_PREFILTER_LAMBDAS: [f64; 7] = [1.0, 4.0, 16.0, 64.0, 256.0, 1024.0, 4096.0];

/// Projects a lat-long map onto real SH of order `order` (see [`crate::sh`] for the convention),
/// per RGB channel, with solid-angle-weighted texels (each texel's value times its solid angle at
/// its centre direction). Returns `[r, g, b]` coefficient vectors of `order^2` entries.
pub fn project_sh(width: usize, height: usize, texels: &[[f32; 3]], order: usize) -> Result<[Vec<f64>; 3], EnvError> {
    let map = LatLong::new(width, height, texels)?;
    let n = crate::sh::sh_count(order);
    let mut out = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let mut y = vec![0.0; n];
    for i in 0..map.rgb.len() {
        let w = map.solid_angle(i / width);
        crate::sh::eval_basis_into(order, map.dir(i), &mut y);
        for (oc, v) in out.iter_mut().zip((map.rgb[i] * w).to_array()) {
            for (o, yk) in oc.iter_mut().zip(&y) {
                *o += v * yk;
            }
        }
    }
    Ok(out)
}

/// The map's compact bright lights split off: the texels brighter than `sun_cap` (default 100)
/// times the median luminance, whole, as at most `max_lights` moment-matched lobes (grouped as
/// [`SunLobes::Moments`] groups them: each lobe with its group's energy, mean direction and
/// angular extent), and the rest of the map (those texels zero). For a technique that shades a
/// studio's key light or a sun apart from the sky: `(lights, sky texels)`; no lights (and the
/// map unchanged) when no texel is over the cap or `sun_cap` is `None`.
pub fn split_lights(
    width: usize,
    height: usize,
    texels: &[[f32; 3]],
    opts: &SgFitOptions,
    max_lights: usize,
) -> Result<(Vec<SgRgb>, Vec<[f32; 3]>), EnvError> {
    let map = LatLong::new(width, height, texels)?;
    let Some(f) = opts.sun_cap else { return Ok((Vec::new(), texels.to_vec())) };
    if !(f > 0.0) {
        return Err(EnvError::BadOption("sun_cap must be > 0"));
    }
    let mut sorted: Vec<f64> = map.rgb.iter().map(|c| luminance(*c)).collect();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let cap = f * sorted[sorted.len() / 2];
    if !(cap > 0.0) || max_lights == 0 {
        return Ok((Vec::new(), texels.to_vec()));
    }
    let over: Vec<bool> = map.rgb.iter().map(|c| luminance(*c) > cap).collect();
    if !over.iter().any(|&o| o) {
        return Ok((Vec::new(), texels.to_vec()));
    }
    let excess = LatLong::from_rgb(
        width,
        height,
        map.rgb.iter().zip(&over).map(|(c, &o)| if o { *c } else { DVec3::ZERO }).collect(),
    );
    let lmax = opts.lambda_max.unwrap_or(2.0 * (height as f64 / PI).powi(2)).max(opts.lambda_min);
    let lights = moment_lobes(&excess, max_lights, opts.lambda_min, 4.0 * lmax);
    let sky = texels.iter().zip(&over).map(|(t, &o)| if o { [0.0; 3] } else { *t }).collect();
    Ok((lights, sky))
}
