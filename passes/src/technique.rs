//! Techniques: the pass chains that turn a frame's G-buffer into linear HDR radiance
//! (shading plus whatever visibility method the technique implements).
//!
//! Adding a technique touches `passes/` (a module implementing [`Technique`] and a line in
//! [`create`]), `glsl/`, a test and a scene; not the engine.

use crate::env::EnvMapGpu;
use crate::gbuffer::GBuffer;
use crate::scene_gpu::SceneHandles;
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Context, Engine, Graph, ImageHandle};
use penumbra_scene::{Frame, Scene};
use std::sync::Arc;

/// What a technique gets each frame.
pub struct TechniqueInputs<'a> {
    pub frame: &'a Frame,
    pub scene: &'a SceneHandles,
    pub gbuffer: &'a GBuffer,
    /// The environment map (lat-long, mipped), sampled.
    pub env: ImageHandle,
    pub env_data: &'a EnvMapGpu,
}

pub trait Technique {
    /// The name used in scene files (`technique = "..."`) and on the CLI.
    fn name(&self) -> &'static str;
    /// Declares the technique's passes; returns the HDR radiance image (RGBA32F, G-buffer size).
    fn add(&mut self, engine: &mut Engine, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle>;
    /// What the technique ignores or approximates in `scene` (local lights it does not render,
    /// texture maps, ...), shown to the user instead of a silently different image.
    fn limitations(&self, _scene: &Scene) -> Vec<String> {
        Vec::new()
    }
    /// For a Monte Carlo technique: the samples per pixel in its image after the last frame
    /// (accumulated over frames where nothing changed); `None` for the others.
    fn samples_per_pixel(&self) -> Option<u32> {
        None
    }
}

/// Applies every `key = value` of `params` (a scene's `[technique_params]` and `--param`s) to
/// `settings` with `set`, reporting all the bad ones together (one per line), not only the first.
pub fn apply_params<S>(
    settings: &mut S,
    params: &std::collections::BTreeMap<String, String>,
    set: impl Fn(&mut S, &str, &str) -> Result<()>,
) -> Result<()> {
    let errors: Vec<String> = params.iter().filter_map(|(k, v)| set(settings, k, v).err().map(|e| format!("{e:#}"))).collect();
    match errors.len() {
        0 => Ok(()),
        1 => Err(anyhow::anyhow!("{}", errors[0])),
        n => Err(anyhow::anyhow!("{n} bad technique parameters:\n  {}", errors.join("\n  "))),
    }
}

/// The accuracy budget of a technique, judged by the scene x technique matrix
/// (`penumbra bench matrix`, `tests/matrix.rs`) against a converged CPU reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// The technique's image must have `rmse_rel_mean` (RMSE over the reference's mean
    /// radiance) at most `rmse_rel_mean`; `source` says where the figure comes from (the paper's
    /// figure where it reports one, otherwise the technique's documented approximation).
    RmseRelMean { rmse_rel_mean: f64, source: &'static str },
    /// An unbiased Monte Carlo estimator with the reference's estimator: its `rmse_rel_mean`
    /// must be at most `factor` times the noise the reference has at the technique's accumulated
    /// samples per pixel (`reference noise x sqrt(reference spp / technique spp)`), i.e. pure
    /// noise, no bias.
    Unbiased { factor: f64, source: &'static str },
    /// The unshadowed baseline (`env`): no budget; its `rel_rmse` is what `shadow_recovered`
    /// measures the shadow techniques against.
    Baseline { source: &'static str },
}

/// One registered technique: its name and what the engine and its tools need to know of it.
#[derive(Clone, Copy, Debug)]
pub struct TechniqueInfo {
    /// The name in scene files (`technique = "..."`), on the CLI and in the matrix.
    pub name: &'static str,
    /// One line for listings.
    pub summary: &'static str,
    /// Accepts `[technique_params]` (the others refuse any).
    pub takes_params: bool,
    /// Precomputes visibility for static geometry only: refuses scenes whose objects move or
    /// deform.
    pub static_only: bool,
    /// Renders shadows: the matrix requires `shadow_recovered >= 0.5` on every scene it accepts.
    pub shadows: bool,
    pub budget: Budget,
}

/// The shadow techniques' common floor: the fraction of the unshadowed image's error
/// (`rel_rmse` of `env`) a shadow technique must remove on every scene it accepts.
pub const MIN_SHADOW_RECOVERED: f64 = 0.5;

/// Both isg modes (per pixel and per vertex) answer to the paper's figure.
const ISG_BUDGET: Budget =
    Budget::RmseRelMean { rmse_rel_mean: 0.05, source: "ISG paper, Fig. 12: RMS errors 3.2 % and 4.6 % against ray tracing" };

/// Adaptive and fixed shells approximate visibility the same way.
const SHADOW_FIELDS_BUDGET: Budget = Budget::RmseRelMean {
    rmse_rel_mean: 0.15,
    source: "shadow-fields paper reports no image error; documented approximation: 4th-order SH (16 coefficients) visibility and lighting",
};

/// Every technique, in listing order: the one place that names them.
pub const REGISTRY: &[TechniqueInfo] = &[
    TechniqueInfo {
        name: "env",
        summary: "environment (SH irradiance, prefiltered specular) and local lights, no visibility",
        takes_params: false,
        static_only: false,
        shadows: false,
        budget: Budget::Baseline { source: "unshadowed baseline: no visibility, so no accuracy budget" },
    },
    TechniqueInfo {
        name: "mc",
        summary: "GPU Monte Carlo with the reference's estimator, progressive while nothing moves",
        takes_params: false,
        static_only: false,
        shadows: true,
        budget: Budget::Unbiased {
            factor: 1.5,
            source: "the reference's estimator on the GPU: unbiased, so within 1.5x the reference estimator's noise at the same samples per pixel",
        },
    },
    TechniqueInfo {
        name: "shadowmaps",
        summary: "the environment as K shadowed directional lights (the papers' shadow-map baseline)",
        takes_params: false,
        static_only: false,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "no paper reports its error; documented approximation: the environment as K importance-sampled directional lights with 3x3-PCF depth maps (the ISG paper compares against 30 and 1024 such maps)",
        },
    },
    TechniqueInfo {
        name: "isg",
        summary: "integral spherical Gaussians, per-pixel visibility over sphere sets (Iwasaki et al. 2012)",
        takes_params: true,
        static_only: false,
        shadows: true,
        budget: ISG_BUDGET,
    },
    TechniqueInfo {
        name: "isg-vertex",
        summary: "integral spherical Gaussians with per-vertex visibility",
        takes_params: true,
        static_only: false,
        shadows: true,
        budget: ISG_BUDGET,
    },
    TechniqueInfo {
        name: "avs",
        summary: "adaptive visibility sampling with hemispherical distance transforms (Wang et al.)",
        takes_params: true,
        static_only: false,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "avs paper reports no error figure; documented approximation: visibility sampled at adaptive points with E_v,max = 10 % relative visibility error",
        },
    },
    TechniqueInfo {
        name: "shadow-fields",
        summary: "adaptive shadow fields (SH occlusion and source radiance fields, adaptive shells)",
        takes_params: true,
        static_only: false,
        shadows: true,
        budget: SHADOW_FIELDS_BUDGET,
    },
    TechniqueInfo {
        name: "shadow-fields-fixed",
        summary: "shadow fields at fixed (non-adaptive) shell resolution",
        takes_params: true,
        static_only: false,
        shadows: true,
        budget: SHADOW_FIELDS_BUDGET,
    },
    TechniqueInfo {
        name: "vv",
        summary: "vectorized visibility with spherical Voronoi interpolation (static geometry)",
        takes_params: true,
        static_only: true,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "vv paper, Fig. 11: 29.58 dB at zeta = 4, an RMSE of 3.3 % of the peak; the paper gives no mean radiance, so 10 % of the mean assumes a peak about 3x the mean (an assumption, not a measurement)",
        },
    },
];

