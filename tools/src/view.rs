//! `penumbra view`: a window (winit + ash-window + a Vulkan swapchain) showing a scene rendered
//! live by the same frame graph as `penumbra render`.
//!
//! Each frame: wait until the engine's next frame slot is free, acquire a swapchain image with
//! that slot's semaphore, import the image into the frame graph (initial access
//! [`Access::Present`] once it has been presented, else undefined contents; final access
//! `Present`), let the renderer tone-map into a transient RGBA8 image and blit it into the
//! swapchain image (any swapchain format and size), submit waiting on the acquire semaphore and
//! signalling the image's render-finished semaphore (both at `ALL_COMMANDS`, the stage the
//! `Present` access declares), and present. No barrier is written here: the graph derives them.
//!
//! Keys: Esc/Q quit, Space pause/resume, Left/Right step one frame while paused, T next
//! technique, C next parameter preset of the technique (its defaults, then each speed/accuracy
//! knob value the registry declares, as `bench pareto` sweeps them), H heads-up overlay on/off
//! (technique and parameters, frame and GPU ms, the slowest passes, and the configuration's
//! measured error when the scene's `fronts/<scene>.pareto.json` or `--pareto` has it), R reload
//! shaders (recompile `glsl/` from source; on errors every failing file is printed and the
//! running pipelines stay), P screenshot (PNG of the presented image), G write the frame graph
//! dumps.

use crate::{apply_max_error, apply_overrides, bad, load_scene, new_renderer, report_validation};
use anyhow::{anyhow, bail, Context as _, Result};
use clap::Args;
use penumbra::engine::dump;
use penumbra::engine::{ash, vk, Access, Context, ContextDesc, ImageDesc, ImportedImage, SubmitSync};
use penumbra::{RenderSettings, Renderer, TargetTexels};
use penumbra_reference::cli::parse_size;
use penumbra_reference::image::write_png_rgb8;
use penumbra_scene::Scene;
use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::window::{Window, WindowId};

#[derive(Args)]
pub struct ViewArgs {
    /// Scene file (.toml) or a bare glTF model (.glb/.gltf); the built-in default scene when omitted.
    scene: Option<PathBuf>,
    /// Render size WxH (also the initial window size; the image is scaled to the window).
    #[arg(long, default_value = "640x480")]
    size: String,
    /// Frames per second of scene time (frame k shows the scene at time k / fps).
    #[arg(long, default_value_t = 30.0)]
    fps: f32,
    /// Quit after this many frames (for scripts and tests); run until closed otherwise.
    #[arg(long)]
    frames: Option<u32>,
    /// With --frames: write the last frame as presented (read back from the swapchain image) to
    /// this PNG.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Directory for screenshots (P) and graph dumps (G).
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Enable the Khronos validation layer with synchronization validation; exit 1 if it
    /// reported any error.
    #[arg(long)]
    validate: bool,
    #[command(flatten)]
    o: crate::SceneOverrides,
    /// Scripted key presses before given frames, e.g. `2:t,4:r,5:p` (keys: q, space, left,
    /// right, t, c, h, r, p, g), for demos and tests.
    #[arg(long, default_value = "")]
    keys: String,
}

const KEYS: [&str; 10] = ["q", "space", "left", "right", "t", "c", "h", "r", "p", "g"];

/// Parses `FRAME:KEY,...`.
fn parse_keys(s: &str) -> Result<Vec<(u32, String)>, String> {
    s.split(',')
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (f, k) = p.split_once(':').ok_or_else(|| format!("'{p}': expected FRAME:KEY"))?;
            let f = f.trim().parse::<u32>().map_err(|_| format!("'{p}': '{f}' is not a frame number"))?;
            let k = k.trim().to_lowercase();
            if !KEYS.contains(&k.as_str()) {
                return Err(format!("'{p}': unknown key '{k}' (keys: {})", KEYS.join(", ")));
            }
            Ok((f, k))
        })
        .collect()
}

