//! Unit tests of the reference's modules, kept out of the library so that the library is
//! compiled once (at opt-level 3) rather than again as a test harness (42 s of a clean build).

mod lights {
    use glam::{Vec2, Vec3};
    use penumbra_reference::lights::*;
    use penumbra_reference::sampling::Pcg32;
    use penumbra_scene::{LightInstance, LightKind};

    /// Irradiance at a point facing a sphere light of radiance L, subtending half-angle a:
    /// E = pi L sin^2(a). Cone sampling must reproduce it.
    #[test]
    fn sphere_light_irradiance() {
        let l = LocalLight::Sphere { center: Vec3::new(0.0, 3.0, 0.0), radius: 1.0, radiance: Vec3::ONE };
        let mut rng = Pcg32::new(1, 1);
        let n = 100_000;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let ls = l.sample(Vec3::ZERO, rng.next_vec2()).unwrap();
            assert!((ls.dist - l.hit(Vec3::ZERO, ls.wi).unwrap()).abs() < 1e-4);
            let x = (ls.li.y * ls.wi.y.max(0.0) / ls.pdf.unwrap()) as f64;
            s += x;
            s2 += x * x;
        }
        let m = s / n as f64;
        let se = ((s2 / n as f64 - m * m) / n as f64).sqrt();
        let exact = std::f64::consts::PI / 9.0;
        assert!((m - exact).abs() < 5.0 * se + 1e-6, "{m} vs {exact} +- {se}");
    }

    #[test]
    fn spot_falloff() {
        let l = LocalLight::new(&LightInstance {
            light: 0,
            kind: LightKind::Spot { inner_deg: 10.0, outer_deg: 20.0 },
            position: Vec3::new(0.0, 1.0, 0.0),
            direction: Vec3::NEG_Y,
            power: Vec3::ONE,
            moved: false,
        })
        .unwrap();
        let at = |deg: f32| {
            let x = Vec3::new(deg.to_radians().tan(), 0.0, 0.0);
            l.sample(x, Vec2::ZERO).map_or(0.0, |s| s.li.x * s.dist * s.dist)
        };
        assert!((at(5.0) - 1.0).abs() < 1e-5);
        let c = |d: f32| d.to_radians().cos();
        let t = (c(15.0) - c(20.0)) / (c(10.0) - c(20.0));
        assert!((at(15.0) - t * t * (3.0 - 2.0 * t)).abs() < 1e-4, "{}", at(15.0));
        assert_eq!(at(25.0), 0.0);
    }
}

mod brdf {
    use glam::Vec3;
    use penumbra_reference::brdf::*;

    use penumbra_reference::sampling::{uniform_hemisphere, Pcg32};
    use penumbra_scene::{BrdfKind, Material};
    use std::f32::consts::TAU;

    fn mat(kind: BrdfKind, albedo: f32, spec: f32, rough: f32, shin: f32) -> Material {
        Material {
            name: "t".into(),
            kind,
            albedo: Vec3::splat(albedo),
            specular: Vec3::splat(spec),
            roughness: rough,
            shininess: shin,
        }
    }

    fn wo_at(theta_deg: f32) -> Vec3 {
        let t = theta_deg.to_radians();
        Vec3::new(t.sin(), 0.0, t.cos())
    }

