//! Unit tests of the passes' modules, kept out of the library so that the library is compiled
//! once rather than again as a test harness (40 s of a clean build).

mod isg_vertex {

    use glam::Vec3;

    use std::collections::HashMap;

    use penumbra_passes::isg::vertex::*;

    #[test]
    fn a_tiny_max_edge_stays_within_the_triangle_budget() {
        // 1e-10 asks for 34 levels: the level count is capped before any shift could overflow
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        for max_edge in [1e-10, 1e-30, f32::MIN_POSITIVE] {
            let r = refine(&p, &[0, 1, 2], 1.0, max_edge);
            assert!(r.indices.len() / 3 <= MAX_REFINED_TRIANGLES && r.indices.len() / 3 > 1, "{max_edge}");
            // what was asked is reported beside what the budget allows (the technique's note)
            let (asked, applied) = subdivision_levels(1, longest_edge(&p, &[0, 1, 2]), max_edge);
            assert_eq!(applied, r.levels, "{max_edge}");
            assert!(asked > applied && asked >= 34, "{max_edge}: asked {asked}");
        }
        // within the budget nothing is cut; nothing is asked where no edge is too long
        assert_eq!(subdivision_levels(1, 4.0, 1.0), (2, 2));
        assert_eq!(subdivision_levels(1, 1.0, 2.0), (0, 0));
        assert_eq!(subdivision_levels(1, f32::NAN, 1.0), (0, 0));
        // an index outside the positions is skipped, not read
        assert_eq!(longest_edge(&p, &[0, 1, 7, 0, 1, 2]), 2f32.sqrt());
    }

    #[test]
    fn refine_splits_shared_edges_once_and_keeps_the_surface() {
        let quad =
            [Vec3::new(0.0, 0.0, 0.0), Vec3::new(4.0, 0.0, 0.0), Vec3::new(4.0, 0.0, 4.0), Vec3::new(0.0, 0.0, 4.0)];
        let idx = [0, 1, 2, 0, 2, 3];
        let r = refine(&quad, &idx, 1.0, 1.0);
        // Longest edge 4 sqrt 2 = 5.66 -> 3 levels (edges 0.71): 2 * 64 triangles, 9 x 9 grid.
        assert_eq!(r.levels, 3);
        assert_eq!(r.indices.len() / 3, 128);
        assert_eq!(r.base_vertices + r.splits.len(), 81);
        let (p, n) = r.apply(&quad, &[Vec3::Y; 4]);
        assert!(p.iter().all(|v| v.y == 0.0 && v.x >= 0.0 && v.x <= 4.0 && v.z >= 0.0 && v.z <= 4.0));
        assert!(n.iter().all(|v| *v == Vec3::Y));
        let area: f32 = r
            .indices
            .chunks_exact(3)
            .map(|t| 0.5 * (p[t[1] as usize] - p[t[0] as usize]).cross(p[t[2] as usize] - p[t[0] as usize]).length())
            .sum();
        assert!((area - 16.0).abs() < 1e-4, "area {area}");
        // Every edge is shared by two triangles or on the boundary (no T-junctions).
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        for t in r.indices.chunks_exact(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        assert_eq!(edges.values().filter(|&&c| c == 1).count(), 4 * 8);
        // Nothing to do, bad thresholds, bad indices.
        assert_eq!(refine(&quad, &idx, 1.0, 10.0).levels, 0);
        assert_eq!(refine(&quad, &idx, 1.0, 0.0).levels, 0);
        assert_eq!(refine(&quad, &idx, f32::NAN, 1.0).levels, 0);
        assert_eq!(refine(&quad, &[0, 1, 9], 1.0, 1.0).indices.len(), 0);
        // The triangle budget caps the levels.
        let r = refine(&quad, &idx, 1.0, 1e-6);
        assert!(r.indices.len() / 3 <= MAX_REFINED_TRIANGLES && r.levels > 0);
    }

    /// The per-vertex tangents Ashikhmin-Shirley's seven lobes turn with: the direction of
    /// increasing u (as the G-buffer's dP/du per pixel), whatever the uv mapping's scale, sign or
    /// rotation; zero without uvs and where every adjacent triangle's mapping is degenerate;
    /// the subdivided mesh's midpoints sum their ends.
    #[test]
    fn vertex_tangents_follow_increasing_u() {
        use glam::Vec2;
        let quad = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, -1.0), Vec3::NEG_Z];
        let idx = [0, 1, 2, 0, 2, 3];
        let dir = |uvs: &[Vec2]| -> Vec<Vec3> {
            vertex_tangents(&quad, uvs, &idx).iter().map(|t| t.try_normalize().unwrap_or(Vec3::ZERO)).collect()
        };
        let near = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
        // u along +x (scaled by 3), v along -z
        let uv = [Vec2::ZERO, Vec2::new(3.0, 0.0), Vec2::new(3.0, 1.0), Vec2::new(0.0, 1.0)];
        assert!(dir(&uv).iter().all(|&t| near(t, Vec3::X)), "{:?}", dir(&uv));
        // u mirrored: along -x
        let mirrored: Vec<Vec2> = uv.iter().map(|p| Vec2::new(-p.x, p.y)).collect();
        assert!(dir(&mirrored).iter().all(|&t| near(t, Vec3::NEG_X)));
        // the mapping turned by 90 degrees: u along the quad's -z edge
        let turned = [Vec2::ZERO, Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)];
        assert!(dir(&turned).iter().all(|&t| near(t, Vec3::NEG_Z)), "{:?}", dir(&turned));
        // no uvs, degenerate uvs: zero (the shaders then take Duff et al.'s basis vector)
        assert!(vertex_tangents(&quad, &[], &idx).iter().all(|t| *t == Vec3::ZERO));
        assert!(vertex_tangents(&quad, &[Vec2::ONE; 4], &idx).iter().all(|t| *t == Vec3::ZERO));
        // bad indices are skipped
        assert_eq!(vertex_tangents(&quad, &uv, &[0, 1, 9]), vec![Vec3::ZERO; 4]);
        // subdivided: the midpoints' sums keep the direction
        let r = refine(&quad, &idx, 1.0, 0.5);
        let t = r.apply_sum(&vertex_tangents(&quad, &uv, &idx));
        assert_eq!(t.len(), 4 + r.splits.len());
        assert!(t.iter().all(|t| near(t.normalize(), Vec3::X)));
    }
}

mod vv {

    use penumbra_passes::vv::*;