pub fn view(args: &ViewArgs, limits: &penumbra_scene::Limits) -> Result<()> {
    let (width, height) = parse_size(&args.size).map_err(bad)?;
    if !(args.fps.is_finite() && args.fps > 0.0) {
        return Err(bad("--fps must be a positive number"));
    }
    if args.frames == Some(0) {
        return Err(bad("--frames must be at least 1"));
    }
    if args.screenshot.is_some() && args.frames.is_none() {
        return Err(bad("--screenshot needs --frames (interactively, press P)"));
    }
    let script = parse_keys(&args.keys).map_err(|e| bad(format!("--keys: {e}")))?;
    let scene = apply_overrides(
        load_scene(args.scene.as_deref(), limits)?,
        &args.o.technique,
        &args.o.params,
        &args.o.volumetric,
    )?;
    let scene = apply_max_error(scene, args.scene.as_deref(), &args.o, width, height)?;
    let settings = RenderSettings {
        width,
        height,
        tonemap: penumbra_passes::tonemap::TonemapParams { exposure: args.o.exposure },
        effects: penumbra_passes::effect::EffectOverrides { volumetric: args.o.volumetric.clone() },
        ..Default::default()
    };
    let event_loop = EventLoop::new().map_err(|e| {
        anyhow!("cannot open a window: {e} (no display? set DISPLAY or WAYLAND_DISPLAY, or run under xvfb-run)")
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = Viewer {
        args,
        scene,
        settings,
        state: None,
        error: None,
        frame: 0,
        prev_t: None,
        time_index: 0,
        paused: false,
        step: 0,
        screenshot_next: None,
        shots: 0,
        gpu_ms: 0.0,
        validation: None,
        shaders: None,
        t_cursor: None,
        script,
        hud: false,
        hud_announce: false,
        preset: 0,
        last_draw: None,
        frame_ms: 0.0,
        slowest: Vec::new(),
        fronts: load_fronts(args.scene.as_deref(), args.o.pareto.as_deref()),
    };
    event_loop.run_app(&mut app).context("window event loop")?;
    let validation = app.validation.clone();
    let error = app.error.take();
    drop(app);
    if let Some(e) = error {
        return Err(e);
    }
    if let Some(log) = validation.filter(|_| args.validate) {
        report_validation(&log)?;
    }
    Ok(())
}

struct Viewer<'a> {
    args: &'a ViewArgs,
    scene: Scene,
    settings: RenderSettings,
    state: Option<State>,
    error: Option<anyhow::Error>,
    /// Frames submitted.
    frame: u32,
    prev_t: Option<f32>,
    /// Scene time index (frame k shows time k / fps).
    time_index: u32,
    paused: bool,
    /// Frames to advance while paused (arrow keys).
    step: i32,
    /// Where to write the next read-back presented image.
    screenshot_next: Option<PathBuf>,
    shots: u32,
    gpu_ms: f64,
    validation: Option<Arc<penumbra::engine::ValidationLog>>,
    /// Scripted key presses (--keys): (frame, key).
    script: Vec<(u32, String)>,
    /// The technique T tried last.
    t_cursor: Option<String>,
    /// Shaders recompiled by R (the embedded ones until then).
    shaders: Option<penumbra::engine::shader::ShaderLibrary>,
    /// The heads-up overlay is shown (H).
    hud: bool,
    /// Print the overlay's lines with the next frame (it was just turned on, or its
    /// configuration changed): scripts and tests read what a person sees.
    hud_announce: bool,
    /// The preset C chose last (index into the technique's configurations).
    preset: usize,
    last_draw: Option<std::time::Instant>,
    /// Wall-clock milliseconds between the last two frames drawn.
    frame_ms: f64,
    /// The last finished frame's passes, slowest first (GPU ms).
    slowest: Vec<(String, f64)>,
    /// Measured points for this scene (its `fronts/<scene>.pareto.json`, or `--pareto`).
    fronts: Vec<crate::pareto::Front>,
}

/// The measured fronts the overlay looks errors up in: `--pareto FILE`, else the scene file's
/// `fronts/<stem>.pareto.json` beside it (the built-in paper scenes have one); none when absent.
fn load_fronts(scene: Option<&Path>, pareto: Option<&Path>) -> Vec<crate::pareto::Front> {
    let path = pareto.map(Path::to_path_buf).or_else(|| {
        let s = scene?;
        Some(s.parent()?.join("fronts").join(format!("{}.pareto.json", s.file_stem()?.to_string_lossy())))
    });
    path.filter(|p| p.exists()).and_then(|p| crate::pareto::read_fronts(&p).ok()).unwrap_or_default()
}

impl ApplicationHandler for Viewer<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match State::new(event_loop, self.args, &self.scene, &self.settings) {
            Ok(s) => {
                self.validation = Some(s.ctx.validation.clone());
                println!(
                    "penumbra view: scene '{}' with '{}' on {} ({:?} swapchain); Esc quits, Space pauses, T next technique, C next preset, H overlay, P screenshot, G graph dump",
                    self.scene.name,
                    self.technique(),
                    s.ctx.device_name,
                    s.swapchain.format
                );
                self.state = Some(s);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(_) => {
                if let Some(s) = &mut self.state {
                    s.swapchain_stale = true;
                }
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                let name = match event.logical_key.as_ref() {
                    Key::Named(NamedKey::Escape) => "q".to_string(),
                    Key::Named(NamedKey::Space) => "space".to_string(),
                    Key::Named(NamedKey::ArrowRight) => "right".to_string(),
                    Key::Named(NamedKey::ArrowLeft) => "left".to_string(),
                    Key::Character(c) => c.to_lowercase(),
                    _ => return,
                };
                if let Err(e) = self.key(event_loop, &name) {
                    self.fail(event_loop, e);
                }
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.draw(event_loop) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(s) = &self.state {
            s.window.request_redraw();
        }
    }
}

impl Viewer<'_> {
    /// One key press (from the window, or scripted by --keys).
    fn key(&mut self, event_loop: &ActiveEventLoop, key: &str) -> Result<()> {
        match key {
            "q" => event_loop.exit(),
            "space" => self.paused = !self.paused,
            "right" => self.step += 1,
            "left" => self.step -= 1,
            "t" => self.next_technique()?,
            "c" => self.next_preset()?,
            "h" => {
                self.hud = !self.hud;
                self.hud_announce = self.hud;
            }
            "r" => self.reload_shaders()?,
            "p" => {
                self.shots += 1;
                self.screenshot_next = Some(self.args.out.join(format!("screenshot_{:04}.png", self.shots)));
            }
            "g" => self.dump_graph()?,
            _ => {}
        }
        Ok(())
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        event_loop.exit();
    }

    fn technique(&self) -> String {
        self.settings.technique.clone().unwrap_or_else(|| self.scene.technique.clone())
    }

    /// Recompiles every shader from `glsl/` and rebuilds the renderer with them; a compile
    /// error is printed (all failing files) and the current pipelines stay.
    fn reload_shaders(&mut self) -> Result<()> {
        let mut lib = penumbra::shader_library();
        let changed = match lib.reload_all() {
            Ok(c) => c,
            Err(e) => {
                eprintln!("shader reload failed, keeping the running shaders:\n{e:#}");
                return Ok(());
            }
        };
        let Some(s) = &mut self.state else { return Ok(()) };
        // (the renderer gives the scene's parameters to the scene's own technique only)
        match penumbra::Renderer::new_with_shaders(s.ctx.clone(), &self.scene, self.settings.clone(), &lib) {
            Ok(r) => {
                s.renderer = Some(r);
                self.shaders = Some(lib);
                println!("reloaded shaders ({} changed: {})", changed.len(), changed.join(", "));
            }
            Err(e) => eprintln!("shader reload failed, keeping the running shaders: {e:#}"),
        }
        Ok(())
    }

    /// Recreates the renderer with the next implemented technique (same device and window).
    fn next_technique(&mut self) -> Result<()> {
        let list = penumbra_passes::registry::names();
        // From the last one tried, so that one failing to build does not stop the cycle.
        let cur = self.t_cursor.clone().unwrap_or_else(|| self.technique());
        let next = list[(list.iter().position(|t| *t == cur).map_or(0, |i| i + 1)) % list.len()];
        self.t_cursor = Some(next.to_string());
        // (the renderer gives the scene's parameters to the scene's own technique only)
        let mut settings = self.settings.clone();
        settings.technique = Some(next.to_string());
        // a preset (C) belongs to the technique it was chosen for
        settings.technique_params = None;
        if self.switch_renderer(settings, format!("technique: {next}"), &format!("technique {next}")) {
            self.preset = 0;
        }
        Ok(())
    }

    /// Replaces the renderer with one built from `settings` (same device, window and shaders):
    /// prints `announce` and the new renderer's notes, and returns true; when it cannot be built
    /// (e.g. a technique needing parameters the scene does not give) the old one keeps running
    /// and the error is printed after `what`.
    fn switch_renderer(&mut self, settings: RenderSettings, announce: String, what: &str) -> bool {
        let Some(s) = &mut self.state else { return false };
        let lib = self.shaders.clone().unwrap_or_else(penumbra::shader_library);
        match penumbra::Renderer::new_with_shaders(s.ctx.clone(), &self.scene, settings.clone(), &lib) {
            Ok(r) => {
                println!("{announce}");
                for l in r.notes() {
                    eprintln!("note: {l}");
                }
                s.renderer = Some(r);
                self.settings = settings;
                true
            }
            Err(e) => {
                eprintln!("{what}: {e:#} (still showing {})", self.technique());
                false
            }
        }
    }

    /// The technique running and its parameters (as the renderer resolved them: `auto`'s
    /// choice, the settings' or the scene's parameters).
    fn running(&self) -> (String, penumbra_passes::registry::Params) {
        let layered = self.state.as_ref().is_some_and(|s| s.ctx.shader_output_layer);
        penumbra::resolve_technique_why(&self.scene, &self.settings, layered)
            .map(|(n, p, _)| (n, p))
            .unwrap_or_else(|_| (self.technique(), Default::default()))
    }

    /// Recreates the renderer with the running technique's next preset: its defaults, then each
    /// knob value of the registry alone (what `bench pareto` measures), so a person sees the
    /// trade live.
    fn next_preset(&mut self) -> Result<()> {
        let (name, _) = self.running();
        let Some(info) = penumbra_passes::registry::info(&name) else { return Ok(()) };
        let presets = crate::pareto::configurations(info);
        self.preset = (self.preset + 1) % presets.len();
        let params = presets[self.preset].clone();
        let label = crate::pareto::label(&params);
        let mut settings = self.settings.clone();
        settings.technique = Some(name.clone());
        settings.technique_params = Some(params);
        let announce = format!("preset {}/{}: {name} {label}", self.preset + 1, presets.len());
        if self.switch_renderer(settings, announce, &format!("preset {label}")) {
            self.hud_announce = self.hud;
        }
        Ok(())
    }

    /// The overlay's lines for the frame at scene time `t`.
    fn hud_lines(&self, t: f32) -> Vec<String> {
        let (name, params) = self.running();
        let mut v = vec![
            format!("{} t={t:.2}s{}", self.scene.name, if self.paused { " (paused)" } else { "" }),
            format!("{name} {}", crate::pareto::label(&params)),
            format!("frame {:.1} ms  GPU {:.1} ms", self.frame_ms, self.gpu_ms),
        ];
        for (pass, ms) in self.slowest.iter().take(3) {
            v.push(format!("  {pass} {ms:.2} ms"));
        }
        let measured = crate::matrix::measured_params(&name, params);
        let hit = self
            .fronts
            .iter()
            .find_map(|f| f.points.iter().find(|p| p.technique == name && p.params == measured).map(|p| (f, p)));
        v.push(match hit {
            Some((f, p)) => format!("error {:.3} RMSE/mean at {}x{}", p.rmse_rel_mean, f.size[0], f.size[1]),
            None => "error: not measured (bench pareto)".to_string(),
        });
        v.push("H overlay  C preset  T technique".to_string());
        v
    }

    fn dump_graph(&mut self) -> Result<()> {
        let Some(r) = self.state.as_ref().and_then(|s| s.renderer.as_ref()) else { return Ok(()) };
        let Some(g) = r.last_graph.as_ref() else { return Ok(()) };
        let out = &self.args.out;
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let timings = r.engine.profiler.gpu_stats();
        std::fs::write(
            out.join("graph.json"),
            serde_json::to_string_pretty(&dump::to_json(g, Some(&timings)))? + "\n",
        )?;
        std::fs::write(out.join("graph.dot"), dump::to_dot(g))?;
        std::fs::write(out.join("graph.txt"), dump::to_text(g, Some(&timings)))?;
        let title = format!("{}: frame graph ({})", self.scene.name, r.technique_name());
        std::fs::write(out.join("graph.html"), penumbra::engine::dump_html::to_html(g, Some(&timings), &title, &[]))?;
        println!("wrote graph.json, graph.dot, graph.txt and graph.html to {}", out.display());
        Ok(())
    }

    fn draw(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        for (_, key) in self.script.iter().filter(|(f, _)| *f == self.frame).cloned().collect::<Vec<_>>() {
            self.key(event_loop, &key)?;
        }
        self.script.retain(|(f, _)| *f != self.frame);
        let last = self.args.frames.is_some_and(|n| self.frame + 1 >= n);
        let advance = !self.paused || self.step != 0;
        let k = self.scene_frame();
        let t = k as f32 / self.args.fps;
        let frame = self.scene.at(t, self.prev_t);
        let want_shot = if last { self.args.screenshot.clone() } else { self.screenshot_next.take() };
        let now = std::time::Instant::now();
        if let Some(prev) = self.last_draw.replace(now) {
            self.frame_ms = (now - prev).as_secs_f64() * 1e3;
        }
        let overlay = self.hud.then(|| {
            let lines = self.hud_lines(t);
            if std::mem::take(&mut self.hud_announce) {
                println!("overlay:\n  {}", lines.join("\n  "));
            }
            let scale = if self.settings.height >= 400 { 2 } else { 1 };
            penumbra_passes::hud::Overlay::text(&lines, scale)
        });
        let Some(s) = &mut self.state else { return Ok(()) };
        if let Some(r) = s.renderer.as_mut() {
            r.set_overlay(overlay);
        }
        let Some(done) = s.draw(&frame, want_shot.is_some())? else {
            // Out of date or minimized: nothing was submitted; retry with the next event.
            if !last {
                self.screenshot_next = want_shot;
            }
            return Ok(());
        };
        let mut done = done;
        let shot_frame = s.renderer.as_ref().map_or(0, |r| r.engine.frame_index()) - 1;
        if last {
            done.extend(s.renderer.as_mut().map(|r| r.finish()).transpose()?.unwrap_or_default());
        }
        for img in &done {
            self.gpu_ms = img.gpu_ms.iter().map(|(_, ms)| ms).sum();
            self.slowest = img.gpu_ms.clone();
            self.slowest.sort_by(|a, b| b.1.total_cmp(&a.1));
        }
        if let Some(path) = &want_shot {
            s.pending_shots.push((shot_frame, path.clone()));
        }
        for img in &done {
            if let Some(i) = s.pending_shots.iter().position(|(f, _)| *f == img.frame) {
                let (_, path) = s.pending_shots.remove(i);
                let t = img.target.as_ref().context("the presented image was not read back")?;
                write_screenshot(&path, t)?;
                println!("wrote {}", path.display());
            }
        }
        s.window.set_title(&format!(
            "penumbra: {} [{}] t={t:.2}s {:.1} ms GPU{}",
            self.scene.name,
            self.settings.technique.clone().unwrap_or_else(|| self.scene.technique.clone()),
            self.gpu_ms,
            if self.paused { " (paused)" } else { "" }
        ));
        self.prev_t = Some(t);
        self.frame += 1;
        if advance {
            self.advance();
        }
        if last {
            event_loop.exit();
        }
        Ok(())
    }

    /// The scene frame shown (time index), which stops while paused.
    fn scene_frame(&self) -> u32 {
        self.time_index
    }

    fn advance(&mut self) {
        if self.paused {
            self.time_index = (self.time_index as i64 + self.step as i64).max(0) as u32;
            self.step = 0;
        } else {
            self.time_index += 1;
        }
    }
}

/// Converts a read-back swapchain image to RGB and writes it as PNG.
fn write_screenshot(path: &Path, t: &TargetTexels) -> Result<()> {
    let (r, b) = match t.format {
        vk::Format::B8G8R8A8_UNORM | vk::Format::B8G8R8A8_SRGB => (2, 0),
        vk::Format::R8G8B8A8_UNORM | vk::Format::R8G8B8A8_SRGB => (0, 2),
        f => bail!("screenshot: swapchain format {f:?} is not an 8-bit RGBA/BGRA format"),
    };
    let rgb: Vec<u8> = t.bytes.chunks_exact(4).flat_map(|p| [p[r], p[1], p[b]]).collect();
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    write_png_rgb8(path, t.width, t.height, &rgb).with_context(|| format!("writing {}", path.display()))
}

struct Swapchain {
    loader: ash::khr::swapchain::Device,
    swapchain: vk::SwapchainKHR,
    format: vk::Format,
    extent: vk::Extent2D,
    usage: vk::ImageUsageFlags,
    images: Vec<vk::Image>,
    /// The image has been presented (its contents and layout are the presentation engine's).
    presented: Vec<bool>,
    /// Per image: signalled by the frame's submission, waited by its present.
    render_done: Vec<vk::Semaphore>,
}

struct State {
    renderer: Option<Renderer>,
    swapchain: Swapchain,
    swapchain_stale: bool,
    /// Per engine frame slot: signalled by the acquire, waited by that slot's submission.
    acquire: Vec<vk::Semaphore>,
    surface_loader: ash::khr::surface::Instance,
    surface: vk::SurfaceKHR,
    /// (engine frame index, path) of screenshots whose frames are still in flight.
    pending_shots: Vec<(u64, PathBuf)>,
    ctx: Arc<Context>,
    window: Window,
}

impl State {
    fn new(event_loop: &ActiveEventLoop, args: &ViewArgs, scene: &Scene, settings: &RenderSettings) -> Result<State> {
        let attrs = Window::default_attributes()
            .with_title(format!("penumbra: {}", scene.name))
            .with_inner_size(winit::dpi::PhysicalSize::new(settings.width, settings.height));
        let window = event_loop.create_window(attrs).context("creating the window")?;
        let display = event_loop.display_handle().context("display handle")?.as_raw();
        let exts = ash_window::enumerate_required_extensions(display).context("surface extensions")?;
        let instance_extensions =
            exts.iter().map(|&p| unsafe { CStr::from_ptr(p) }.to_owned()).collect::<Vec<CString>>();
        let ctx = Context::new(&ContextDesc {
            validation: args.validate,
            device_name: args.o.device.clone(),
            tracer: args.o.tracer,
            instance_extensions,
            swapchain: true,
            ..Default::default()
        })?;
        let surface = unsafe {
            ash_window::create_surface(
                &ctx.entry,
                &ctx.instance,
                display,
                window.window_handle().context("window handle")?.as_raw(),
                None,
            )
        }
        .context("creating the window surface")?;
        let surface_loader = ash::khr::surface::Instance::new(&ctx.entry, &ctx.instance);
        let supported =
            unsafe { surface_loader.get_physical_device_surface_support(ctx.physical, ctx.queue_family, surface) }?;
        if !supported {
            unsafe { surface_loader.destroy_surface(surface, None) };
            bail!("device '{}' cannot present to this window's surface", ctx.device_name);
        }
        let renderer = new_renderer(ctx.clone(), scene, settings.clone());
        let renderer = match renderer {
            Ok(r) => r,
            Err(e) => {
                unsafe { surface_loader.destroy_surface(surface, None) };
                return Err(e);
            }
        };
        for l in renderer.notes() {
            eprintln!("note: {l}");
        }
        let sem = || unsafe { ctx.device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) };
        let acquire = (0..settings.frames_in_flight).map(|_| sem()).collect::<Result<Vec<_>, _>>()?;
        let loader = ash::khr::swapchain::Device::new(&ctx.instance, &ctx.device);
        let empty = Swapchain {
            loader,
            swapchain: vk::SwapchainKHR::null(),
            format: vk::Format::UNDEFINED,
            extent: vk::Extent2D::default(),
            usage: vk::ImageUsageFlags::empty(),
            images: Vec::new(),
            presented: Vec::new(),
            render_done: Vec::new(),
        };
        let mut s = State {
            renderer: Some(renderer),
            swapchain: empty,
            swapchain_stale: true,
            acquire,
            surface_loader,
            surface,
            pending_shots: Vec::new(),
            ctx,
            window,
        };
        s.recreate_swapchain()?;
        Ok(s)
    }

    /// (Re)creates the swapchain for the window's current size. False when the window has no
    /// area (minimized).
    fn recreate_swapchain(&mut self) -> Result<bool> {
        let d = &self.ctx.device;
        unsafe { d.device_wait_idle()? };
        let caps =
            unsafe { self.surface_loader.get_physical_device_surface_capabilities(self.ctx.physical, self.surface) }?;
        let size = self.window.inner_size();
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: size.width.clamp(caps.min_image_extent.width, caps.max_image_extent.width),
                height: size.height.clamp(caps.min_image_extent.height, caps.max_image_extent.height),
            }
        };
        if extent.width == 0 || extent.height == 0 {
            return Ok(false);
        }
        let formats =
            unsafe { self.surface_loader.get_physical_device_surface_formats(self.ctx.physical, self.surface) }?;
        // UNORM: the tone map already encodes sRGB.
        let format = [vk::Format::B8G8R8A8_UNORM, vk::Format::R8G8B8A8_UNORM]
            .into_iter()
            .find_map(|f| formats.iter().find(|s| s.format == f).copied())
            .or_else(|| formats.first().copied())
            .context("the surface offers no format")?;
        if !caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_DST) {
            bail!("the surface's images cannot be blitted into (no TRANSFER_DST usage)");
        }
        // TRANSFER_SRC lets screenshots read back what is presented.
        let usage =
            vk::ImageUsageFlags::TRANSFER_DST | (caps.supported_usage_flags & vk::ImageUsageFlags::TRANSFER_SRC);
        let mut count = caps.min_image_count + 1;
        if caps.max_image_count > 0 {
            count = count.min(caps.max_image_count);
        }
        let sc = &mut self.swapchain;
        let old = sc.swapchain;
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(count)
            .image_format(format.format)
            .image_color_space(format.color_space)
            .image_extent(extent)
            .image_array_layers(1)
            .image_usage(usage)
            .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
            .pre_transform(caps.current_transform)
            .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
            .present_mode(vk::PresentModeKHR::FIFO)
            .clipped(true)
            .old_swapchain(old);
        let new = unsafe { sc.loader.create_swapchain(&info, None) }.context("creating the swapchain")?;
        Self::destroy_images(d, sc);
        if old != vk::SwapchainKHR::null() {
            unsafe { sc.loader.destroy_swapchain(old, None) };
        }
        sc.swapchain = new;
        sc.format = format.format;
        sc.extent = extent;
        sc.usage = usage;
        sc.images = unsafe { sc.loader.get_swapchain_images(new) }?;
        for (i, &image) in sc.images.iter().enumerate() {
            // The images are only blitted into and read back (transfers): no view.
            self.ctx.set_name(image, &format!("swapchain image {i}"));
            sc.render_done.push(unsafe { d.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }?);
        }
        sc.presented = vec![false; sc.images.len()];
        self.swapchain_stale = false;
        Ok(true)
    }

    fn destroy_images(d: &ash::Device, sc: &mut Swapchain) {
        for s in sc.render_done.drain(..) {
            unsafe { d.destroy_semaphore(s, None) };
        }
        sc.images.clear();
    }

    /// Renders `frame` into the next swapchain image and presents it. `None` when nothing was
    /// submitted (swapchain out of date or window minimized).
    fn draw(&mut self, frame: &penumbra_scene::Frame, readback: bool) -> Result<Option<Vec<penumbra::FrameImages>>> {
        if self.swapchain_stale && !self.recreate_swapchain()? {
            return Ok(None);
        }
        let renderer = self.renderer.as_mut().context("no renderer")?;
        // The slot's previous frame must be complete before its acquire semaphore is reused.
        renderer.engine.wait_next_slot()?;
        let acquire = self.acquire[renderer.engine.next_slot() % self.acquire.len()];
        let sc = &mut self.swapchain;
        let index = match unsafe { sc.loader.acquire_next_image(sc.swapchain, u64::MAX, acquire, vk::Fence::null()) } {
            Ok((i, _suboptimal)) => i as usize,
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.swapchain_stale = true;
                return Ok(None);
            }
            Err(e) => return Err(e).context("acquiring a swapchain image"),
        };
        let target = ImportedImage {
            image: sc.images[index],
            view: vk::ImageView::null(),
            desc: ImageDesc::new_2d(sc.format, sc.extent.width, sc.extent.height),
            usage: sc.usage,
            initial: sc.presented[index].then_some(Access::Present),
            initial_layout: vk::ImageLayout::UNDEFINED,
            final_access: Some(Access::Present),
        };
        let all = vk::PipelineStageFlags2::ALL_COMMANDS;
        let sync = SubmitSync { wait: vec![(acquire, all)], signal: vec![(sc.render_done[index], all)] };
        let readback = readback && sc.usage.contains(vk::ImageUsageFlags::TRANSFER_SRC);
        let done = renderer.render_with(frame, Some(target), readback, &sync)?;
        sc.presented[index] = true;
        let (waits, chains, indices) = ([sc.render_done[index]], [sc.swapchain], [index as u32]);
        let present = vk::PresentInfoKHR::default().wait_semaphores(&waits).swapchains(&chains).image_indices(&indices);
        match unsafe { sc.loader.queue_present(self.ctx.queue, &present) } {
            Ok(false) => {}
            Ok(true) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => self.swapchain_stale = true,
            Err(e) => return Err(e).context("presenting"),
        }
        Ok(Some(done))
    }
}

impl Drop for State {
    fn drop(&mut self) {
        let d = &self.ctx.device;
        let _ = unsafe { d.device_wait_idle() };
        self.renderer = None;
        for &s in &self.acquire {
            unsafe { d.destroy_semaphore(s, None) };
        }
        Self::destroy_images(d, &mut self.swapchain);
        unsafe {
            self.swapchain.loader.destroy_swapchain(self.swapchain.swapchain, None);
            self.surface_loader.destroy_surface(self.surface, None);
        }
    }
}