    /// (mean, standard error) of the directional albedo by BRDF importance sampling.
    fn albedo_is(b: &Brdf, wo: Vec3, n: usize, seed: u64) -> (f64, f64) {
        let mut rng = Pcg32::new(seed, 1);
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let ul = rng.next_f32();
            let u = rng.next_vec2();
            let x = match b.sample(wo, ul, u) {
                Some(wi) => {
                    let pdf = b.pdf(wo, wi);
                    if pdf > 0.0 {
                        (b.eval(wo, wi).y * wi.z / pdf) as f64
                    } else {
                        0.0
                    }
                }
                None => 0.0,
            };
            s += x;
            s2 += x * x;
        }
        let m = s / n as f64;
        (m, ((s2 / n as f64 - m * m).max(0.0) / (n as f64 - 1.0)).sqrt())
    }

    /// (albedo mean, se, pdf-integral mean, se) by uniform hemisphere sampling.
    fn albedo_uniform(b: &Brdf, wo: Vec3, n: usize, seed: u64) -> (f64, f64, f64, f64) {
        let mut rng = Pcg32::new(seed, 2);
        let (mut s, mut s2, mut p, mut p2) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for _ in 0..n {
            let wi = uniform_hemisphere(rng.next_vec2());
            let x = (b.eval(wo, wi).y * wi.z * TAU) as f64;
            let q = (b.pdf(wo, wi) * TAU) as f64;
            s += x;
            s2 += x * x;
            p += q;
            p2 += q * q;
        }
        let nf = n as f64;
        let (m, pm) = (s / nf, p / nf);
        (m, ((s2 / nf - m * m).max(0.0) / (nf - 1.0)).sqrt(), pm, ((p2 / nf - pm * pm).max(0.0) / (nf - 1.0)).sqrt())
    }

    fn cases() -> Vec<(&'static str, Brdf)> {
        vec![
            ("lambert", Brdf::from_material(&mat(BrdfKind::Diffuse, 1.0, 0.0, 1.0, 1.0))),
            ("blinn-phong s=20", Brdf::from_material(&mat(BrdfKind::BlinnPhong, 0.0, 1.0, 0.5, 20.0))),
            ("blinn-phong s=2", Brdf::from_material(&mat(BrdfKind::BlinnPhong, 0.0, 1.0, 0.5, 2.0))),
            ("ggx r=0.3", Brdf::from_material(&mat(BrdfKind::CookTorrance, 0.0, 1.0, 0.3, 1.0))),
            ("ggx r=0.9", Brdf::from_material(&mat(BrdfKind::CookTorrance, 0.0, 1.0, 0.9, 1.0))),
            ("ashikhmin-shirley n=50", Brdf::from_material(&mat(BrdfKind::AshikhminShirley, 0.0, 1.0, 0.5, 50.0))),
            ("ashikhmin-shirley aniso", {
                let mut b = Brdf::from_material(&mat(BrdfKind::AshikhminShirley, 0.0, 1.0, 0.5, 10.0));
                b.nu = 10.0;
                b.nv = 200.0;
                b
            }),
            ("ashikhmin-shirley diffuse", Brdf::from_material(&mat(BrdfKind::AshikhminShirley, 1.0, 0.0, 0.5, 10.0))),
            ("ggx + lambert", Brdf::from_material(&mat(BrdfKind::CookTorrance, 0.7, 0.04, 0.5, 1.0))),
        ]
    }

    /// White furnace per BRDF: directional albedo <= 1 (within 5 sigma) at several angles, equal
    /// by two independent estimators (validates sample/pdf/eval consistency), and the pdf
    /// integrates to the probability that sample() returns a direction.
    #[test]
    fn furnace_and_sampling_consistency() {
        let n = 40_000;
        for (name, b) in cases() {
            for (k, theta) in [0.0f32, 30.0, 60.0, 80.0].into_iter().enumerate() {
                let wo = wo_at(theta);
                let (a, se) = albedo_is(&b, wo, n, 10 + k as u64);
                let (au, seu, pint, pse) = albedo_uniform(&b, wo, 4 * n, 20 + k as u64);
                eprintln!("{name:28} theta {theta:4}: albedo {a:.4} +- {se:.4} (uniform {au:.4} +- {seu:.4}), pdf integral {pint:.4}");
                assert!(a <= 1.0 + 5.0 * se + 1e-6, "{name} theta {theta}: albedo {a} > 1");
                let tol = 5.0 * (se * se + seu * seu).sqrt() + 1e-4;
                assert!((a - au).abs() <= tol, "{name} theta {theta}: IS {a} vs uniform {au}");
                // Fraction of successful samples.
                let mut rng = Pcg32::new(99, 3);
                let m = 20_000;
                let ok = (0..m)
                    .filter(|_| {
                        let ul = rng.next_f32();
                        b.sample(wo, ul, rng.next_vec2()).is_some()
                    })
                    .count() as f64
                    / m as f64;
                let ok_se = (ok * (1.0 - ok) / m as f64).sqrt();
                assert!(
                    (pint - ok).abs() <= 5.0 * (pse * pse + ok_se * ok_se).sqrt() + 2e-3,
                    "{name} theta {theta}: pdf integral {pint} vs sample success {ok}"
                );
            }
        }
    }

    #[test]
    fn white_lambert_is_exactly_one() {
        let b = Brdf::from_material(&mat(BrdfKind::Diffuse, 1.0, 0.0, 1.0, 1.0));
        let (a, se) = albedo_is(&b, wo_at(45.0), 1000, 1);
        assert!((a - 1.0).abs() < 1e-5 && se < 1e-5, "{a} {se}");
    }

    #[test]
    fn blinn_phong_normal_incidence_albedo_is_analytic() {
        for s in [0.0f32, 1.0, 8.0, 64.0, 500.0] {
            let b = Brdf::from_material(&mat(BrdfKind::BlinnPhong, 0.0, 1.0, 0.5, s));
            let (a, se) = albedo_is(&b, Vec3::Z, 40_000, 7);
            let expect = blinn_phong_normal_albedo(s as f64);
            eprintln!("blinn-phong s={s}: normal-incidence albedo {a:.5} +- {se:.1e}, analytic {expect:.5}");
            assert!((a - expect).abs() <= 5.0 * se + 1e-4, "s={s}: {a} +- {se} vs {expect}");
        }
    }
}

mod converge {
    use penumbra_reference::converge::*;
    use penumbra_reference::image::Image;
    use penumbra_reference::render::{render, ReferenceOptions};
    use penumbra_scene::Scene;