/// The registered technique `name`.
pub fn info(name: &str) -> Option<&'static TechniqueInfo> {
    REGISTRY.iter().find(|t| t.name == name)
}

/// The names of every registered technique, in [`REGISTRY`] order.
pub fn names() -> Vec<&'static str> {
    REGISTRY.iter().map(|t| t.name).collect()
}

/// Techniques implemented so far (every [`REGISTRY`] entry; kept for existing callers).
pub const IMPLEMENTED: &[&str] =
    &["avs", "env", "isg", "isg-vertex", "mc", "shadowmaps", "shadow-fields", "shadow-fields-fixed", "vv"];

/// Why technique `name` refuses `scene` before anything is built, if it does: a static-only
/// technique on moving or deforming geometry (naming the object).
pub fn refusal(name: &str, scene: &Scene) -> Option<String> {
    let info = info(name)?;
    if info.static_only {
        for (i, o) in scene.objects.iter().enumerate() {
            let oi = scene.object_info(i);
            if oi.is_moving() || oi.is_deforming() {
                return Some(format!(
                    "'{name}' precomputes visibility for static geometry; object '{}' {}",
                    o.name,
                    if oi.is_moving() { "moves" } else { "deforms" }
                ));
            }
        }
    }
    None
}

/// Techniques that precompute visibility for static geometry only: creating one for a scene
/// whose objects move or deform is an error naming the object.
pub const STATIC_ONLY: &[&str] = &["vv"];