    #[test]
    fn specular_and_refine_parameters() {
        let mut s = VvSettings::default();
        assert!(s.specular);
        s.set("specular", "off").unwrap();
        assert!(!s.specular);
        s.set("specular", "on").unwrap();
        assert!(s.specular);
        assert!(s.set("specular", "maybe").is_err());
        s.set("refine", "0").unwrap();
        assert_eq!(s.refine, 0);
        assert!(s.set("refine", "-1").is_err());
        assert_eq!(refine_edge(36.0, 0), 0.0);
        assert!((refine_edge(36.0, 1024) - 0.1875).abs() < 1e-6);
    }
}

mod registry {

    use penumbra_scene::Scene;

    use penumbra_passes::registry::*;

    #[test]
    fn registry_names_every_technique_once_with_a_budget() {
        let names = names();
        let mut sorted = names.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), names.len(), "duplicate names in {names:?}");
        for t in REGISTRY {
            match t.budget {
                Budget::RmseRelMean { rmse_rel_mean, source } => {
                    assert!(rmse_rel_mean > 0.0 && rmse_rel_mean < 1.0 && !source.is_empty(), "{}", t.name)
                }
                Budget::Unbiased { factor, source } => assert!(factor >= 1.0 && !source.is_empty(), "{}", t.name),
                Budget::Baseline { .. } => assert!(!t.shadows, "{}: a shadow technique needs a budget", t.name),
            }
        }
    }

    /// A technique that bakes the lighting refuses a scene whose environment is animated, naming
    /// the ones that follow it; with the environment still, it is accepted.
    #[test]
    fn techniques_that_bake_the_lighting_refuse_an_animated_environment() {
        let mut s = Scene::default_scene();
        assert!(s.environment.is_some());
        let key = |t, r| penumbra_scene::Track::new(vec![0.0, t], vec![0.0, r], penumbra_scene::Interp::Linear, false);
        s.environment_animation =
            Some(penumbra_scene::EnvironmentAnimation { rotation: Some(key(1.0, 1.5).unwrap()), intensity: None });
        assert!(s.requirements().animated_environment);
        let baked: Vec<_> = REGISTRY.iter().filter(|t| !t.animated_environment).collect();
        assert!(!baked.is_empty());
        for t in REGISTRY {
            match refusal(t.name, &s) {
                Some(why) => {
                    assert!(!t.animated_environment, "{}: {why}", t.name);
                    assert!(why.contains("[[environment.keys]]") && why.contains("isg"), "{why}");
                }
                None => assert!(t.animated_environment, "{} must refuse", t.name),
            }
        }
        // a constant track animates nothing
        s.environment_animation =
            Some(penumbra_scene::EnvironmentAnimation { rotation: Some(key(1.0, 0.0).unwrap()), intensity: None });
        assert!(!s.requirements().animated_environment);
        assert!(baked.iter().all(|t| refusal(t.name, &s).is_none() || t.static_only));
    }

    /// The shadow fields precompute one rigid field per object: a scene whose shadow casters
    /// deform is refused, naming them (rather than shadowed by their rest mesh), moving rigid
    /// objects are accepted, and so is a deforming object that casts no shadow.
    #[test]
    fn rigid_field_techniques_refuse_deforming_shadow_casters_by_name() {
        let scenes = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        let mut hat = Scene::load(scenes.join("hat_on_cloth.toml")).unwrap();
        let falling = Scene::load(scenes.join("falling.toml")).unwrap();
        assert!(hat.requirements().deforming_objects && falling.requirements().moving_objects);
        let rigid: Vec<_> = REGISTRY.iter().filter(|t| t.rigid_only).collect();
        assert_eq!(rigid.len(), 3, "{rigid:?}");
        for t in REGISTRY {
            let why = refusal(t.name, &hat);
            if t.rigid_only || t.static_only {
                let why = why.unwrap_or_else(|| panic!("{} must refuse hat_on_cloth", t.name));
                assert!(why.contains("deform"), "{why}");
            } else {
                assert!(why.is_none(), "{}: {why:?}", t.name);
            }
        }
        for t in &rigid {
            assert!(refusal(t.name, &falling).is_none(), "{}", t.name);
            let why = refusal(t.name, &hat).unwrap();
            assert!(
                why.contains("'cloth', 'hat'") && why.contains("casts_shadow = false") && why.contains("shadowmaps"),
                "{why}"
            );
        }
        // the hat alone casts shadows: only it is named
        let cloth = hat.objects.iter().position(|o| o.name == "cloth").unwrap();
        hat.object_info[cloth].casts_shadow = false;
        let why = refusal("shadow-fields", &hat).unwrap();
        assert!(why.contains("'hat'") && !why.contains("'cloth'"), "{why}");
        // neither casts: nothing a rigid field would get wrong
        let h = hat.objects.iter().position(|o| o.name == "hat").unwrap();
        hat.object_info[h].casts_shadow = false;
        assert!(rigid.iter().all(|t| refusal(t.name, &hat).is_none()));
    }

    /// `auto`: shadowmaps for a lit scene, mc where the device cannot render layered shadow
    /// maps, env without light; every choice is a registered technique.
    #[test]
    fn auto_chooses_by_scene_and_device() {
        let lit = Scene::default_scene();
        assert_eq!(choose_auto(&lit, true).0, "shadowmaps");
        assert_eq!(choose_auto(&lit, false).0, "mc");
        let mut dark = Scene::empty("dark");
        dark.environment = None;
        assert_eq!(choose_auto(&dark, true).0, "env");
        for (s, l) in [(&lit, true), (&lit, false), (&dark, true)] {
            let (name, params, why) = choose_auto(s, l);
            assert!(info(name).is_some() && params.is_empty() && why.starts_with(&format!("auto: {name}")));
        }
        assert!(check_name(AUTO).is_ok() && check_name("nope").is_err());
    }

    /// Each technique's own parser accepts every documented key at its documented default, and
    /// the documented defaults are the parser's defaults.
    #[test]
    fn documented_parameters_are_the_parsers_parameters() {
        let defaults = |params: &[ParamDoc]| -> Params {
            params.iter().map(|p| (p.key.to_string(), p.default.to_string())).collect()
        };
        for t in REGISTRY {
            let all = defaults(t.params);
            check_params(t.name, &all).unwrap();
        }
        let isg = penumbra_passes::isg::IsgSettings::from_params(&defaults(lookup("isg").unwrap().params)).unwrap();
        let d = penumbra_passes::isg::IsgSettings::default();
        assert_eq!(
            (isg.lobes, isg.fit_error, isg.spheres_per_object, isg.patch_side, isg.epsilon, isg.lod, isg.max_edge),
            (d.lobes, d.fit_error, d.spheres_per_object, d.patch_side, d.epsilon, d.lod, d.max_edge)
        );
        assert_eq!(
            (isg.thin_tolerance, isg.traced_visibility, isg.min_lobe_fraction, isg.light_mesh),
            (d.thin_tolerance, d.traced_visibility, d.min_lobe_fraction, d.light_mesh)
        );
        let avs = penumbra_passes::avs::AvsSettings::from_params(&defaults(lookup("avs").unwrap().params)).unwrap();
        let d = penumbra_passes::avs::AvsSettings::default();
        assert_eq!(
            (avs.r, avs.e_max, avs.iterations, avs.max_points, avs.neighbours),
            (d.r, d.e_max, d.iterations, d.max_points, d.neighbours)
        );
        assert_eq!((avs.traced_lights, avs.key_lights), (d.traced_lights, d.key_lights));
        let sf =
            penumbra_passes::shadow_fields::SfOptions::from_params(&defaults(lookup("shadow-fields").unwrap().params))
                .unwrap();
        let d = penumbra_passes::shadow_fields::SfOptions::default();
        assert_eq!(
            (sf.params.shells, sf.params.resolution, sf.params.map_res, sf.params.threshold),
            (d.params.shells, d.params.resolution, d.params.map_res, d.params.threshold)
        );
        assert_eq!((sf.srf, sf.light_traced, sf.key_lights), (d.srf, d.light_traced, d.key_lights));
        let sfw = penumbra_passes::shadow_fields::wavelet::SfwOptions::from_params(&defaults(
            lookup("shadow-fields-wavelet").unwrap().params,
        ))
        .unwrap();
        let d = penumbra_passes::shadow_fields::wavelet::SfwOptions::default();
        assert_eq!(
            (sfw.shells, sfw.resolution, sfw.cube, sfw.keep, sfw.threshold, sfw.light_traced, sfw.key_lights),
            (d.shells, d.resolution, d.cube, d.keep, d.threshold, d.light_traced, d.key_lights)
        );
        assert_eq!(lookup("mc").unwrap().params[0].default.parse::<u32>().unwrap(), penumbra_passes::mc::DEFAULT_SPP);
        // Every knob is a documented parameter and its values parse.
        for t in REGISTRY {
            for kn in t.knobs {
                for v in kn.values.iter().chain(kn.finer) {
                    let one: Params = [(kn.key.to_string(), v.to_string())].into_iter().collect();
                    check_params(t.name, &one).unwrap_or_else(|e| panic!("{} knob {}: {e}", t.name, kn.key));
                }
            }
        }
        let sm = penumbra_passes::shadowmaps::ShadowMapsSettings::from_params(&defaults(
            lookup("shadowmaps").unwrap().params,
        ))
        .unwrap();
        assert_eq!(sm, penumbra_passes::shadowmaps::ShadowMapsSettings::default());
        let vv = penumbra_passes::vv::VvSettings::from_params(&defaults(lookup("vv").unwrap().params)).unwrap();
        assert_eq!(vv, penumbra_passes::vv::VvSettings::default());
        // An undocumented key is refused before any parser sees it.
        for t in REGISTRY {
            let bogus: Params = [("bogus".to_string(), "1".to_string())].into();
            let e = check_params(t.name, &bogus).unwrap_err().to_string();
            assert!(e.contains("bogus"), "{}: {e}", t.name);
        }
    }

    #[test]
    fn unknown_names_list_the_registered_ones() {
        let e = lookup("hsdt").unwrap_err().to_string();
        assert!(e.contains("unknown technique 'hsdt'") && e.contains("avs") && e.contains("vv"), "{e}");
        assert!(describe().contains("shadow-fields-fixed") && describe().contains("volumetric"));
    }

    #[test]
    fn bad_parameters_are_reported_together() {
        let params: Params = [("zeta", "-3"), ("mode", "fragment1"), ("bogus", "1")]
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        let e = penumbra_passes::vv::VvSettings::from_params(&params).unwrap_err().to_string();
        assert!(e.starts_with("2 bad technique parameters"), "{e}");
        assert!(e.contains("zeta") && e.contains("bogus") && !e.contains("fragment1"), "{e}");
        let one: Params = [("lobes".to_string(), "zero".to_string())].into();
        let e = penumbra_passes::isg::IsgSettings::from_params(&one).unwrap_err().to_string();
        assert!(e.contains("lobes") && !e.contains("bad technique parameters"), "{e}");
        let good: Params = [("mode".to_string(), "vertex".to_string())].into();
        assert!(penumbra_passes::shadow_fields::SfOptions::from_params(&good).is_ok());
    }
}

