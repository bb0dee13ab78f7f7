//! The `shadow-fields` technique through the facade on the Vulkan device (lavapipe):
//! validation clean on moving rigid objects, shadows darken (ringing measured), and the
//! image error of adaptive and fixed fields against the CPU reference (exact mode).

use penumbra_reference::metrics::{compare, Comparison};
use penumbra_reference::render::{render as reference_render, Mode, ReferenceOptions};

mod common;
use common::reference_at;
use common::{hdr_image as image, render_times as render, scene};

#[test]
fn shadow_fields_render_validation_clean_and_against_the_reference() {
    let s = scene("sf_spheres.toml");
    let (w, h, t) = (64, 48, 0.8);
    let start = std::time::Instant::now();
    let (r, frames) = render(&s, "shadow-fields", w, h, &[0.0, t], true);
    println!("shadow-fields: precompute (or cache load) + 2 frames in {:.1} s", start.elapsed().as_secs_f64());
    let log = r.context().validation.clone();
    // The technique's fields (default options; loaded from the per-object cache it just wrote).
    let fields = penumbra::passes::shadow_fields::SceneFields::build(&s, &Default::default()).expect("fields");
    for rep in &fields.reports {
        println!(
            "{}: {} tris, fixed {} B, adaptive {} B, file {} / {} B, precompute {:.2} s (cached {}), R per shell {:?}",
            rep.mesh,
            rep.triangles,
            rep.fixed_bytes,
            rep.adaptive_bytes,
            rep.fixed_file_bytes,
            rep.adaptive_file_bytes,
            rep.seconds,
            rep.cached,
            rep.resolutions
        );
        assert!(rep.adaptive_bytes <= rep.fixed_bytes);
    }
    assert_eq!(frames.len(), 2);
    for f in &frames {
        assert!(f.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0), "non-finite or negative radiance");
        assert!(f.gpu_ms.iter().any(|(p, _)| p == "sf_shade"), "no sf_shade pass: {:?}", f.gpu_ms);
        println!("gpu ms: {:?}", f.gpu_ms);
    }
    drop(r);
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());

    // Same frame with and without occluders. Order-4 triple products ring, so a shadowed pixel
    // can come out slightly brighter than unshadowed (the paper's method has the same
    // property); measure it and require it to stay rare and small next to the darkening.
    let sf = &frames[1];
    let mut open = s.clone();
    for i in 0..open.objects.len() {
        if open.object_info.len() <= i {
            open.object_info.resize(i + 1, Default::default());
        }
        open.object_info[i].casts_shadow = false;
    }
    let (_r, un) = render(&open, "shadow-fields", w, h, &[t], false);
    let (mut darker, mut brighter, mut max_bright) = (0, 0, 0.0f32);
    let (mut gained, mut lost) = (0.0f64, 0.0f64);
    for (a, b) in sf.hdr.iter().zip(&un[0].hdr) {
        let (la, lb) = (a[0] + a[1] + a[2], b[0] + b[1] + b[2]);
        gained += (la - lb).max(0.0) as f64;
        lost += (lb - la).max(0.0) as f64;
        if la < 0.9 * lb {
            darker += 1;
        }
        if la > 1.02 * lb + 1e-4 {
            brighter += 1;
        }
        if lb > 1e-3 {
            max_bright = max_bright.max(la / lb - 1.0);
        }
    }
    println!(
        "pixels darkened by shadow fields: {darker}, brightened > 2%: {brighter} (max {:.1}%) of {}; energy gained / lost {:.3}",
        100.0 * max_bright,
        sf.hdr.len(),
        gained / lost.max(1e-9)
    );
    assert!(darker > 20, "no visible shadows ({darker} pixels)");
    // The overshoot of an order-4 cap indicator (Gibbs) is about 10%: brightening stays below
    // 20% per pixel and well below the light the shadows remove.
    assert!(max_bright < 0.2, "ringing brightens a pixel by {max_bright}");
    assert!(gained < 0.3 * lost, "ringing gains {gained} vs shadows' {lost}");

    // Image error against the exact reference, adaptive vs fixed vs unshadowed.
    let reference = reference_at(&s, (w, h), 32, t, Mode::Exact);
    let (_r, fixed) = render(&s, "shadow-fields-fixed", w, h, &[t], false);
    let ca = compare(&reference.radiance, "reference", &image(sf), "adaptive").unwrap();
    let cf = compare(&reference.radiance, "reference", &image(&fixed[0]), "fixed").unwrap();
    let cu = compare(&reference.radiance, "reference", &image(&un[0]), "unshadowed").unwrap();
    let (_r, env) = render(&s, "env", w, h, &[t], false);
    let ce = compare(&reference.radiance, "reference", &image(&env[0]), "env").unwrap();
    println!("env (unshadowed) vs reference: {}", ce.summary());
    let caf = compare(&image(&fixed[0]), "fixed", &image(sf), "adaptive").unwrap();
    println!("adaptive vs reference: {}", ca.summary());
    println!("fixed vs reference: {}", cf.summary());
    println!("unshadowed vs reference: {}", cu.summary());
    println!("adaptive vs fixed: {}", caf.summary());
    // Shadow fields must beat the same shading without occluders, and adaptive must stay
    // close to fixed (the adaptive threshold bounds the visibility error per sample by 0.01).
    assert!(ca.rel_rmse < cu.rel_rmse, "adaptive {} not below unshadowed {}", ca.rel_rmse, cu.rel_rmse);
    assert!(caf.rel_rmse < 0.05, "adaptive vs fixed relRMSE {}", caf.rel_rmse);
}

