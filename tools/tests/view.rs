//! `penumbra view` in a real window: an X server (Xvfb, installed by scripts/install-deps.sh)
//! displays the window and lavapipe presents to it through a swapchain. The presented image is
//! read back from the swapchain image and must equal, texel for texel, what `penumbra render`
//! writes for the same frame; validation (with synchronization validation) must stay clean.

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};

mod common;
use common::{text, tmp};

/// An Xvfb server on a display it chose itself, killed on drop.
struct Xvfb {
    child: Child,
    display: String,
    /// Xvfb's stdout, kept open for the server's lifetime.
    _stdout: std::io::BufReader<std::process::ChildStdout>,
}

impl Xvfb {
    fn start() -> Xvfb {
        // Xvfb picks a free display number and writes it to its stdout once it accepts
        // connections (-displayfd 1). Choosing numbers here raced: under nextest every test is
        // its own process, two servers were started on one number, and a test could talk to the
        // other test's server, killed under it ("Failed to set window title: Connection").
        let mut child = Command::new("Xvfb")
            .args(["-displayfd", "1", "-screen", "0", "640x480x24", "-nolisten", "tcp"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("Xvfb is needed for the window tests (scripts/install-deps.sh installs the package xvfb)");
        let mut line = String::new();
        let mut stdout = std::io::BufReader::new(child.stdout.take().expect("Xvfb's stdout"));
        std::io::BufRead::read_line(&mut stdout, &mut line).expect("reading Xvfb's display");
        let num: u32 = line.trim().parse().unwrap_or_else(|_| panic!("Xvfb did not start (it wrote {line:?})"));
        Xvfb { child, display: format!(":{num}"), _stdout: stdout }
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn penumbra(args: &[&str], display: Option<&str>) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_penumbra"));
    c.args(args).env_remove("WAYLAND_DISPLAY");
    match display {
        Some(d) => c.env("DISPLAY", d),
        None => c.env_remove("DISPLAY"),
    };
    c.output().expect("run penumbra")
}

fn rgb(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn window_presents_what_render_writes_with_clean_validation() {
    let x = Xvfb::start();
    let out = tmp("view_present");
    let shot = out.join("shot.png");
    let o = penumbra(
        &["view", "--size", "96x64", "--frames", "4", "--screenshot", shot.to_str().unwrap(), "--validate"],
        Some(&x.display),
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("validation: 0 error(s)"), "{}", text(&o));
    let o = penumbra(&["render", "--size", "96x64", "--frames", "4", "--out", out.to_str().unwrap()], None);
    assert!(o.status.success(), "{}", text(&o));
    let (w, h, presented) = rgb(&shot);
    let (w2, h2, rendered) = rgb(&out.join("frame_0003.png"));
    assert_eq!((w, h), (96, 64));
    assert_eq!((w, h), (w2, h2));
    let diff = presented.iter().zip(&rendered).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
    assert_eq!(diff, 0, "the presented frame differs from the rendered one (max channel difference {diff})");
    // Not a blank window: the default scene has structure.
    let mean = presented.iter().map(|&v| v as f64).sum::<f64>() / presented.len() as f64;
    assert!(mean > 20.0 && mean < 235.0, "mean {mean}");
}

/// Scripted keys: T switches technique on the same window and device, R recompiles every shader
/// from `glsl/` at run time (identical SPIR-V to the build's: 0 changed), P screenshots, G dumps
/// the graph, whose swapchain image is blitted into and ends in PRESENT_SRC.
#[test]
fn scripted_keys_switch_technique_reload_shaders_and_dump() {
    let x = Xvfb::start();
    let out = tmp("view_keys");
    let o = penumbra(
        &[
            "view",
            "--size",
            "64x48",
            "--frames",
            "9",
            "--technique",
            "mc",
            "--keys",
            // G late: the dumped frame's swapchain image was presented before (Mesa 25's X11
            // swapchain has more images than 22.3's: frame 3 still got a fresh one)
            "1:t,2:r,3:p,8:g",
            "--out",
            out.to_str().unwrap(),
            "--validate",
        ],
        Some(&x.display),
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    // From mc (cheap to create, unlike isg's tables) to the next implemented technique.
    let list = penumbra_passes::registry::names();
    let next = list[(list.iter().position(|t| *t == "mc").unwrap() + 1) % list.len()];
    assert!(t.contains(&format!("technique: {next}")), "{t}");
    assert!(t.contains("reloaded shaders (0 changed"), "run-time compile differs from build.rs: {t}");
    assert!(t.contains("validation: 0 error(s)"), "{t}");
    let (w, h, _) = rgb(&out.join("screenshot_0001.png"));
    assert_eq!((w, h), (64, 48));
    let graph = std::fs::read_to_string(out.join("graph.txt")).unwrap();
    assert!(graph.contains("blit_target (Transfer)"), "{graph}");
    assert!(graph.contains("PRESENT_SRC_KHR -> TRANSFER_DST_OPTIMAL"), "{graph}");
    assert!(graph.contains("TRANSFER_DST_OPTIMAL -> PRESENT_SRC_KHR"), "{graph}");
    let html = std::fs::read_to_string(out.join("graph.html")).unwrap();
    assert!(html.contains("data-pass=\"blit_target\">") && html.contains("PRESENT_SRC_KHR"), "graph.html");
    let o = penumbra(&["view", "--frames", "2", "--keys", "1:x"], Some(&x.display));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("unknown key 'x'"), "{}", text(&o));
}

/// H shows the heads-up overlay over the presented image (the rest of the image is what
/// `render` writes, texel for texel), C cycles the technique's parameter presets, and the
/// overlay gives the configuration's error from the scene's measured front.
#[test]
fn overlay_shows_the_configuration_and_presets_cycle() {
    let x = Xvfb::start();
    let out = tmp("view_hud");
    let shot = out.join("shot.png");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/falling.toml");
    let scene = scene.to_str().unwrap();
    let args = ["--size", "320x240", "--technique", "shadowmaps"];
    let o = penumbra(
        &[&["view", scene], &args[..], &["--frames", "4", "--keys", "0:h,1:c", "--screenshot"]]
            .concat()
            .into_iter()
            .chain([shot.to_str().unwrap(), "--validate"])
            .collect::<Vec<_>>(),
        Some(&x.display),
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("validation: 0 error(s)"), "{t}");
    // the first preset after the defaults: shadowmaps' first knob value, measured on the front
    assert!(t.contains("preset 2/5: shadowmaps count=8"), "{t}");
    assert!(t.contains("overlay:") && t.contains("shadowmaps count=8"), "{t}");
    assert!(t.contains("error 0.035 RMSE/mean at 160x120"), "{t}");
    let o = penumbra(
        &[&["render", scene], &args[..], &["--param", "count=8", "--frames", "4", "--out", out.to_str().unwrap()]]
            .concat(),
        None,
    );
    assert!(o.status.success(), "{}", text(&o));
    let (w, h, presented) = rgb(&shot);
    let (_, _, rendered) = rgb(&out.join("frame_0003.png"));
    assert_eq!((w, h), (320, 240));
    let at = |img: &[u8], x: u32, y: u32| -> [u8; 3] {
        let i = ((y * w + x) * 3) as usize;
        [img[i], img[i + 1], img[i + 2]]
    };
    // below the overlay's eight lines the presented image is the rendered one
    for y in 120..h {
        for x in 0..w {
            assert_eq!(at(&presented, x, y), at(&rendered, x, y), "({x}, {y}) outside the overlay");
        }
    }
    // the overlay: white glyphs on a darkened box in the top-left corner
    let (mut ink, mut darker) = (0, 0);
    for y in 8..80 {
        for x in 8..200 {
            let (p, r) = (at(&presented, x, y), at(&rendered, x, y));
            ink += (p == [255, 255, 255] && r != [255, 255, 255]) as u32;
            darker += p.iter().zip(r).all(|(a, b)| *a < b) as u32;
        }
    }
    assert!(ink > 300 && darker > 3000, "overlay not visible: {ink} ink texels, {darker} darkened");
}

#[test]
fn view_without_a_display_or_with_bad_flags_fails_cleanly() {
    let o = penumbra(&["view", "--frames", "1"], None);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("cannot open a window"), "{}", text(&o));
    let o = penumbra(&["view", "--screenshot", "x.png"], None);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--screenshot needs --frames"), "{}", text(&o));
    let o = penumbra(&["view", "--size", "0x10", "--frames", "1"], None);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}