mod raster {

    use penumbra_engine::vk;

    use penumbra_passes::raster::*;

    #[test]
    fn stages_come_from_file_extensions() {
        assert_eq!(stage_of("a.vert"), Some(vk::ShaderStageFlags::VERTEX));
        assert_eq!(stage_of("x/b.tesc"), Some(vk::ShaderStageFlags::TESSELLATION_CONTROL));
        assert_eq!(stage_of("b.tese"), Some(vk::ShaderStageFlags::TESSELLATION_EVALUATION));
        assert_eq!(stage_of("c.geom"), Some(vk::ShaderStageFlags::GEOMETRY));
        assert_eq!(stage_of("d.frag"), Some(vk::ShaderStageFlags::FRAGMENT));
        assert_eq!(stage_of("e.comp"), None);
    }
}

mod env {

    use glam::Vec3;

    use penumbra_passes::env::*;
    use penumbra_scene::Environment;

    #[test]
    fn an_environment_over_the_device_limit_is_halved_until_it_fits_keeping_its_mean() {
        let texels: Vec<[f32; 3]> = (0..64 * 32).map(|i| [(i % 7) as f32, 1.0, (i / 64) as f32]).collect();
        let env = Environment { width: 64, height: 32, texels, intensity: 2.0, rotation: 0.5 };
        assert!(fit_to_device(&env, 64).is_none());
        let f = fit_to_device(&env, 20).unwrap();
        assert_eq!((f.width, f.height, f.intensity, f.rotation), (16, 8, 2.0, 0.5));
        let mean = |e: &Environment| e.texels.iter().map(|t| t[0] + t[1] + t[2]).sum::<f32>() / e.texels.len() as f32;
        assert!((mean(&f) - mean(&env)).abs() < 1e-3 * mean(&env), "{} {}", mean(&f), mean(&env));
    }

    fn uniform(w: u32, h: u32, l: f32) -> Environment {
        Environment { width: w, height: h, texels: vec![[l; 3]; (w * h) as usize], intensity: 1.0, rotation: 0.3 }
    }

