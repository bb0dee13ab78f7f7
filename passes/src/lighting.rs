//! The scene's environment as the SG techniques light with it (isg, avs): K spherical-Gaussian
//! lighting lobes fitted to the map, the map prefiltered with normalised SGs for glossy lookups,
//! its irradiance, and its key lights split off it (`split_key_lights`: avs and the shadow
//! fields shade those with traced shadows and the rest through their own visibility). Each takes
//! the environment, so a split-off rest of the map needs no copy of the scene. Shared building
//! blocks of the frame layer: no technique owns them.

use glam::DVec3;
use penumbra_scene::{Environment, EnvironmentState};

/// The sources the cached products are computed by: a change to any of them (even a comment)
/// changes every cache key, so a cache file never outlives the code that wrote it.
const CACHE_SOURCES: [&[u8]; 5] = [
    include_bytes!("lighting.rs"),
    include_bytes!("../../math/src/envmap.rs"),
    include_bytes!("../../math/src/sg.rs"),
    include_bytes!("../../math/src/nnls.rs"),
    include_bytes!("../../math/src/quad.rs"),
];

/// FNV-1a, 64 bits (stable across toolchains, unlike `std`'s hasher).
fn fnv(h: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *h ^= *b as u64;
        *h = h.wrapping_mul(0x100_0000_01b3);
    }
}

/// Key of a product of environment `e` (texels, size, intensity, rotation), kind and parameters.
pub fn cache_key(kind: &str, e: &Environment, params: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for src in CACHE_SOURCES {
        fnv(&mut h, src);
    }
    fnv(&mut h, kind.as_bytes());
    fnv(&mut h, params);
    fnv(&mut h, &e.width.to_le_bytes());
    fnv(&mut h, &e.height.to_le_bytes());
    fnv(&mut h, &e.intensity.to_bits().to_le_bytes());
    fnv(&mut h, &e.rotation.to_bits().to_le_bytes());
    for t in &e.texels {
        for c in t {
            fnv(&mut h, &c.to_bits().to_le_bytes());
        }
    }
    h
}

/// `compute()`'s bytes through the on-disk cache `<temp>/penumbra-lighting/<kind>-<key>.bin`:
/// the SG fit and the prefiltering take seconds on a 2k map and depend only on the map and their
/// parameters, so every isg/avs technique, test and bench process after the first reads them
/// back (as vv's and the shadow fields' precomputes). A file whose header does not match is
/// recomputed; files are written to a temporary name and renamed (processes may race).
pub fn cached_bytes(kind: &str, key: u64, compute: impl FnOnce() -> Vec<u8>) -> Vec<u8> {
    let dir = std::env::temp_dir().join("penumbra-lighting");
    let path = dir.join(format!("{kind}-{key:016x}.bin"));
    let magic = b"PLC1";
    if let Ok(b) = std::fs::read(&path) {
        if b.len() >= 20 && &b[..4] == magic && b[4..12] == key.to_le_bytes() {
            let n = u64::from_le_bytes(b[12..20].try_into().unwrap()) as usize;
            if b.len() == 20 + n {
                return b[20..].to_vec();
            }
        }
    }
    let data = compute();
    let mut file = Vec::with_capacity(20 + data.len());
    file.extend_from_slice(magic);
    file.extend_from_slice(&key.to_le_bytes());
    file.extend_from_slice(&(data.len() as u64).to_le_bytes());
    file.extend_from_slice(&data);
    let tmp = dir.join(format!("{kind}-{key:016x}.{}.tmp", std::process::id()));
    // a cache that cannot be written only costs the next process the computation
    if std::fs::create_dir_all(&dir).is_ok()
        && std::fs::write(&tmp, &file).is_ok()
        && std::fs::rename(&tmp, &path).is_err()
    {
        let _ = std::fs::remove_file(&tmp);
    }
    data
}

fn f32s_to_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn bytes_to_f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
}

/// Lighting SG lobes of the scene's environment in world space (its loaded intensity and rotation
/// applied, [`lobes_at`]), as `[axis, lambda], [rgb mu, 0]` pairs; the fit's relative L2 error.
pub fn lighting_lobes(env: Option<&Environment>, k: usize) -> (Vec<[f32; 4]>, Option<f64>) {
    let (lobes, err) = lighting_lobes_local(env, k);
    (lobes_at(&lobes, env.map_or(EnvironmentState::NONE, Environment::state)), err)
}

