//! Unit tests of the math modules, kept out of the library so that the library is compiled once
//! (at opt-level 3) rather than again as a test harness (26 s of a clean build).

mod dfg {

    use penumbra_math::dfg::*;

    #[test]
    fn dfg_table_is_current() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/dfg/dfg_table.rs");
        let want = rust_source();
        if std::env::var_os("UPDATE_DFG").is_some() {
            std::fs::write(&path, &want).unwrap();
        }
        let got = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(got == want, "{} is not what dfg::rust_source() generates (rerun with UPDATE_DFG=1)", path.display());
        assert_eq!(packed().len(), 768);
    }

    #[test]
    fn no_energy_from_nowhere() {
        // the white lobes' albedo stays below 1; a smooth white mirror at normal incidence
        // reflects (nearly) everything
        for e in DFG_TABLE {
            assert!(e.iter().all(|&x| x >= 0.0) && e[0] + e[1] <= 1.0 + 1e-6 && e[2] <= 1.0 + 1e-6, "{e:?}");
        }
        let (a, b) = ggx_albedo(1e-3, 1.0);
        assert!((a + b - 1.0).abs() < 0.01, "{}", a + b);
    }
}

mod sphereset {
    use glam::DVec3;

    use penumbra_math::sphereset::*;

    /// The row walk visits exactly the voxels the plain test accepts, in the same order, for
    /// centres on and between voxels, radii from zero to past the grid, and balls cut by its faces.
    #[test]
    fn row_walk_visits_exactly_the_voxels_within_the_radius() {
        let dims = [13usize, 9, 11];
        let mut seed = 0x2545f4914f6cdd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut cases =
            vec![(DVec3::new(6.0, 4.0, 5.0), 0.0), (DVec3::new(6.5, 4.5, 5.5), 2.5), (DVec3::new(-3.0, 4.0, 5.0), 4.0)];
        cases.push((DVec3::new(6.0, 4.0, 5.0), 30.0));
        for _ in 0..500 {
            let c = DVec3::new(next() * 19.0 - 3.0, next() * 15.0 - 3.0, next() * 17.0 - 3.0);
            let r = if next() < 0.2 { (next() * 6.0).round() } else { next() * 7.0 };
            cases.push((c, r));
        }
        for (c, r) in cases {
            let mut brute = Vec::new();
            let lo = (c - DVec3::splat(r)).floor().max(DVec3::ZERO);
            let hi = (c + DVec3::splat(r)).ceil();
            for z in lo.z as usize..=(hi.z as usize).min(dims[2] - 1) {
                for y in lo.y as usize..=(hi.y as usize).min(dims[1] - 1) {
                    for x in lo.x as usize..=(hi.x as usize).min(dims[0] - 1) {
                        if DVec3::new(x as f64, y as f64, z as f64).distance_squared(c) <= r * r {
                            brute.push((x, y, z));
                        }
                    }
                }
            }
            let mut walked = Vec::new();
            for_voxels_in_sphere(dims, c, r, |x, y, z| walked.push((x, y, z)));
            assert_eq!(walked, brute, "centre {c}, radius {r}");
        }
    }
}

mod vv_sat {
    use glam::DVec3;
    use penumbra_math::vv_sat::*;
    use std::f64::consts::PI;