    #[test]
    fn uniform_environment_gives_pi_irradiance() {
        let e = EnvMapGpu::new(Some(&uniform(64, 32, 2.0)));
        for n in [Vec3::X, Vec3::Y, Vec3::NEG_Y, Vec3::new(0.3, -0.5, 0.8).normalize()] {
            let irr = sh9_irradiance(&e.sh, n);
            // Midpoint quadrature of sin(theta) on 32 rows: relative error ~ 1e-3.
            assert!((irr.x / (2.0 * std::f32::consts::PI) - 1.0).abs() < 2e-3, "{n:?}: {irr:?}");
        }
        assert_eq!(e.mips.last().unwrap().0, 1);
        assert_eq!(e.mips.len(), 7);
    }

    #[test]
    fn upper_hemisphere_light_matches_clamped_cosine() {
        // L = 1 above the horizon, 0 below: E(+Y) = pi, E(-Y) = 0, E(horizontal) = pi/2.
        let (w, h) = (128u32, 64u32);
        let texels = (0..h).flat_map(|j| (0..w).map(move |_| if j < h / 2 { [1.0; 3] } else { [0.0; 3] })).collect();
        let env = Environment { width: w, height: h, texels, intensity: 1.0, rotation: 0.0 };
        let e = EnvMapGpu::new(Some(&env));
        let pi = std::f32::consts::PI;
        // Order-2 SH of a hemispherical step: known ringing; bounds from Ramamoorthi-Hanrahan (~9% max error).
        assert!((sh9_irradiance(&e.sh, Vec3::Y).x - pi).abs() < 0.1 * pi);
        assert!(sh9_irradiance(&e.sh, Vec3::NEG_Y).x < 0.1 * pi);
        assert!((sh9_irradiance(&e.sh, Vec3::X).x - pi / 2.0).abs() < 0.02 * pi);
    }

