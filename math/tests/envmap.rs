//! Environment-map SG fit and prefiltering: error handling, synthetic maps with known answers
//! (exact SG lighting, a sun 1e4 x brighter than the sky) and the CC0 maps in /work/shared/assets.

use glam::DVec3;
use penumbra_math::envmap::*;
use penumbra_math::sg::{Sg, SgRgb};
use std::time::Instant;

fn make_map(w: usize, h: usize, f: impl Fn(DVec3) -> DVec3) -> Vec<[f32; 3]> {
    let mut t = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let d = latlong_direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            let c = f(d);
            t.push([c.x as f32, c.y as f32, c.z as f32]);
        }
    }
    t
}

#[test]
fn bad_input_is_an_error() {
    assert_eq!(fit_sg_lighting(0, 0, &[], 4).unwrap_err(), EnvError::Empty);
    assert!(matches!(fit_sg_lighting(4, 2, &[[1.0; 3]; 7], 4), Err(EnvError::SizeMismatch { .. })));
    let mut t = vec![[1.0f32; 3]; 8];
    t[3][1] = f32::NAN;
    assert_eq!(fit_sg_lighting(4, 2, &t, 4).unwrap_err(), EnvError::NonFinite { index: 3 });
    assert!(matches!(fit_sg_lighting(4, 2, &[[1.0; 3]; 8], 0), Err(EnvError::BadOption(_))));
    assert!(prefilter(0, 0, &[], &[1.0], 8).is_err());
    // a black map fits with zero lobes and zero error, no NaN
    let f = fit_sg_lighting(8, 4, &[[0.0; 3]; 32], 4).unwrap();
    assert!(f.lobes.is_empty() && f.rel_l2_error == 0.0);
    // a 1x1 map works
    let f = fit_sg_lighting(1, 1, &[[2.0; 3]], 2).unwrap();
    assert!(f.rel_l2_error.is_finite() && f.rel_l2_error < 0.5);
}

#[test]
fn convention_matches_scene_formula() {
    let d = latlong_direction(0.25, 0.5);
    assert!((d - DVec3::X).length() < 1e-15);
    assert!((latlong_direction(0.0, 0.0) - DVec3::Y).length() < 1e-15);
    assert!((latlong_direction(0.0, 0.5) - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-15);
    for (u, v) in [(0.1, 0.2), (0.7, 0.9), (0.5, 0.5)] {
        let (uu, vv) = latlong_uv(latlong_direction(u, v));
        assert!((uu - u).abs() < 1e-12 && (vv - v).abs() < 1e-12);
    }
    let m = LatLong::new(64, 32, &vec![[1.0; 3]; 64 * 32]).unwrap();
    let total: f64 = (0..32).map(|y| m.solid_angle(y) * 64.0).sum();
    assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-12);
}

#[test]
fn recovers_exact_sg_lighting() {
    let truth = [
        SgRgb { axis: DVec3::new(0.3, 0.8, -0.2).normalize(), lambda: 40.0, mu: DVec3::new(5.0, 4.0, 3.0) },
        SgRgb { axis: DVec3::new(-0.6, 0.1, 0.7).normalize(), lambda: 4.0, mu: DVec3::new(0.5, 0.7, 1.0) },
        SgRgb { axis: DVec3::new(0.2, -0.9, 0.1).normalize(), lambda: 1.0, mu: DVec3::new(0.2, 0.2, 0.2) },
    ];
    let (w, h) = (256, 128);
    let t = make_map(w, h, |d| SgRgb::eval_sum(&truth, d));
    let fitter = SgEnvFitter::new(w, h, &t, SgFitOptions::default()).unwrap();
    let f3 = fitter.fit(3).unwrap();
    let f8 = fitter.fit(8).unwrap();
    println!("exact 3-SG map: K=3 rel L2 {:.4}, K=8 rel L2 {:.4}", f3.rel_l2_error, f8.rel_l2_error);
    for l in &f3.lobes {
        println!("  lobe axis {:.3?} lambda {:.2} mu {:.3?}", l.axis, l.lambda, l.mu);
    }
    // the sharp, bright lobe is found at the right place with about the right sharpness
    let main = f3.lobes.iter().max_by(|a, b| a.mu.x.partial_cmp(&b.mu.x).unwrap()).unwrap();
    assert!(main.axis.angle_between(truth[0].axis) < 0.02, "axis {:?}", main.axis);
    assert!((main.lambda / 40.0).ln().abs() < 0.5f64.ln().abs());
    // with a sharpness ladder of ratio 2 refined to 2^(1/4) steps (a lobe whose sharpness is off
    // by 2^(1/8) already has ~5% relative L2 error) the 3-lobe fit cannot be exact, but must
    // explain most of the map; more lobes must not be worse
    assert!(f3.rel_l2_error < 0.12);
    assert!(f8.rel_l2_error <= f3.rel_l2_error + 1e-9);
}

