//! Techniques: the pass chains that turn a frame's G-buffer into linear HDR radiance
//! (shading plus whatever visibility method the technique implements).
//!
//! Techniques are named, documented and constructed by [`crate::registry`] only.

use crate::env::EnvMapGpu;
use crate::gbuffer::GBuffer;
use crate::scene_gpu::{DrawList, SceneHandles};
use anyhow::Result;
use penumbra_engine::{Engine, FrameStore, Graph, ImageHandle};
use penumbra_scene::{Frame, Scene};

/// What a technique or an effect gets each frame: the scene as loaded, the frame (its instances,
/// lights, camera at this time), the frame's GPU buffers and draws, the G-buffer and the
/// environment map (lat-long, mipped, sampled).
pub struct FrameInputs<'a> {
    pub scene: &'a Scene,
    pub frame: &'a Frame,
    pub handles: &'a SceneHandles,
    /// The frame's draws (mesh ranges, instance indices) for passes that rasterize geometry.
    pub draws: &'a DrawList,
    pub gbuffer: &'a GBuffer,
    pub env: ImageHandle,
    pub env_data: &'a EnvMapGpu,
}

/// What a technique gets each frame.
pub type TechniqueInputs<'a> = FrameInputs<'a>;

/// What a technique's setup before a frame gets ([`Technique::prepare`]).
pub struct PrepareInputs<'a> {
    pub frame: &'a Frame,
    /// The image size (the G-buffer's).
    pub width: u32,
    pub height: u32,
}

/// A visibility technique. `Send`, so that an embedding host can move its renderer to a render
/// thread (no technique holds thread-bound state).
pub trait Technique: Send {
    /// The name used in scene files (`technique = "..."`) and on the CLI.
    fn name(&self) -> &'static str;
    /// Work before the frame is declared that may wait on the GPU (submissions of its own
    /// through the engine); counted in the technique's CPU time. None for every technique but
    /// `avs`, whose spatial adaptation runs here: on the CPU by default (`adaptation = cpu`, no
    /// wait), or as waited GPU rounds when asked (`adaptation = rounds`; with `late`, only a fresh
    /// point set's).
    fn prepare(&mut self, _engine: &mut Engine, _inputs: &PrepareInputs) -> Result<()> {
        Ok(())
    }
    /// Declares the technique's passes (with a [`FrameStore`]: no submission, so building the
    /// frame never waits on the GPU); returns the HDR radiance image (RGBA32F, G-buffer size).
    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle>;
    /// What the technique ignores or approximates in `scene` (local lights it does not render,
    /// texture maps, ...), shown to the user instead of a silently different image.
    fn limitations(&self, _scene: &Scene) -> Vec<String> {
        Vec::new()
    }
    /// Choices the technique made for `scene` that the user should know of but that leave
    /// nothing out (isg casting a thin wall as triangles, a sphere file replaced by fitted
    /// spheres): shown with the limitations, but not failing an accuracy-matrix cell.
    fn notes(&self, _scene: &Scene) -> Vec<String> {
        Vec::new()
    }
    /// Whether the technique integrates the scene's participating medium itself (attenuation and
    /// in-scattering in its own image, as `mc` does): the renderer then adds no volumetric effect.
    fn renders_medium(&self) -> bool {
        false
    }
    /// For a Monte Carlo technique: the samples per pixel in its image after the last frame
    /// (accumulated over frames where nothing changed); `None` for the others.
    fn samples_per_pixel(&self) -> Option<u32> {
        None
    }
    /// Statistics of the technique's last frame, as its own type (`AvsStats`, `VvStats`, ...),
    /// read by `Renderer::technique_stats::<T>()`; `None` if it keeps none. Never waits on the
    /// GPU: counts the GPU writes are those of the last finished frame.
    fn stats(&self) -> Option<Box<dyn std::any::Any>> {
        None
    }
}

/// `S`'s defaults with every parameter in `params` set through `set` (every bad one reported, as
/// [`apply_params`]): the `from_params` of every technique's settings.
pub fn settings_from_params<S: Default>(
    params: &std::collections::BTreeMap<String, String>,
    set: impl Fn(&mut S, &str, &str) -> Result<()>,
) -> Result<S> {
    let mut s = S::default();
    apply_params(&mut s, params, set)?;
    Ok(s)
}