/// Lighting SG lobes fitted to the environment's texels, in the map's own frame at intensity 1
/// (lobes that are not finite dropped), as [`lighting_lobes`]'s pairs: a frame's lobes are
/// [`lobes_at`] its `Frame::environment`, so an animated environment (turned, dimmed) is not
/// fitted again.
pub fn lighting_lobes_local(env: Option<&Environment>, k: usize) -> (Vec<[f32; 4]>, Option<f64>) {
    let Some(e) = env else { return (Vec::new(), None) };
    // cached as the fit's error (f64, NaN: no fit) then the lobes' floats
    let b = cached_bytes("lobes", cache_key("lobes", e, &(k as u64).to_le_bytes()), || {
        let (lobes, err) = lighting_lobes_uncached(e, k);
        let mut b = err.unwrap_or(f64::NAN).to_le_bytes().to_vec();
        b.extend(f32s_to_bytes(&lobes.iter().flatten().copied().collect::<Vec<f32>>()));
        b
    });
    if b.len() < 8 || (b.len() - 8) % 16 != 0 {
        return lighting_lobes_uncached(e, k); // not what this code writes: ignore it
    }
    let err = f64::from_le_bytes(b[..8].try_into().unwrap());
    let lobes = bytes_to_f32s(&b[8..]).chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
    (lobes, (!err.is_nan()).then_some(err))
}

/// The lobe counts [`lobes_for_error`] tries, fewest first.
pub const LOBE_COUNTS: [usize; 5] = [4, 8, 16, 32, 64];

/// The fewest lighting lobes of [`LOBE_COUNTS`] whose fit of `env` has a relative L2 error of at
/// most `target` (the last count when none does): (K, the lobes as [`lighting_lobes_local`]
/// gives them, the fit's error). Each fit goes through the on-disk cache.
pub fn lobes_for_error(env: Option<&Environment>, target: f64) -> (usize, Vec<[f32; 4]>, Option<f64>) {
    let mut last = (0, Vec::new(), None);
    for k in LOBE_COUNTS {
        let (lobes, err) = lighting_lobes_local(env, k);
        let done = err.is_none_or(|e| e <= target);
        last = (k, lobes, err);
        if done {
            break;
        }
    }
    last
}

fn lighting_lobes_uncached(e: &Environment, k: usize) -> (Vec<[f32; 4]>, Option<f64>) {
    let Ok(fit) = penumbra_math::envmap::fit_sg_lighting(e.width as usize, e.height as usize, &e.texels, k.max(1))
    else {
        return (Vec::new(), None);
    };
    (lobe_pairs(&fit.lobes), Some(fit.rel_l2_error))
}

/// `lobes` as the shaders read them, 2 vec4 per lobe: `[axis, lambda], [rgb mu, 0]`; lobes that
/// are not finite dropped.
fn lobe_pairs(lobes: &[penumbra_math::sg::SgRgb]) -> Vec<[f32; 4]> {
    let mut out = Vec::new();
    for l in lobes.iter().filter(|l| l.axis.is_finite() && l.lambda.is_finite() && l.mu.is_finite()) {
        out.push([l.axis.x as f32, l.axis.y as f32, l.axis.z as f32, l.lambda as f32]);
        out.push([l.mu.x as f32, l.mu.y as f32, l.mu.z as f32, 0.0]);
    }
    out
}

/// `lobes` (`[axis, lambda], [rgb mu, 0]` pairs in the map's frame at intensity 1,
/// [`lighting_lobes_local`]) in world space at `state`: axes turned by its rotation about +Y,
/// amplitudes scaled by its intensity. As many pairs as given: a pair that would not be finite
/// becomes a black lobe.
pub fn lobes_at(lobes: &[[f32; 4]], state: EnvironmentState) -> Vec<[f32; 4]> {
    let (s, c) = (state.rotation as f64).sin_cos();
    let mut out = Vec::with_capacity(lobes.len());
    for pair in lobes.chunks_exact(2) {
        let (a, mu) = (DVec3::new(pair[0][0] as f64, pair[0][1] as f64, pair[0][2] as f64), pair[1]);
        let axis = DVec3::new(c * a.x + s * a.z, a.y, -s * a.x + c * a.z);
        let mu = [mu[0], mu[1], mu[2]].map(|m| m * state.intensity);
        if axis.is_finite() && pair[0][3].is_finite() && mu.iter().all(|m| m.is_finite()) {
            out.push([axis.x as f32, axis.y as f32, axis.z as f32, pair[0][3]]);
            out.push([mu[0], mu[1], mu[2], 0.0]);
        } else {
            out.extend([[0.0, 1.0, 0.0, 1.0], [0.0; 4]]);
        }
    }
    out
}

/// [`lobes_at`] as a storage buffer's bytes: one black stand-in pair when there are no lobes (a
/// buffer is never empty; the shaders are told the count).
pub fn lobes_bytes_at(lobes: &[[f32; 4]], state: EnvironmentState) -> Vec<u8> {
    let lobes = lobes_at(lobes, state);
    crate::util::bytes_of(if lobes.is_empty() { &[[0.0f32; 4]; 2][..] } else { &lobes })
}

/// SG sharpness levels of the prefiltered environment (0.25 and the math crate's default stack).
pub const PREFILTER_LAMBDAS: [f64; 8] = [0.25, 1.0, 4.0, 16.0, 64.0, 256.0, 1024.0, 4096.0];