    fn sky(w: usize, h: usize, sun: Option<(DVec3, f32)>) -> Vec<[f32; 3]> {
        let mut t = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let d =
                    penumbra_math::envmap::latlong_direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
                let mut c =
                    if d.y > 0.0 { [0.3 + 0.5 * d.y as f32, 0.5 + 0.3 * d.y as f32, 1.0] } else { [0.2, 0.15, 0.1] };
                c[0] += 0.3 * (3.0 * d.x).sin().abs() as f32;
                if let Some((s, k)) = sun {
                    if d.dot(s) > (0.6f64).to_radians().cos() {
                        c = [k, k * 0.9, k * 0.8];
                    }
                }
                t.push(c);
            }
        }
        t
    }

    fn ones(w: usize, h: usize) -> Vec<[f32; 3]> {
        vec![[1.0; 3]; w * h]
    }

    #[test]
    fn constant_map_cap_is_analytic() {
        let (w, h) = (128, 64);
        let sat = Sat::new(w, h, &ones(w, h)).unwrap();
        let t = sat.total();
        assert!((t.0[3].x - 4.0 * PI).abs() < 1e-9, "sphere area {}", t.0[3].x);
        assert!(t.0[0].x.abs() < 1e-9 && t.0[1].x.abs() < 1e-9 && t.0[2].x.abs() < 1e-9);
        for (axis, cr) in [
            (DVec3::new(0.3, 0.8, 0.5), 0.7),
            (DVec3::new(0.1, -0.9, 0.3), 0.2),
            (DVec3::new(0.9, 0.05, -0.4), 0.0),
            (DVec3::Y, 0.5),
            (DVec3::NEG_Y, 0.5),
        ] {
            let axis = axis.normalize();
            let o = IntegrateOptions::default();
            let m = region_moments(&sat, axis, cr, &[], None, &o).moments;
            let area = 2.0 * PI * (1.0 - cr);
            let first = PI * (1.0 - cr * cr);
            // the cap's circle is a polygon of 32 arcs: compare to the inscribed polygon's bound
            assert!((m.0[3].x - area).abs() / area < 0.02, "axis {axis:?} cos {cr}: area {} vs {area}", m.0[3].x);
            assert!((m.dot(axis).x - first).abs() / first < 0.02, "axis {axis:?}: {} vs {first}", m.dot(axis).x);
        }
    }

    /// Loops, their brute-force membership test, and both integrals.
    fn check(
        sat: &Sat,
        w: usize,
        h: usize,
        tex: &[[f32; 3]],
        n: DVec3,
        occ: &[Vec<DVec3>],
        tol: f64,
        what: &str,
    ) -> f64 {
        let o = IntegrateOptions::default();
        let got = visible_moments(sat, n, occ, &o).moments;
        let reference = brute_force(w, h, tex, 6, |d| d.dot(n) >= 0.0 && !occ.iter().any(|l| inside_loop(l, d)));
        let e = rel_error(&got, &reference);
        let irr_g = got.dot(n);
        let irr_r = reference.dot(n);
        let ed = (irr_g - irr_r).length() / irr_r.length().max(1e-12);
        println!("{what}: moments rel. error {e:.2e}, n.moments rel. error {ed:.2e}");
        assert!(ed < tol, "{what}: diffuse integral error {ed} > {tol} (got {irr_g:?}, reference {irr_r:?})");
        ed
    }

    fn polygon(center: DVec3, radius: f64, n: usize, rng: &mut u64) -> Vec<DVec3> {
        let (u, v) = basis(center);
        (0..n)
            .map(|i| {
                let a = 2.0 * PI * i as f64 / n as f64;
                let r = radius * (0.6 + 0.4 * rand01(rng));
                (center + (u * a.cos() + v * a.sin()) * r.tan()).normalize()
            })
            .rev() // counter-clockwise seen from the centre
            .collect()
    }

    fn rand01(s: &mut u64) -> f64 {
        *s ^= *s << 13;
        *s ^= *s >> 7;
        *s ^= *s << 17;
        (*s >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn hemisphere_and_empty_region() {
        let (w, h) = (128, 64);
        let tex = sky(w, h, None);
        let sat = Sat::new(w, h, &tex).unwrap();
        for n in [
            DVec3::Y,
            DVec3::NEG_Y,
            DVec3::new(0.6, 0.3, -0.74).normalize(),
            DVec3::new(-0.2, -0.5, 0.84).normalize(),
            DVec3::X,
        ] {
            check(&sat, w, h, &tex, n, &[], 0.01, &format!("hemisphere {n:?}"));
        }
        // empty region: an occluder covering the whole hemisphere
        let n = DVec3::new(0.3, 0.9, 0.1).normalize();
        let cover = cap_loop(n, -0.05, 64);
        let m = visible_moments(&sat, n, &[cover], &IntegrateOptions::default()).moments;
        let full = visible_moments(&sat, n, &[], &IntegrateOptions::default()).moments;
        assert!(m.dot(n).length() < 1e-3 * full.dot(n).length(), "empty region integral {:?}", m.dot(n));
    }

    #[test]
    fn random_polygons_against_brute_force() {
        let (w, h) = (128, 64);
        let tex = sky(w, h, None);
        let sat = Sat::new(w, h, &tex).unwrap();
        let mut rng = 0x9e3779b97f4a7c15u64;
        let mut worst: f64 = 0.0;
        for k in 0..12 {
            let n =
                DVec3::new(rand01(&mut rng) - 0.5, rand01(&mut rng) * 0.5 + 0.3, rand01(&mut rng) - 0.5).normalize();
            let mut occ = Vec::new();
            for _ in 0..1 + k % 3 {
                let c = (n + DVec3::new(rand01(&mut rng) - 0.5, rand01(&mut rng) - 0.5, rand01(&mut rng) - 0.5) * 1.6)
                    .normalize();
                occ.push(polygon(c, 0.15 + 0.3 * rand01(&mut rng), 5 + (rand01(&mut rng) * 10.0) as usize, &mut rng));
            }
            // disjoint occluders only (the representation's loops do not overlap)
            let overlap = (0..occ.len())
                .any(|i| (0..occ.len()).any(|j| i != j && occ[i].iter().any(|p| inside_loop(&occ[j], *p))));
            if overlap {
                continue;
            }
            worst = worst.max(check(&sat, w, h, &tex, n, &occ, 0.02, &format!("random {k}")));
        }
        println!("random polygons: worst diffuse relative error {worst:.2e}");
    }

    #[test]
    fn seam_and_pole_crossings() {
        let (w, h) = (128, 64);
        let tex = sky(w, h, None);
        let sat = Sat::new(w, h, &tex).unwrap();
        let mut rng = 7u64;
        // an occluder straddling the phi seam (-Z), one over the north pole, one around it
        let seam = polygon(DVec3::new(0.0, 0.5, -1.0).normalize(), 0.4, 9, &mut rng);
        check(&sat, w, h, &tex, DVec3::new(0.0, 0.6, -0.8), std::slice::from_ref(&seam), 0.02, "seam crossing");
        let pole = polygon(DVec3::new(0.05, 1.0, 0.02).normalize(), 0.35, 7, &mut rng);
        check(&sat, w, h, &tex, DVec3::new(0.2, 0.9, 0.3).normalize(), &[pole], 0.02, "over the north pole");
        // a single arc passing exactly over the pole
        let tri = vec![
            DVec3::new(0.3, 0.9, 0.0).normalize(),
            DVec3::new(-0.3, 0.9, 0.0).normalize(),
            DVec3::new(0.0, 0.9, 0.4).normalize(),
        ];
        let tri = if winding_about(&tri, DVec3::new(0.0, 0.95, 0.15).normalize()) > 0 {
            tri
        } else {
            tri.into_iter().rev().collect()
        };
        check(&sat, w, h, &tex, DVec3::Y, &[tri], 0.02, "arc through the pole");
        let south = polygon(DVec3::new(0.1, -1.0, 0.0).normalize(), 0.3, 8, &mut rng);
        check(&sat, w, h, &tex, DVec3::new(0.0, -0.8, 0.6).normalize(), &[south], 0.02, "around the south pole");
        // boundary points behind the tangent plane
        let n = DVec3::new(0.0, 0.2, 1.0).normalize();
        let (un, _) = basis(n);
        let low = polygon((un + n * 0.15).normalize(), 0.5, 10, &mut rng);
        assert!(low.iter().any(|p| p.dot(n) < 0.0) && low.iter().any(|p| p.dot(n) > 0.0));
        check(&sat, w, h, &tex, n, &[low], 0.02, "occluder crossing the tangent plane");
    }

    #[test]
    fn bright_sun_pixels() {
        let (w, h) = (128, 64);
        let sun = DVec3::new(0.35, 0.6, 0.72).normalize();
        let tex = sky(w, h, Some((sun, 1.0e4)));
        let sat = Sat::new(w, h, &tex).unwrap();
        let mut rng = 99u64;
        let n = DVec3::new(0.3, 0.8, 0.5).normalize();
        // occluders fully hiding, half-covering and missing the sun
        let hide = polygon(sun, 0.2, 8, &mut rng);
        let (u, _) = basis(sun);
        let half = polygon((sun + u * 0.12).normalize(), 0.12, 9, &mut rng);
        let miss = polygon((sun - u * 0.5).normalize(), 0.15, 6, &mut rng);
        let e1 = check(&sat, w, h, &tex, n, &[hide], 0.02, "sun hidden");
        let e2 = check(&sat, w, h, &tex, n, &[half], 0.10, "sun half covered");
        let e3 = check(&sat, w, h, &tex, n, &[miss], 0.02, "sun visible");
        println!("sun 1e4: errors {e1:.2e} {e2:.2e} {e3:.2e}");
    }

    #[test]
    fn cap_ratio_limits() {
        let (w, h) = (128, 64);
        let tex = sky(w, h, None);
        let sat = Sat::new(w, h, &tex).unwrap();
        let o = IntegrateOptions::default();
        let n = DVec3::Y;
        let r = DVec3::new(0.3, 0.9, 0.2).normalize();
        let c = phong_cap_cos(100.0);
        let g = cap_ratio(&sat, n, r, c, &[], &o);
        assert!((g - DVec3::ONE).abs().max_element() < 0.02, "unoccluded gamma {g:?}");
        let block = cap_loop(r, c - 0.05, 32);
        let g = cap_ratio(&sat, n, r, c, &[block], &o);
        assert!(g.max_element() < 0.02, "occluded gamma {g:?}");
        // half: an occluder covering one side of the cap
        let (u, _) = basis(r);
        let side = polygon((r + u * 0.3).normalize(), 0.3, 16, &mut 5u64);
        let g = cap_ratio(&sat, n, r, c, std::slice::from_ref(&side), &o);
        let cos_xi = c;
        let reference = {
            let v = |l: DVec3| l.dot(r) >= cos_xi && l.dot(n) >= 0.0;
            let num = brute_force(w, h, &tex, 4, |l| v(l) && !inside_loop(&side, l));
            let den = brute_force(w, h, &tex, 4, |l| l.dot(r) >= cos_xi);
            let f = |m: &Moments| m.dot(r) - m.radiance() * cos_xi;
            f(&num) / f(&den)
        };
        println!("partial gamma {g:?} reference {reference:?}");
        assert!((g - reference).abs().max_element() < 0.03);
    }

    /// A loop with a vertex inside the cap and another arc that dips into the cap between two
    /// outside vertices (clip_to_cap follows the circle between each exit and the next entry,
    /// including the dip's), against brute force.
    #[test]
    fn cap_ratio_with_dipping_arc() {
        let (w, h) = (128, 64);
        let tex = sky(w, h, None);
        let sat = Sat::new(w, h, &tex).unwrap();
        let o = IntegrateOptions::default();
        let r = DVec3::new(0.2, 0.9, -0.3).normalize();
        let n = r;
        let c = phong_cap_cos(16.0);
        let xi = c.acos();
        let (u, v) = basis(r);
        let at = |a: f64, d: f64| (r * d.cos() + (u * a.cos() + v * a.sin()) * d.sin()).normalize();
        // vertex 0 inside; the arc 2 -> 3 passes at 0.7 xi from r with both ends outside
        let w0 = at(PI, 0.7 * xi);
        let t = r.cross(w0).normalize();
        let mut p2 = (w0 * (1.4 * xi).cos() + t * (1.4 * xi).sin()).normalize();
        let mut p3 = (w0 * (1.4 * xi).cos() - t * (1.4 * xi).sin()).normalize();
        // p2 on the side of positive angles about r (simple polygon in angular order)
        if p2.dot(v) < 0.0 {
            std::mem::swap(&mut p2, &mut p3);
        }
        let mut l = vec![at(0.0, 0.5 * xi), at(0.6, 1.6 * xi), p2, p3, at(-0.6, 1.6 * xi)];
        // r is inside the loop (the notch at angle 0 is outside): make the loop positive
        if winding_about(&l, r) < 0 {
            l.reverse();
        }
        let inside = |p: DVec3| p.dot(r) >= c;
        assert!(inside(l[0]) || inside(l[l.len() - 1]) || l.iter().any(|p| inside(*p)));
        let g = cap_ratio(&sat, n, r, c, &[l.clone()], &o);
        let reference = {
            let num = brute_force(w, h, &tex, 4, |d| inside(d) && d.dot(n) >= 0.0 && !inside_loop(&l, d));
            let den = brute_force(w, h, &tex, 4, inside);
            let f = |m: &Moments| m.dot(r) - m.radiance() * c;
            f(&num) / f(&den)
        };
        println!("dipping arc: gamma {g:?} reference {reference:?}");
        assert!(
            reference.max_element() < 0.95 && reference.min_element() > 0.05,
            "the loop should cover part of the cap: {reference:?}"
        );
        assert!((g - reference).abs().max_element() < 0.03, "gamma {g:?} vs brute force {reference:?}");
    }
}

mod ray {
    use glam::DVec3;
    use penumbra_math::ray::*;

    #[test]
    fn hits_inside_edges_and_respects_the_interval() {
        let tri = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let down = DVec3::new(0.0, 0.0, -1.0);
        let o = |x, y| DVec3::new(x, y, 1.0);
        assert_eq!(ray_triangle(o(0.25, 0.25), down, &tri, 10.0, 1e-18), Some(1.0));
        assert_eq!(ray_triangle(o(0.5, 0.5), down, &tri, 10.0, 1e-18), Some(1.0)); // on the hypotenuse
        assert_eq!(ray_triangle(o(0.6, 0.6), down, &tri, 10.0, 1e-18), None);
        assert_eq!(ray_triangle(o(0.25, 0.25), down, &tri, 1.0, 1e-18), None); // t = tmax excluded
        assert_eq!(ray_triangle(o(0.25, 0.25), -down, &tri, 10.0, 1e-18), None); // behind
        assert_eq!(ray_triangle(o(0.25, 0.25), DVec3::X, &tri, 10.0, 1e-18), None); // parallel
        let flat = [DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
        assert_eq!(ray_triangle(o(0.5, 0.0), down, &flat, 10.0, 1e-18), None); // degenerate
    }
}

mod special {

    use penumbra_math::special::*;
    #[test]
    fn erf_reference_values() {
        // Reference values (Abramowitz & Stegun table 7.1 / high-precision tables).
        let cases = [
            (0.0, 0.0),
            (0.1, 0.112_462_916_018_284_9),
            (0.5, 0.520_499_877_813_046_5),
            (1.0, 0.842_700_792_949_714_9),
            (2.0, 0.995_322_265_018_952_7),
            (2.9, 0.999_958_902_121_900_5),
            (3.5, 0.999_999_256_901_627_7),
        ];
        for (x, e) in cases {
            assert!((erf(x) - e).abs() < 2e-15, "erf({x}) = {} vs {e}", erf(x));
            assert!((erf(-x) + e).abs() < 2e-15);
        }
        // erfc(5) = 1.5374597944280348e-12 (tiny: must be accurate in relative terms).
        assert!((erfc(5.0) / 1.537_459_794_428_035_1e-12 - 1.0).abs() < 1e-12);
        // continuity at the switch point
        assert!((erf(3.0 - 1e-12) - erf(3.0 + 1e-12)).abs() < 1e-14);
    }
}

mod quad {
    use glam::DVec3;
    use penumbra_math::quad::*;
    use std::f64::consts::PI;
    #[test]
    fn kronrod_exact_for_degree_22() {
        let v = integrate_adaptive(|x| x.powi(22) + x.powi(21), -1.0, 1.0, &[], 0.0, 0.0, 1);
        assert!((v - 2.0 / 23.0).abs() < 1e-15, "{v}");
    }
    #[test]
    fn gauss_legendre_exact() {
        for n in [1usize, 2, 5, 8, 17] {
            let (x, w) = gauss_legendre(n);
            let d = 2 * n - 2;
            let v: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(d as i32)).sum();
            assert!((v - 2.0 / (d as f64 + 1.0)).abs() < 1e-14, "n={n}: {v}");
        }
    }
    #[test]
    fn sphere_area_and_hemisphere() {
        let a = integrate_sphere_about(DVec3::new(0.3, 0.4, 0.5), None, 1e-12, |_| 1.0);
        assert!((a - 4.0 * PI).abs() < 1e-11, "{a}");
        let n = DVec3::new(0.0, 1.0, 0.0);
        let h = integrate_sphere_about(DVec3::new(0.3, 0.4, 0.5), Some(n), 1e-12, |_| 1.0);
        assert!((h - 2.0 * PI).abs() < 1e-10, "{h}");
        // integral of cos over the hemisphere = pi
        let c = integrate_sphere_about(DVec3::new(0.3, -0.4, 0.5), Some(n), 1e-12, |w| w.dot(n));
        assert!((c - PI).abs() < 1e-10, "{c}");
    }
}

mod avs_sampling {
    use glam::Vec3;
    use penumbra_math::avs_maps::VisMap;
    use penumbra_math::avs_sampling::*;

    fn plane(nx: usize, nz: usize) -> Vec<SurfacePoint> {
        let mut v = Vec::new();
        for z in 0..nz {
            for x in 0..nx {
                v.push(SurfacePoint { pos: Vec3::new(x as f32, 0.0, z as f32), normal: Vec3::Y });
            }
        }
        v
    }

    #[test]
    fn eg_metric() {
        let a = e_g(0.3, 0.5, Vec3::ZERO, Vec3::Y, Vec3::new(2.0, 0.0, 0.0), Vec3::Y);
        assert!((a - 0.3).abs() < 1e-6);
        // opposite normals add 2
        let b = e_g(0.3, 0.5, Vec3::ZERO, Vec3::Y, Vec3::ZERO, -Vec3::Y);
        assert!((b - 2.0).abs() < 1e-6);
        // perpendicular: sqrt(2)
        let c = e_g(0.0, 1.0, Vec3::ZERO, Vec3::Y, Vec3::ONE, Vec3::X);
        assert!((c - 2f32.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn kmeans_spreads_points_and_separates_normals() {
        // a 20x20 plane: 16 clusters are spread (every quadrant gets some)
        let p = plane(20, 20);
        let s = kmeans_eg(&p, 16, 0.3, 8, &mut |_, _| {});
        assert!(s.len() >= 12 && s.len() <= 16, "{}", s.len());
        for q in 0..4 {
            let (qx, qz) = (q % 2, q / 2);
            let n = s
                .iter()
                .filter(|&&i| (p[i].pos.x >= 10.0) as usize == qx && (p[i].pos.z >= 10.0) as usize == qz)
                .count();
            assert!(n >= 2, "quadrant {q} has {n} points");
        }
        // two coincident sheets with opposite normals never share a cluster representative side:
        // both sides get sample points
        let mut two = plane(10, 10);
        two.extend(plane(10, 10).into_iter().map(|v| SurfacePoint { pos: v.pos, normal: -Vec3::Y }));
        let s = kmeans_eg(&two, 8, 0.3, 8, &mut |_, _| {});
        let up = s.iter().filter(|&&i| two[i].normal.y > 0.0).count();
        assert!(up >= 2 && s.len() - up >= 2, "up {up} of {}", s.len());
        // extremes: k >= n, empty
        assert_eq!(kmeans_eg(&two[..3], 5, 0.3, 3, &mut |_, _| {}), vec![0, 1, 2]);
        assert!(kmeans_eg(&[], 5, 0.3, 3, &mut |_, _| {}).is_empty());
    }

    #[test]
    fn grid_queries_match_brute_force() {
        let pts: Vec<Vec3> = (0..500)
            .map(|i| {
                let f = i as f32;
                Vec3::new((f * 0.37).sin() * 3.0, (f * 0.11).cos(), (f * 0.73).sin() * 2.0)
            })
            .collect();
        let g = Grid::new(&pts, 0.0);
        for q in [Vec3::ZERO, Vec3::new(2.9, 1.0, -1.9), Vec3::new(10.0, 10.0, 10.0)] {
            let mut a = g.range(q, 0.7);
            a.sort();
            let b: Vec<usize> = (0..pts.len()).filter(|&i| (pts[i] - q).length() <= 0.7).collect();
            assert_eq!(a, b);
            let n = g.nearest(q).unwrap();
            let bn = (0..pts.len()).min_by(|&x, &y| (pts[x] - q).length().total_cmp(&(pts[y] - q).length())).unwrap();
            assert!(((pts[n] - q).length() - (pts[bn] - q).length()).abs() < 1e-6);
        }
    }

    /// `PointTree::nearest` is the brute-force nearest point, the lowest index among equally
    /// near ones: on scattered points, on a regular grid (exact ties at cell centres and
    /// midpoints), with duplicated points, far outside every point, and empty.
    #[test]
    fn point_tree_nearest_is_the_brute_force_nearest_with_ties_to_the_lowest_index() {
        let brute = |pts: &[Vec3], q: Vec3| -> Option<usize> {
            (0..pts.len()).min_by(|&x, &y| {
                (pts[x] - q).length_squared().total_cmp(&(pts[y] - q).length_squared()).then(x.cmp(&y))
            })
        };
        let scattered: Vec<Vec3> = (0..700)
            .map(|i| {
                let f = i as f32;
                Vec3::new((f * 0.37).sin() * 3.0, (f * 0.11).cos(), (f * 0.73).sin() * 2.0)
            })
            .collect();
        let mut lattice: Vec<Vec3> = Vec::new();
        for x in 0..12 {
            for z in 0..9 {
                lattice.push(Vec3::new(x as f32 * 0.5, 0.0, z as f32 * 0.5));
            }
        }
        // duplicates: the same positions again, at higher indices
        let dup: Vec<Vec3> = lattice.iter().chain(lattice.iter()).copied().collect();
        let mut queries: Vec<Vec3> = (0..400)
            .map(|i| {
                let f = i as f32;
                Vec3::new((f * 1.3).sin() * 4.0, (f * 0.7).cos() * 0.6, (f * 0.9).sin() * 3.0)
            })
            .collect();
        // cell centres and edge midpoints of the lattice: two or four points equally near
        for x in 0..11 {
            for z in 0..8 {
                queries.push(Vec3::new(x as f32 * 0.5 + 0.25, 0.0, z as f32 * 0.5 + 0.25));
                queries.push(Vec3::new(x as f32 * 0.5 + 0.25, 0.1, z as f32 * 0.5));
            }
        }
        queries.extend([Vec3::splat(100.0), Vec3::new(-50.0, 3.0, 7.0)]);
        for pts in [&scattered, &lattice, &dup] {
            let t = PointTree::new(pts);
            for &q in &queries {
                assert_eq!(t.nearest(q), brute(pts, q), "query {q}");
            }
        }
        assert_eq!(PointTree::new(&[]).nearest(Vec3::ZERO), None);
        assert_eq!(PointTree::new(&[Vec3::ONE]).nearest(Vec3::ZERO), Some(0));
    }

    /// `visit_ring` visits exactly the points of the cells at Chebyshev distance `ring` from the
    /// query's cell (each once), at the grid's corners and edges too, and says when the ring
    /// lies wholly outside.
    #[test]
    fn grid_rings_visit_exactly_their_cells() {
        let pts: Vec<Vec3> = (0..800)
            .map(|i| {
                let f = i as f32;
                Vec3::new((f * 0.37).sin() * 3.0, (f * 0.11).cos() * 2.0, (f * 0.73).sin() * 2.0)
            })
            .collect();
        let g = Grid::new(&pts, 0.35);
        for q in [Vec3::ZERO, Vec3::new(2.9, 1.9, -1.9), Vec3::new(-3.0, -2.0, 2.0), Vec3::new(30.0, 0.0, 0.0)] {
            let c = g.cell_of(q);
            for ring in 0..=(g.dims.iter().max().copied().unwrap() as i32 + 1) {
                let mut seen = Vec::new();
                let inside = g.visit_ring(q, ring, |i, d2| {
                    assert!(((pts[i] - q).length_squared() - d2).abs() < 1e-4);
                    seen.push(i);
                });
                seen.sort();
                let mut expected: Vec<usize> = (0..pts.len())
                    .filter(|&i| {
                        let p = g.cell_of(pts[i]);
                        (0..3).map(|a| (p[a] - c[a]).abs()).max().unwrap() == ring
                    })
                    .collect();
                expected.sort();
                assert_eq!(seen, expected, "q {q:?}, ring {ring}");
                let any_cell = (0..3).any(|a| c[a] - ring >= 0 || c[a] + ring < g.dims[a] as i32);
                assert_eq!(inside, any_cell, "q {q:?}, ring {ring}");
            }
        }
    }

    #[test]
    fn sh_projection_of_full_and_empty_maps() {
        let f = point_frame(Vec3::Y);
        let full = sh16_project(&VisMap::filled(32, true), &f);
        // hemisphere around +y: c0 = 2 pi Y00, the y-linear coefficient (index 1, -0.4886 y) = -pi * 0.4886
        assert!((full[0] - 2.0 * std::f32::consts::PI * 0.282095).abs() < 1e-3, "{}", full[0]);
        assert!((full[1] + std::f32::consts::PI * 0.488603).abs() < 2e-3, "{}", full[1]);
        let empty = sh16_project(&VisMap::filled(32, false), &f);
        assert!(empty.iter().all(|c| *c == 0.0));
        assert!(e_v(&full, &empty) > 1.0);
    }

    #[test]
    fn weights_are_inverse_eg() {
        let w = eq8_weights(0.3, 1.0, Vec3::ZERO, Vec3::Y, &[(Vec3::X, Vec3::Y), (Vec3::X * 2.0, Vec3::Y)]);
        assert!((w[0] + w[1] - 1.0).abs() < 1e-6);
        assert!((w[0] / w[1] - 2.0).abs() < 1e-4);
        // a coincident neighbour dominates but stays finite
        let w = eq8_weights(0.3, 1.0, Vec3::ZERO, Vec3::Y, &[(Vec3::ZERO, Vec3::Y), (Vec3::X, Vec3::Y)]);
        assert!(w.iter().all(|x| x.is_finite()) && w[0] > 0.99);
    }

    #[test]
    fn adaptation_inserts_at_a_shadow_edge_and_erases_in_flat_regions() {
        // 1D row of points on a plane; the left half is occluded (SH of an empty map), the right
        // free: points at the edge have large relative errors and get new points between them;
        // interior points are interpolated exactly and become erase candidates, never two
        // neighbours at once.
        let pool = plane(41, 1);
        let pool_tree = PointTree::new(&pool.iter().map(|p| p.pos).collect::<Vec<_>>());
        let idx: Vec<usize> = (0..41).step_by(4).collect();
        let pts: Vec<SurfacePoint> = idx.iter().map(|&i| pool[i]).collect();
        let f = point_frame(Vec3::Y);
        let full = sh16_project(&VisMap::filled(16, true), &f);
        let half = {
            let mut h = full;
            for c in h.iter_mut() {
                *c *= 0.2;
            }
            h
        };
        let sh: Vec<[f32; SH_COUNT]> = pts.iter().map(|p| if p.pos.x < 20.0 { half } else { full }).collect();
        let params = AdaptParams { alpha: 0.3, radius: 4.5, e_max: 0.10, e_min: 0.05 };
        let open = vec![1.0; pts.len()];
        let st = adapt_step(&pts, &idx, &sh, &open, &pool, &pool_tree, &params);
        // the edge lies between x = 16 and x = 20: a point at x = 18 is inserted
        assert!(st.insert.contains(&18), "{:?}", st.insert);
        assert!(st.insert.iter().all(|&v| !idx.contains(&v)));
        assert!(!st.erase.is_empty());
        for w in st.erase.windows(2) {
            assert!(w[1] > w[0] + 1, "adjacent points erased together: {:?}", st.erase);
        }
        // points next to the edge are not erased
        assert!(!st.erase.contains(&4) && !st.erase.contains(&5), "{:?}", st.erase);
        // a lone point (no neighbours) has no error and is kept
        let st = adapt_step(&pts[..1], &idx[..1], &sh[..1], &open[..1], &pool, &pool_tree, &params);
        assert_eq!(st.rel_error, vec![None]);
        assert!(st.insert.is_empty() && st.erase.is_empty());
        // a buried point (all occluded: zero SH, zero visible solid angle) has no error and is
        // no neighbour: nothing is inserted towards it (pool vertices 2 and 6, the midpoints to
        // its neighbours), where the same zero map taken as seen draws insertions
        let mut sh_b = sh.clone();
        sh_b[1] = [0.0; SH_COUNT];
        let mut vis_b = open.clone();
        vis_b[1] = 0.0;
        let st = adapt_step(&pts, &idx, &sh_b, &vis_b, &pool, &pool_tree, &params);
        assert_eq!(st.rel_error[1], None);
        assert!(!st.insert.contains(&2) && !st.insert.contains(&6), "{:?}", st.insert);
        let st = adapt_step(&pts, &idx, &sh_b, &open, &pool, &pool_tree, &params);
        assert!(st.insert.contains(&2) || st.insert.contains(&6), "{:?}", st.insert);
        let st = adapt_step(&pts[..1], &idx[..1], &sh[..1], &open[..1], &pool, &pool_tree, &params);
        assert_eq!(st.rel_error, vec![None]);
        assert!(st.insert.is_empty() && st.erase.is_empty());
    }
}

mod nnls {

    use penumbra_math::nnls::*;

    fn gram(a: &[Vec<f64>], y: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let n = a[0].len();
        let mut q = vec![0.0; n * n];
        let mut b = vec![0.0; n];
        for (row, yi) in a.iter().zip(y) {
            for i in 0..n {
                b[i] += row[i] * yi;
                for j in 0..n {
                    q[i * n + j] += row[i] * row[j];
                }
            }
        }
        (q, b)
    }

    #[test]
    fn unconstrained_solution_when_positive() {
        let a = vec![vec![1.0, 0.0], vec![0.0, 2.0], vec![1.0, 1.0]];
        let x_true = [0.5, 1.5];
        let y: Vec<f64> = a.iter().map(|r| r[0] * x_true[0] + r[1] * x_true[1]).collect();
        let (q, b) = gram(&a, &y);
        let x = nnls_gram(&q, &b);
        assert!((x[0] - 0.5).abs() < 1e-10 && (x[1] - 1.5).abs() < 1e-10, "{x:?}");
    }

    #[test]
    fn kkt_conditions_hold() {
        // y pulls the second coefficient negative: the solution must clamp it and satisfy KKT
        let a = vec![vec![1.0, 1.0, 0.0], vec![1.0, 0.9, 0.1], vec![0.0, 1.0, 1.0], vec![0.5, 0.0, 1.0]];
        let y = [1.0, 1.2, -2.0, 0.3];
        let (q, b) = gram(&a, &y);
        let x = nnls_gram(&q, &b);
        let n = 3;
        for i in 0..n {
            let g: f64 = b[i] - (0..n).map(|j| q[i * n + j] * x[j]).sum::<f64>();
            assert!(x[i] >= 0.0);
            if x[i] > 0.0 {
                assert!(g.abs() < 1e-9, "gradient {g} at free variable {i}");
            } else {
                assert!(g <= 1e-9, "positive gradient {g} at clamped variable {i}");
            }
        }
        // duplicate columns are handled (singular Gram)
        let a2: Vec<Vec<f64>> = a.iter().map(|r| vec![r[0], r[0], r[1]]).collect();
        let (q2, b2) = gram(&a2, &y);
        let x2 = nnls_gram(&q2, &b2);
        assert!(x2.iter().all(|v| v.is_finite() && *v >= 0.0));
    }
}

mod avs_maps {
    use glam::DVec3;
    use penumbra_math::avs_maps::*;
    use std::f64::consts::PI;

    #[test]
    fn resolution_checks() {
        for r in [8, 16, 64, 128, 256] {
            assert!(check_res(r).is_ok());
        }
        for r in [0, 4, 12, 100, 264, 512] {
            let e = check_res(r).unwrap_err();
            assert!(e.contains(&r.to_string()), "{e}");
        }
        assert_eq!(words_per_map(128) * 4, 2048);
        assert_eq!(ssdf_words_per_map(128) * 4, 32768);
    }

    #[test]
    fn texel_round_trip_and_hemisphere() {
        for r in [8, 64, 256] {
            for i in 0..r {
                for j in 0..r {
                    let w = texel_dir(i, j, r);
                    assert!((w.length() - 1.0).abs() < 1e-12);
                    assert!(w.z > 0.0, "texel ({i},{j}) of r={r} below the horizon");
                    assert_eq!(dir_to_texel(w, r), Some((i, j)));
                    let (t, p) = local_to_angles(w).unwrap();
                    assert!((t - texel_theta(i, r)).abs() < 1e-9 && (p - texel_phi(j, r)).abs() < 1e-9);
                    let wf = texel_dir_f32(i, j, r);
                    assert!((wf.as_dvec3() - w).length() < 1e-6);
                }
            }
        }
        // the normal is the map centre
        assert_eq!(dir_to_texel(DVec3::Z, 128), Some((64, 64)));
    }

    #[test]
    fn poles_seam_and_horizon() {
        let r = 64;
        // poles: tangent axis +x is row 0, -x is row r-1 (any column)
        assert_eq!(dir_to_texel(DVec3::X, r).unwrap().0, 0);
        assert_eq!(dir_to_texel(-DVec3::X, r).unwrap().0, r - 1);
        // horizon halves: +y is phi = 0 (column 0), -y is phi = pi (column r-1)
        assert_eq!(dir_to_texel(DVec3::Y, r), Some((r / 2, 0)));
        assert_eq!(dir_to_texel(-DVec3::Y, r), Some((r / 2, r - 1)));
        // below the horizon: none
        assert_eq!(dir_to_texel(DVec3::new(0.0, 0.6, -0.8), r), None);
        // the two seam columns are far apart except near the poles
        let d_mid = angle_between(texel_dir(r / 2, 0, r), texel_dir(r / 2, r - 1, r));
        assert!(d_mid > PI - 2.0 * texel_angle(r));
        let d_pole = angle_between(texel_dir(0, 0, r), texel_dir(0, r - 1, r));
        assert!(d_pole < 2.0 * texel_angle(r), "{d_pole}");
        // nearby directions just across a texel edge map to adjacent texels
        let h = texel_angle(r);
        let a = angles_to_local(10.0 * h - 1e-9, 20.0 * h + 1e-9);
        let b = angles_to_local(10.0 * h + 1e-9, 20.0 * h - 1e-9);
        assert_eq!(dir_to_texel(a, r), Some((9, 20)));
        assert_eq!(dir_to_texel(b, r), Some((10, 19)));
    }

    #[test]
    fn solid_angles_sum_to_hemisphere() {
        for r in [8, 128, 256] {
            let s: f64 = (0..r).map(|i| texel_solid_angle(i, r) * r as f64).sum();
            assert!((s - 2.0 * PI).abs() < 1e-12, "{s}");
            // matches the closed form (cos a - cos b) h
            let h = PI / r as f64;
            for i in [0, r / 3, r - 1] {
                let direct = ((i as f64 * h).cos() - ((i + 1) as f64 * h).cos()) * h;
                assert!((direct - texel_solid_angle(i, r)).abs() < 1e-15);
            }
        }
        // a cosine-weighted sum over texels integrates cos to pi
        let r = 128;
        let mut s = 0.0;
        for i in 0..r {
            for j in 0..r {
                s += texel_dir(i, j, r).z * texel_solid_angle(i, r);
            }
        }
        assert!((s - PI).abs() < 1e-3, "{s}");
    }

    #[test]
    fn distances_agree() {
        let r = 128;
        for (i1, j1, i2, j2) in [(0, 0, 0, 127), (3, 5, 100, 7), (64, 64, 64, 65), (127, 0, 0, 0), (10, 10, 10, 10)] {
            let a = angular_distance(texel_theta(i1, r), texel_phi(j1, r), texel_theta(i2, r), texel_phi(j2, r));
            let b = angle_between(texel_dir(i1, j1, r), texel_dir(i2, j2, r));
            assert!((a - b).abs() < 1e-12, "{a} {b}");
        }
    }

    #[test]
    fn frames_are_orthonormal_right_handed() {
        let ns = [DVec3::Z, -DVec3::Z, DVec3::X, DVec3::new(0.3, -0.4, 0.1), DVec3::new(1e-9, 0.0, -1.0)];
        for n in ns {
            for f in [Frame::from_normal(n), Frame::from_normal_hint(n, DVec3::Y), Frame::from_normal_hint(n, n)] {
                let nn = n.normalize();
                assert!((f.n - nn).length() < 1e-12);
                assert!(f.t.dot(f.n).abs() < 1e-12 && f.b.dot(f.n).abs() < 1e-12 && f.t.dot(f.b).abs() < 1e-12);
                assert!((f.t.length() - 1.0).abs() < 1e-12 && (f.b.length() - 1.0).abs() < 1e-12);
                assert!((f.n.cross(f.t) - f.b).length() < 1e-12);
                let w = DVec3::new(0.2, -0.5, 0.7).normalize();
                assert!((f.to_world(f.to_local(w)) - w).length() < 1e-12);
                // the normal is the map centre
                assert!((f.to_world(angles_to_local(PI / 2.0, PI / 2.0)) - nn).length() < 1e-12);
            }
        }
    }

    #[test]
    fn bit_packing() {
        let r = 16;
        let m = VisMap::from_fn(r, |i, j| (i * 7 + j * 3) % 5 == 0);
        for i in 0..r {
            for j in 0..r {
                let k = (i * r + j) as usize;
                assert_eq!(m.get(i, j), (m.bits[k / 32] >> (k % 32)) & 1 == 1);
                assert_eq!(m.get(i, j), (i * 7 + j * 3) % 5 == 0);
            }
        }
        // texel (0, 1) is bit 1 of word 0, texel (2, 0) of r=16 is bit 0 of word 1
        let mut z = VisMap::filled(r, false);
        z.set(0, 1, true);
        z.set(2, 0, true);
        assert_eq!(z.bits[0], 2);
        assert_eq!(z.bits[1], 1);
        assert_eq!(VisMap::filled(r, true).count_visible(), r * r);
        assert!((VisMap::filled(128, true).visible_solid_angle() - 2.0 * PI).abs() < 1e-10);
    }

    #[test]
    fn half_conversion_matches_ieee() {
        for (x, h) in [
            (0.0f32, 0u16),
            (1.0, 0x3c00),
            (-2.0, 0xc000),
            (65504.0, 0x7bff),
            (1e6, 0x7c00),
            (6.1035156e-5, 0x0400),
            (5.9604645e-8, 0x0001),
            (std::f32::consts::PI, 0x4248),
        ] {
            assert_eq!(f32_to_f16(x), h, "{x}");
            if h != 0x7c00 && h != 0x4248 {
                assert_eq!(f16_to_f32(h), x);
            }
        }
        // round trip of every finite half
        for h in 0..0x7c00u16 {
            assert_eq!(f32_to_f16(f16_to_f32(h)), h);
            assert_eq!(f32_to_f16(-f16_to_f32(h)), h | 0x8000);
        }
        // round to nearest even at a tie: 1 + 2^-11 lies between 1 and 1 + 2^-10
        assert_eq!(f32_to_f16(1.0 + 2f32.powi(-11)), 0x3c00);
        assert_eq!(f32_to_f16(1.0 + 3.0 * 2f32.powi(-11)), 0x3c02);
        let v = [0.5f32, -1.25, 3.0];
        let p = pack_ssdf_f16(&v);
        assert_eq!(p.len(), 2);
        assert_eq!(&unpack_ssdf_f16(&p)[..3], &v);
    }
}

mod hsdt {
    use penumbra_math::avs_maps::{texel_angle, texel_theta};
    use penumbra_math::avs_maps::{VisMap, NO_BOUNDARY};
    use penumbra_math::hsdt::*;

    #[test]
    fn latitude_scan_nearest_in_row() {
        let r = 16;
        let m = VisMap::from_fn(r, |i, j| !(i == 2 && (j == 3 || j == 10)));
        let mut out = vec![0u16; r as usize];
        latitude_scan(&m, 2, false, &mut out);
        let expect: Vec<u16> = (0..16).map(|j| if j <= 6 { 3 } else { 10 }).collect();
        assert_eq!(out, expect);
        latitude_scan(&m, 0, false, &mut out);
        assert!(out.iter().all(|&g| g == NONE));
    }

    /// The GPU's phase 1 (bits scanned a word at a time) gives the latitude scans' answer, also
    /// where rows straddle words (r = 8, 24, 40).
    #[test]
    fn nearest_in_row_matches_latitude_scan() {
        for r in [8, 24, 40] {
            for (name, m) in test_maps(r, 3 + r as u64) {
                for feature in [false, true] {
                    let mut out = vec![0u16; r as usize];
                    for i in 0..r {
                        latitude_scan(&m, i, feature, &mut out);
                        for j in 0..r {
                            assert_eq!(
                                nearest_in_row(&m, i, j, feature),
                                out[j as usize],
                                "r={r} {name} ({i}, {j}) {feature}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// The closed-form separator the GPU uses against bisection on the haversine comparison: where
    /// they differ, the two candidates' distances at the rows between agree to rounding.
    #[test]
    fn closed_form_separator_matches_bisection() {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move |n: u32| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as u32
        };
        let (mut differ, mut total) = (0, 0);
        for r in [8u32, 64, 256] {
            let tab = SinTables::new(r);
            for _ in 0..20000 {
                let (j, s, u) = (next(r), next(r), next(r));
                if s >= u {
                    continue;
                }
                // nearest-feature columns: often the query column itself, else anywhere
                let (gs, gu) = (if next(3) == 0 { j } else { next(r) }, if next(3) == 0 { j } else { next(r) });
                let pred = |i: u32| tab.hav(i, j, u, gu) <= tab.hav(i, j, s, gs);
                let bisect = (0..r).find(|&i| pred(i)).unwrap_or(r);
                let closed =
                    closed_form_separator(r, s, haversine_weight(r, j, s, gs), u, haversine_weight(r, j, u, gu));
                total += 1;
                if closed != bisect {
                    differ += 1;
                    for i in closed.min(bisect)..closed.max(bisect) {
                        let (a, b) = (tab.hav(i, j, u, gu), tab.hav(i, j, s, gs));
                        assert!((a - b).abs() <= 1e-12 * a.max(b), "r={r} j={j} s=({s},{gs}) u=({u},{gu}): closed {closed}, bisection {bisect}, row {i}: {a} vs {b}");
                    }
                }
            }
        }
        println!("{differ} of {total} separators differ from bisection (ties)");
        assert!(total > 20000 && differ * 100 < total, "{differ} of {total} differ");
    }

    #[test]
    fn hsdt_matches_brute_force_on_random_and_adversarial_maps() {
        for r in [16, 32] {
            for (name, m) in test_maps(r, 1 + r as u64) {
                let bf = ssdf_brute_force(&m);
                let h = hsdt_f64(&m);
                let (mx, mean) = field_error(&h, &bf);
                assert!(mx < 1e-12, "r={r} {name}: max error {mx} rad (mean {mean})");
                for (k, (&a, &b)) in h.iter().zip(&bf).enumerate() {
                    assert_eq!(a > 0.0, b > 0.0, "r={r} {name} texel {k}: sign");
                    assert_eq!(a > 0.0, m.get(k as u32 / r, k as u32 % r), "sign vs visibility");
                }
            }
        }
    }

    #[test]
    fn hsdt_at_64_against_brute_force() {
        let r = 64;
        let maps = test_maps(r, 99);
        for (name, m) in
            maps.iter().filter(|(n, _)| n.starts_with("random") || n.contains("pole") || n.contains("seam"))
        {
            let (mx, _) = field_error(&hsdt_f64(m), &ssdf_brute_force(m));
            assert!(mx < 1e-12, "{name}: {mx}");
        }
    }

    #[test]
    fn known_values() {
        let r = 32;
        let h = texel_angle(r);
        // an isolated occluded texel in the middle of the map: its neighbours are one texel away
        // in phi (distance h sin(theta)) or theta (h); it is -(nearest visible)
        let (ci, cj) = (r / 2, r / 2);
        let m = VisMap::from_fn(r, |i, j| !(i == ci && j == cj));
        let d = hsdt_f64(&m);
        let at = |i: u32, j: u32| d[(i * r + j) as usize];
        let dphi = 2.0 * (texel_theta(ci, r).sin() * (0.5 * h).sin()).asin();
        assert!((at(ci, cj) + dphi.min(h)).abs() < 1e-12, "{}", at(ci, cj));
        assert!((at(ci + 1, cj) - h).abs() < 1e-12);
        // the two seam columns are far apart: an occluded texel at (equator, phi = pi) is ~pi away
        // from (equator, phi = 0), no wrap-around
        let m = VisMap::from_fn(r, |i, j| !(i == r / 2 && j == r - 1));
        let d = hsdt_f64(&m);
        let eq = (r / 2) as usize * r as usize;
        assert!(d[eq] > std::f64::consts::PI - 2.0 * h, "{}", d[eq]);
        // all visible / occluded
        assert!(hsdt_f64(&VisMap::filled(r, true)).iter().all(|&v| v == NO_BOUNDARY));
        assert!(hsdt_f64(&VisMap::filled(r, false)).iter().all(|&v| v == -NO_BOUNDARY));
    }
}

mod ssdf_integrate {
    use glam::DVec3;
    use penumbra_math::avs_maps::texel_dir;
    use penumbra_math::avs_maps::VisMap;
    use penumbra_math::hsdt::hsdt;
    use penumbra_math::sg::Sg;
    use penumbra_math::ssdf_integrate::*;
    use std::f64::consts::PI;

    fn lobe(axis: DVec3, lambda: f64) -> Sg {
        Sg::new(axis.normalize(), lambda, 1.0)
    }

    #[test]
    fn t_limits() {
        for lambda in [1e-2, 1.0, 30.0, 1e4] {
            assert!((t_exact(lambda, 0.0) - 0.5).abs() < 1e-9, "{lambda}");
            assert_eq!(t_exact(lambda, PI), 1.0);
            assert_eq!(t_exact(lambda, -PI), 0.0);
            for d in [0.001, 0.05, 0.5, 2.0, 3.0] {
                let a = t_exact(lambda, d);
                assert!((a + t_exact(lambda, -d) - 1.0).abs() < 1e-9);
                assert!((0.5..=1.0).contains(&a));
            }
        }
        // uniform measure: (1 + sin(d/2)) / 2
        for d in [-2.5f64, -0.3, 0.7, 2.9] {
            let want = 0.5 * (1.0 + (0.5 * d).sin());
            assert!((t_exact(1e-7, d) - want).abs() < 1e-5, "{d}: {} vs {want}", t_exact(1e-7, d));
        }
        // sharp lobe, locally straight edge: normal CDF of d sqrt(lambda)
        let phi = |x: f64| 0.5 * (1.0 + penumbra_math::special::erf(x / std::f64::consts::SQRT_2));
        for d in [0.003, 0.01, 0.02] {
            let a = t_exact(1e4, d);
            assert!((a - phi(d * 100.0)).abs() < 2e-3, "{d}: {a} vs {}", phi(d * 100.0));
        }
    }

    #[test]
    fn table_lookup_matches_direct() {
        let t = AxisTable::generate(|_| {});
        let mut worst: f64 = 0.0;
        for lambda in [0.013, 0.4, 2.5, 17.0, 260.0, 3300.0, 9000.0] {
            for k in 0..60 {
                let d = -PI + 2.0 * PI * (k as f64 + 0.37) / 60.0;
                worst = worst.max((t.lookup(lambda, d) - t_exact(lambda, d)).abs());
            }
            for d in [-0.02, -0.005, 0.001, 0.004, 0.03] {
                worst = worst.max((t.lookup(lambda, d) - t_exact(lambda, d)).abs());
            }
        }
        assert!(worst < 5e-3, "table interpolation error {worst}");
    }

    fn cap_map(r: u32, caps: &[(DVec3, f64)]) -> VisMap {
        VisMap::from_dir_fn(r, |w| caps.iter().all(|(c, a)| w.dot(c.normalize()) < a.cos()))
    }

    #[test]
    fn fully_visible_and_occluded() {
        let r = 32;
        let vis = VisMap::filled(r, true);
        let occ = VisMap::filled(r, false);
        let sv = hsdt(&vis);
        let so = hsdt(&occ);
        let (v, o) = (SsdfView { r, values: &sv }, SsdfView { r, values: &so });
        let table = AxisTable::generate(|_| {});
        for lambda in [1e-2, 1.0, 50.0, 1e4] {
            for axis in [DVec3::Z, DVec3::new(0.3, -0.2, 0.9), DVec3::new(0.9, 0.0, 0.05), DVec3::new(0.0, 0.6, -0.4)] {
                let g = lobe(axis, lambda);
                for cosine in [false, true] {
                    let bf = brute_force(&vis, &g, cosine, false);
                    let c = visible_cells(&v, &g, cosine);
                    assert!(
                        (c - bf).abs() <= 1e-3 * bf + 1e-6 * g.sphere_integral(),
                        "cells all visible lambda {lambda} {axis:?}: {c} vs {bf}"
                    );
                    assert_eq!(visible_cells(&o, &g, cosine), 0.0);
                    assert_eq!(visible_axis(&o, &table, &g, cosine), 0.0);
                }
                // (a) on a fully visible map is the hemisphere integral (Tokuyoshi approximation)
                let a = visible_axis(&v, &table, &g, false);
                let exact = g.hemisphere_integral(DVec3::Z);
                assert!(
                    (a - exact).abs() <= 0.03 * exact + 0.005 * g.sphere_integral(),
                    "axis all visible: {a} vs {exact}"
                );
            }
        }
    }

    /// Random cap occluders, grazing and sharp lobes: errors of both methods against the
    /// brute-force integral over the binary map. Printed, and bounded (relative to the unoccluded
    /// hemisphere integral of the lobe, so fully shadowed lobes do not divide by ~0).
    #[test]
    fn methods_against_brute_force() {
        let r = 64;
        let table = AxisTable::generate(|_| {});
        let mut seed = 12345u64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst_cells: f64 = 0.0;
        let mut worst_axis_sharp: f64 = 0.0;
        let mut sum_cells = 0.0;
        let mut sum_axis = 0.0;
        let mut n = 0;
        for k in 0..6 {
            let caps: Vec<(DVec3, f64)> = (0..(1 + k % 3))
                .map(|_| {
                    let z = 0.1 + 0.9 * rnd();
                    let a = std::f64::consts::TAU * rnd();
                    let s = (1.0 - z * z).sqrt();
                    (DVec3::new(s * a.cos(), s * a.sin(), z), 0.2 + 0.6 * rnd())
                })
                .collect();
            let map = cap_map(r, &caps);
            let sv = hsdt(&map);
            let view = SsdfView { r, values: &sv };
            for lambda in [1e-2, 3.0, 40.0, 800.0, 1e4] {
                for g_axis in [
                    texel_dir(r / 2, r / 2, r),
                    DVec3::new(2.0 * rnd() - 1.0, 2.0 * rnd() - 1.0, rnd()),
                    DVec3::new(0.2, 0.97, 0.02), // grazing
                ] {
                    let g = lobe(g_axis, lambda);
                    let norm = brute_force(&VisMap::filled(r, true), &g, true, false).max(1e-12);
                    let bf = brute_force(&map, &g, true, false);
                    let c = visible_cells(&view, &g, true);
                    let ec = (c - bf).abs() / norm;
                    worst_cells = worst_cells.max(ec);
                    sum_cells += ec;
                    let norm_sg = brute_force(&VisMap::filled(r, true), &g, true, true).max(1e-12);
                    let bfa = brute_force(&map, &g, true, true);
                    let a = visible_axis(&view, &table, &g, true);
                    let ea = (a - bfa).abs() / norm_sg;
                    sum_axis += ea;
                    if lambda >= 800.0 {
                        worst_axis_sharp = worst_axis_sharp.max(ea);
                    }
                    n += 1;
                }
            }
        }
        println!(
            "r={r}: cells max {worst_cells:.4} mean {:.5}; axis mean {:.4}, max (lambda >= 800) {worst_axis_sharp:.4} (relative to the unoccluded integral)",
            sum_cells / n as f64,
            sum_axis / n as f64
        );
        assert!(worst_cells < 0.02, "cell method error {worst_cells}");
        assert!(sum_cells / (n as f64) < 0.005);
        assert!(sum_axis / (n as f64) < 0.15, "axis method mean error {}", sum_axis / n as f64);
    }
}

// Unit tests of the vv module on tiny hand-made models (the integration tests with scene
// meshes are in `tests/vv_precompute.rs`).
mod vv {
    use glam::{Mat4, Vec3};

    use penumbra_math::vv::precompute::{trace_occluder, Topology};
    use penumbra_math::vv::trace::Tracer;
    use penumbra_math::vv::*;

    /// `n x n` quad grid of side `size` in the plane y = `y`, facing +y.
    pub(crate) fn grid(n: u32, size: f32, y: f32) -> (Vec<Vec3>, Vec<Vec3>, Vec<u32>) {
        let mut p = Vec::new();
        for i in 0..=n {
            for j in 0..=n {
                p.push(Vec3::new(size * (i as f32 / n as f32 - 0.5), y, size * (j as f32 / n as f32 - 0.5)));
            }
        }
        let mut idx = Vec::new();
        let id = |i: u32, j: u32| i * (n + 1) + j;
        for i in 0..n {
            for j in 0..n {
                idx.extend([id(i, j), id(i, j + 1), id(i + 1, j), id(i + 1, j), id(i, j + 1), id(i + 1, j + 1)]);
            }
        }
        let nrm = vec![Vec3::Y; p.len()];
        (p, nrm, idx)
    }

    /// Axis-aligned box (flat normals, 24 vertices), outward facing.
    pub(crate) fn cuboid(c: Vec3, h: Vec3) -> (Vec<Vec3>, Vec<Vec3>, Vec<u32>) {
        let mut p = Vec::new();
        let mut nrm = Vec::new();
        let mut idx = Vec::new();
        for axis in 0..3 {
            for s in [-1.0f32, 1.0] {
                let mut n = Vec3::ZERO;
                n[axis] = s;
                let (u, v) = (n.any_orthonormal_vector(), n.cross(n.any_orthonormal_vector()));
                let b = p.len() as u32;
                for (a, bb) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    let q = n + u * a + v * bb;
                    p.push(c + q * h);
                    nrm.push(n);
                }
                idx.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
            }
        }
        (p, nrm, idx)
    }

    pub(crate) fn model(parts: &[((Vec<Vec3>, Vec<Vec3>, Vec<u32>), bool)]) -> VvModel {
        VvModel::from_objects(parts.iter().map(|((p, n, i), occ)| ObjectMesh {
            positions: p,
            normals: n,
            indices: i,
            world: Mat4::IDENTITY,
            casts_shadow: *occ,
        }))
    }

    /// Occluded solid angle at `p` by uniform hemisphere sampling (stratified) with the
    /// precompute's tracing conventions.
    fn traced_occluded_solid_angle(m: &VvModel, v: usize, n_samples: u32) -> f64 {
        let topo = Topology::new(m);
        let tracer = Tracer::new(&m.positions, &m.indices, &m.occluder);
        let nn = m.normals[v].as_dvec3();
        let f = frame(m.normals[v]);
        let mut occ = 0;
        // equal-area: uniform in the Lambert disk
        for d in lambert_grid(n_samples, &f) {
            if trace_occluder(&tracer, &topo, &[topo.pos_group[v]], m.positions[v].as_dvec3(), nn, d).is_some() {
                occ += 1;
            }
        }
        // each disk cell of area (2/n)^2 is a solid angle 2 pi * area / pi
        occ as f64 * 2.0 * (2.0 / n_samples as f64).powi(2)
    }

    fn occluded_solid_angle(vis: &VectorizedVisibility, m: &VvModel, v: usize) -> f64 {
        synthesize(vis, v, m.positions[v], m.normals[v]).iter().map(|l| signed_solid_angle(l, m.normals[v])).sum()
    }

    #[test]
    fn box_over_floor_loop_matches_traced_occlusion() {
        let m =
            model(&[(grid(4, 4.0, 0.0), false), (cuboid(Vec3::new(0.3, 1.0, 0.0), Vec3::new(0.5, 0.2, 0.4)), true)]);
        let params = VvParams { resolution: 48, ..Default::default() };
        let vis = precompute_visibility(&m, &params, &|_| {}).unwrap();
        // the floor centre vertex (i = j = 2) sees one loop around the box
        let v = 2 * 5 + 2;
        assert_eq!(vis.vertex_sequences(v).len(), 1, "{:?}", vis.vertex_seqs[v]);
        let a = occluded_solid_angle(&vis, &m, v);
        let t = traced_occluded_solid_angle(&m, v, 200);
        assert!(t > 0.3, "box subtends {t}");
        assert!((a - t).abs() < 0.03 * t + 0.01, "loop {a} vs traced {t}");
        // every point of that loop is on the box (w = 1)
        for k in vis.vertex_sequences(v) {
            assert!(vis.sequence(k).iter().all(|q| q[3] == 1.0 && (q[1] - 1.0).abs() <= 0.2001));
            assert!(vis.sequence(k).len() >= 4 && vis.sequence(k).len() < 200);
        }
        // a floor corner far from the box: occluded much less
        assert!(occluded_solid_angle(&vis, &m, 0) < a);
    }

    #[test]
    fn unoccluded_vertex_has_no_sequence_and_enclosed_vertex_a_horizon_loop() {
        // a floor grid with nothing above: empty visibility everywhere
        let m = model(&[(grid(2, 2.0, 0.0), true)]);
        let vis = precompute_visibility(&m, &VvParams { resolution: 16, ..Default::default() }, &|_| {}).unwrap();
        assert_eq!(vis.sequence_count(), 0);
        assert!(vis.vertex_seqs.iter().all(|s| s[1] == 0));
        // a floor inside a closed box: the centre vertex is fully enclosed
        let m =
            model(&[(grid(2, 1.0, 0.0), false), (cuboid(Vec3::new(0.0, 0.5, 0.0), Vec3::new(1.0, 0.7, 1.0)), true)]);
        let vis = precompute_visibility(&m, &VvParams { resolution: 24, ..Default::default() }, &|_| {}).unwrap();
        let v = 4;
        assert_eq!(vis.vertex_sequences(v).len(), 1);
        let seq = vis.sequence(vis.vertex_sequences(v).start);
        assert!(seq.iter().all(|q| q[3] == 0.0), "horizon points are directions");
        let a = occluded_solid_angle(&vis, &m, v);
        assert!((a - 2.0 * std::f64::consts::PI).abs() < 0.05, "enclosed: {a}");
    }

    #[test]
    fn points_behind_the_tangent_plane_are_clamped_to_the_horizon() {
        let n = Vec3::Y;
        let d = clamp_to_hemisphere(Vec3::new(1.0, -1.0, 0.0).normalize(), n);
        assert!((d - Vec3::X).length() < 1e-6);
        assert!(clamp_to_hemisphere(-n, n).dot(n).abs() < 1e-6);
        // a cap of radius 30 deg centred on the horizon: half of it is behind the tangent plane;
        // clamped, its loop encloses exactly the upper half
        let cap = |c: Vec3, r: f32, m: usize| -> Vec<Vec3> {
            let (u, v) = (c.any_orthonormal_vector(), c.cross(c.any_orthonormal_vector()));
            (0..m)
                .map(|i| {
                    let a = i as f32 * std::f32::consts::TAU / m as f32;
                    (c * r.cos() + (u * a.cos() + v * a.sin()) * r.sin()).normalize()
                })
                .collect()
        };
        let r = 30f32.to_radians();
        let l: Vec<Vec3> = cap(Vec3::X, r, 256).into_iter().map(|d| clamp_to_hemisphere(d, n)).collect();
        let half = std::f64::consts::PI * (1.0 - (r as f64).cos());
        let a = signed_solid_angle(&l, n);
        assert!((a - half).abs() < 0.01 * half, "{a} vs {half}");
        // the clamped loop says occluded exactly for directions inside the upper half of the cap
        let inside = Vec3::new(0.95, 0.2, 0.0).normalize();
        let outside = Vec3::new(0.7, 0.1, 0.7).normalize();
        assert!(occluded_by(std::slice::from_ref(&l), inside, n) && !occluded_by(&[l], outside, n));
        // a cap wholly behind the plane (not around -n) encloses nothing once clamped
        let below = Vec3::new(1.0, -1.0, 0.3).normalize();
        let l: Vec<Vec3> = cap(below, 20f32.to_radians(), 64).into_iter().map(|d| clamp_to_hemisphere(d, n)).collect();
        assert!(l.iter().all(|d| d.dot(n).abs() < 1e-6));
        assert!(signed_solid_angle(&l, n).abs() < 1e-6);
    }

    #[test]
    fn file_roundtrip_and_malformed_files() {
        let m = model(&[(grid(2, 4.0, 0.0), false), (cuboid(Vec3::new(0.0, 1.0, 0.0), Vec3::splat(0.4)), true)]);
        let vis = precompute_visibility(&m, &VvParams { resolution: 16, ..Default::default() }, &|_| {}).unwrap();
        let d = VvData {
            model_hash: m.hash(),
            vertex_count: m.positions.len() as u32,
            triangle_count: m.triangle_count() as u32,
            params: VvParams { resolution: 16, ..Default::default() },
            corr: Correspondence {
                tri_offsets: vec![0; m.triangle_count() + 1],
                loop_offsets: vec![0],
                triples: vec![],
            },
            vis,
            stats: VvStats::default(),
        }
        .with_sizes();
        let b = d.to_bytes();
        let back = VvData::from_bytes(&b, "x.pvv").unwrap();
        assert_eq!(back, d);
        back.check_model(&m).unwrap();
        for cut in [0, 3, 10, 40, b.len() - 1] {
            let e = VvData::from_bytes(&b[..cut], "x.pvv").unwrap_err();
            assert!(e.starts_with("x.pvv: ") && (e.contains("truncated") || e.contains("magic")), "{cut}: {e}");
        }
        let mut bad = b.clone();
        bad[4] = 9;
        assert!(VvData::from_bytes(&bad, "x.pvv").unwrap_err().contains("version 9"));
        let mut bad = b.clone();
        bad.push(0);
        assert!(VvData::from_bytes(&bad, "x.pvv").unwrap_err().contains("trailing"));
        let mut other = m.clone();
        other.positions[0].x += 0.5;
        assert!(back.check_model(&other).unwrap_err().contains("different model"));
    }

    /// Checks the spherical Delaunay property: V - E + F = 2 (E = 3F/2), every site is a vertex
    /// of some face, and no site lies strictly inside a face's circumcircle (beyond the symbolic
    /// perturbation).
    fn check_delaunay(sites: &hull::Sites) {
        let f = hull::convex_hull(&sites.dirs);
        let n = sites.dirs.len();
        assert_eq!(f.len(), 2 * n - 4, "Euler: {} faces for {n} sites", f.len());
        let mut seen = vec![false; n];
        for t in &f {
            for &v in t {
                seen[v] = true;
            }
            let (a, b, c) = (sites.dirs[t[0]], sites.dirs[t[1]], sites.dirs[t[2]]);
            let cc = (b - a).cross(c - a).normalize();
            let r = cc.dot(a);
            for (i, s) in sites.dirs.iter().enumerate() {
                if !t.contains(&i) {
                    assert!(cc.dot(*s) <= r + 1e-9, "site {i} inside the circumcircle of {t:?}");
                }
            }
        }
        assert!(seen.iter().all(|&s| s), "every site has a Voronoi cell");
    }

    #[test]
    fn spherical_voronoi_of_duplicate_and_cocircular_sites() {
        use glam::DVec3;
        // 12 sites on one small circle, 12 on the equator (cocircular), the poles, and every site
        // duplicated (three colours seeing the same directions)
        let mut input = Vec::new();
        for i in 0..12 {
            let a = i as f64 * std::f64::consts::TAU / 12.0;
            input.push(DVec3::new(a.cos(), a.sin(), 0.0));
            input.push(DVec3::new(0.5 * a.cos(), 0.5 * a.sin(), 0.75f64.sqrt()));
        }
        input.push(DVec3::Z);
        input.push(-DVec3::Z);
        let dup: Vec<DVec3> = input.iter().chain(input.iter()).chain(input.iter()).copied().collect();
        let s = hull::sites(&dup, 7);
        assert_eq!(s.dirs.len(), input.len(), "duplicates merged");
        assert!(s.members.iter().all(|m| m.len() == 3));
        check_delaunay(&s);
        // deterministic for a seed
        let s2 = hull::sites(&dup, 7);
        assert_eq!(hull::convex_hull(&s.dirs), hull::convex_hull(&s2.dirs));
        // all sites on one great circle (a fully enclosed triangle's horizon loops): no 3D hull,
        // the fan still gives triangles over all sites
        let ring: Vec<DVec3> = (0..16)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / 16.0;
                DVec3::new(a.cos(), 0.0, a.sin())
            })
            .collect();
        let s = hull::sites(&ring, 3);
        let f = hull::convex_hull(&s.dirs);
        assert!(!f.is_empty());
        let mut seen = [false; 16];
        f.iter().flatten().for_each(|&v| seen[v] = true);
        assert!(seen.iter().all(|&x| x));
        // fewer than three sites
        assert!(hull::convex_hull(&[DVec3::X, DVec3::Y]).is_empty());
        // RGB tripoints of three identical colour sets: every site is its own zero-distance triple
        let dirs: Vec<Vec3> = input.iter().map(|d| d.as_vec3()).collect();
        let ents = [(0..26).collect::<Vec<u32>>(), (100..126).collect(), (200..226).collect()];
        let c = corr::rgb_tripoints(&ents, &[dirs.clone(), dirs.clone(), dirs], 5, 0.0);
        for i in 0..26u32 {
            assert!(c.iter().any(|(t, d)| *t == [i, 100 + i, 200 + i] && *d < 1e-3), "site {i}");
        }
    }

    /// The winding flip of issue 9: a vertex enclosed up to its horizon (one loop of horizon points
    /// around the whole hemisphere) next to vertices that see two separate regions. The triangle's
    /// two groups each hold two interleaved arcs of the ring; closed by chords, each group winds
    /// once around the normal at that vertex (2 pi each, 4 pi in all instead of 2 pi). With the
    /// jumps routed through the vertex's pole (corr step 6) eq. 21 at every corner gives back that
    /// vertex's own visibility.
    #[test]
    fn split_horizon_ring_is_reproduced_at_the_corners() {
        let n = Vec3::Y;
        let mut points: Vec<[f32; 4]> = Vec::new();
        // vertex 0: 12 horizon directions, counter-clockwise about the occluded hemisphere
        for i in 0..12 {
            let a = (i as f32 * 30.0).to_radians();
            points.push([a.cos(), 0.0, -a.sin(), 0.0]);
        }
        // vertices 1 and 2: two small regions each, points on occluders (w = 1)
        let region = |c: Vec3| -> Vec<[f32; 4]> {
            let (u, v) = (Vec3::Y, c.cross(Vec3::Y).normalize());
            (0..4)
                .map(|i| {
                    let a = (i as f32 * -90.0).to_radians();
                    let p = c + 0.2 * (u * a.cos() + v * a.sin()) + 0.25 * u;
                    [p.x, p.y, p.z, 1.0]
                })
                .collect()
        };
        for c in [Vec3::X, -Vec3::X, Vec3::Z, -Vec3::Z] {
            points.extend(region(c));
        }
        let vis0 = VectorizedVisibility {
            vertex_points: points.len() as u32,
            seq_offsets: vec![0, 12, 16, 20, 24, 28],
            vertex_seqs: vec![[0, 1], [1, 2], [3, 2]],
            points,
        };
        let m = VvModel {
            positions: vec![Vec3::ZERO, Vec3::new(0.05, 0.0, 0.0), Vec3::new(0.0, 0.0, 0.05)],
            normals: vec![n; 3],
            indices: vec![0, 1, 2],
            occluder: vec![true],
        };
        let own: Vec<f64> = (0..3)
            .map(|v| synthesize(&vis0, v, m.positions[v], n).iter().map(|l| signed_solid_angle(l, n)).sum())
            .collect();
        assert!((own[0] - std::f64::consts::TAU).abs() < 1e-6, "ring: {}", own[0]);
        // two groups: ring arcs {0,1,2} + {6,7} with the first regions, {3,4,5} + {8..11} with the
        // second ones (interleaved, as the relaxed stage leaves them)
        let g0: Vec<[u32; 3]> = [(0, 12, 20), (1, 13, 21), (2, 14, 22), (6, 15, 23), (7, 15, 23)]
            .iter()
            .map(|&(a, b, c)| [a, b, c])
            .collect();
        let g1: Vec<[u32; 3]> =
            [(3, 16, 24), (4, 17, 25), (5, 18, 26), (8, 19, 27), (9, 19, 27), (10, 19, 27), (11, 19, 27)]
                .iter()
                .map(|&(a, b, c)| [a, b, c])
                .collect();
        let build = |vis: &VectorizedVisibility, loops: &[Vec<[u32; 3]>]| {
            let mut c =
                Correspondence { tri_offsets: vec![0, loops.len() as u32], loop_offsets: vec![0], triples: Vec::new() };
            for l in loops {
                c.triples.extend_from_slice(l);
                c.loop_offsets.push(c.triples.len() as u32);
            }
            let _ = vis;
            c
        };
        let corner = |vis: &VectorizedVisibility, c: &Correspondence, k: usize| -> f64 {
            let mut l = [0.0f32; 3];
            l[k] = 1.0;
            interpolate(vis, c, 0, l, m.positions[k], n).iter().map(|x| signed_solid_angle(x, n)).sum()
        };
        // before: chords along the horizon take the short way, each group winds once
        let before = build(&vis0, &[g0.clone(), g1.clone()]);
        let e0 = (corner(&vis0, &before, 0) - own[0]).abs();
        assert!(e0 > 3.0, "the unrouted groups should show the flip: error {e0}");
        // after: jumps through the poles
        let mut vis = vis0.clone();
        let pole = [0, 1, 2].map(|_| {
            vis.points.push([n.x, n.y, n.z, 0.0]);
            vis.points.len() as u32 - 1
        });
        let mut info = vec![(0u32, 0u32); vis.vertex_points as usize];
        for s in 0..vis.sequence_count() {
            for g in vis.seq_offsets[s]..vis.seq_offsets[s + 1] {
                info[g as usize] = (s as u32, g - vis.seq_offsets[s]);
            }
        }
        let mut loops = vec![g0, g1];
        let added = corr::route_jumps(&vis, &info, &mut loops, pole);
        assert!(added > 0);
        let after = build(&vis, &loops);
        for (k, &own_k) in own.iter().enumerate() {
            let e = (corner(&vis, &after, k) - own_k).abs();
            assert!(e < 1e-4, "corner {k}: interpolated {} own {own_k}", corner(&vis, &after, k));
        }
        // every original triple is still there, in order
        for (l, orig) in loops.iter().zip([&before.triples[..5], &before.triples[5..]]) {
            let kept: Vec<[u32; 3]> = l.iter().copied().filter(|t| t.iter().all(|&g| g < vis.vertex_points)).collect();
            let mut it = kept.iter();
            assert!(orig.iter().all(|o| it.any(|x| x == o)), "{l:?}");
        }
    }

    #[test]
    fn interpolation_disagreement_flags_a_corrupted_correspondence() {
        // a box over a 4 x 4 floor: the correspondence of the floor triangles under the box is sound
        let m =
            model(&[(grid(4, 4.0, 0.0), false), (cuboid(Vec3::new(0.3, 1.0, 0.0), Vec3::new(0.5, 0.2, 0.4)), true)]);
        let params = VvParams { resolution: 32, ..Default::default() };
        let d = compute(&m, &params, &|_, _| {}).unwrap();
        let dis = interpolation_disagreement(&m, &d.vis, &d.corr);
        assert_eq!(dis.len(), m.triangle_count());
        assert!(dis.iter().all(|x| x.is_finite() && *x >= 0.0));
        // a floor triangle with loops under the box, and its disagreement when sound
        let t = (0..32).filter(|&t| !d.corr.triangle_loops(t).is_empty()).max_by(|&a, &b| {
            let len = |t: usize| d.corr.triangle_loops(t).map(|l| d.corr.loop_triples(l).len()).sum::<usize>();
            len(a).cmp(&len(b))
        });
        let t = t.expect("a floor triangle sees the box");
        assert!(dis[t] < 0.25, "sound triangle {t}: {}", dis[t]);
        // turn its loops inside out (reversed triple order: the occluded region becomes its
        // complement within the hemisphere, far more than eq. 19's blend)
        let mut corr = d.corr.clone();
        for l in corr.triangle_loops(t) {
            let (a, b) = (corr.loop_offsets[l] as usize, corr.loop_offsets[l + 1] as usize);
            corr.triples[a..b].reverse();
        }
        let bad = interpolation_disagreement(&m, &d.vis, &corr);
        assert!(bad[t] > 0.5, "reversed loops of triangle {t}: {} (sound {})", bad[t], dis[t]);
        // the other triangles are unchanged
        assert!((0..m.triangle_count()).filter(|&u| u != t).all(|u| bad[u] == dis[u]));
    }
}
