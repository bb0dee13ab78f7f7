//! `mc-denoised` (passes/src/mc/denoise.rs): mc's samples filtered spatio-temporally (SVGF).

mod common;
use penumbra_reference::metrics::compare;
use penumbra_reference::ReferenceOptions;

/// falling (objects move every frame, studio.exr) at 96x72 over frames 0-30: four samples per
/// pixel per frame of `mc` (which restarts every frame: things move), denoised, against the same
/// samples undenoised and against the unshadowed `env`, all compared with the reference at frame
/// 30's pixel centres (the objects near the floor, moving fast). The denoiser must remove most of
/// mc's error and keep the shadows (well under env's error), and its history clipped to the
/// frame's neighbourhood must beat SVGF's unclipped one, whose shadows drag behind the objects;
/// validation clean. Measured: mc 0.430, mc-denoised 0.176, unclipped 0.192, env 0.377 (with a
/// 32-frame unclipped history instead of 5: 0.30).
#[test]
fn denoising_the_same_samples_lowers_the_error_and_keeps_the_shadows() {
    let s = common::scene("falling.toml");
    let (w, h) = (96u32, 72u32);
    let times: Vec<f32> = (0..=30).map(|k| k as f32 / 30.0).collect();
    let t = *times.last().unwrap();
    let opts = ReferenceOptions { width: w, height: h, spp: 256, pixel_grid: 1, time: Some(t), ..Default::default() };
    let reference = penumbra_reference::render(&s, &opts).expect("reference").radiance;
    let err = |technique: &str, params: &[(&str, &str)]| {
        let scene = common::with(&s, params);
        let (r, frames) = common::render_times(&scene, technique, w, h, &times, true);
        assert_eq!(r.context().validation.error_count(), 0, "{technique}: validation errors");
        let img = common::hdr_image(frames.last().unwrap());
        compare(&reference, "reference", &img, technique).expect("compare").rmse_rel_mean
    };
    let mc = err("mc", &[("spp", "4"), ("aa", "false")]);
    let denoised = err("mc-denoised", &[("spp", "4")]);
    let env = err("env", &[]);
    // the history clipped to the frame's neighbourhood (default) against SVGF's unclipped one
    let unclipped = err("mc-denoised", &[("spp", "4"), ("clip", "0")]);
    eprintln!("rmse/mean at frame 30: mc {mc:.4}, mc-denoised {denoised:.4} (unclipped {unclipped:.4}), env {env:.4}");
    assert!(denoised < 0.6 * mc, "mc-denoised {denoised} against mc {mc} from the same samples");
    assert!(denoised < 0.6 * env, "mc-denoised {denoised} against the unshadowed env {env}");
    assert!(
        denoised < 0.95 * unclipped,
        "clipped history {denoised} against the unclipped {unclipped}: moving shadows"
    );
}