fn sun_sky_map(w: usize, h: usize) -> (Vec<[f32; 3]>, DVec3, f64) {
    let sun_dir = DVec3::new(0.4, 0.5, -0.6).normalize();
    let sun_radius = 1.5f64.to_radians();
    let t = make_map(w, h, |d| {
        let sky = DVec3::new(0.3, 0.5, 1.0) * (0.3 + 0.7 * d.y.max(0.0)) + DVec3::splat(0.05);
        let ground = DVec3::new(0.2, 0.15, 0.1) * (d.y < 0.0) as i32 as f64;
        let base = if d.y >= 0.0 { sky } else { ground + DVec3::splat(0.05) };
        if d.angle_between(sun_dir) < sun_radius {
            base + DVec3::new(1.0, 0.95, 0.9) * 1e4
        } else {
            base
        }
    });
    (t, sun_dir, sun_radius)
}

#[test]
fn robust_to_a_sun_1e4_brighter_than_the_sky() {
    let (w, h) = (256, 128);
    let (t, sun_dir, _) = sun_sky_map(w, h);
    let map = LatLong::new(w, h, &t).unwrap();
    let t0 = Instant::now();
    let fitter = SgEnvFitter::new(w, h, &t, SgFitOptions::default()).unwrap();
    let unclamped = SgEnvFitter::new(w, h, &t, SgFitOptions { sun_cap: None, ..Default::default() }).unwrap();
    for k in [4usize, 16] {
        let f = fitter.fit(k).unwrap();
        let fu = unclamped.fit(k).unwrap();
        println!(
            "sun+sky K={k}: plain L2 (no sun/sky split) rel L2 {:.4} (sun-dominated L2 optimum direction)",
            fu.rel_l2_error
        );
        assert!(f.lobes.iter().all(|l| l.mu.is_finite() && l.mu.min_element() >= 0.0 && l.lambda.is_finite()));
        // sky-only error: texels farther than 10 degrees from the sun
        let sky_error = |lobes: &[SgRgb]| {
            let (mut num, mut den) = (0.0, 0.0);
            for y in 0..h {
                for x in 0..w {
                    let i = y * w + x;
                    let d = map.dir(i);
                    if d.angle_between(sun_dir) > 10f64.to_radians() {
                        let e = SgRgb::eval_sum(lobes, d) - map.rgb[i];
                        num += map.solid_angle(y) * e.length_squared();
                        den += map.solid_angle(y) * map.rgb[i].length_squared();
                    }
                }
            }
            (num / den).sqrt()
        };
        let sky_err = sky_error(&f.lobes);
        println!("sun+sky K={k}: plain L2 fit sky-only rel L2 {:.4}", sky_error(&fu.lobes));
        let energy = f.lobes.iter().map(|l| l.mu * l.unit().sphere_integral()).sum::<DVec3>();
        let energy_err = (energy.length() / map.integral().length() - 1.0).abs();
        if std::env::var("SG_DEBUG").is_ok() {
            for l in &f.lobes {
                println!("   lobe {:.3?} lambda {:.1} mu {:.3?}", l.axis, l.lambda, l.mu);
            }
        }
        let sun_lobe = f.lobes.iter().max_by(|a, b| a.mu.x.partial_cmp(&b.mu.x).unwrap()).unwrap();
        println!(
            "sun+sky 256x128, K={k}: rel L2 {:.4}, sky-only rel L2 {sky_err:.4}, energy error {:.2}%, brightest lobe {:.2} deg from sun, lambda {:.0}; {:.2?}",
            f.rel_l2_error,
            100.0 * energy_err,
            sun_lobe.axis.angle_between(sun_dir).to_degrees(),
            sun_lobe.lambda,
            t0.elapsed()
        );
        assert!(sun_lobe.axis.angle_between(sun_dir) < 0.5f64.to_radians());
        // the sun's disk (radius 1.5 texels here) is not a Gaussian, but its own sharp lobes
        // capture it to a few percent of the (sun-dominated) L2 norm
        assert!(f.rel_l2_error < 0.1, "{}", f.rel_l2_error);
        // an L2 fit of a disk by Gaussians does not conserve energy exactly (reported above)
        assert!(energy_err < 0.15);
        // the sun/sky split gives the sky its own lobes even at K = 4 (the plain L2 fit spends
        // them on the sun: sky-only error ~0.9 at K = 4, printed above)
        assert!(sky_err < 0.35, "sky must still be represented: {sky_err}");
    }
}