/// Local lights through their source radiance fields, in both display modes (per vertex as the
/// paper, per pixel), validation clean; against the exact reference each mode beats the same
/// shading without occluders, and the vertex mode's self-occlusion is in the image.
#[test]
fn shadow_fields_local_lights_vertex_and_pixel_modes_against_the_reference() {
    let s = scene("sf_lamps.toml");
    let (w, h, t) = (64, 48, 0.9);
    let with = |mode: &str, casts: bool| {
        let mut sc = s.clone();
        // small fields (the defaults' precompute is for the bench): 16 shells, R = 16
        // (light_shadows = fields: the lights through their fields, not the default's rays)
        for (k, v) in
            [("mode", mode), ("shells", "16"), ("resolution", "16"), ("map_res", "16"), ("light_shadows", "fields")]
        {
            sc.technique_params.insert(k.into(), v.into());
        }
        if !casts {
            for i in 0..sc.objects.len() {
                if sc.object_info.len() <= i {
                    sc.object_info.resize(i + 1, Default::default());
                }
                sc.object_info[i].casts_shadow = false;
            }
        }
        sc
    };
    let reference = reference_at(&s, (w, h), 32, t, Mode::Exact);
    // the same shading without occluders (lights and environment unshadowed)
    let (_r, open) = render(&with("pixel", false), "shadow-fields", w, h, &[t], false);
    let cu = compare(&reference.radiance, "reference", &image(&open[0]), "unshadowed").unwrap();
    let mut results = Vec::new();
    for mode in ["vertex", "pixel"] {
        let (r, frames) = render(&with(mode, true), "shadow-fields", w, h, &[t], true);
        let log = r.context().validation.clone();
        let f = &frames[0];
        assert!(f.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
        let passes: Vec<&str> = f.gpu_ms.iter().map(|(p, _)| p.as_str()).collect();
        assert_eq!(passes.contains(&"sf_vertex") && passes.contains(&"sf_points"), mode == "vertex", "{passes:?}");
        drop(r);
        assert_eq!(log.error_count(), 0, "{mode}: validation errors: {:#?}", log.errors());
        let c = compare(&reference.radiance, "reference", &image(f), mode).unwrap();
        println!("{mode}: {}  (without occluders: {})", c.summary(), cu.summary());
        assert!(c.rel_rmse < cu.rel_rmse, "{mode}: {} not below unshadowed {}", c.rel_rmse, cu.rel_rmse);
        results.push(image(f));
    }
    // The two modes agree broadly (same fields; they differ by interpolation and self-occlusion).
    let c = compare(&results[1], "pixel", &results[0], "vertex").unwrap();
    println!("vertex vs pixel: {}", c.summary());
    assert!(c.rel_rmse < 0.5, "{}", c.rel_rmse);
}

/// The all-frequency variant (`shadow-fields-wavelet`) on the local-light scene: validation
/// clean, every pixel finite, and against a pixel-centre reference it is within the shadow-fields
/// budget (0.15 of the mean) where the order-4 SH fields, whose point-light shadows are a
/// band-limited smear, are not: the wavelet error must be at most 0.8 of the SH error.
#[test]
fn shadow_fields_wavelet_casts_the_local_lights_sharp_shadows() {
    let s = scene("sf_lamps.toml");
    let (w, h, t) = (64, 48, 0.9);
    let opts = ReferenceOptions { width: w, height: h, spp: 256, time: Some(t), pixel_grid: 1, ..Default::default() };
    let reference = reference_render(&s, &opts).expect("reference");
    let mut sw = s.clone();
    sw.technique_params.clear();
    // R = 16 keeps the precompute to seconds; 32 shells reach 6.4 bounding radii (long shadows)
    // both variants' lights shadowed from their fields (light_shadows = fields), not the
    // default's rays through the kd-tree
    for (k, v) in [("shells", "32"), ("resolution", "16"), ("cube", "16"), ("light_shadows", "fields")] {
        sw.technique_params.insert(k.into(), v.into());
    }
    let start = std::time::Instant::now();
    let (r, frames) = render(&sw, "shadow-fields-wavelet", w, h, &[t], true);
    println!("shadow-fields-wavelet: precompute + 1 frame in {:.1} s", start.elapsed().as_secs_f64());
    let log = r.context().validation.clone();
    drop(r);
    assert_eq!(log.error_count(), 0, "validation errors: {:#?}", log.errors());
    let f = &frames[0];
    assert!(f.hdr.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
    let cw = compare(&reference.radiance, "reference", &image(f), "wavelet").unwrap();
    let (_r, sh) = render(&common::with(&s, &[("light_shadows", "fields")]), "shadow-fields", w, h, &[t], false);
    let cs = compare(&reference.radiance, "reference", &image(&sh[0]), "sh").unwrap();
    println!("wavelet: {}\nSH: {}", cw.summary(), cs.summary());
    assert!(cw.rmse_rel_mean <= 0.15, "wavelet error {} of the mean", cw.rmse_rel_mean);
    assert!(cw.rmse_rel_mean <= 0.8 * cs.rmse_rel_mean, "wavelet {} vs SH {}", cw.rmse_rel_mean, cs.rmse_rel_mean);
}

/// Both shadow-field variants, with small fields, rendered at `w x h` and time `t` on `s` with
/// parameter `key` set to `on` (validation on: zero errors asserted) and to `off`, each against
/// the exact pixel-centre reference (256 spp): per variant `(technique, on, off)`.
fn variants_on_and_off(
    s: &penumbra_scene::Scene,
    (w, h, t): (u32, u32, f32),
    key: &str,
    (on, off): (&str, &str),
) -> Vec<(&'static str, Comparison, Comparison)> {
    let opts = ReferenceOptions {
        width: w,
        height: h,
        spp: 256,
        time: Some(t),
        mode: Mode::Exact,
        pixel_grid: 1,
        ..Default::default()
    };
    let reference = reference_render(s, &opts).expect("reference");
    let mut out = Vec::new();
    for (technique, small) in [
        ("shadow-fields", &[("shells", "16"), ("resolution", "16"), ("map_res", "16")]),
        ("shadow-fields-wavelet", &[("shells", "32"), ("resolution", "16"), ("cube", "16")]),
    ] {
        let with = |value: &str| {
            let mut sc = common::with(s, small);
            sc.technique_params.insert(key.into(), value.into());
            sc
        };
        let (r, frames_on) = render(&with(on), technique, w, h, &[t], true);
        let log = r.context().validation.clone();
        drop(r);
        assert_eq!(log.error_count(), 0, "{technique}: validation errors: {:#?}", log.errors());
        let (_r, frames_off) = render(&with(off), technique, w, h, &[t], false);
        let c_on = compare(&reference.radiance, "reference", &image(&frames_on[0]), on).unwrap();
        let c_off = compare(&reference.radiance, "reference", &image(&frames_off[0]), off).unwrap();
        println!("{technique}: {key} = {on}: {}\n{technique}: {key} = {off}: {}", c_on.summary(), c_off.summary());
        out.push((technique, c_on, c_off));
    }
    out
}

/// `light_shadows = traced` (default): the local lights' shadows by rays through the frame's
/// kd-tree, in both shadow-field variants, against the fields' own visibility toward the
/// lights (the SH fields' order-4 smear, the wavelet fields' nearest shell samples, which
/// shifted and doubled vol_rotating's square shadow: 160x120 0.42 and 0.21 of the mean, 0.030
/// traced). sf_lamps without its environment (spot, point and sphere lights over a ball, a cube
/// and a ring), against the exact pixel-centre reference; validation clean. Measured (64x48,
/// 256 spp): rmse/mean traced 0.0065 in both, fields 0.110 (SH) and 0.063 (wavelet).
#[test]
fn traced_local_light_shadows_beat_the_fields() {
    let mut s = scene("sf_lamps.toml");
    s.environment = None;
    s.technique_params.clear();
    for (technique, ct, cf) in variants_on_and_off(&s, (64, 48, 0.9), "light_shadows", ("traced", "fields")) {
        println!("{technique}: rmse/mean traced {:.4}, fields {:.4}", ct.rmse_rel_mean, cf.rmse_rel_mean);
        assert!(
            ct.rmse_rel_mean < 0.25 * cf.rmse_rel_mean,
            "{technique}: traced {} against fields {}",
            ct.rmse_rel_mean,
            cf.rmse_rel_mean
        );
    }
}

/// `key_lights` (default 4, with `light_shadows = traced`): studio.exr's key and fill lights split
/// off the environment's SH (`penumbra_math::envmap::split_lights`) and shaded as lights of their
/// extent with traced shadows (and the glossy lobe's visibility traced), the sky left to the
/// order-4 fields. Order 4 cannot hold the shadow of a light of a few degrees that carries most of
/// a floor's light: at 160x120 every studio scene's SH cell failed (chess 0.28, isg_bunny 0.31 of
/// the mean) and passes with them (0.044, 0.075). sf_spheres against the exact pixel-centre
/// reference, in both variants (the wavelet fields' cube and irradiance map then hold the rest of
/// the map); validation clean. Measured (64x48, 256 spp): SH 0.057 against 0.190, wavelet 0.057
/// against 0.075.
#[test]
fn key_lights_split_off_the_environment_cast_their_shadows() {
    let mut s = scene("sf_spheres.toml");
    s.technique_params.clear();
    for (technique, ck, cf) in variants_on_and_off(&s, (64, 48, 0.5), "key_lights", ("4", "0")) {
        println!(
            "{technique}: rmse/mean key lights {:.4}, all in the fields {:.4}",
            ck.rmse_rel_mean, cf.rmse_rel_mean
        );
        assert!(ck.rmse_rel_mean < 0.15, "{technique}: key lights {} over the shadow fields' budget", ck.rmse_rel_mean);
        if technique == "shadow-fields" {
            assert!(
                ck.rmse_rel_mean < 0.5 * cf.rmse_rel_mean,
                "{technique}: key lights {} against {}",
                ck.rmse_rel_mean,
                cf.rmse_rel_mean
            );
        } else {
            assert!(
                ck.rmse_rel_mean < cf.rmse_rel_mean,
                "{technique}: key lights {} against {}",
                ck.rmse_rel_mean,
                cf.rmse_rel_mean
            );
        }
    }
}

/// `glossy = transfer` (the paper's glossy transfer): the specular lobe times the cosine projected
/// into the order-4 SH, multiplied by the occluders' visibilities by triple products and closed by
/// the environment's SH, times the lobe's directional albedo. A purely specular floor (no diffuse
/// albedo, Cook-Torrance roughness 0.6) under a diffuse ball, lit by a sky linear in the
/// direction's height (order 4 holds it exactly) kept whole in the fields (`key_lights = 0`): the
/// floor's only light is its glossy term, so the ball's shadow on it comes from the occluder's
/// visibility multiplying the glossy transfer alone. Against the exact pixel-centre reference
/// (2048 spp), `glossy = reflection` (visibility along the mirror direction: a shadow too small
/// and too dark) and `env` (unshadowed); validation clean. Measured (64x48): rmse/mean transfer
/// 0.048, reflection 0.105, unshadowed 0.138.
#[test]
fn glossy_transfer_shadows_a_specular_floor() {
    use glam::{Mat4, Vec3};
    use penumbra_scene::{Material, MeshData, Object};
    let mut s = common::bare_scene(
        vec![MeshData::plane(6.0, 8), MeshData::uv_sphere(0.5, 24, 12)],
        vec![Material::glossy("floor", Vec3::ZERO, Vec3::splat(0.9), 0.6), Material::diffuse("ball", Vec3::splat(0.6))],
        vec![
            Object { name: "floor".into(), mesh: 0, material: 0, transform: Mat4::IDENTITY },
            Object {
                name: "ball".into(),
                mesh: 1,
                material: 1,
                transform: Mat4::from_translation(Vec3::new(0.0, 0.5, 0.0)),
            },
        ],
    );
    s.camera.eye = Vec3::new(0.0, 2.2, 3.2);
    s.camera.target = Vec3::new(0.0, 0.2, 0.0);
    s.camera.up = Vec3::Y;
    s.camera.fov_y_deg = 45.0;
    let (ew, eh) = (32usize, 16usize);
    let s = common::with_env(&s, ew, eh, |_, y| {
        let up = (std::f32::consts::PI * (y as f32 + 0.5) / eh as f32).cos(); // the direction's y
        let v = 0.1 + 0.5 * (1.0 + up);
        [v, v, v]
    });
    let fields = common::with(&s, &[("shells", "16"), ("resolution", "16"), ("map_res", "16"), ("key_lights", "0")]);
    let (w, h) = (64u32, 48u32);
    let opts = ReferenceOptions {
        width: w,
        height: h,
        spp: 2048,
        time: Some(0.0),
        mode: Mode::Exact,
        pixel_grid: 1,
        ..Default::default()
    };
    let reference = reference_render(&s, &opts).expect("reference");
    let err = |scene: &penumbra_scene::Scene, technique: &str, validation: bool| {
        let (r, frames) = render(scene, technique, w, h, &[0.0], validation);
        let log = r.context().validation.clone();
        drop(r);
        assert_eq!(log.error_count(), 0, "{technique}: validation errors: {:#?}", log.errors());
        let img = image(&frames[0]);
        compare(&reference.radiance, "reference", &img, technique).unwrap().rmse_rel_mean
    };
    let transfer = err(&common::with(&fields, &[("glossy", "transfer")]), "shadow-fields", true);
    let reflection = err(&fields, "shadow-fields", false);
    let unshadowed = err(&s, "env", false);
    println!(
        "rmse/mean: glossy = transfer {transfer:.4}, reflection {reflection:.4}, env (unshadowed) {unshadowed:.4}"
    );
    assert!(transfer < 0.5 * unshadowed, "transfer {transfer} against unshadowed {unshadowed}");
    assert!(transfer < 0.75 * reflection, "transfer {transfer} against reflection {reflection}");
}