/// Applies every `key = value` of `params` (a scene's `[technique_params]` and `--param`s) to
/// `settings` with `set`, reporting all the bad ones together (one per line), not only the first.
pub fn apply_params<S>(
    settings: &mut S,
    params: &std::collections::BTreeMap<String, String>,
    set: impl Fn(&mut S, &str, &str) -> Result<()>,
) -> Result<()> {
    let errors: Vec<String> =
        params.iter().filter_map(|(k, v)| set(settings, k, v).err().map(|e| format!("{e:#}"))).collect();
    match errors.len() {
        0 => Ok(()),
        1 => Err(anyhow::anyhow!("{}", errors[0])),
        n => Err(anyhow::anyhow!("{n} bad technique parameters:\n  {}", errors.join("\n  "))),
    }
}

/// One `key = value` technique parameter as a technique's `set` reads it: typed readers whose
/// errors all read "`<technique>` parameter `<key>` = '`<value>`': expected ..." (the value as
/// written, surrounding white space ignored).
#[derive(Clone, Copy, Debug)]
pub struct Param<'a> {
    technique: &'a str,
    key: &'a str,
    value: &'a str,
}

impl<'a> Param<'a> {
    pub fn new(technique: &'a str, key: &'a str, value: &'a str) -> Self {
        Param { technique, key: key.trim(), value }
    }

    /// The key, trimmed.
    pub fn key(&self) -> &'a str {
        self.key
    }

    /// The value, trimmed.
    pub fn text(&self) -> &'a str {
        self.value.trim()
    }

    /// The error for a value that is not `expected`.
    pub fn bad(&self, expected: &str) -> anyhow::Error {
        anyhow::anyhow!("{} parameter {} = '{}': expected {expected}", self.technique, self.key, self.value)
    }

    /// The error for a key the technique does not take (`known`: the keys it takes).
    pub fn unknown(&self, known: &str) -> anyhow::Error {
        anyhow::anyhow!("unknown {} parameter '{}' (known: {known})", self.technique, self.key)
    }

    /// `true`/`1` or `false`/`0`.
    pub fn flag(&self) -> Result<bool> {
        self.choice(&[("true", true), ("1", true), ("false", false), ("0", false)])
            .map_err(|_| self.bad("true or false"))
    }

    /// An integer in `lo..=hi`.
    pub fn int(&self, lo: u64, hi: u64) -> Result<u64> {
        self.text()
            .parse::<u64>()
            .ok()
            .filter(|x| (lo..=hi).contains(x))
            .ok_or_else(|| self.bad(&format!("an integer in {lo}..={hi}")))
    }

    /// A power of two in `lo..=hi`.
    pub fn pow2(&self, lo: u64, hi: u64) -> Result<u64> {
        let n = self.int(lo, hi).ok().filter(|n| n.is_power_of_two());
        n.ok_or_else(|| self.bad(&format!("a power of two in {lo}..={hi}")))
    }

    /// A finite number in `[lo, hi]`.
    pub fn float(&self, lo: f64, hi: f64) -> Result<f64> {
        self.number(|x| x >= lo && x <= hi, &format!("a number in [{lo}, {hi}]"))
    }

    /// A finite number for which `ok` holds (`what` says which, for the error).
    pub fn number(&self, ok: impl Fn(f64) -> bool, what: &str) -> Result<f64> {
        self.text().parse::<f64>().ok().filter(|x| x.is_finite() && ok(*x)).ok_or_else(|| self.bad(what))
    }

    /// The value of the option whose name the text is.
    pub fn choice<T: Copy>(&self, options: &[(&str, T)]) -> Result<T> {
        if let Some((_, t)) = options.iter().find(|(name, _)| *name == self.text()) {
            return Ok(*t);
        }
        let names: Vec<String> = options.iter().map(|(n, _)| format!("'{n}'")).collect();
        Err(self.bad(&match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => names.concat(),
        }))
    }
}