fn read_exr(path: &str) -> Result<(usize, usize, Vec<[f32; 3]>), String> {
    type Texels = (usize, usize, Vec<[f32; 3]>);
    let img = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |res, _| (res.width(), res.height(), vec![[0.0; 3]; res.width() * res.height()]),
        |(w, _, t): &mut Texels, pos, (r, g, b, _): (f32, f32, f32, f32)| t[pos.y() * *w + pos.x()] = [r, g, b],
    )
    .map_err(|e| e.to_string())?;
    Ok(img.layer_data.channel_data.pixels)
}

#[test]
fn cc0_maps_fit_error() {
    let mut found = 0;
    let mut sunset = None;
    for name in ["studio", "sunset", "forest", "sunset-dwab"] {
        let path = format!("/work/shared/assets/{name}.exr");
        if !std::path::Path::new(&path).exists() {
            println!("{path}: not present, skipped");
            continue;
        }
        let (w, h, t) = read_exr(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        found += 1;
        if name == "sunset" {
            sunset = Some(t.clone());
        }
        if name == "sunset-dwab" {
            // same image, lossy DWAB: must decode to nearly the same texels; fit one K only
            if let Some(s) = &sunset {
                let (mut num, mut den) = (0.0f64, 0.0f64);
                for (a, b) in s.iter().zip(&t) {
                    for c in 0..3 {
                        num += ((a[c] - b[c]) as f64).powi(2);
                        den += (a[c] as f64).powi(2);
                    }
                }
                println!("sunset-dwab vs sunset: relative L2 texel difference {:.2e}", (num / den).sqrt());
                assert!((num / den).sqrt() < 0.05);
            }
            let f = fit_sg_lighting(w, h, &t, 8).unwrap();
            println!("{name} ({w}x{h}): K=8: rel L2 {:.4}", f.rel_l2_error);
            continue;
        }
        let t0 = Instant::now();
        let fitter = SgEnvFitter::new(w, h, &t, SgFitOptions::default()).unwrap();
        let prep = t0.elapsed();
        let mut errs = vec![];
        for k in [4usize, 8, 16, 32] {
            let t1 = Instant::now();
            let f = fitter.fit(k).unwrap();
            assert!(f.rel_l2_error.is_finite() && f.rel_l2_error < 1.0);
            assert!(f.lobes.iter().all(|l| l.mu.min_element() >= 0.0));
            errs.push((k, f.rel_l2_error, f.lobes.len(), t1.elapsed()));
        }
        println!(
            "{name} ({w}x{h}): prep {prep:.2?}; {}",
            errs.iter()
                .map(|(k, e, n, d)| format!("K={k}: rel L2 {e:.4} ({n} lobes, {d:.2?})"))
                .collect::<Vec<_>>()
                .join("; ")
        );
        // more lobes must help over 4
        assert!(errs[3].1 < errs[0].1, "{name}: K=32 not better than K=4");
        if std::env::var("PENUMBRA_MATH_COMPARE").is_ok() {
            // report only: the plain least-squares fit without the sun/sky split
            let plain = SgEnvFitter::new(w, h, &t, SgFitOptions { sun_cap: None, ..Default::default() }).unwrap();
            let e: Vec<String> = [4usize, 8, 16, 32]
                .iter()
                .map(|&k| format!("K={k}: {:.4}", plain.fit(k).unwrap().rel_l2_error))
                .collect();
            println!("{name}: plain L2 fit (sun_cap None): {}", e.join("; "));
        }
    }
    assert!(found > 0, "no CC0 map found");
}

#[test]
fn prefilter_constant_and_exact_sg() {
    let (w, h) = (128, 64);
    let t = vec![[2.0f32, 1.0, 0.5]; w * h];
    let levels = prefilter(w, h, &t, &[0.5, 8.0, 100.0, 3000.0], 64).unwrap();
    for l in &levels {
        for c in &l.texels {
            assert!((c[0] - 2.0).abs() < 1e-5 && (c[1] - 1.0).abs() < 1e-5 && (c[2] - 0.5).abs() < 1e-5);
        }
    }
    // map = one SG; the normalised prefiltered value is <G_L, G_a> / int G_a (analytic)
    let gl = Sg::new(DVec3::new(0.2, 0.7, 0.4), 20.0, 3.0);
    let (w, h) = (512, 256);
    let t = make_map(w, h, |d| DVec3::splat(gl.eval(d)));
    let lam = [2.0, 30.0, 200.0];
    let levels = prefilter(w, h, &t, &lam, 128).unwrap();
    let mut worst: f64 = 0.0;
    for l in &levels {
        for y in (0..l.height).step_by(3) {
            for x in (0..l.width).step_by(5) {
                let a = latlong_direction((x as f64 + 0.5) / l.width as f64, (y as f64 + 0.5) / l.height as f64);
                let probe = Sg::new(a, l.lambda, 1.0);
                let exact = probe.inner_product(&gl) / probe.sphere_integral();
                let got = l.texels[y * l.width + x][0] as f64;
                // discretisation (box-filtered mip levels, midpoint rule) error relative to the peak
                worst = worst.max((got - exact).abs() / 3.0);
            }
        }
    }
    println!("prefilter of an exact SG map: max error relative to the peak {worst:.2e}");
    assert!(worst < 5e-3);
}

#[test]
fn sh_projection_of_a_latlong_map() {
    use penumbra_math::sh;
    // a band-limited map (order 3) is recovered up to the midpoint-rule error of the texel grid
    let c: Vec<f64> = (0..9).map(|i| 1.0 / (1.0 + i as f64) * if i % 2 == 0 { 1.0 } else { -0.5 }).collect();
    let (w, h) = (256, 128);
    let t = make_map(w, h, |d| DVec3::splat(sh::eval(&c, d) + 2.0)); // + constant keeps it positive
    let p = project_sh(w, h, &t, 4).unwrap();
    let mut expect = c.clone();
    expect[0] += 2.0 * (4.0 * std::f64::consts::PI).sqrt();
    expect.resize(16, 0.0);
    let e = p[1].iter().zip(&expect).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    println!("SH projection of a 256x128 band-limited map: max coefficient error {e:.2e}");
    // midpoint rule on a pi/128 grid: O(h^2) ~ 6e-4 relative; plus f32 storage of the texels
    assert!(e < 1e-3);
    assert!(project_sh(0, 0, &[], 4).is_err());
    assert_eq!(DEFAULT_PREFILTER_LAMBDAS.len(), 7);
}

/// The irradiance map: a constant environment gives pi L everywhere; a map with one bright texel
/// (a sun 1e4 x the sky) gives the sun's power times the clamped cosine plus the sky's pi L, at
/// every output texel (grazing and back-facing included), within 1% of the sun's normal-incidence
/// irradiance.
#[test]
fn irradiance_map_is_the_cosine_convolution() {
    let (w, h) = (128, 64);
    let flat = vec![[0.5f32, 1.0, 2.0]; w * h];
    let e = irradiance_map(w, h, &flat, 16, 8, 64).unwrap();
    for t in &e {
        for (c, l) in t.iter().zip([0.5, 1.0, 2.0]) {
            assert!((*c as f64 / (std::f64::consts::PI * l) - 1.0).abs() < 1e-3, "{t:?}");
        }
    }
    let mut sun = vec![[0.01f32; 3]; w * h];
    let (sx, sy) = (37, 20);
    sun[sy * w + sx] = [1e4; 3];
    let map = LatLong::new(w, h, &sun).unwrap();
    let (sd, sp) = (map.dir(sy * w + sx), 1e4 * map.solid_angle(sy));
    let e = irradiance_map(w, h, &sun, 16, 8, 64).unwrap();
    for (j, t) in e.iter().enumerate() {
        let n = latlong_direction((j % 16) as f64 / 16.0, (j / 16) as f64 / 7.0);
        let expect = sp * sd.dot(n).max(0.0) + std::f64::consts::PI * 0.01;
        assert!((t[0] as f64 - expect).abs() < 0.01 * sp, "texel {j}: {} vs {expect}", t[0]);
    }
}

/// A studio light: a disk of 8 degrees radius, 1e3 x brighter than a dim sky, and a second,
/// weaker one across the sky. Moment lobes (default) keep each light's energy, direction and
/// angular extent: a uniform disk of radius r has mean cosine (1 + cos r) / 2, the SG of the
/// same mean cosine has lambda about 2 / (1 - cos r), whose shadows have the disk's penumbrae.
/// Four lobes leave one for the lights: the weaker gives its energy to the stronger, whose
/// direction and extent stay its own.
#[test]
fn moment_lobes_keep_each_lights_energy_direction_and_extent() {
    let (w, h) = (512, 256);
    let key = DVec3::new(0.6, 0.6, -0.3).normalize();
    let fill = DVec3::new(-0.7, 0.3, 0.6).normalize();
    let (rk, rf) = (8f64.to_radians(), 4f64.to_radians());
    let t = make_map(w, h, |d| {
        let mut c = DVec3::splat(0.02) + DVec3::new(0.01, 0.02, 0.04) * d.y.max(0.0);
        if d.angle_between(key) < rk {
            c += DVec3::new(30.0, 28.0, 25.0);
        }
        if d.angle_between(fill) < rf {
            c += DVec3::new(10.0, 10.0, 12.0);
        }
        c
    });
    let map = LatLong::new(w, h, &t).unwrap();
    let energy_near = |axis: DVec3, r: f64| -> DVec3 {
        (0..w * h)
            .filter(|&i| map.dir(i).angle_between(axis) < r + 0.01)
            .map(|i| map.rgb[i] * map.solid_angle(i / w))
            .sum()
    };
    let (ek, ef) = (energy_near(key, rk), energy_near(fill, rf));
    let fitter = SgEnvFitter::new(w, h, &t, SgFitOptions::default()).unwrap();
    let f = fitter.fit(16).unwrap();
    let lobe_near = |axis: DVec3| {
        *f.lobes.iter().filter(|l| l.axis.angle_between(axis) < 0.05).max_by(|a, b| a.mu.x.total_cmp(&b.mu.x)).unwrap()
    };
    for (axis, r, e) in [(key, rk, ek), (fill, rf, ef)] {
        let l = lobe_near(axis);
        let lobe_energy = l.mu * l.unit().sphere_integral();
        let want = 2.0 / (1.0 - r.cos());
        println!(
            "light of radius {:.1} deg: lobe {:.2} deg off, lambda {:.1} (disk-equivalent {want:.1}), energy {:.3?} of the light's {:.3?}",
            r.to_degrees(),
            l.axis.angle_between(axis).to_degrees(),
            l.lambda,
            lobe_energy,
            e
        );
        assert!(l.axis.angle_between(axis) < 0.5f64.to_radians());
        assert!((l.lambda / want - 1.0).abs() < 0.15, "lambda {} against {want}", l.lambda);
        // the lobe carries the excess over the sky's cap, nearly all of the light
        assert!((lobe_energy.x / e.x - 1.0).abs() < 0.05, "energy {lobe_energy:?} against {e:?}");
    }
    let pursuit =
        SgEnvFitter::new(w, h, &t, SgFitOptions { sun_lobes: SunLobes::Pursuit, ..Default::default() }).unwrap();
    println!("rel L2: moments {:.4}, pursuit {:.4}", f.rel_l2_error, pursuit.fit(16).unwrap().rel_l2_error);
    let f4 = fitter.fit(4).unwrap();
    let l = f4.lobes.iter().max_by(|a, b| a.mu.x.total_cmp(&b.mu.x)).unwrap();
    let lights: DVec3 = f4.lobes.iter().filter(|l| l.lambda > 50.0).map(|l| l.mu * l.unit().sphere_integral()).sum();
    assert_eq!(f4.lobes.iter().filter(|l| l.lambda > 50.0).count(), 1, "{:?}", f4.lobes);
    assert!(l.axis.angle_between(key) < 0.5f64.to_radians());
    assert!((l.lambda / (2.0 / (1.0 - rk.cos())) - 1.0).abs() < 0.15);
    assert!((lights.x / (ek.x + ef.x) - 1.0).abs() < 0.05, "{lights:?} against {:?}", ek + ef);
}

/// `split_lights`: the lights over the cap leave the map whole (the sky keeps the rest), as
/// the moment lobes of the fit.
#[test]
fn split_lights_takes_the_lights_out_of_the_map() {
    let (w, h) = (256, 128);
    let key = DVec3::new(0.5, 0.7, -0.4).normalize();
    let r = 6f64.to_radians();
    let t = make_map(w, h, |d| {
        DVec3::splat(0.05) + if d.angle_between(key) < r { DVec3::splat(40.0) } else { DVec3::ZERO }
    });
    let (lights, sky) = split_lights(w, h, &t, &SgFitOptions::default(), 4).unwrap();
    assert_eq!(lights.len(), 1, "{lights:?}");
    let l = lights[0];
    assert!(l.axis.angle_between(key) < 0.5f64.to_radians());
    assert!((l.lambda / (2.0 / (1.0 - r.cos())) - 1.0).abs() < 0.15, "lambda {}", l.lambda);
    let map = LatLong::new(w, h, &t).unwrap();
    let energy = |tx: &[[f32; 3]]| -> f64 { (0..w * h).map(|i| tx[i][0] as f64 * map.solid_angle(i / w)).sum() };
    let light = l.mu.x * l.unit().sphere_integral();
    // light + sky = the map, the sky holds no texel of the light
    assert!(((light + energy(&sky)) / energy(&t) - 1.0).abs() < 0.01);
    assert!((0..w * h).all(|i| map.dir(i).angle_between(key) >= r || sky[i] == [0.0; 3]));
    // no light over the cap: nothing split
    let flat = make_map(w, h, |_| DVec3::splat(1.0));
    let (none, same) = split_lights(w, h, &flat, &SgFitOptions::default(), 4).unwrap();
    assert!(none.is_empty() && same == flat);
}