    #[test]
    fn the_unshadowed_diffuse_term_is_the_exact_irradiance_not_sh9() {
        // studio.exr: its brightest texel is about 1466 times its mean radiance. The map in the
        // camera buffer (env_shade.glsl's env_irradiance) holds the exact cosine convolution at
        // its nodes; the 9-coefficient SH it replaced rings far from it.
        let dir = std::env::temp_dir().join(format!("penumbra-irr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let exr = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/assets/studio.exr");
        let toml = format!(
            "name = \"irr\"\n[camera]\neye = [0.0, 0.0, 2.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 40\n[environment]\nfile = {:?}\n[materials.m]\ntype = \"diffuse\"\nalbedo = 0.5\n[[object]]\nname = \"o\"\nmesh = {{ type = \"plane\", size = 1 }}\nmaterial = \"m\"\n",
            exr.display().to_string()
        );
        std::fs::write(dir.join("irr.toml"), toml).unwrap();
        let scene = penumbra_scene::Scene::load(dir.join("irr.toml")).unwrap();
        let map = penumbra_passes::lighting::camera_irradiance(scene.environment.as_ref());
        let (w, h) = penumbra_passes::lighting::CAMERA_IRRADIANCE_SIZE;
        assert_eq!(map.len(), w * h);
        let e = scene.environment.as_ref().unwrap();
        // brute force over a 4x coarser copy of the map (area averages), channel 0
        let k = 4usize;
        let (sw, sh) = (e.width as usize / k, e.height as usize / k);
        let mut src = Vec::with_capacity(sw * sh);
        for j in 0..sh {
            for i in 0..sw {
                let mut acc = 0.0f64;
                for y in 0..k {
                    for x in 0..k {
                        acc += e.texels[(j * k + y) * e.width as usize + i * k + x][0] as f64;
                    }
                }
                let theta = std::f64::consts::PI * (j as f64 + 0.5) / sh as f64;
                let dw = (2.0 * std::f64::consts::PI / sw as f64) * (std::f64::consts::PI / sh as f64) * theta.sin();
                let d = Environment::direction((i as f32 + 0.5) / sw as f32, (j as f32 + 0.5) / sh as f32);
                src.push((d, acc / (k * k) as f64 * dw));
            }
        }
        let exact = |n: Vec3| src.iter().map(|(d, c)| c * d.dot(n).max(0.0) as f64).sum::<f64>();
        let env_gpu = EnvMapGpu::new(Some(e));
        let (mut worst_map, mut worst_sh) = (0.0f64, 0.0f64);
        let e_max = (0..w * h).map(|i| map[i][0] as f64).fold(0.0, f64::max);
        for j in (0..h).step_by(3) {
            for i in (0..w).step_by(3) {
                let n = Environment::direction(i as f32 / w as f32, j as f32 / (h - 1) as f32);
                let ex = exact(n);
                if ex < 0.05 * e_max {
                    continue;
                }
                worst_map = worst_map.max((map[j * w + i][0] as f64 / ex - 1.0).abs());
                // EnvMapGpu's SH is in the world frame (rotation applied): rotate n likewise
                let nw = Vec3::new(
                    n.x * e.rotation.cos() + n.z * e.rotation.sin(),
                    n.y,
                    -n.x * e.rotation.sin() + n.z * e.rotation.cos(),
                );
                worst_sh = worst_sh.max((sh9_irradiance(&env_gpu.sh, nw).x as f64 / ex - 1.0).abs());
            }
        }
        assert!(worst_map < 0.03, "the map is {worst_map} off the exact irradiance");
        assert!(worst_sh > 0.2, "SH9 was expected to ring here ({worst_sh})");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn mip_levels_keep_the_solid_angle_mean() {
        // Bright at the horizon, dark at the poles (a sunset's shape): every level's texels,
        // weighted by their own rows' solid angle, keep the map's mean radiance over the sphere.
        // (An unweighted box filter counted the polar rows as much as the equator's: its 1x1
        // level of this map reads 0.64 of the true mean.)
        let (w, h) = (64u32, 32u32);
        let texels = (0..h)
            .flat_map(|j| {
                let theta = std::f32::consts::PI * (j as f32 + 0.5) / h as f32;
                (0..w).map(move |_| [theta.sin().powi(40) * 10.0, 1.0, 0.0])
            })
            .collect();
        let env = Environment { width: w, height: h, texels, intensity: 1.0, rotation: 0.0 };
        let e = EnvMapGpu::new(Some(&env));
        let mean = |lw: u32, lh: u32, t: &[[f32; 4]]| {
            let band = |j: u32| {
                let c = |r: u32| (std::f64::consts::PI * r as f64 / lh as f64).cos();
                c(j) - c(j + 1)
            };
            let mut acc = [0.0f64; 2];
            for j in 0..lh {
                for i in 0..lw {
                    for (c, a) in acc.iter_mut().enumerate() {
                        *a += t[(j * lw + i) as usize][c] as f64 * band(j) / (2.0 * lw as f64);
                    }
                }
            }
            acc
        };
        let base = mean(e.mips[0].0, e.mips[0].1, &e.mips[0].2);
        assert!(base[0] > 0.5 && (base[1] - 1.0).abs() < 1e-5, "{base:?}");
        for (lw, lh, t) in &e.mips {
            let m = mean(*lw, *lh, t);
            assert!((m[0] / base[0] - 1.0).abs() < 1e-4, "level {lw}x{lh}: {} vs {}", m[0], base[0]);
            assert!((m[1] - 1.0).abs() < 1e-5, "level {lw}x{lh}: a uniform channel reads {}", m[1]);
        }
    }

    #[test]
    fn sun_1e5_times_the_sky_keeps_energy_and_stays_finite() {
        let (w, h) = (256u32, 128u32);
        let mut env = uniform(w, h, 0.5);
        env.rotation = 0.0;
        let sun = (20 * w + 77) as usize;
        env.texels[sun] = [5e4; 3];
        let e = EnvMapGpu::new(Some(&env));
        assert!(e.sh.iter().flatten().all(|c| c.is_finite()));
        assert!(e.mips.iter().all(|m| m.2.iter().flatten().all(|c| c.is_finite() && *c >= 0.0)));
        // Mean irradiance over the sphere = pi x mean radiance (only the DC term survives).
        let dw = |j: u32| {
            (2.0 * std::f64::consts::PI / w as f64)
                * (std::f64::consts::PI / h as f64)
                * (std::f64::consts::PI * (j as f64 + 0.5) / h as f64).sin()
        };
        let mut energy = 0.0;
        for j in 0..h {
            for i in 0..w {
                energy += env.texels[(j * w + i) as usize][0] as f64 * dw(j);
            }
        }
        let mean_l = energy / (4.0 * std::f64::consts::PI);
        let mut mean_e = 0.0;
        let n = 20000;
        for k in 0..n {
            // Fibonacci sphere directions.
            let z = 1.0 - 2.0 * (k as f64 + 0.5) / n as f64;
            let phi = k as f64 * 2.399963229728653;
            let r = (1.0 - z * z).sqrt();
            let d = Vec3::new((r * phi.cos()) as f32, z as f32, (r * phi.sin()) as f32);
            // Without the clamp at 0 (a sun's SH ringing goes negative): the DC term alone.
            let b = sh9_basis(d);
            mean_e += (0..9).map(|i| e.sh[i][0] as f64 * b[i] as f64).sum::<f64>();
        }
        mean_e /= n as f64;
        assert!(
            (mean_e / (std::f64::consts::PI * mean_l) - 1.0).abs() < 1e-3,
            "{mean_e} vs {}",
            std::f64::consts::PI * mean_l
        );
        // The sun's side is brighter than the opposite side.
        let sun_dir = world_direction((77.0 + 0.5) / w as f32, (20.0 + 0.5) / h as f32, 0.0);
        assert!(sh9_irradiance(&e.sh, sun_dir).x > sh9_irradiance(&e.sh, -sun_dir).x);
    }

    #[test]
    fn bad_texels_are_repaired_and_counted() {
        let mut env = uniform(8, 4, 1.0);
        env.texels[3] = [f32::NAN, 1.0, 1.0];
        env.texels[5] = [f32::INFINITY, 1.0, 1.0];
        env.texels[6] = [-1.0, 1.0, 1.0];
        let e = EnvMapGpu::new(Some(&env));
        assert_eq!(e.repaired_texels, 3);
        assert!(e.sh.iter().flatten().all(|c| c.is_finite()));
        assert!(e.mips.iter().all(|m| m.2.iter().flatten().all(|c| c.is_finite())));
    }

    /// `mc`'s and `shadowmaps`' importance tables read bad texels as black, as the texture and
    /// the reference do: no negative radiance to sample or to hit (mc drew negative pixels).
    #[test]
    fn importance_tables_read_bad_texels_as_black() {
        let mut env = uniform(8, 4, 1.0);
        env.texels[3] = [f32::NAN, 1.0, 1.0];
        env.texels[5] = [f32::INFINITY, 1.0, 1.0];
        env.texels[6] = [-149.0, 2.0, 2.0];
        let t = EnvTables::new(Some(&env));
        for i in [3, 5, 6] {
            assert_eq!(t.texels[i], [0.0; 4], "texel {i}");
        }
        assert!(t.texels.iter().all(|x| x.iter().all(|c| c.is_finite() && *c >= 0.0)));
        let p: f32 = t.texels.iter().map(|x| x[3]).sum();
        assert!((p - 1.0).abs() < 1e-5, "{p}");
    }

    #[test]
    fn missing_environment_is_black() {
        let e = EnvMapGpu::new(None);
        // its texels (the frames' intensity is `Frame::environment`'s, 0 without a map)
        assert!(e.mips.iter().all(|(_, _, t)| t.iter().all(|c| c[..3] == [0.0; 3])));
        assert!(e.sh.iter().flatten().all(|c| *c == 0.0));
    }
}

mod volumetric_airlight {

    use penumbra_passes::volumetric::airlight::*;

    #[test]
    // 1.5707: a sample just inside the table's v range [0, pi/2], not pi/2 itself.
    #[allow(clippy::approx_constant)]
    fn isotropic_closed_forms() {
        // u = 0, g = 0: F = v; v = pi/2, u large: F ~ 1/u.
        let t = table(0.0);
        for v in [0.1, 0.7, 1.3, 1.5707] {
            assert!((lookup(&t, 0.0, v) - v).abs() < 1e-3, "{v}: {}", lookup(&t, 0.0, v));
        }
        let u = 300.0;
        let f = lookup(&t, u, std::f64::consts::FRAC_PI_2);
        assert!((f * u - 1.0).abs() < 0.02, "{}", f * u);
    }

    #[test]
    // 1.5707: a sample just inside the table's v range [0, pi/2], not pi/2 itself.
    #[allow(clippy::approx_constant)]
    fn table_matches_direct_integration() {
        // Relative error of the interpolated table against Simpson with 20000 intervals, over
        // the range the scenes use (u = sigma_t D from 0 to ~20) and a forward-scattering g.
        for g in [0.0f32, 0.5, -0.3, 0.9] {
            let t = table(g);
            let mut worst = 0.0f64;
            for u in [0.0, 0.05, 0.3, 1.0, 2.5, 7.0, 20.0, 3000.0] {
                for v in [0.01, 0.2, 0.5, 0.785, 1.1, 1.4, 1.5707] {
                    let exact = f_numeric(u, v, g as f64, 20000);
                    let got = lookup(&t, u, v);
                    let rel = (got - exact).abs() / exact.abs().max(1e-6);
                    worst = worst.max(rel);
                    assert!(rel < 5e-3, "g {g} u {u} v {v}: table {got}, direct {exact}");
                }
            }
            println!("g {g}: worst relative error {worst:.2e}");
        }
    }
}

mod textures {

    use penumbra_scene::Texture;

    use penumbra_passes::textures::*;

    #[test]
    fn layers_resample_and_mip() {
        let t =
            Texture::pattern("checker", penumbra_scene::Pattern::Checker, 64, 2.0, glam::Vec4::ZERO, glam::Vec4::ONE);
        let m = TextureLayers::new(&[t]);
        assert_eq!(m.layer_count(), 1);
        let mips = m.mips(0);
        assert_eq!(mips.len(), 9); // 256 .. 1
                                   // A 2x2 checker of 0 and 1 averages to 0.5 at the last mip.
        let last = mips.last().unwrap()[0];
        assert!((last[0] - 0.5).abs() < 1e-3, "{last:?}");
        // Top-left quadrant is colour a (0), top-right colour b (1).
        assert!(mips[0][(10 * 256 + 10) as usize][0] < 0.01);
        assert!(mips[0][(10 * 256 + 200) as usize][0] > 0.99);
        let empty = TextureLayers::new(&[]);
        assert_eq!(empty.layer_count(), 1);
        assert_eq!(empty.mips(0)[0][0], [1.0; 4]);
    }
}
mod lighting {

    use penumbra_passes::lighting::*;
    use penumbra_scene::Environment;

    /// The cache hands back what was computed, computes once, and recomputes a damaged file.
    #[test]
    fn cached_bytes_round_trip_and_damaged_files_are_recomputed() {
        let kind = format!("test{}", std::process::id());
        let key = 0x1234_5678_9abc_def0u64;
        let path = std::env::temp_dir().join("penumbra-lighting").join(format!("{kind}-{key:016x}.bin"));
        let _ = std::fs::remove_file(&path);
        let mut calls = 0;
        let a = cached_bytes(&kind, key, || {
            calls += 1;
            vec![1, 2, 3, 4, 5]
        });
        let b = cached_bytes(&kind, key, || {
            calls += 1;
            vec![9]
        });
        assert_eq!((a.as_slice(), b.as_slice(), calls), (&[1u8, 2, 3, 4, 5][..], &[1u8, 2, 3, 4, 5][..], 1));
        // truncated: recomputed and rewritten
        let full = std::fs::read(&path).unwrap();
        std::fs::write(&path, &full[..full.len() - 1]).unwrap();
        let c = cached_bytes(&kind, key, || vec![7, 7]);
        assert_eq!(c, vec![7, 7]);
        assert_eq!(cached_bytes(&kind, key, || vec![0]), vec![7, 7]);
        let _ = std::fs::remove_file(&path);
    }

    /// Different maps, parameters or intensities never share a key.
    #[test]
    fn cache_keys_follow_the_map_and_the_parameters() {
        let e = Environment {
            width: 2,
            height: 1,
            texels: vec![[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]],
            intensity: 1.0,
            rotation: 0.0,
        };
        let mut e2 = e.clone();
        e2.texels[1][2] = 0.25;
        let mut e3 = e.clone();
        e3.intensity = 2.0;
        let k = cache_key("lobes", &e, &[16]);
        assert_eq!(k, cache_key("lobes", &e.clone(), &[16]));
        for other in [
            cache_key("lobes", &e2, &[16]),
            cache_key("lobes", &e3, &[16]),
            cache_key("lobes", &e, &[8]),
            cache_key("prefiltered", &e, &[16]),
        ] {
            assert_ne!(k, other);
        }
    }
}

/// An animated environment (`Frame::environment`): what the techniques build once, in the map's
/// frame at intensity 1, and turn and scale per frame gives what building it at that state gives.
mod environment_state {

    use glam::Vec3;
    use penumbra_passes::{env::EnvTables, lighting, shadow_fields};
    use penumbra_scene::{Environment, EnvironmentState};

    /// A small map with a bright off-axis spot (so a turn about +Y moves it) over a dim sky.
    fn spot_map() -> Environment {
        let (w, h) = (64u32, 32u32);
        let texels = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if (x as i32 - 40).abs() < 3 && (y as i32 - 10).abs() < 3 {
                    [40.0, 30.0, 20.0]
                } else {
                    [0.2, 0.3, 0.5]
                }
            })
            .collect();
        Environment { width: w, height: h, texels, intensity: 1.0, rotation: 0.0 }
    }

