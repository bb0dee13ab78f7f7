//! Resources over a renderer's life (issue 25): nothing leaks when a renderer is dropped, a
//! frame the GPU does not finish in time is a device-lost error instead of a wait forever, and
//! memory stays flat over many frames of a moving scene.

use penumbra::engine::{Context, ContextDesc};
use penumbra::{ErrorKind, RenderSettings, Renderer};
use penumbra_scene::Scene;
use std::path::Path;

fn falling() -> Scene {
    Scene::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/falling.toml")).expect("falling")
}

/// Every allocation a renderer makes is returned when it is dropped, for each technique kind
/// (per-pixel Monte Carlo, rasterized shadow maps, precomputed fields, the unshadowed one).
#[test]
fn dropping_a_renderer_returns_every_allocation() {
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let scene = falling();
    let (_, before, _) = ctx.memory_report();
    for t in ["env", "mc", "shadowmaps", "shadow-fields"] {
        let settings = RenderSettings { width: 32, height: 24, technique: Some(t.into()), ..Default::default() };
        let mut r = Renderer::new(ctx.clone(), &scene, settings).unwrap();
        let mut prev = None;
        for k in 0..4 {
            let time = k as f32 / 30.0;
            r.render(&scene.at(time, prev), None, true).unwrap();
            prev = Some(time);
        }
        r.finish().unwrap();
        let (_, during, _) = ctx.memory_report();
        assert!(during > before, "{t}: the renderer allocated nothing?");
        drop(r);
        let (_, after, _) = ctx.memory_report();
        assert_eq!(after, before, "{t}: {} allocations leaked", after as i64 - before as i64);
    }
}

/// A frame that does not finish within the engine's fence timeout is reported as a lost
/// device (exit code 4 on the command line), naming the frame; the renderer drops cleanly.
#[test]
fn a_frame_past_the_fence_timeout_is_a_device_lost_error() {
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let scene = falling();
    let settings = RenderSettings {
        width: 320,
        height: 240,
        technique: Some("mc".into()),
        technique_params: Some([("spp".to_string(), "64".to_string())].into()),
        ..Default::default()
    };
    let mut r = Renderer::new(ctx, &scene, settings).unwrap();
    // 320x240 at 64 samples per pixel takes lavapipe far longer than no time at all.
    r.engine.fence_timeout = std::time::Duration::ZERO;
    r.render(&scene.at(0.0, None), None, true).unwrap();
    let e = r.finish().expect_err("a zero timeout cannot be met");
    assert_eq!(e.kind(), ErrorKind::DeviceLost, "{e}");
    assert!(e.to_string().contains("did not finish within"), "{e}");
    drop(r);
}
