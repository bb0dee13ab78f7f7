//! Effects: pass chains a scene's requirements add after its technique, transforming the HDR
//! radiance image (e.g. volumetric single scattering for scenes with a participating medium).
//! The graph gets only the effects the scene needs: a scene without a medium has no volumetric
//! passes.
//!
//! Adding an effect touches `passes/` (a module implementing [`Effect`], an entry in
//! `registry::EFFECTS` and a line in [`create_for`]), `glsl/`, a test and a scene; not the engine.

use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Context, FrameStore, Graph, ImageHandle};
use penumbra_scene::Scene;
use std::sync::Arc;

/// What an effect gets each frame (the same as a technique).
pub type EffectInputs<'a> = crate::technique::FrameInputs<'a>;

/// A pass chain added after the technique (`Send`, as techniques are).
pub trait Effect: Send {
    fn name(&self) -> &'static str;
    /// Declares the effect's passes reading `hdr` (through a [`FrameStore`]: no submission, so
    /// building the frame never waits on the GPU); returns the new HDR image (or `hdr` itself
    /// after a read-modify-write).
    fn add(
        &mut self,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        inputs: &EffectInputs,
        hdr: ImageHandle,
    ) -> Result<ImageHandle>;
    /// What the effect leaves out or approximates for this scene and device, for the user
    /// (`Renderer::notes`).
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }
}

/// Per-run overrides of the scene's effect choices (e.g. the CLI's `--volumetric`).
#[derive(Clone, Debug, Default)]
pub struct EffectOverrides {
    /// Volumetric method override (`temporal` or `full`).
    pub volumetric: Option<String>,
}

/// The effects `scene` requires, in the order they run: volumetric single scattering for a
/// scene with a medium (method from the scene's `volumetric` key, overridden by
/// `overrides.volumetric`).
pub fn create_for(
    scene: &Scene,
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    overrides: &EffectOverrides,
) -> Result<Vec<Box<dyn Effect>>> {
    let mut v: Vec<Box<dyn Effect>> = Vec::new();
    if scene.medium.is_some() {
        let name =
            overrides.volumetric.clone().or_else(|| scene.volumetric.clone()).unwrap_or_else(|| "temporal".into());
        let method = crate::volumetric::VolumetricMethod::parse(&name)?;
        let params = crate::volumetric::VolumetricParams { method, ..Default::default() };
        v.push(Box::new(crate::volumetric::VolumetricEffect::new(scene, ctx, shaders, params)?));
    } else if let Some(m) = &overrides.volumetric {
        // Still reject a bad name, so typos are not silently ignored.
        crate::volumetric::VolumetricMethod::parse(m)?;
    }
    Ok(v)
}
