//! The scene's environment as the SG techniques light with it (isg, avs): K spherical-Gaussian
//! lighting lobes fitted to the map, and the map prefiltered with normalised SGs for glossy
//! lookups. Shared building blocks of the frame layer: no technique owns them.

use glam::DVec3;
use penumbra_scene::Scene;

/// Lighting SG lobes of the scene's environment in world space (intensity and rotation
/// applied), as `[axis, lambda], [rgb mu, 0]` pairs; the fit's relative L2 error.
pub fn lighting_lobes(scene: &Scene, k: usize) -> (Vec<[f32; 4]>, Option<f64>) {
    let Some(e) = scene.environment.as_ref() else { return (Vec::new(), None) };
    let Ok(fit) = penumbra_math::envmap::fit_sg_lighting(e.width as usize, e.height as usize, &e.texels, k.max(1))
    else {
        return (Vec::new(), None);
    };
    let (s, c) = (e.rotation as f64).sin_cos();
    let mut out = Vec::new();
    for l in &fit.lobes {
        let a = l.axis;
        let axis = DVec3::new(c * a.x + s * a.z, a.y, -s * a.x + c * a.z);
        let mu = l.mu * e.intensity as f64;
        if !(axis.is_finite() && l.lambda.is_finite() && mu.is_finite()) {
            continue;
        }
        out.push([axis.x as f32, axis.y as f32, axis.z as f32, l.lambda as f32]);
        out.push([mu.x as f32, mu.y as f32, mu.z as f32, 0.0]);
    }
    (out, Some(fit.rel_l2_error))
}

/// SG sharpness levels of the prefiltered environment (0.25 and the math crate's default stack).
pub const PREFILTER_LAMBDAS: [f64; 8] = [0.25, 1.0, 4.0, 16.0, 64.0, 256.0, 1024.0, 4096.0];

/// The environment prefiltered with normalised SGs ([`PREFILTER_LAMBDAS`], at most 128 rows) in
/// the layout of `Prefiltered` in `glsl/isg/isg_shade.comp`; `[0.0]` (no levels) without an
/// environment.
pub fn prefiltered_env(scene: &Scene) -> Vec<f32> {
    let Some(e) = scene.environment.as_ref() else { return vec![0.0] };
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

/// Size of [`irradiance_env`]'s map (lat-long, the environment's own frame).
pub const IRRADIANCE_SIZE: (usize, usize) = (64, 32);

/// The environment's diffuse irradiance as a 64 x 32 lat-long map (exact cosine convolution,
/// [`penumbra_math::envmap::irradiance_map`]; intensity and rotation are applied by the shader's
/// lookup, as for [`prefiltered_env`]): `[width, height]` then RGB texels row by row; `[0, 0]`
/// without an environment. Read by `irr_eval` in `glsl/include/irradiance.glsl`.
pub fn irradiance_env(scene: &Scene) -> Vec<f32> {
    let Some(e) = scene.environment.as_ref() else { return vec![0.0, 0.0] };
    let (w, h) = IRRADIANCE_SIZE;
    let Ok(map) = penumbra_math::envmap::irradiance_map(e.width as usize, e.height as usize, &e.texels, w, h, 64)
    else {
        return vec![0.0, 0.0];
    };
    let mut out = vec![w as f32, h as f32];
    out.extend(map.iter().flat_map(|t| t.map(|c| if c.is_finite() { c.max(0.0) } else { 0.0 })));
    out
}