/// Creates the technique `name` for `scene`, or `None` if it is not implemented.
pub fn create(name: &str, ctx: &Arc<Context>, shaders: &ShaderLibrary, _scene: &Scene) -> Result<Option<Box<dyn Technique>>> {
    if name == "vv" {
        if let Some(why) = refusal(name, _scene) {
            anyhow::bail!("{why}");
        }
        let settings = crate::vv::VvSettings::from_params(&_scene.technique_params)?;
        return Ok(Some(Box::new(crate::vv::VvTechnique::new(ctx, shaders, _scene, settings)?)));
    }
    // Techniques without parameters refuse any, rather than ignore them.
    if info(name).is_some_and(|i| !i.takes_params) && !_scene.technique_params.is_empty() {
        anyhow::bail!(
            "technique '{name}' takes no parameters (got: {})",
            _scene.technique_params.keys().cloned().collect::<Vec<_>>().join(", ")
        );
    }
    Ok(match name {
        "avs" => Some(Box::new(crate::avs::AvsTechnique::new(ctx, shaders, _scene, crate::avs::AvsSettings::from_params(&_scene.technique_params)?)?)),
        "env" => Some(Box::new(crate::shade_env::ShadeEnvPass::new(ctx, shaders)?)),
        "isg" | "isg-vertex" => {
            let mut settings = crate::isg::IsgSettings { per_vertex: name == "isg-vertex", ..Default::default() };
            for (k, v) in &_scene.technique_params {
                settings.set(k, v)?;
            }
            Some(Box::new(crate::isg::IsgTechnique::new(ctx, shaders, _scene, settings)?))
        }
        "mc" => Some(Box::new(crate::mc::McTechnique::new(ctx, shaders, _scene)?)),
        "shadowmaps" => Some(Box::new(crate::shadowmaps::ShadowMapsTechnique::new(ctx, shaders, _scene)?)),
        "shadow-fields" | "shadow-fields-fixed" => Some(Box::new(crate::shadow_fields::ShadowFieldsTechnique::new(ctx, shaders, _scene, crate::shadow_fields::SfOptions { adaptive: name == "shadow-fields", ..crate::shadow_fields::SfOptions::from_params(&_scene.technique_params)? })?)),
        _ => None,
    })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    #[test]
    fn registry_names_every_technique_once_with_a_budget() {
        let names = super::names();
        let mut sorted = names.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), names.len(), "duplicate names in {names:?}");
        let mut implemented = super::IMPLEMENTED.to_vec();
        implemented.sort();
        assert_eq!(sorted, implemented);
        for t in super::REGISTRY {
            match t.budget {
                super::Budget::RmseRelMean { rmse_rel_mean, source } => {
                    assert!(rmse_rel_mean > 0.0 && rmse_rel_mean < 1.0 && !source.is_empty(), "{}", t.name)
                }
                super::Budget::Unbiased { factor, source } => assert!(factor >= 1.0 && !source.is_empty(), "{}", t.name),
                super::Budget::Baseline { .. } => assert!(!t.shadows, "{}: a shadow technique needs a budget", t.name),
            }
            assert_eq!(super::STATIC_ONLY.contains(&t.name), t.static_only, "{}", t.name);
        }
    }

    #[test]
    fn bad_parameters_are_reported_together() {
        let params: BTreeMap<String, String> =
            [("zeta", "-3"), ("mode", "fragment1"), ("bogus", "1")].iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        let e = crate::vv::VvSettings::from_params(&params).unwrap_err().to_string();
        assert!(e.starts_with("2 bad technique parameters"), "{e}");
        assert!(e.contains("zeta") && e.contains("bogus") && !e.contains("fragment1"), "{e}");
        let one: BTreeMap<String, String> = [("lobes".to_string(), "zero".to_string())].into();
        let e = crate::isg::IsgSettings::from_params(&one).unwrap_err().to_string();
        assert!(e.contains("lobes") && !e.contains("bad technique parameters"), "{e}");
        let good: BTreeMap<String, String> = [("mode".to_string(), "vertex".to_string())].into();
        assert!(crate::shadow_fields::SfOptions::from_params(&good).is_ok());
    }
}
