//! The GPU Monte Carlo baseline (`mc`) converges to the CPU reference (lavapipe): PSNR against a
//! high-spp reference rises with the accumulated spp, the accumulation restarts when the camera
//! moves, and static geometry builds the kd-tree once.

mod common;
use common::{root, shaders};
use penumbra_engine::{Context, ContextDesc, Engine, Graph};
use penumbra_passes::mc::McTechnique;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{render, ReferenceOptions};
use penumbra_scene::Scene;

/// Renders one frame of `mc` and returns (image, kd-tree build passes in the graph).
fn frame(engine: &mut Engine, mc: &mut McTechnique, f: &penumbra_scene::Frame, w: u32, h: u32) -> (Image, usize) {
    let mut g = Graph::new();
    let hdr = mc.add_frame(&mut penumbra_engine::FrameStore::new(engine), &mut g, f, w, h).unwrap().hdr;
    let builds =
        g.passes().iter().filter(|p| p.name.starts_with("kdtree_level") && !p.name.ends_with("_small")).count();
    penumbra_passes::readback::add(&mut g, "readback", &[(hdr, "hdr")]);
    engine.submit(g).unwrap();
    let out = engine.drain().unwrap().pop().unwrap();
    let bytes = &out.readbacks["hdr"];
    let px: Vec<[f32; 4]> = bytes
        .chunks_exact(16)
        .map(|c| std::array::from_fn(|i| f32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap())))
        .collect();
    assert_eq!(px.len(), (w * h) as usize);
    (
        Image::from_fn(w, h, |x, y| {
            let p = px[(y * w + x) as usize];
            [p[0], p[1], p[2]]
        }),
        builds,
    )
}

#[test]
fn mc_converges_to_the_cpu_reference() {
    let (w, h) = (40u32, 30u32);
    let scene = Scene::load(root().join("scenes/trace_test.toml")).unwrap();
    let opts = ReferenceOptions { width: w, height: h, spp: 2048, time: Some(0.0), seed: 11, ..Default::default() };
    let t0 = std::time::Instant::now();
    let reference = render(&scene, &opts).unwrap();
    println!("reference {w}x{h} at {} spp: {:.1} s", opts.spp, t0.elapsed().as_secs_f64());

    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let mut mc = McTechnique::new(&ctx, &lib, &scene).unwrap();
    let f = scene.at(0.0, None);
    let mut psnrs = Vec::new();
    let mut total_builds = 0;
    let t0 = std::time::Instant::now();
    // spp per frame doubles: accumulated 4, 8, 16, ..., 512
    let mut img = None;
    for k in 0..8 {
        mc.spp = if k == 0 { 4 } else { mc.accumulated };
        let (im, builds) = frame(&mut engine, &mut mc, &f, w, h);
        total_builds += builds;
        let c = compare(&reference.radiance, "reference", &im, "mc").unwrap();
        let psnr = c.psnr_db.unwrap_or(f64::INFINITY);
        println!("mc {} spp: PSNR {:.2} dB, rel RMSE {:.4}", mc.accumulated, psnr, c.rel_rmse);
        psnrs.push((mc.accumulated, psnr));
        img = Some(im);
    }
    println!("mc frames: {:.1} s", t0.elapsed().as_secs_f64());
    assert!(total_builds > 0, "the tree was built");
    let levels = mc.builder.last_levels as usize;
    assert_eq!(total_builds, levels, "static scene: the kd-tree is built once ({total_builds} level passes)");
    // PSNR rises with spp: every doubling gains (noise halves in variance), overall by a lot.
    for p in psnrs.windows(2) {
        assert!(p[1].1 > p[0].1, "PSNR does not rise from {} to {} spp: {psnrs:?}", p[0].0, p[1].0);
    }
    let (first, last) = (psnrs[0].1, psnrs[psnrs.len() - 1].1);
    assert!(last - first > 12.0, "PSNR rises by only {:.1} dB: {psnrs:?}", last - first);
    assert!(last > 40.0, "PSNR at {} spp is {last:.1} dB", psnrs.last().unwrap().0);

    // Moving the camera restarts the accumulation.
    let mut f2 = scene.at(0.0, None);
    f2.camera.eye += glam::Vec3::new(0.3, 0.0, 0.0);
    f2.camera_moved = true;
    mc.spp = 4;
    let (moved, builds) = frame(&mut engine, &mut mc, &f2, w, h);
    assert_eq!(builds, 0);
    assert_eq!(mc.accumulated, 4, "camera move resets the accumulation");
    let c = compare(img.as_ref().unwrap(), "before", &moved, "moved").unwrap();
    assert!(c.psnr_db.unwrap_or(f64::INFINITY) < 40.0);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

/// Local lights (coarse: an orbiting sphere light beside the environment, ground with
/// `casts_shadow = false`) and texture maps (chess: albedo and roughness maps, Blinn-Phong and
/// Cook-Torrance): the estimator matches the reference's light sampling, MIS and maps.
#[test]
fn mc_with_local_lights_and_textures_converges_to_the_cpu_reference() {
    let (w, h) = (32u32, 24u32);
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    for (file, t) in [("coarse.toml", 1.0f32), ("chess.toml", 0.0)] {
        let scene = Scene::load(root().join("scenes").join(file)).unwrap();
        let opts = ReferenceOptions { width: w, height: h, spp: 1024, time: Some(t), seed: 3, ..Default::default() };
        let reference = render(&scene, &opts).unwrap();
        let mut engine = Engine::new(ctx.clone(), 1).unwrap();
        let mut mc = McTechnique::new(&ctx, &lib, &scene).unwrap();
        let f = scene.at(t, None);
        match file {
            "coarse.toml" => assert!(!f.lights.is_empty()),
            _ => assert!(!scene.textures.is_empty()),
        }
        let mut psnrs = Vec::new();
        for k in 0..6 {
            mc.spp = if k == 0 { 8 } else { mc.accumulated };
            let (im, _) = frame(&mut engine, &mut mc, &f, w, h);
            let c = compare(&reference.radiance, "reference", &im, "mc").unwrap();
            let psnr = c.psnr_db.unwrap_or(f64::INFINITY);
            println!("{file}: mc {} spp: PSNR {:.2} dB, rel RMSE {:.4}", mc.accumulated, psnr, c.rel_rmse);
            psnrs.push((mc.accumulated, psnr));
        }
        for p in psnrs.windows(2) {
            assert!(p[1].1 > p[0].1, "{file}: PSNR does not rise from {} to {} spp: {psnrs:?}", p[0].0, p[1].0);
        }
        // Noise-limited (256 spp against a 1024-spp reference): about 3 dB per doubling, no plateau.
        let (first, last) = (psnrs[0].1, psnrs[psnrs.len() - 1].1);
        assert!(last - first > 10.0 && last > 32.0, "{file}: {psnrs:?}");
    }
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}
