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

/// Techniques implemented so far.
pub const IMPLEMENTED: &[&str] =
    &["avs", "env", "isg", "isg-vertex", "mc", "shadowmaps", "shadow-fields", "shadow-fields-fixed", "vv"];

/// Techniques that precompute visibility for static geometry only: creating one for a scene
/// whose objects move or deform is an error naming the object.
pub const STATIC_ONLY: &[&str] = &["vv"];

/// Creates the technique `name` for `scene`, or `None` if it is not implemented.
pub fn create(name: &str, ctx: &Arc<Context>, shaders: &ShaderLibrary, _scene: &Scene) -> Result<Option<Box<dyn Technique>>> {
    if name == "vv" {
        let settings = crate::vv::VvSettings::from_params(&_scene.technique_params)?;
        return Ok(Some(Box::new(crate::vv::VvTechnique::new(ctx, shaders, _scene, settings)?)));
    }
    // Techniques without parameters refuse any, rather than ignore them.
    if !matches!(name, "avs" | "isg" | "isg-vertex" | "shadow-fields" | "shadow-fields-fixed") && !_scene.technique_params.is_empty() {
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