    #[test]
    fn halves_noise_is_half_the_rms_difference_over_the_mean() {
        let a = Image { width: 2, height: 1, pixels: vec![[1.0; 3], [3.0; 3]] };
        let b = Image { width: 2, height: 1, pixels: vec![[1.2; 3], [2.8; 3]] };
        // RMS(a - b) = 0.2, / 2 = 0.1; mean of (a + b) / 2 = 2.0
        let n = halves_noise(&a, &b).unwrap();
        assert!((n - 0.05).abs() < 1e-6, "{n}");
        assert_eq!(halves_noise(&a, &a), Some(0.0));
        let black = Image::new(2, 1);
        assert_eq!(halves_noise(&black, &a).map(|v| v.is_finite()), Some(true));
        assert!(halves_noise(&a, &Image::new(1, 1)).is_none());
    }

    #[test]
    fn pixel_noise_is_the_root_mean_variance_over_the_mean() {
        let img = Image { width: 2, height: 1, pixels: vec![[1.0; 3], [3.0; 3]] };
        // mean 2.0; variances 0.01 and 0.03: root of their mean 0.1414
        let n = pixel_noise(&img, &[[0.01; 3], [0.03; 3]]);
        assert!((n - 0.02f64.sqrt() / 2.0).abs() < 1e-9, "{n}");
        assert_eq!(pixel_noise(&img, &[[0.0; 3]; 2]), 0.0);
        assert!(pixel_noise(&Image::new(2, 1), &[[0.01; 3]; 2]).is_infinite());
        // a non-finite pixel is left out of both the variance and the mean
        let nan = Image { width: 2, height: 1, pixels: vec![[1.0; 3], [f32::NAN; 3]] };
        assert!((pixel_noise(&nan, &[[0.01; 3]; 2]) - 0.1).abs() < 1e-9);
    }

    /// Where one pixel holds the variance, the two halves' estimate is one draw of a chi-square
    /// of about one degree of freedom (isg_bunny's 40x30 reference said 0.0034 where the truth
    /// was 0.009); the per-pixel variance over the samples is steady, and right: independent
    /// renders of the same count differ from each other by about sqrt(2) times it.
    #[test]
    fn pixel_variance_noise_is_steady_where_the_halves_are_not() {
        let scene = Scene::default_scene();
        let base = ReferenceOptions { width: 2, height: 1, frame: 3, pixel_grid: 1, ..Default::default() };
        let (mut px, mut hv, mut err) = (Vec::new(), Vec::new(), Vec::new());
        for seed in 0..10u64 {
            let opts = ConvergeOptions {
                base: ReferenceOptions { seed, ..base.clone() },
                target_noise: 1e-9,
                start_spp: 32,
                max_spp: 64,
                ..Default::default()
            };
            let c = render_converged(&scene, &opts).unwrap();
            assert_eq!(c.meta.spp, 64);
            assert_eq!(c.meta.noise_method, "pixel_variance");
            px.push(c.meta.noise_rmse_rel_mean);
            hv.push(c.meta.halves_noise_rmse_rel_mean.unwrap());
            let other = render(&scene, &ReferenceOptions { spp: 64, seed: 1000 + seed, ..base.clone() }).unwrap();
            err.push(
                penumbra_reference::metrics::compare(&c.radiance, "a", &other.radiance, "b").unwrap().rmse_rel_mean,
            );
        }
        let spread = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            ((v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt() / m, m)
        };
        let ((sp, mp), (sh, _)) = (spread(&px), spread(&hv));
        assert!(mp > 0.0, "the scene's two pixels have no variance: {px:?}");
        assert!(sp < 0.5 * sh, "pixel-variance spread {sp:.3} against the halves' {sh:.3}: {px:?} {hv:?}");
        // mean squared difference of two independent renders: 2 noise^2
        let msd = err.iter().map(|e| e * e).sum::<f64>() / err.len() as f64;
        let ratio = (msd / 2.0).sqrt() / mp;
        assert!((0.6..1.6).contains(&ratio), "independent renders' rms / sqrt(2) over the estimate: {ratio}");
    }