/// The environment prefiltered with normalised SGs ([`PREFILTER_LAMBDAS`], at most 128 rows) in
/// the layout of `Prefiltered` in `glsl/isg/isg_shade.comp`; `[0.0]` (no levels) without an
/// environment.
pub fn prefiltered_env(env: Option<&Environment>) -> Vec<f32> {
    let Some(e) = env else { return vec![0.0] };
    let params: Vec<u8> = PREFILTER_LAMBDAS.iter().flat_map(|l| l.to_le_bytes()).collect();
    bytes_to_f32s(&cached_bytes("prefiltered", cache_key("prefiltered", e, &params), || {
        f32s_to_bytes(&prefiltered_env_uncached(e))
    }))
}

fn prefiltered_env_uncached(e: &Environment) -> Vec<f32> {
    let Ok(levels) =
        penumbra_math::envmap::prefilter(e.width as usize, e.height as usize, &e.texels, &PREFILTER_LAMBDAS, 128)
    else {
        return vec![0.0];
    };
    let mut out = vec![levels.len() as f32];
    let header = 1 + 4 * levels.len();
    let mut offset = header;
    for l in &levels {
        out.extend([l.lambda as f32, l.width as f32, l.height as f32, offset as f32]);
        offset += 3 * l.texels.len();
    }
    for l in &levels {
        out.extend(l.texels.iter().flat_map(|t| t.map(|c| if c.is_finite() { c.max(0.0) } else { 0.0 })));
    }
    out
}

/// Size of [`camera_irradiance`]'s map: small enough to ride in the camera uniform buffer.
pub const CAMERA_IRRADIANCE_SIZE: (usize, usize) = (32, 16);

/// The environment's diffuse irradiance (exact cosine convolution, as [`irradiance_env`]) as a
/// 32 x 16 lat-long map, one `[r, g, b, 0]` per texel, rows from pole to pole at
/// `v = j / (h - 1)`, columns at `u = i / w`; intensity and rotation applied by the shader's
/// lookup. It follows the specular albedo table in the camera buffer (`cam_irr` of
/// `glsl/include/env_shade.glsl`): the unshadowed diffuse term of every technique that shades
/// through `env_unshadowed_parts`. Zeros without an environment.
pub fn camera_irradiance(env: Option<&Environment>) -> Vec<[f32; 4]> {
    let (w, h) = CAMERA_IRRADIANCE_SIZE;
    match irradiance_texels(env, w, h) {
        Some(m) => m.iter().map(|c| [c[0], c[1], c[2], 0.0]).collect(),
        None => vec![[0.0; 4]; w * h],
    }
}

/// The environment's exact irradiance on a `w x h` lat-long grid
/// ([`penumbra_math::envmap::irradiance_map`], at most 64 source rows), non-finite or negative
/// channels as 0; `None` without an environment. Shared by [`camera_irradiance`] and
/// [`irradiance_env`].
fn irradiance_texels(env: Option<&Environment>, w: usize, h: usize) -> Option<Vec<[f32; 3]>> {
    let e = env?;
    let map = penumbra_math::envmap::irradiance_map(e.width as usize, e.height as usize, &e.texels, w, h, 64).ok()?;
    Some(map.iter().map(|t| t.map(|c| if c.is_finite() { c.max(0.0) } else { 0.0 })).collect())
}

/// Size of [`irradiance_env`]'s map (lat-long, the environment's own frame).
pub const IRRADIANCE_SIZE: (usize, usize) = (64, 32);

/// The environment's diffuse irradiance as a 64 x 32 lat-long map (exact cosine convolution,
/// [`penumbra_math::envmap::irradiance_map`]; intensity and rotation are applied by the shader's
/// lookup, as for [`prefiltered_env`]): `[width, height]` then RGB texels row by row; `[0, 0]`
/// without an environment. Read by `irr_eval` in `glsl/include/irradiance.glsl`.
pub fn irradiance_env(env: Option<&Environment>) -> Vec<f32> {
    let (w, h) = IRRADIANCE_SIZE;
    let Some(map) = irradiance_texels(env, w, h) else { return vec![0.0, 0.0] };
    let mut out = vec![w as f32, h as f32];
    out.extend(map.iter().flatten());
    out
}

/// `env` with its key lights (at most `max`, [`penumbra_math::envmap::split_lights`]) split off:
/// the rest of the map, and the lights' lobes in the map's frame at intensity 1 (pairs as
/// [`lighting_lobes_local`]'s: a frame's are [`lobes_at`] its environment's state); no map and no
/// lobes without an environment, with `max = 0` (the split turned off) or when no texel is over
/// the cap.
pub fn split_key_lights(env: Option<&Environment>, max: usize) -> anyhow::Result<(Option<Environment>, Vec<[f32; 4]>)> {
    let Some(env) = env.filter(|_| max > 0) else { return Ok((None, Vec::new())) };
    let (lobes, sky) = penumbra_math::envmap::split_lights(
        env.width as usize,
        env.height as usize,
        &env.texels,
        &Default::default(),
        max,
    )
    .map_err(|e| anyhow::anyhow!("the environment map: splitting off its lights: {e:?}"))?;
    if lobes.is_empty() {
        return Ok((None, Vec::new()));
    }
    Ok((Some(Environment { texels: sky, ..env.clone() }), lobe_pairs(&lobes)))
}
