//! The shadow-map baseline (`shadowmaps`) against the CPU reference (lavapipe): with shadows it
//! is closer to the reference than the same lights without shadows, and within a PSNR bound;
//! static geometry renders the depth maps once; validation is clean.

mod common;
use common::{root, shaders};
use penumbra_engine::{Context, ContextDesc, Engine, Graph};
use penumbra_passes::gbuffer::GBufferPass;
use penumbra_passes::scene_gpu::{FrameConstants, SceneGpu};
use penumbra_passes::shadowmaps::ShadowMapsTechnique;
use penumbra_reference::image::Image;
use penumbra_reference::metrics::compare;
use penumbra_reference::render::{render, ReferenceOptions};
use penumbra_scene::Scene;


#[test]
fn shadowmaps_approach_the_reference_and_shadows_help() {
    let (w, h) = (64u32, 48u32);
    let scene = Scene::load(root().join("scenes/trace_test.toml")).unwrap();
    let opts = ReferenceOptions { width: w, height: h, spp: 256, time: Some(0.0), seed: 5, ..Default::default() };
    let reference = render(&scene, &opts).unwrap();

    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).expect("context");
    let lib = shaders();
    let mut engine = Engine::new(ctx.clone(), 1).unwrap();
    let scene_gpu = SceneGpu::new(&ctx, &scene).unwrap();
    let gbuffer = GBufferPass::new(&ctx, &lib).unwrap();
    let mut sm = ShadowMapsTechnique::new(&ctx, &lib, &scene).unwrap();
    sm.set_count(64);
    let f = scene.at(0.0, None);
    let mut results = Vec::new();
    for visibility in [true, false, true] {
        sm.visibility = visibility;
        let mut g = Graph::new();
        let consts = FrameConstants::new(&f, None, w, h);
        let (handles, draws) = scene_gpu.add(&mut g, &f, &consts);
        let gb = gbuffer.add(&mut g, &handles, draws, w, h);
        let hdr = sm.add_frame(&mut engine, &mut g, &f, &gb, handles.textures).unwrap();
        let depth_passes = g.passes().iter().filter(|p| p.name == "shadowmaps_depth").count();
        penumbra_passes::readback::add(&mut g, "readback", &[(hdr, "hdr")]);
        engine.submit(g).unwrap();
        let out = engine.drain().unwrap().pop().unwrap();
        let px: Vec<[f32; 4]> = out.readbacks["hdr"]
            .chunks_exact(16)
            .map(|c| std::array::from_fn(|i| f32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap())))
            .collect();
        let img = Image::from_fn(w, h, |x, y| {
            let p = px[(y * w + x) as usize];
            [p[0], p[1], p[2]]
        });
        let c = compare(&reference.radiance, "reference", &img, "shadowmaps").unwrap();
        println!(
            "shadowmaps visibility {visibility}: PSNR {:.2} dB, rel RMSE {:.4}, depth passes {depth_passes}",
            c.psnr_db.unwrap_or(f64::INFINITY),
            c.rel_rmse
        );
        results.push((c.psnr_db.unwrap_or(f64::INFINITY), depth_passes));
    }
    assert_eq!(results[0].1, 1, "first frame renders the depth maps");
    assert_eq!(results[1].1 + results[2].1, 0, "static geometry: depth maps kept");
    assert!(results[0].0 > results[1].0 + 3.0, "shadows bring it closer to the reference: {results:?}");
    assert!(results[0].0 > 30.0, "PSNR {results:?}");
    assert!((results[0].0 - results[2].0).abs() < 1e-6, "deterministic: {results:?}");
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}