    const STATE: EnvironmentState = EnvironmentState { rotation: 1.1, intensity: 0.6 };

    #[test]
    fn lobes_turned_and_scaled_per_frame_are_the_lobes_fitted_at_that_state() {
        let e = spot_map();
        let (local, err) = lighting::lighting_lobes_local(Some(&e), 8);
        assert!(err.is_some() && local.len() >= 2);
        let at = lighting::lobes_at(&local, STATE);
        let turned = Environment { rotation: STATE.rotation, intensity: STATE.intensity, ..e.clone() };
        let (direct, _) = lighting::lighting_lobes(Some(&turned), 8);
        assert_eq!(at.len(), direct.len());
        for (a, b) in at.iter().zip(&direct) {
            for c in 0..4 {
                assert!((a[c] - b[c]).abs() <= 1e-5 * (1.0 + b[c].abs()), "{a:?} vs {b:?}");
            }
        }
        // the brightest lobe points at the spot, turned with the map
        let brightest = at.chunks(2).max_by(|a, b| a[1][0].total_cmp(&b[1][0])).unwrap();
        let axis = Vec3::new(brightest[0][0], brightest[0][1], brightest[0][2]);
        let spot = Environment::direction(40.5 / 64.0, 10.5 / 32.0);
        let (s, c) = STATE.rotation.sin_cos();
        let spot_world = Vec3::new(c * spot.x + s * spot.z, spot.y, -s * spot.x + c * spot.z);
        assert!(axis.dot(spot_world) > 0.95, "{axis} vs {spot_world}");
        // a black lobe stands in for one that would not be finite: the count never changes
        let inf = EnvironmentState { rotation: 0.0, intensity: f32::INFINITY };
        let black = lighting::lobes_at(&local, inf);
        assert_eq!(black.len(), local.len());
        assert!(black.chunks(2).all(|p| p[1] == [0.0; 4]));
    }

