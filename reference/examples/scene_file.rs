//! Render a scene file with the reference renderer and print timing and noise.
//!
//! `cargo run --release -p penumbra-reference --example scene_file -- SCENE [WxH] [SPP] [FRAME] [OUT_DIR]`

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else { anyhow::bail!("usage: scene_file SCENE [WxH] [SPP] [FRAME] [OUT_DIR]") };
    let scene = penumbra_scene::Scene::load(path)?;
    let (width, height) = penumbra_reference::cli::parse_size(args.get(2).map(String::as_str).unwrap_or("160x120"))?;
    let spp: u32 = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(16);
    let frame: u32 = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(0);
    let opts = penumbra_reference::ReferenceOptions { width, height, spp, frame, progress: true, ..Default::default() };
    let img = penumbra_reference::render(&scene, &opts)?;
    println!(
        "{path}: {width}x{height}, {spp} spp, frame {frame}, {} triangles, {} lights, medium {}: {:.2} s, mean rel. s.e. {:.3e}",
        img.triangles,
        scene.lights.len(),
        scene.medium.is_some(),
        img.render_seconds,
        img.noise.mean_rel_std_error
    );
    if let Some(dir) = args.get(5) {
        img.write(std::path::Path::new(dir))?;
        let png = std::path::Path::new(dir).join("reference.png");
        let rgb = penumbra_reference::metrics::to_srgb8(&img.radiance, 0.0);
        penumbra_reference::image::write_png_rgb8(&png, width, height, &rgb)?;
    }
    Ok(())
}
