//! Render the built-in default scene with the reference renderer and print timing and noise.
//!
//! `cargo run --release -p penumbra-reference --example default_scene -- [WxH] [SPP] [OUT_DIR]`

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (width, height) = penumbra_reference::cli::parse_size(args.get(1).map(String::as_str).unwrap_or("320x240"))?;
    let spp: u32 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(256);
    let seed: u64 = std::env::var("SEED").ok().map(|s| s.parse()).transpose()?.unwrap_or(0);
    let scene = penumbra_scene::Scene::default_scene();
    let opts = penumbra_reference::ReferenceOptions { width, height, spp, seed, progress: true, ..Default::default() };
    let img = penumbra_reference::render(&scene, &opts)?;
    println!(
        "default scene {width}x{height}, {spp} spp, {} triangles, {} threads: {:.2} s",
        img.triangles,
        rayon::current_num_threads(),
        img.render_seconds
    );
    println!("{}", serde_json::to_string_pretty(&img.noise)?);
    if let Some(dir) = args.get(3) {
        let s = img.write(std::path::Path::new(dir))?;
        println!("wrote {}", s.image.display());
        // A tone-mapped preview (exposure 0, clamp, sRGB) next to the EXR.
        let png = std::path::Path::new(dir).join("reference.png");
        let rgb = penumbra_reference::metrics::to_srgb8(&img.radiance, 0.0);
        penumbra_reference::image::write_png_rgb8(&png, width, height, &rgb)?;
        println!("wrote {}", png.display());
    }
    Ok(())
}