    #[test]
    fn the_shadow_fields_sh_turned_per_frame_is_the_sh_projected_at_that_state() {
        let e = spot_map();
        let unit = EnvironmentState { rotation: 0.0, intensity: 1.0 };
        let local = shadow_fields::env_light_sh_at(Some(&e), unit);
        let at = shadow_fields::sh_at(&local, STATE);
        let direct = shadow_fields::env_light_sh_at(Some(&e), STATE);
        let norm: f64 = direct.iter().flatten().map(|c| c * c).sum::<f64>().sqrt();
        let diff: f64 =
            at.iter().flatten().zip(direct.iter().flatten()).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
        // the projection is a quadrature over the map's texels, the rotation exact: they agree to
        // the quadrature's error
        assert!(diff < 2e-3 * norm, "{diff} of {norm}");
        assert_eq!(shadow_fields::env_light_sh(Some(&e)), shadow_fields::env_light_sh_at(Some(&e), e.state()));
    }

    #[test]
    fn importance_tables_sample_the_turned_and_scaled_map() {
        let e = spot_map();
        let mut t = EnvTables::new(Some(&e));
        assert!(!t.set_state(e.state()), "the loaded state is the tables' own");
        assert!(t.set_state(STATE));
        let turned = Environment { rotation: STATE.rotation, intensity: STATE.intensity, ..e.clone() };
        for k in 0..64 {
            let u = [(k as f32 + 0.5) / 64.0, ((k * 37) % 64) as f32 / 64.0 + 0.007, 0.5, 0.5];
            let (d, l, pdf) = t.sample(u).unwrap();
            assert!(pdf > 0.0);
            let want = turned.radiance(d);
            assert!((l - want).abs().max_element() <= 1e-4 * (1.0 + want.max_element()), "{d}: {l} vs {want}");
        }
    }
}

mod kdtree {

    use glam::Vec3;

    use penumbra_passes::kdtree::*;
    use penumbra_scene::{Frame, Scene};
    use std::sync::Arc;

    #[test]
    fn world_triangles_drop_degenerates_and_name_bad_input() {
        let scene = Scene::default_scene();
        let frame = scene.at(0.0, None);
        let all = world_triangles(&scene, &frame).unwrap();
        assert!(!all.is_empty());
        let name = |f: &Frame| scene.objects[f.instances[0].object].name.clone();

        // A degenerate (collinear) triangle appended to the first instance's mesh is dropped.
        let mut f = frame.clone();
        let mut m = scene.meshes[f.instances[0].mesh].clone();
        let n = m.positions.len() as u32;
        m.positions.extend([Vec3::ZERO, Vec3::X, Vec3::X * 2.0]);
        m.indices.extend([n, n + 1, n + 2]);
        f.instances[0].deformed_mesh = Some(Arc::new(m.clone()));
        assert_eq!(world_triangles(&scene, &f).unwrap().len(), all.len());

        // An index out of range names the mesh and the object.
        m.indices.extend([0, 1, n + 7]);
        f.instances[0].deformed_mesh = Some(Arc::new(m.clone()));
        let e = world_triangles(&scene, &f).unwrap_err().to_string();
        assert!(e.contains("index out of range") && e.contains(&name(&f)) && e.contains(&m.name), "{e}");

        // Non-finite vertices and transforms are errors naming the object.
        let mut m2 = scene.meshes[frame.instances[0].mesh].clone();
        m2.positions[0] = Vec3::NAN;
        let mut f = frame.clone();
        f.instances[0].deformed_mesh = Some(Arc::new(m2));
        let e = world_triangles(&scene, &f).unwrap_err().to_string();
        assert!(e.contains("non-finite vertices") && e.contains(&name(&f)), "{e}");
        let mut f = frame.clone();
        f.instances[0].world.x_axis.x = f32::NAN;
        let e = world_triangles(&scene, &f).unwrap_err().to_string();
        assert!(e.contains("non-finite world transform") && e.contains(&name(&f)), "{e}");
        let mut f = frame.clone();
        f.instances[0].mesh = 999;
        f.instances[0].deformed_mesh = None;
        let e = world_triangles(&scene, &f).unwrap_err().to_string();
        assert!(e.contains("refers to mesh 999"), "{e}");
    }
}

mod isg_spheres {
    use glam::{Mat4, Vec3};
    use penumbra_passes::isg::*;
    use penumbra_scene::{Material, MeshData, Object, ObjectInfo, Scene};

    /// A box scaled non-uniformly (a pillar: a unit cube scaled by (0.25, 1, 0.25)) gets spheres
    /// fitted to its scaled shape: every world sphere stays near the pillar (with the unit
    /// cube's spheres times the largest axis scale they reached 0.5 from its axis, a blob four
    /// times too wide), while a uniformly scaled box keeps its set in the mesh's frame.
    #[test]
    fn non_uniformly_scaled_objects_get_spheres_of_their_shape() {
        let mut s = Scene::empty("pillar");
        s.meshes.push(MeshData::cube(0.5));
        s.materials.push(Material::diffuse("m", Vec3::splat(0.5)));
        let pillar = Mat4::from_translation(Vec3::new(1.0, 0.5, 0.0)) * Mat4::from_scale(Vec3::new(0.25, 1.0, 0.25));
        s.objects.push(Object { name: "pillar".into(), mesh: 0, material: 0, transform: pillar });
        s.objects.push(Object {
            name: "cube".into(),
            mesh: 0,
            material: 0,
            transform: Mat4::from_scale(Vec3::splat(0.5)),
        });
        s.object_info = vec![ObjectInfo::default(); 2];
        assert_eq!(baked_scale(&s, 0), Vec3::new(0.25, 1.0, 0.25));
        assert_eq!(baked_scale(&s, 1), Vec3::ONE);
        let sets = scene_sphere_sets(&s, 16);
        assert!(sets.iter().all(|x| x.is_some()));
        let frame = s.at(0.0, None);
        let spheres = frame_spheres(&s, &sets, &frame);
        let (mut near_pillar, mut near_cube) = (0, 0);
        for w in &spheres {
            let off = w.center - Vec3::new(1.0, 0.5, 0.0);
            if off.length() < 0.8 {
                near_pillar += 1;
                // within the pillar's half-width (0.125) plus a little, across its axis
                let across = Vec3::new(off.x, 0.0, off.z).length() + w.radius;
                assert!(across < 0.2, "sphere {w:?} reaches {across} from the pillar's axis");
                assert!(off.y.abs() - w.radius < 0.55, "{w:?}");
            } else {
                near_cube += 1;
                assert!(w.center.length() + w.radius < 0.5, "{w:?}");
            }
        }
        assert!(near_pillar > 0 && near_cube > 0, "{near_pillar} {near_cube}");
    }
}

mod hud {
    use penumbra_passes::hud::Overlay;