    /// A reference cached with the two halves' estimate only is re-estimated from fresh samples
    /// when loaded, the old figure kept beside it, and its sidecar rewritten.
    #[test]
    fn a_cached_halves_estimate_is_re_estimated_once() {
        let scene = Scene::default_scene();
        let opts = ConvergeOptions {
            base: ReferenceOptions { width: 8, height: 6, frame: 3, ..Default::default() },
            target_noise: 0.05,
            start_spp: 4,
            max_spp: 1 << 12,
            ..Default::default()
        };
        let dir = std::env::temp_dir().join(format!("penumbra-renoise-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = load_or_render(&scene, b"default", "default", &opts, Some(&dir)).unwrap();
        let json = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.extension().is_some_and(|e| e == "json"))
            .unwrap();
        // what a sidecar written before the per-pixel estimate looks like, with a low draw
        let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let o = v.as_object_mut().unwrap();
        o.remove("noise_method");
        o.remove("halves_noise_rmse_rel_mean");
        o.insert("noise_rmse_rel_mean".into(), serde_json::json!(1e-5));
        std::fs::write(&json, serde_json::to_string_pretty(&v).unwrap()).unwrap();
        let again = load_or_render(&scene, b"default", "default", &opts, Some(&dir)).unwrap();
        assert!(again.cached);
        assert_eq!(again.meta.noise_method, "pixel_variance_resampled");
        assert_eq!(again.meta.halves_noise_rmse_rel_mean, Some(1e-5));
        let ratio = again.meta.noise_rmse_rel_mean / c.meta.noise_rmse_rel_mean;
        assert!(
            (0.7..1.4).contains(&ratio),
            "re-estimated {} against {}",
            again.meta.noise_rmse_rel_mean,
            c.meta.noise_rmse_rel_mean
        );
        let stored: ConvergedMeta = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(stored.noise_method, "pixel_variance_resampled");
        assert!((stored.noise_rmse_rel_mean / again.meta.noise_rmse_rel_mean - 1.0).abs() < 1e-12);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn cache_key_changes_with_every_input() {
        let o = ConvergeOptions::default();
        let k = cache_key(b"scene", &o);
        assert_eq!(k, cache_key(b"scene", &o.clone()));
        assert_ne!(k, cache_key(b"scene2", &o));
        let mut o2 = o.clone();
        o2.base.frame = 1;
        assert_ne!(k, cache_key(b"scene", &o2));
        let mut o3 = o.clone();
        o3.base.width += 1;
        assert_ne!(k, cache_key(b"scene", &o3));
        let mut o4 = o.clone();
        o4.target_noise = 0.02;
        assert_ne!(k, cache_key(b"scene", &o4));
        // the pixel sampling is part of the key; the default (jittered) keeps the old keys
        let mut o5 = o.clone();
        o5.base.pixel_grid = 1;
        assert_ne!(k, cache_key(b"scene", &o5));
        let mut o6 = o.clone();
        o6.base.pixel_grid = 2;
        assert_ne!(cache_key(b"scene", &o5), cache_key(b"scene", &o6));
    }

    /// A scene using what the reference learned to draw after its version's last change
    /// (emission, directional lights) gets a key of its own; any other keeps the file's key.
    #[test]
    fn scene_cache_key_tags_emission_and_directional_lights() {
        let o = ConvergeOptions::default();
        let plain = penumbra_scene::Scene::default_scene();
        assert_eq!(scene_cache_key(&plain, b"scene", &o), cache_key(b"scene", &o));
        let mut glow = plain.clone();
        glow.material_extras.resize(glow.materials.len(), Default::default());
        glow.material_extras[0].emission = glam::Vec3::ONE;
        let mut sun = plain.clone();
        sun.lights.push(penumbra_scene::Light {
            name: "sun".into(),
            kind: penumbra_scene::LightKind::Directional,
            position: glam::Vec3::ZERO,
            direction: glam::Vec3::NEG_Y,
            color: glam::Vec3::ONE,
            intensity: 1.0,
            motion: penumbra_scene::RigidMotion::Static,
            fixture: None,
        });
        let (kg, ks) = (scene_cache_key(&glow, b"scene", &o), scene_cache_key(&sun, b"scene", &o));
        assert!(kg != cache_key(b"scene", &o) && ks != cache_key(b"scene", &o) && kg != ks);
    }

    #[test]
    fn converges_to_the_target_and_reuses_the_cache() {
        let scene = Scene::default_scene();
        let opts = ConvergeOptions {
            base: ReferenceOptions { width: 16, height: 12, frame: 3, ..Default::default() },
            target_noise: 0.02,
            start_spp: 4,
            max_spp: 1 << 14,
            ..Default::default()
        };
        let dir = std::env::temp_dir().join(format!("penumbra-converge-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = load_or_render(&scene, b"default", "default", &opts, Some(&dir)).unwrap();
        assert!(!c.cached);
        assert!(c.converged(), "noise {} after {} spp", c.meta.noise_rmse_rel_mean, c.meta.spp);
        assert!(c.meta.spp >= 8);
        // The estimate is honest: an independent render at the same spp differs from it by about
        // sqrt(2) times the estimated noise (RMS over mean), not by far more or far less.
        let other = render(&scene, &ReferenceOptions { spp: c.meta.spp, seed: 12345, ..opts.base.clone() }).unwrap();
        let cmp = penumbra_reference::metrics::compare(&c.radiance, "a", &other.radiance, "b").unwrap();
        let ratio = cmp.rmse_rel_mean / (c.meta.noise_rmse_rel_mean * 2f64.sqrt());
        assert!((0.5..2.0).contains(&ratio), "independent-render error / expected = {ratio}");
        let again = load_or_render(&scene, b"default", "default", &opts, Some(&dir)).unwrap();
        assert!(again.cached);
        assert_eq!(again.radiance, c.radiance);
        assert_eq!(again.meta.spp, c.meta.spp);
        let changed = ConvergeOptions { base: ReferenceOptions { frame: 4, ..opts.base.clone() }, ..opts.clone() };
        assert_ne!(cache_key(b"default", &changed), c.meta.key);
        let _ = std::fs::remove_dir_all(&dir);
    }
}

mod cli {

    use clap::Parser;
    use penumbra_reference::cli::*;

    use penumbra_scene::Scene;

    #[derive(Parser)]
    struct R {
        #[command(flatten)]
        a: ReferenceArgs,
    }
    #[derive(Parser)]
    struct C {
        #[command(flatten)]
        a: CompareArgs,
    }

    #[test]
    fn parses_arguments() {
        let r =
            R::try_parse_from(["x", "s.toml", "--frame", "3", "--spp", "16", "--size", "64x32", "--out", "o"]).unwrap();
        let o = r.a.options().unwrap();
        assert_eq!((o.width, o.height, o.spp, o.frame), (64, 32, 16, 3));
        assert!((o.time_s() - 0.1).abs() < 1e-6);
        assert!(R::try_parse_from(["x", "--size", "64"]).unwrap().a.options().is_err());
        let c = C::try_parse_from(["x", "a.exr", "b.exr", "--json", "--diff", "d.png"]).unwrap();
        assert!(c.a.json && c.a.diff.is_some());
        assert_eq!(parse_size(" 320 x 240 ").unwrap(), (320, 240));
        assert!(parse_size("0x5").is_err());
    }

    #[test]
    fn reference_then_compare_end_to_end() {
        let dir = std::env::temp_dir().join(format!("penumbra-ref-cli-{}", std::process::id()));
        let out = dir.to_str().unwrap().to_string();
        for (sub, seed, mode) in [("a", "1", "exact"), ("b", "2", "sg")] {
            let r = R::try_parse_from([
                "x",
                "--size",
                "8x6",
                "--spp",
                "4",
                "--seed",
                seed,
                "--mode",
                mode,
                "--sg-lobes",
                "4",
                "--no-progress",
                "--out",
                &format!("{out}/{sub}"),
            ])
            .unwrap();
            run_reference(&r.a, &Scene::default_scene()).unwrap();
        }
        let diff = dir.join("diff.png");
        let c = C::try_parse_from([
            "x",
            &format!("{out}/a/reference.exr"),
            &format!("{out}/b/reference.exr"),
            "--json",
            "--diff",
            diff.to_str().unwrap(),
        ])
        .unwrap();
        run_compare(&c.a).unwrap();
        assert!(diff.is_file());
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("b/reference.json")).unwrap()).unwrap();
        assert!(j["sg_fit_rel_l2"].as_f64().is_some());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn compare_reports_missing_file() {
        let e = run_compare(&CompareArgs { a: "nope_a.exr".into(), b: "nope_b.exr".into(), json: true, diff: None })
            .unwrap_err();
        assert!(format!("{e:#}").contains("nope_a.exr"));
    }
}

mod sampling {
    use glam::Vec3;
    use glam::Vec3Swizzles;
    use penumbra_reference::sampling::*;
    use penumbra_scene::Environment;
    use std::f32::consts::TAU;

    #[test]
    fn alias_table_matches_weights() {
        let w = [1.0, 0.0, 3.0, 6.0];
        let t = AliasTable::new(&w).unwrap();
        let mut counts = [0usize; 4];
        let mut rng = Pcg32::new(1, 2);
        let n = 200_000;
        for _ in 0..n {
            counts[t.sample(rng.next_f32(), rng.next_f32())] += 1;
        }
        for i in 0..4 {
            let p = w[i] / 10.0;
            let sigma = (p * (1.0 - p) / n as f64).sqrt();
            let f = counts[i] as f64 / n as f64;
            assert!((f - p).abs() <= 5.0 * sigma + 1e-12, "{i}: {f} vs {p}");
        }
        assert!(AliasTable::new(&[0.0, 0.0]).is_none());
    }

    /// The env pdf integrates to 1 over the sphere and agrees with sample(): E[L / pdf] over
    /// env samples equals the integral of L over the sphere (computed per texel exactly).
    #[test]
    fn env_sampling_is_unbiased() {
        let mut env = Environment::procedural_sky(32, 16);
        env.rotation = 0.7;
        env.intensity = 1.5;
        let e = EnvLight::new(&env).unwrap();
        // Exact integral of luminance over the sphere.
        let mut exact = 0.0f64;
        for (i, t) in env.texels.iter().enumerate() {
            let j = i / 32;
            exact += luminance(Vec3::from_array(*t) * 1.5) as f64 * e.row_solid_angle(j) as f64;
        }
        let mut rng = Pcg32::new(3, 4);
        let n = 100_000;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let u = [rng.next_f32(), rng.next_f32(), rng.next_f32(), rng.next_f32()];
            let (d, l, pdf) = e.sample(u).unwrap();
            assert!((pdf - e.pdf(d)).abs() <= 1e-4 * pdf);
            assert!((l - e.radiance(d)).length() == 0.0);
            let x = (luminance(l) / pdf) as f64;
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let se = ((s2 / n as f64 - mean * mean) / (n as f64 - 1.0)).sqrt();
        assert!((mean - exact).abs() <= 5.0 * se + 1e-4 * exact, "{mean} vs {exact} (se {se})");
        // pdf integrates to one: uniform sphere quadrature of pdf.
        let m = 200_000;
        let mut acc = 0.0f64;
        for _ in 0..m {
            let z = 2.0 * rng.next_f32() - 1.0;
            let phi = TAU * rng.next_f32();
            let r = (1.0 - z * z).max(0.0).sqrt();
            acc += e.pdf(Vec3::new(r * phi.cos(), z, r * phi.sin())) as f64 * 4.0 * std::f64::consts::PI;
        }
        let integral = acc / m as f64;
        assert!((integral - 1.0).abs() < 0.05, "pdf integral {integral}");
    }

    #[test]
    fn rotation_convention() {
        let mut env = Environment::procedural_sky(64, 32);
        let e0 = EnvLight::new(&env).unwrap();
        env.rotation = 1.0;
        let e1 = EnvLight::new(&env).unwrap();
        let q = glam::Quat::from_rotation_y(1.0);
        let mut rng = Pcg32::new(5, 6);
        let mut mismatches = 0;
        for _ in 0..1000 {
            let d = uniform_hemisphere(rng.next_vec2()).zxy() * if rng.next_f32() < 0.5 { 1.0 } else { -1.0 };
            if (e1.radiance(q * d) - e0.radiance(d)).length() > 1e-6 {
                mismatches += 1; // only possible right at texel borders
            }
        }
        assert!(mismatches <= 5, "{mismatches}");
        // Same lookup as the scene crate's own Environment::radiance (nearest texel).
        env.intensity = 1.7;
        let e2 = EnvLight::new(&env).unwrap();
        let mut differ = 0;
        for _ in 0..1000 {
            let d = uniform_hemisphere(rng.next_vec2()).zxy() * if rng.next_f32() < 0.5 { 1.0 } else { -1.0 };
            if (e2.radiance(d) - env.radiance(d)).length() > 1e-5 * env.radiance(d).length().max(1.0) {
                differ += 1;
            }
        }
        assert!(differ <= 5, "{differ}");
        // And the map's +Y pole is world +Y whatever the rotation.
        assert_eq!(e1.radiance(Vec3::Y), e0.radiance(Vec3::Y));
    }
}

mod metrics {
    use penumbra_reference::image::Image;
    use penumbra_reference::metrics::*;

    fn gradient(w: u32, h: u32) -> Image {
        Image::from_fn(w, h, |x, y| {
            let t = (x + y * w) as f32 / (w * h) as f32;
            [t, 0.5 * t + 0.1, 2.0 * (1.0 - t)]
        })
    }

    #[test]
    fn constant_offset_known_psnr_rmse() {
        let a = gradient(32, 16);
        let peak = a.pixels.iter().flat_map(|p| p.iter()).fold(0.0f32, |m, &c| m.max(c)) as f64;
        let d = 0.01f32;
        let b = Image { pixels: a.pixels.iter().map(|p| p.map(|c| c + d)).collect(), ..a.clone() };
        let c = compare(&a, "a", &b, "b").unwrap();
        // Every channel differs by d (up to f32 rounding of c + d).
        assert!((c.rmse - d as f64).abs() < 1e-6, "rmse {}", c.rmse);
        assert!((c.mean_abs_error - d as f64).abs() < 1e-6);
        assert!((c.max_abs_error - d as f64).abs() < 1e-6);
        let expect = 10.0 * (peak * peak / (d as f64 * d as f64)).log10();
        assert!((c.psnr_db.unwrap() - expect).abs() < 1e-3, "{:?} vs {expect}", c.psnr_db);
        assert_eq!(c.psnr_peak, peak);
        assert!(!c.identical);
        assert_eq!(c.pixels_compared, 32 * 16);
        // relMSE: mean of d^2/(a^2+eps), computed independently.
        let rel: f64 = a
            .pixels
            .iter()
            .flat_map(|p| p.iter())
            .map(|&x| (d as f64).powi(2) / ((x as f64).powi(2) + REL_EPSILON))
            .sum::<f64>()
            / (3.0 * 32.0 * 16.0);
        assert!((c.rel_rmse - rel.sqrt()).abs() < 1e-4 * rel.sqrt());
    }

    #[test]
    fn single_pixel_error() {
        let a = Image::from_fn(10, 10, |_, _| [0.5, 0.5, 0.5]);
        let mut b = a.clone();
        b.set(3, 7, [0.5, 1.5, 0.5]);
        let c = compare(&a, "a", &b, "b").unwrap();
        // MSE = 1^2 / 300 channels; peak 0.5.
        let mse = 1.0 / 300.0;
        assert!((c.mse - mse).abs() < 1e-12);
        assert!((c.rmse - mse.sqrt()).abs() < 1e-9);
        assert!((c.psnr_db.unwrap() - 10.0 * (0.25 / mse).log10()).abs() < 1e-9);
        assert_eq!(c.max_abs_error, 1.0);
        assert_eq!(c.max_abs_error_at, [3, 7]);
        assert!((c.mean_abs_error - 1.0 / 300.0).abs() < 1e-12);
        assert!(c.flip_mean > 0.0 && c.flip_mean < 0.05, "flip {}", c.flip_mean);
    }

    #[test]
    fn identical_images_infinite_psnr_is_null_in_json() {
        let a = gradient(16, 16);
        let c = compare(&a, "a", &a, "a").unwrap();
        assert!(c.identical);
        assert_eq!(c.psnr_db, None);
        assert_eq!(c.rmse, 0.0);
        assert_eq!(c.flip_mean, 0.0);
        let j = serde_json::to_string(&c).unwrap();
        assert!(j.contains("\"psnr_db\":null"), "{j}");
        let back: Comparison = serde_json::from_str(&j).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn size_mismatch_is_an_error_naming_both() {
        let e = compare(&gradient(4, 4), "ref.exr", &gradient(4, 5), "test.exr").unwrap_err();
        let m = e.to_string();
        assert!(m.contains("ref.exr") && m.contains("test.exr") && m.contains("4x5"), "{m}");
    }

    #[test]
    fn nan_pixels_are_counted_and_excluded() {
        let a = gradient(8, 8);
        let mut b = a.clone();
        b.set(1, 1, [f32::NAN, 0.0, 0.0]);
        b.set(2, 1, [0.0, f32::INFINITY, 0.0]);
        let c = compare(&a, "a", &b, "b").unwrap();
        assert_eq!(c.non_finite_b, 2);
        assert_eq!(c.non_finite_a, 0);
        assert_eq!(c.pixels_compared, 62);
        assert_eq!(c.mse, 0.0);
        assert!(!c.identical);
        assert!(c.flip_mean.is_finite());
        let rgb = diff_rgb8(&a, &b, 1.0);
        assert_eq!(&rgb[3 * 9..3 * 9 + 3], &[0, 255, 255]);
    }

    #[test]
    fn tiny_and_extreme_images_do_not_panic() {
        let a = Image::from_fn(1, 1, |_, _| [1.0, 2.0, 3.0]);
        let b = Image::from_fn(1, 1, |_, _| [1.0, 2.0, 4.0]);
        let c = compare(&a, "a", &b, "b").unwrap();
        assert!((c.max_abs_error - 1.0).abs() < 1e-12 && c.flip_mean.is_finite());
        let a = Image::from_fn(3, 1, |_, _| [1e30, -1e30, 0.0]);
        let c = compare(&a, "a", &Image::new(3, 1), "b").unwrap();
        assert!(c.rmse.is_finite() && c.flip_mean.is_finite());
        let empty = Image::new(0, 0);
        assert!(compare(&empty, "e", &empty, "e").unwrap_err().to_string().contains("empty"));
    }

    #[test]
    fn flip_grows_with_error() {
        let a = gradient(32, 32);
        let small = Image { pixels: a.pixels.iter().map(|p| p.map(|c| c * 1.02)).collect(), ..a.clone() };
        let big = Image { pixels: a.pixels.iter().map(|p| p.map(|c| c * 1.5)).collect(), ..a.clone() };
        let fs = compare(&a, "a", &small, "s").unwrap().flip_mean;
        let fb = compare(&a, "a", &big, "b").unwrap().flip_mean;
        assert!(fs < fb, "{fs} {fb}");
    }

    #[test]
    fn exr_round_trip_and_file_errors() {
        let dir = std::env::temp_dir().join(format!("penumbra-ref-metrics-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = gradient(12, 7);
        let pa = dir.join("a.exr");
        a.write_exr(&pa).unwrap();
        let back = Image::read_exr(&pa).unwrap();
        assert_eq!(back, a);
        // Half-float RGBA file.
        let ph = dir.join("half.exr");
        exr::prelude::write_rgba_file(&ph, 12, 7, |x, y| {
            let p = a.get(x as u32, y as u32);
            (
                exr::prelude::f16::from_f32(p[0]),
                exr::prelude::f16::from_f32(p[1]),
                exr::prelude::f16::from_f32(p[2]),
                exr::prelude::f16::from_f32(1.0),
            )
        })
        .unwrap();
        let diff = dir.join("diff.png");
        let c = compare_files(&pa, &ph, Some(&diff)).unwrap();
        assert!(c.max_abs_error < 2e-3, "half rounding {}", c.max_abs_error);
        assert!(std::fs::metadata(&diff).unwrap().len() > 0);
        assert_eq!(c.reference_noise_rms, None);
        // A standard-error image beside A is picked up.
        Image::from_fn(12, 7, |_, _| [0.5, 0.5, 0.5]).write_exr(dir.join("a_stderr.exr")).unwrap();
        let c = compare_files(&pa, &ph, None).unwrap();
        assert!((c.reference_noise_rms.unwrap() - 0.5).abs() < 1e-12);
        assert!(c.summary().contains("ref. noise"));
        // Missing file.
        let missing = dir.join("missing.exr");
        let m = compare_files(&pa, &missing, None).unwrap_err().to_string();
        assert!(m.contains("missing.exr") && m.contains("not found"), "{m}");
        // Not an EXR.
        let junk = dir.join("junk.exr");
        std::fs::write(&junk, b"hello").unwrap();
        let m = Image::read_exr(&junk).unwrap_err().to_string();
        assert!(m.contains("junk.exr"), "{m}");
        // Luminance-only EXR: unsupported channels.
        let py = dir.join("y.exr");
        let ch = exr::prelude::AnyChannels::sort(smallvec_one(exr::prelude::AnyChannel::new(
            "Y",
            exr::prelude::FlatSamples::F32(vec![0.5; 4]),
        )));
        use exr::prelude::WritableImage;
        exr::prelude::Image::from_channels((2, 2), ch).write().to_file(&py).unwrap();
        let m = Image::read_exr(&py).unwrap_err().to_string();
        assert!(m.contains("y.exr") && m.contains("unsupported channels") && m.contains("Y"), "{m}");
        // Size mismatch from files.
        let pb = dir.join("b.exr");
        gradient(5, 5).write_exr(&pb).unwrap();
        let m = compare_files(&pa, &pb, None).unwrap_err().to_string();
        assert!(m.contains("a.exr") && m.contains("b.exr") && m.contains("12x7"), "{m}");
        std::fs::remove_dir_all(&dir).ok();
    }

    fn smallvec_one(
        c: exr::prelude::AnyChannel<exr::prelude::FlatSamples>,
    ) -> exr::prelude::SmallVec<[exr::prelude::AnyChannel<exr::prelude::FlatSamples>; 4]> {
        let mut v = exr::prelude::SmallVec::new();
        v.push(c);
        v
    }
}

mod facing {
    use glam::Vec3;
    use penumbra_reference::render::{facing_normal, FACING_MIN_COS};

    /// `facing_normal` leaves normals the eye sees from above alone and turns the others towards
    /// the eye just far enough: unit, only the component along v raised (to FACING_MIN_COS before
    /// normalizing, so n.v = eps / sqrt(1 - (n.v)^2 + eps^2) >= eps), the rest kept; it survives
    /// n = -v and non-finite input.
    #[test]
    fn normals_are_turned_to_the_eye_only_when_they_face_away() {
        let eps = FACING_MIN_COS;
        let v = Vec3::new(0.3, 0.2, 0.9).normalize();
        for n in [v, Vec3::Z, Vec3::new(0.0, 1.0, 0.2).normalize()] {
            assert!(n.dot(v) >= eps);
            assert_eq!(facing_normal(n, v), n);
        }
        let t = Vec3::new(0.9, -0.3, 0.0);
        let t = (t - v * t.dot(v)).normalize();
        for k in 0..=64 {
            // from just under the threshold (grazing) to straight away from the eye
            let a = (eps * 0.99).asin() - k as f32 / 64.0 * 0.999 * std::f32::consts::FRAC_PI_2;
            let n = (v * a.sin() + t * a.cos()).normalize();
            let (c0, b) = (n.dot(v), facing_normal(n, v));
            assert!(c0 < eps && (b.length() - 1.0).abs() < 1e-5, "{n} -> {b}");
            let want = eps / (1.0 - c0 * c0 + eps * eps).sqrt();
            let c = b.dot(v);
            // (n almost -v: its part across v is a difference of nearly equal numbers)
            assert!(c >= 0.999 * eps && (c - want).abs() < 1e-4 + 1e-3 * want, "{n} -> {b}: n.v {c}, want {want}");
            let (tn, tb) = (n - v * c0, b - v * c);
            assert!(tn.normalize().dot(tb.normalize()) > 0.999, "{n} -> {b}: turned sideways");
        }
        assert!((facing_normal(-v, v) - v).length() < 1e-4);
        let nan = Vec3::new(f32::NAN, 0.0, 1.0);
        assert!(facing_normal(nan, v).x.is_nan(), "non-finite n.v: n returned as it came");
    }
}