    #[test]
    fn text_is_drawn_in_the_8x8_font_on_a_box() {
        // 'I' of the font: rows 0x1E, 0x0C x5, 0x1E, 0 (bit x = column x)
        let o = Overlay::text(&["I".to_string()], 1);
        assert_eq!((o.width, o.height), (8 + 4, 9 + 4));
        assert_eq!(o.texels.len(), (o.width * o.height) as usize);
        let (pad, ink) = (2, |x, y| o.ink_at(x, y));
        assert!((1..=4).all(|x| ink(pad + x, pad)) && !ink(pad, pad) && !ink(pad + 5, pad));
        assert!(ink(pad + 2, pad + 3) && ink(pad + 3, pad + 3) && !ink(pad + 1, pad + 3));
        assert!(!ink(pad + 2, pad + 7), "the glyph's last row is empty");
        // the box behind: translucent black, never transparent
        assert!(o.texels.iter().all(|&t| t >> 24 > 0));
        // twice the scale: every ink texel a 2x2 block, the box grows with it
        let big = Overlay::text(&["I".to_string(), "II".to_string()], 2);
        assert_eq!((big.width, big.height), (2 * 16 + 8, 2 * 18 + 8));
        assert!(big.ink_at(4 + 2, 4) && big.ink_at(4 + 3, 5) && !big.ink_at(4 + 1, 4));
        // outside ASCII: a question mark, not a blank or a panic
        let q = Overlay::text(&["é".to_string()], 1);
        assert_eq!(q.texels, Overlay::text(&["?".to_string()], 1).texels);
        assert_eq!(Overlay::text(&[], 1).texels.len(), 16);
    }
}

/// isg's `fit_error`: the fewest lobe counts whose fit of the environment meets the error target.
mod lobe_count_for_an_error {
    use penumbra_passes::lighting::{lighting_lobes_local, lobes_for_error, LOBE_COUNTS};
    use penumbra_scene::Environment;

    #[test]
    fn the_fewest_lobes_within_the_target_are_chosen() {
        // a sky gradient with three bright spots: more lobes fit it better
        let (w, h) = (64u32, 32u32);
        let texels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as i32, (i / w) as i32);
                let spot =
                    [(10, 8), (40, 12), (55, 20)].iter().any(|&(sx, sy)| (x - sx).abs() <= 1 && (y - sy).abs() <= 1);
                if spot {
                    [30.0, 25.0, 20.0]
                } else {
                    let g = 1.0 - y as f32 / h as f32;
                    [0.2 + 0.5 * g, 0.3 + 0.4 * g, 0.6 * g + 0.1]
                }
            })
            .collect();
        let e = Environment { width: w, height: h, texels, intensity: 1.0, rotation: 0.0 };
        let errors: Vec<f64> = LOBE_COUNTS.iter().map(|&k| lighting_lobes_local(Some(&e), k).1.unwrap()).collect();
        // a target between two counts' errors picks the first count that meets it
        for (i, &k) in LOBE_COUNTS.iter().enumerate() {
            let target = errors[i] * 1.0001;
            if errors[..i].iter().any(|&x| x <= target) {
                continue;
            }
            let (chosen, lobes, err) = lobes_for_error(Some(&e), target);
            assert_eq!(chosen, k, "target {target}: errors {errors:?}");
            assert_eq!(err, Some(errors[i]));
            assert_eq!(lobes, lighting_lobes_local(Some(&e), k).0);
        }
        // an unreachable target takes the most lobes; no environment, none
        assert_eq!(lobes_for_error(Some(&e), 0.0).0, *LOBE_COUNTS.last().unwrap());
        assert!(lobes_for_error(None, 0.1).1.is_empty());
        // and the parameter reads it (0: off)
        let mut s = penumbra_passes::isg::IsgSettings::default();
        s.set("fit_error", "0.2").unwrap();
        assert_eq!(s.fit_error, Some(0.2));
        s.set("fit_error", "0").unwrap();
        assert_eq!(s.fit_error, None);
        assert!(s.set("fit_error", "1.5").is_err());
    }
}

/// The avs gather's grid buffer holds two levels over the same points (the coarse one at word 3,
/// cells of `COARSE_CELLS` fine cells): each lists every point's slot once, in the cell holding it.
#[test]
fn avs_grid_words_hold_both_levels() {
    use glam::Vec3;
    use penumbra_math::avs_sampling::Grid;
    let mut pts = Vec::new();
    let mut x = 12345u32;
    let mut rnd = || {
        x = x.wrapping_mul(1664525).wrapping_add(1013904223);
        (x >> 8) as f32 / 16777216.0
    };
    for _ in 0..500 {
        // a dense patch and a sparse floor
        let dense = pts.len() % 2 == 0;
        let s = if dense { 0.5 } else { 8.0 };
        pts.push(Vec3::new(rnd() * s, if dense { rnd() * 0.2 } else { 0.0 }, rnd() * s));
    }
    let slots: Vec<u32> = (0..pts.len() as u32).map(|i| 1000 + i).collect();
    let grid = Grid::new(&pts, 0.05);
    let w = penumbra_passes::avs::grid_words(&grid, &slots);
    let coarse = w[3] as usize;
    assert!(coarse > 16, "no coarse level");
    for (base, edge) in [(0usize, grid.cell), (coarse, grid.cell * penumbra_passes::avs::COARSE_CELLS)] {
        let dims = [w[base], w[base + 1], w[base + 2]];
        let lo = Vec3::new(f32::from_bits(w[base + 4]), f32::from_bits(w[base + 5]), f32::from_bits(w[base + 6]));
        let cell = f32::from_bits(w[base + 7]);
        assert!(cell >= edge * 0.999, "level at {base}: cell {cell} below {edge}");
        let items = w[base + 8] as usize;
        let ncells = (dims[0] * dims[1] * dims[2]) as usize;
        assert_eq!(items, base + 16 + ncells + 1);
        let mut seen = vec![0u32; pts.len()];
        for c in 0..ncells {
            let (s0, s1) = (w[base + 16 + c] as usize, w[base + 17 + c] as usize);
            for &slot in &w[items + s0..items + s1] {
                let i = (slot - 1000) as usize;
                seen[i] += 1;
                let q = ((pts[i] - lo) / cell).floor();
                let cc = [
                    (q.x as i64).clamp(0, dims[0] as i64 - 1) as usize,
                    (q.y as i64).clamp(0, dims[1] as i64 - 1) as usize,
                    (q.z as i64).clamp(0, dims[2] as i64 - 1) as usize,
                ];
                assert_eq!(
                    cc[0] + dims[0] as usize * (cc[1] + dims[1] as usize * cc[2]),
                    c,
                    "point {i} in the wrong cell"
                );
            }
        }
        assert!(seen.iter().all(|&n| n == 1), "level at {base}: points not listed exactly once");
    }
}
