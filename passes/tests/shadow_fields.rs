//! Shadow fields, CPU side: precompute against analytic sphere occlusion, quantization bounds,
//! adaptive shells, file format, SH rotation near gimbal configurations, many overlapping
//! occluders (negative lobes), points inside/outside the shells.

use glam::{DMat3, DMat4, DVec3, Vec3};
use penumbra_math::sh::{eval_basis, eval_basis_into, TripleProductTensor};
use penumbra_math::shadow_field::{
    self as sf, cosine_transfer, eq1_error, occluded_transfer, rotate, rotation_blocks, sample_angles, sample_grid,
    DirTable, InstanceFrame, LightFrame, LightSource, ObjectField, Params, RawField, ShadeOptions, ShadePoint, Window,
    NCOEF, Y0,
};
use penumbra_scene::MeshData;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// Order-4 SH of the visibility of a point at distance `d` from a sphere of radius `r` centred
/// in direction `axis` (1 outside the blocked cap of half-angle asin(r/d)): zonal coefficients
/// of the cap indicator, `2 pi sqrt((2l+1)/4pi) int_{cos a}^1 P_l`, rotated to `axis`.
fn analytic_sphere_visibility(axis: DVec3, d: f64, r: f64) -> [f64; NCOEF] {
    let t = (1.0 - (r / d).powi(2)).max(0.0).sqrt(); // cos of the cap half-angle
    let ip = [1.0 - t, (1.0 - t * t) / 2.0, (t - t * t * t) / 2.0, (-0.25 - 1.25 * t.powi(4) + 1.5 * t * t) / 2.0];
    let y = eval_basis(4, axis.normalize());
    let mut out = [0.0; NCOEF];
    out[0] = (4.0 * PI).sqrt();
    for l in 0..4 {
        let zl = 2.0 * PI * ((2 * l + 1) as f64 / (4.0 * PI)).sqrt() * ip[l];
        let k = (4.0 * PI / (2 * l + 1) as f64).sqrt() * zl;
        for m in 0..2 * l + 1 {
            out[l * l + m] -= k * y[l * l + m];
        }
    }
    out
}

fn unit_sphere() -> MeshData {
    MeshData::uv_sphere(1.0, 48, 24)
}

fn sphere_params() -> Params {
    Params { shells: 8, resolution: 8, map_res: 32, threshold: 0.010, min_resolution: 1 }
}

/// The raw field of the unit sphere (computed once for the tests of this file).
fn sphere_raw() -> &'static RawField {
    static RAW: OnceLock<RawField> = OnceLock::new();
    RAW.get_or_init(|| {
        let m = unit_sphere();
        let raw = sf::precompute(&m.positions, &m.normals, &m.indices, &sphere_params(), &|_| {}).unwrap();
        println!("unit sphere: {} tris, {} rays in {:.2} s", m.indices.len() / 3, raw.rays, raw.seconds);
        raw
    })
}

fn f64s(a: &[f32; NCOEF]) -> [f64; NCOEF] {
    a.map(|x| x as f64)
}

#[test]
fn shadow_fields_sphere_occluder_matches_the_analytic_cap() {
    let raw = sphere_raw();
    let table = DirTable::new(48);
    let r = raw.resolution;
    assert!((raw.bound_radius - 1.0).abs() < 1e-3);
    let mut worst = 0.0f64;
    // Shells 5..7 (radius 1.2 .. 1.6) are outside the sphere; shells 0..3 (0.2 .. 0.8) inside.
    for c in 5..8 {
        let d = 0.2 * (c + 1) as f64;
        for s in 0..r {
            for t in 0..r {
                let (th, ph) = sample_angles(r, s, t);
                let axis = -sf::polar_dir(th, ph); // towards the centre
                let exact = analytic_sphere_visibility(axis, d, 1.0);
                let e = eq1_error(&exact, &raw.shells[c][s * r + t], &table);
                worst = worst.max(e);
            }
        }
    }
    println!("sphere OOF vs analytic cap: largest eq.1 error {worst:.4}");
    // Error sources: the 32 x 64 occlusion map (cells of 0.1 rad across the cap edge) and the
    // 48 x 24 faceting; a wrong sign, frame or scale gives errors of order 0.1 - 1.
    assert!(worst < 0.02, "{worst}");
    // Inside the sphere every direction is blocked: visibility 0.
    for c in 0..4 {
        let m = raw.shells[c].iter().flat_map(|v| v.iter()).fold(0.0f32, |a, x| a.max(x.abs()));
        assert!(m < 1e-6, "shell {c} inside the sphere: {m}");
    }
    // Interpolated lookups between shells and samples converge to the cap as R grows: the
    // lookup linearly blends coefficient vectors whose cap axes differ by the sample spacing
    // (0.39 x 0.79 rad at R = 8), which shrinks the higher bands.
    let fine = {
        let m = unit_sphere();
        sf::precompute(
            &m.positions,
            &m.normals,
            &m.indices,
            &Params { resolution: 32, map_res: 16, ..sphere_params() },
            &|_| {},
        )
        .unwrap()
    };
    let lookup_error = |field: &ObjectField| {
        let mut worst = 0.0f64;
        for k in 0..40 {
            let dir = sf::polar_dir(0.3 + 0.06 * k as f64, 0.77 * k as f64);
            let d = 1.25 + 0.008 * k as f64;
            let got = field.ocv(dir * d).unwrap();
            let exact = analytic_sphere_visibility(-dir, d, 1.0);
            worst = worst.max(eq1_error(&got, &exact.map(|x| x as f32), &table));
        }
        worst
    };
    let (e8, e32) = (lookup_error(&raw.to_fixed()), lookup_error(&fine.to_fixed()));
    println!("interpolated lookups vs analytic: largest eq.1 error {e8:.4} at R = 8, {e32:.4} at R = 32");
    // At R = 32 what remains is the radial interpolation (shells 0.2 apart) and the 16 x 32
    // occlusion maps; a frame or sign error in the lookup would give errors of order 0.1-1.
    assert!(e32 < 0.03 && e32 < 0.5 * e8, "{e8} {e32}");
}

#[test]
fn shadow_fields_outside_outermost_and_inside_innermost() {
    let field = sphere_raw().to_fixed();
    // Outside the outermost shell (1.6): the object is ignored.
    assert!(field.ocv(DVec3::new(0.0, 0.0, 1.61)).is_none());
    assert!(field.ocv(DVec3::new(50.0, -3.0, 2.0)).is_none());
    assert!(field.ocv(DVec3::new(f64::NAN, 0.0, 0.0)).is_none());
    // Inside the innermost shell (and at the centre): clamped to shell 0, fully blocked.
    for p in [DVec3::ZERO, DVec3::new(0.05, 0.0, 0.0), DVec3::new(0.0, -0.1, 0.1)] {
        let o = field.ocv(p).unwrap();
        assert!(o.iter().all(|x| x.abs() < 1e-3), "{p}: {o:?}");
    }
    // Exactly on the outermost shell: defined and close to the analytic value.
    // (at a sample direction, so only the radial clamp is exercised: the sample-point error
    // of the first test, 0.02, applies)
    let (th, ph) = sample_angles(8, 3, 2);
    let dir = sf::polar_dir(th, ph);
    let o = field.ocv(dir * 1.6).unwrap();
    let exact = analytic_sphere_visibility(-dir, 1.6, 1.0);
    assert!(eq1_error(&o, &exact.map(|x| x as f32), &DirTable::new(32)) < 0.02);
}

#[test]
fn shadow_fields_quantization_error_is_half_a_step() {
    // Real field and a synthetic one with a huge dynamic range (1e-6 .. 1e3 in one coefficient).
    let raw = sphere_raw().clone();
    let mut synth = raw.clone();
    for (i, v) in synth.shells[6].iter_mut().enumerate() {
        v[3] = if i % 2 == 0 { 1e-6 } else { 1e3 };
        v[7] = -1e3 * (i as f32 / 64.0);
    }
    for rf in [&raw, &synth] {
        let q = rf.to_fixed();
        for (c, g) in rf.shells.iter().enumerate() {
            let sh = &q.shells[c];
            for (i, v) in g.iter().enumerate() {
                let dq = q.sample(c, i);
                for e in 0..NCOEF {
                    let err = (dq[e] - v[e] as f64).abs();
                    // half a step, plus f32 rounding of min + q * step
                    let bound = 0.5 * sh.step[e] as f64 + 1e-6 * (v[e].abs() as f64 + sh.min[e].abs() as f64 + 1.0);
                    assert!(err <= bound, "shell {c} sample {i} coef {e}: {err} > {bound}");
                }
            }
        }
    }
    // The huge range costs precision only in its own coefficient: step 1e3/255.
    let q = synth.to_fixed();
    assert!((q.shells[6].step[3] - 1e3 / 255.0).abs() < 1e-2);
    assert!(q.shells[6].step[0] < 1e-2, "other coefficients keep their own step");
}

#[test]
fn shadow_fields_adaptive_shells_shrink_within_threshold() {
    let raw = sphere_raw();
    let p = sphere_params();
    let table = DirTable::new(16);
    let fixed = raw.to_fixed();
    let adaptive = raw.to_adaptive(p.threshold, p.min_resolution);
    println!(
        "sphere: R per shell {:?}, fixed {} B, adaptive {} B",
        adaptive.resolutions(),
        fixed.data_bytes(),
        adaptive.data_bytes()
    );
    assert!(adaptive.data_bytes() < fixed.data_bytes());
    for (c, sh) in adaptive.shells.iter().enumerate() {
        let r = sh.resolution as usize;
        assert!(r.is_power_of_two() && r <= raw.resolution, "shell {c}: R {r}");
        // Independent check of eq. 1 at every initial sample, from the stored (quantized) grid.
        let grid = adaptive.shell_grid(c);
        // Quantization adds at most (1/4pi) sum_e |d_e| int |Y_e| <= sum_e (step_e / 2) / sqrt(4pi).
        let qa: f64 = sh.step.iter().map(|s| 0.5 * *s as f64).sum::<f64>() / (4.0 * PI).sqrt();
        let r0 = raw.resolution;
        for s in 0..r0 {
            for t in 0..r0 {
                let (th, ph) = sample_angles(r0, s, t);
                let rec = sample_grid(&grid, r, th, ph);
                let e = eq1_error(&rec, &raw.shells[c][s * r0 + t], &table);
                assert!(e < p.threshold + qa + 1e-4, "shell {c} R {r}: error {e} (quantization allowance {qa})");
            }
        }
    }
    // Shells inside the sphere (constant zero) collapse to the minimum (the paper's teapot).
    for c in 0..4 {
        assert_eq!(adaptive.shells[c].resolution, 1, "shell {c}");
    }
    // A zero threshold keeps every shell at the initial resolution where the field varies.
    let strict = raw.to_adaptive(0.0, 1);
    assert!(strict.shells[5..].iter().all(|s| s.resolution as usize == raw.resolution));
}

#[test]
fn shadow_fields_file_round_trip_and_bad_input() {
    let f = sphere_raw().to_adaptive(0.01, 1);
    let bytes = f.to_bytes();
    assert_eq!(bytes.len(), f.file_bytes());
    let g = ObjectField::from_bytes(&bytes).unwrap();
    assert_eq!(f, g);
    let path =
        std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("sf_test_{}.psf", std::process::id()));
    std::fs::write(&path, &bytes).unwrap();
    assert_eq!(ObjectField::from_bytes(&std::fs::read(&path).unwrap()).unwrap(), f);
    let _ = std::fs::remove_file(&path);
    // Truncations, bad magic, trailing bytes, corrupt counts: errors, never panics.
    for cut in [0, 3, 4, 10, 30, bytes.len() / 2, bytes.len() - 1] {
        assert!(ObjectField::from_bytes(&bytes[..cut]).is_err(), "cut {cut}");
    }
    let mut bad = bytes.clone();
    bad[0] = b'X';
    assert!(ObjectField::from_bytes(&bad).is_err());
    let mut long = bytes.clone();
    long.push(0);
    assert!(ObjectField::from_bytes(&long).is_err());
    let mut huge = bytes.clone();
    huge[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(ObjectField::from_bytes(&huge).is_err());
    let mut huge_v = bytes.clone();
    huge_v[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(ObjectField::from_bytes(&huge_v).is_err());
    let mut nan = bytes.clone();
    nan[12..16].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(ObjectField::from_bytes(&nan).is_err());
    // Bad meshes are errors too.
    let p = sphere_params();
    assert!(sf::precompute(&[], &[], &[], &p, &|_| {}).is_err());
    assert!(sf::precompute(&[Vec3::ZERO; 3], &[], &[0, 1, 2], &p, &|_| {}).is_err());
    assert!(sf::precompute(&[Vec3::NAN, Vec3::X, Vec3::Y], &[], &[0, 1, 2], &p, &|_| {}).is_err());
    assert!(
        sf::precompute(&[Vec3::ZERO, Vec3::X, Vec3::Y], &[], &[0, 1, 2], &Params { shells: 0, ..p }, &|_| {}).is_err()
    );
}

#[test]
fn shadow_fields_rotation_near_gimbal_configurations() {
    // Rotating the projection of a delta at d0 gives the projection of a delta at R d0.
    let dirs = [DVec3::new(0.3, -0.5, 0.8).normalize(), DVec3::Z, DVec3::new(-1.0, 0.2, 0.1).normalize()];
    let mut worst = 0.0f64;
    for eps in [0.0, 1e-9, 1e-6, 1e-3] {
        for (a, g) in [(0.3, -1.1), (2.0, 0.7), (0.0, 0.0)] {
            for beta in [eps, PI - eps, -eps, PI + eps, 0.5 * PI] {
                let r = DMat3::from_rotation_z(a) * DMat3::from_rotation_y(beta) * DMat3::from_rotation_z(g);
                let blocks = rotation_blocks(r);
                for d0 in dirs {
                    let mut y = [0.0; NCOEF];
                    eval_basis_into(4, d0, &mut y);
                    let got = rotate(&blocks, &y);
                    let mut want = [0.0; NCOEF];
                    eval_basis_into(4, r * d0, &mut want);
                    for e in 0..NCOEF {
                        worst = worst.max((got[e] - want[e]).abs());
                    }
                }
            }
        }
    }
    println!("gimbal rotations: largest coefficient error {worst:.2e}");
    assert!(worst < 1e-9, "{worst}");
    // A rotated occluder's field, looked up through InstanceFrame, equals the field of the
    // rotated configuration: the sphere is rotation invariant, so rotating the instance about
    // its centre must not change the world-space visibility at a fixed world point.
    let field = sphere_raw().to_fixed();
    let tensor = TripleProductTensor::new(4);
    let p = ShadePoint {
        pos: DVec3::new(0.2, 0.1, 1.35),
        inst: 1,
        albedo: DVec3::ONE,
        transfer: cosine_transfer(DVec3::Z),
    };
    let base = {
        let insts = [InstanceFrame::new(Some(&field), DMat4::IDENTITY), InstanceFrame::new(None, DMat4::IDENTITY)];
        occluded_transfer(&p, &insts, &tensor).0
    };
    for beta in [1e-7, PI - 1e-7, 0.5 * PI] {
        let q = DMat4::from_euler(glam::EulerRot::ZYZ, 0.4, beta, -0.9);
        let insts = [InstanceFrame::new(Some(&field), q), InstanceFrame::new(None, DMat4::IDENTITY)];
        let u = occluded_transfer(&p, &insts, &tensor).0;
        // Differences come from the polar grid's anisotropy (8 x 8 samples, bilinear): small
        // against the transfer's DC (about 0.5 here).
        let d: f64 = u.iter().zip(&base).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(d < 0.05, "beta {beta}: {d}");
    }
}

#[test]
fn shadow_fields_many_overlapping_occluders_clamp_negative_lobes() {
    // A receiver at the origin (normal +y) surrounded by k unit spheres at distance 1.45 (inside
    // their outermost shell, 1.6; neighbouring caps of half-angle 44 degrees overlap); the
    // visibility product of the order-4 projections rings; measure it and check the clamp.
    let field = sphere_raw().to_fixed();
    let tensor = TripleProductTensor::new(4);
    let table = DirTable::new(24);
    let light = {
        // constant white sky: radiance 1 everywhere
        let mut l = [[0.0; 3]; NCOEF];
        l[0] = [(4.0 * PI).sqrt(); 3];
        l
    };
    for k in [1usize, 2, 4, 8, 12] {
        let mut insts = vec![InstanceFrame::new(None, DMat4::IDENTITY)];
        let mut centers = Vec::new();
        for i in 0..k {
            let phi = 2.0 * PI * i as f64 / k as f64;
            let th = 0.9 + 0.25 * (i % 3) as f64;
            let c = sf::polar_dir(th, phi);
            let c = DVec3::new(c.x, c.z.abs() + 0.3, c.y).normalize() * 1.45; // above the horizon
            centers.push(c);
            insts.push(InstanceFrame::new(Some(&field), DMat4::from_translation(c)));
        }
        let p = ShadePoint { pos: DVec3::ZERO, inst: 0, albedo: DVec3::ONE, transfer: cosine_transfer(DVec3::Y) };
        let (u, applied) = occluded_transfer(&p, &insts, &tensor);
        assert_eq!(applied, k);
        // Exact irradiance fraction by ray casting the spheres.
        let mut exact = 0.0;
        let mut neg = 0usize;
        let mut minv = 0.0f64;
        for (d, w, y) in &table.dirs {
            let cs = d.y.max(0.0);
            let blocked = centers.iter().any(|c| {
                let b = d.dot(*c);
                b > 0.0 && c.length_squared() - b * b < 1.0
            });
            if !blocked {
                exact += w * cs / PI;
            }
            let v: f64 = u.iter().zip(y).map(|(a, b)| a * b).sum();
            if v < 0.0 {
                neg += 1;
                minv = minv.min(v);
            }
        }
        let approx = u[0] * (4.0 * PI).sqrt(); // int U over the sphere
        let shaded = sf::shade_points(&[p], &insts, &light, &tensor);
        let (c, raw_min) = shaded[0];
        println!(
            "{k} occluders: transfer integral {approx:.4} vs exact {exact:.4}, negative in {:.1}% of directions (min {minv:.3}), radiance {:.4} (raw min {raw_min:.4})",
            100.0 * neg as f64 / table.dirs.len() as f64,
            c.x
        );
        assert!(c.min_element() >= 0.0 && c.is_finite(), "clamped and finite");
        assert!((c.x - approx.max(0.0)).abs() < 1e-9, "white sky: radiance = transfer integral");
        // Order-4 products of order-4 visibilities: the integral stays within 0.12 of the
        // exact irradiance fraction (out of 1) even with 12 overlapping occluders.
        assert!((approx - exact).abs() < 0.12, "{k}: {approx} vs {exact}");
    }
}

#[test]
fn shadow_fields_cosine_transfer_and_self_occlusion() {
    // cosine_transfer(n) is the projection of max(n.w, 0)/pi up to band 3 (band 3 is zero).
    let n = DVec3::new(0.3, 0.8, -0.2).normalize();
    let proj = penumbra_math::sh::project_fn(4, 64, |d| n.dot(d).max(0.0) / PI);
    let ct = cosine_transfer(n);
    for e in 0..NCOEF {
        assert!((proj[e] - ct[e]).abs() < 2e-3, "coef {e}: {} vs {}", proj[e], ct[e]);
    }
    // Convex sphere: no self-occlusion, so the self-transfer is the cosine lobe of the normal
    // up to the 32 x 64 direction grid.
    let raw = sphere_raw();
    let m = unit_sphere();
    for vi in (0..m.positions.len()).step_by(97) {
        let t = f64s(&raw.self_transfer[vi]);
        let c = cosine_transfer(m.normals[vi].as_dvec3());
        assert!(
            (t[0] - c[0]).abs() < 0.01 && (t[1] - c[1]).abs() < 0.02,
            "vertex {vi}: {:?} vs {:?}",
            &t[..4],
            &c[..4]
        );
    }
    // Below a cube the cube blocks part of the sphere of directions (a face subtending
    // between 0.3 and 2.6 sr whichever way `cube(0.5)` measures its size).
    let cube = MeshData::cube(0.5);
    let raw = sf::precompute(
        &cube.positions,
        &cube.normals,
        &cube.indices,
        &Params { shells: 8, resolution: 4, map_res: 16, ..sphere_params() },
        &|_| {},
    )
    .unwrap();
    let f = raw.to_fixed();
    let o = f.ocv(DVec3::new(0.0, -0.9, 0.0)).unwrap();
    let vis = o[0] / (4.0 * PI).sqrt();
    assert!(vis > 0.6 && vis < 0.99, "visible fraction below the cube {vis}");
}

#[test]
fn shadow_fields_glsl_basis_constants_match_the_sh_library() {
    // The closed forms of `sh16_basis` in glsl/include/sh16.glsl (shadow fields' and avs's),
    // read from the file, evaluated at a few directions against penumbra_math::sh.
    let src =
        std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../glsl/include/sh16.glsl"))
            .unwrap();
    let body = &src[src.find("void sh16_basis").expect("sh16_basis in sh16.glsl")..];
    let body = &body[..body.find("\n}").unwrap()];
    let lines: Vec<&str> = body.lines().filter(|l| l.trim_start().starts_with("y[")).collect();
    assert_eq!(lines.len(), 16);
    for d in [DVec3::new(0.3, -0.5, 0.8), DVec3::new(-0.9, 0.1, 0.2), DVec3::new(0.0, 1.0, 0.0)] {
        let d = d.normalize();
        let want = eval_basis(4, d);
        for (i, l) in lines.iter().enumerate() {
            // "y[i] = <expr>;" with x, yy, z: evaluate by substituting into a tiny evaluator
            let expr = l.split('=').nth(1).unwrap().trim().trim_end_matches(';');
            let got = eval_expr(expr, d.x, d.y, d.z);
            assert!((got - want[i]).abs() < 1e-6, "y[{i}] = {expr}: {got} vs {}", want[i]);
        }
    }
}

/// Evaluates the products/sums of the basis closed forms (numbers, x, yy, z, + - * and
/// parentheses).
fn eval_expr(s: &str, x: f64, y: f64, z: f64) -> f64 {
    fn sum(t: &[String], i: &mut usize, v: &(f64, f64, f64)) -> f64 {
        let mut a = prod(t, i, v);
        while *i < t.len() && (t[*i] == "+" || t[*i] == "-") {
            let op = t[*i].clone();
            *i += 1;
            let b = prod(t, i, v);
            a = if op == "+" { a + b } else { a - b };
        }
        a
    }
    fn prod(t: &[String], i: &mut usize, v: &(f64, f64, f64)) -> f64 {
        let mut a = atom(t, i, v);
        while *i < t.len() && t[*i] == "*" {
            *i += 1;
            a *= atom(t, i, v);
        }
        a
    }
    fn atom(t: &[String], i: &mut usize, v: &(f64, f64, f64)) -> f64 {
        let tok = t[*i].clone();
        *i += 1;
        match tok.as_str() {
            "-" => -atom(t, i, v),
            "(" => {
                let a = sum(t, i, v);
                *i += 1; // ")"
                a
            }
            "x" => v.0,
            "yy" => v.1,
            "z" => v.2,
            n => n.parse().unwrap_or_else(|_| panic!("token {n}")),
        }
    }
    let mut toks = Vec::new();
    let mut cur = String::new();
    for c in s.chars() {
        if c.is_alphanumeric() || c == '.' {
            cur.push(c);
        } else {
            if !cur.is_empty() {
                toks.push(std::mem::take(&mut cur));
            }
            if !c.is_whitespace() {
                toks.push(c.to_string());
            }
        }
    }
    if !cur.is_empty() {
        toks.push(cur);
    }
    let mut i = 0;
    sum(&toks, &mut i, &(x, y, z))
}

// ---------------------------------------------------------------------------------------------
// Source radiance fields (local lights), windowing, Fig. 3 ordering

fn srf_params() -> Params {
    Params { shells: 8, resolution: 32, map_res: 8, threshold: 0.010, min_resolution: 1 }
}

/// Relative eq. 1 error of `got` against `want` (normalized by want's mean |radiance|).
fn rel_eq1(got: &[f64; NCOEF], want: &[f64; NCOEF], table: &DirTable) -> f64 {
    let mut num = 0.0;
    let mut den = 0.0;
    for (_, w, y) in &table.dirs {
        let a: f64 = got.iter().zip(y).map(|(c, b)| c * b).sum();
        let b: f64 = want.iter().zip(y).map(|(c, b)| c * b).sum();
        num += w * (a - b).abs();
        den += w * b.abs();
    }
    num / den.max(1e-300)
}

#[test]
fn shadow_fields_srf_matches_the_analytic_lights() {
    let table = DirTable::new(24);
    let reach = 4.0;
    let sources = [
        ("point", LightSource::Point),
        ("spot", LightSource::Spot { cos_inner: 25f64.to_radians().cos(), cos_outer: 40f64.to_radians().cos() }),
        ("sphere", LightSource::Sphere { radius: 0.2 }),
    ];
    for (name, src) in sources {
        let raw = sf::precompute_srf(src, reach, &srf_params(), &|_| {}).unwrap();
        let fixed = raw.to_fixed();
        let adaptive = raw.to_adaptive_relative(0.010, 1);
        assert!((fixed.shell_step() * 8.0 - reach).abs() < 1e-6, "outermost shell at the reach");
        // Points between shells, inside the innermost (r < 0.5) and in the spot's cone.
        let mut worst = (0.0f64, 0.0f64);
        let mut plain_worst = 0.0f64;
        let mut inside_worst = 0.0f64;
        for k in 0..60 {
            let th = if name == "spot" { 0.05 + 0.01 * k as f64 } else { 0.2 + 0.045 * k as f64 };
            let d = sf::polar_dir(th, 0.61 * k as f64);
            let r = 0.3 + 3.6 * ((k * 37 % 60) as f64 / 60.0);
            let p = d * r;
            let want = src.rcv(p);
            if want[0] == 0.0 {
                continue;
            }
            let (gf, ga) = (fixed.rcv(p).unwrap(), adaptive.rcv(p).unwrap());
            if r < fixed.shell_step() {
                // inside the innermost shell: the innermost shell scaled by r0^2 / r^2 (exact
                // for point and spot lights; a sphere light's cap widens faster near it)
                inside_worst = inside_worst.max(rel_eq1(&gf, &want, &table));
                continue;
            }
            worst.0 = worst.0.max(rel_eq1(&gf, &want, &table));
            worst.1 = worst.1.max(rel_eq1(&ga, &want, &table));
            // plain linear interpolation between the two shells (what r^2 scaling avoids)
            let x = r / fixed.shell_step() - 1.0;
            if x > 0.0 {
                let (c0, w) = (x.floor(), x - x.floor());
                let a = src.rcv(d * fixed.shell_step() * (c0 + 1.0));
                let b = src.rcv(d * fixed.shell_step() * (c0 + 2.0));
                let lin: [f64; NCOEF] = std::array::from_fn(|e| (1.0 - w) * a[e] + w * b[e]);
                plain_worst = plain_worst.max(rel_eq1(&lin, &want, &table));
            }
        }
        println!(
            "{name}: SRF R per shell {:?}, {} -> {} B; largest relative eq.1 error fixed {:.4}, adaptive {:.4} (plain linear radial interpolation: {plain_worst:.3}; inside the innermost shell {inside_worst:.3})",
            adaptive.resolutions(),
            fixed.data_bytes(),
            adaptive.data_bytes(),
            worst.0,
            worst.1
        );
        // Sources of error: bilinear blending of lobes 11 degrees apart (R = 32) and 8-bit
        // quantization; a wrong frame, sign or radial law gives errors of order 1.
        assert!(worst.0 < 0.2 && worst.1 < 0.3, "{name}: {worst:?}");
        if name != "sphere" {
            assert!(inside_worst < 0.2, "{name} inside the innermost shell: {inside_worst}");
        }
        if name != "spot" {
            assert!(
                plain_worst > 2.0 * worst.0,
                "{name}: r^2 interpolation must beat plain linear ({plain_worst} vs {})",
                worst.0
            );
        }
        // Beyond the outermost shell: the caller's analytic fallback.
        assert!(fixed.rcv(DVec3::new(0.0, 0.0, reach * 1.01)).is_none());
        // At the light itself: no radiance, no NaN.
        assert!(fixed.rcv(DVec3::ZERO).unwrap().iter().all(|x| *x == 0.0));
    }
    // The spot's cone: no radiance behind the light, full inside the inner cone.
    let spot = LightSource::Spot { cos_inner: 0.9, cos_outer: 0.8 };
    assert!(spot.rcv(DVec3::new(0.0, 0.0, -1.0)).iter().all(|x| *x == 0.0));
    let a = spot.rcv(DVec3::new(0.0, 0.0, 2.0));
    let b = LightSource::Point.rcv(DVec3::new(0.0, 0.0, 2.0));
    assert!((a[0] - b[0]).abs() < 1e-12 && (b[0] - Y0 / 4.0).abs() < 1e-12);
    // A small sphere light approaches a point light of intensity L pi a^2.
    let s = LightSource::Sphere { radius: 0.01 }.rcv(DVec3::new(3.0, 0.0, 0.0));
    let pt = LightSource::Point.rcv(DVec3::new(3.0, 0.0, 0.0));
    for e in 0..NCOEF {
        assert!((s[e] - PI * 1e-4 * pt[e]).abs() < 1e-3 * PI * 1e-4 * pt[0].abs() + 1e-12, "coef {e}");
    }
    // Inside a sphere light: nothing (as the reference).
    assert!(LightSource::Sphere { radius: 0.5 }.rcv(DVec3::new(0.1, 0.0, 0.0)).iter().all(|x| *x == 0.0));
}

#[test]
fn shadow_fields_srf_quantization_with_a_huge_dynamic_range() {
    // 32 shells: the radiance of a point light falls 1024x from the innermost to the outermost
    // shell, and a bright light (1e6) scales everything. Per-shell min/step keeps the relative
    // quantization error of every shell at the same level.
    let raw =
        sf::precompute_srf(LightSource::Point, 8.0, &Params { shells: 32, resolution: 8, ..srf_params() }, &|_| {})
            .unwrap();
    let mut bright = raw.clone();
    for g in &mut bright.shells {
        for v in g.iter_mut() {
            for x in v.iter_mut() {
                *x *= 1e6;
            }
        }
    }
    for (label, rf) in [("unit", &raw), ("1e6", &bright)] {
        let q = rf.to_fixed();
        let mut per_shell = Vec::new();
        for (c, g) in rf.shells.iter().enumerate() {
            let scale = g[0][0].abs() as f64; // |c_0| is the same over a point light's shell
            let mut worst = 0.0f64;
            for (i, v) in g.iter().enumerate() {
                let dq = q.sample(c, i);
                for e in 0..NCOEF {
                    worst = worst.max((dq[e] - v[e] as f64).abs() / scale);
                }
            }
            per_shell.push(worst);
        }
        let (lo, hi) = per_shell.iter().fold((f64::MAX, 0.0f64), |(a, b), x| (a.min(*x), b.max(*x)));
        println!("{label}: shell 0 |c0| {:.3e}, shell 31 |c0| {:.3e}; relative quantization error per shell {lo:.2e} .. {hi:.2e}", rf.shells[0][0][0], rf.shells[31][0][0]);
        assert!((rf.shells[0][0][0] / rf.shells[31][0][0] - 1024.0).abs() < 1.0);
        // half a step of a coefficient range of at most 2 max|Y_lm| / Y_0 ~ 5.3 |c_0|: 5.3 / 510,
        // the same on every shell whatever its radiance
        assert!(hi < 1.1e-2 && hi < 1.5 * lo, "{label}: {lo} .. {hi}");
    }
}

#[test]
fn shadow_fields_lights_are_shadowed_only_by_nearer_occluders() {
    // Receiver at the origin facing +y, a unit-sphere occluder at (0, 1.4, 0); a point light
    // above it (blocked) and a point light between the receiver and the occluder (not blocked).
    let field = sphere_raw().to_fixed();
    let tensor = TripleProductTensor::new(4);
    let occ = DVec3::new(0.0, 1.4, 0.0);
    let insts =
        [InstanceFrame::new(None, DMat4::IDENTITY), InstanceFrame::new(Some(&field), DMat4::from_translation(occ))];
    let p = ShadePoint { pos: DVec3::ZERO, inst: 0, albedo: DVec3::ONE, transfer: cosine_transfer(DVec3::Y) };
    let env = [[0.0; 3]; NCOEF];
    let shade = |lpos: DVec3, with_occluder: bool| {
        let l = [LightFrame::new(None, LightSource::Point, lpos, DVec3::Z, DVec3::ONE)];
        let ins: Vec<InstanceFrame> =
            if with_occluder { insts.to_vec() } else { vec![insts[0], InstanceFrame { field: None, ..insts[1] }] };
        sf::shade_point(&p, &ins, &l, &env, &tensor, &ShadeOptions::default()).x
    };
    let above = DVec3::new(0.0, 2.9, 0.0); // behind the occluder (its centre is nearer)
    let below = DVec3::new(0.0, 0.25, 0.0); // nearer than the occluder's centre
    let (a0, a1) = (shade(above, false), shade(above, true));
    let (b0, b1) = (shade(below, false), shade(below, true));
    // Unoccluded: order-3 reconstruction of cos / pi at the normal, times 1 / r^2.
    assert!((a0 - 1.0 / PI / 2.9f64.powi(2)).abs() < 0.1 / PI / 2.9f64.powi(2), "{a0}");
    println!("light behind the occluder: {a1:.4} of {a0:.4}; light in front: {b1:.4} of {b0:.4}");
    assert!(a1 < 0.35 * a0, "a light behind an occluder is shadowed ({a1} vs {a0})");
    assert_eq!(b1, b0, "an occluder farther than the light does not shadow it");
}

#[test]
fn shadow_fields_window_reduces_ringing_of_overlapping_occluders() {
    // As the overlapping-occluders test: 12 unit spheres around a receiver; the windowed
    // visibilities ring less (fewer and smaller negative directions of the product).
    let field = sphere_raw().to_fixed();
    let tensor = TripleProductTensor::new(4);
    let table = DirTable::new(24);
    let mut insts = vec![InstanceFrame::new(None, DMat4::IDENTITY)];
    for i in 0..12 {
        let c = sf::polar_dir(0.9 + 0.25 * (i % 3) as f64, 2.0 * PI * i as f64 / 12.0);
        insts.push(InstanceFrame::new(
            Some(&field),
            DMat4::from_translation(DVec3::new(c.x, c.z.abs() + 0.3, c.y).normalize() * 1.45),
        ));
    }
    assert_eq!(Window::Hanning.sigma().map(|x| (x * 1e3).round()), [1000.0, 854.0, 500.0, 146.0]);
    assert_eq!(Window::Lanczos.sigma().map(|x| (x * 1e3).round()), [1000.0, 900.0, 637.0, 300.0]);
    assert_eq!(Window::parse("hanning"), Some(Window::Hanning));
    assert_eq!(Window::parse("boxcar"), None);
    let mut mins = Vec::new();
    for w in [Window::None, Window::Hanning, Window::Lanczos] {
        // the product of the windowed visibilities (transfer = constant 1)
        let mut u = [0.0; NCOEF];
        u[0] = (4.0 * PI).sqrt();
        for inst in &insts[1..] {
            let mut o =
                rotate(&inst.rot, &inst.field.unwrap().ocv(inst.world_to_local.transform_point3(DVec3::ZERO)).unwrap());
            w.apply(&mut o);
            u = sf::triple(&tensor, &o, &u);
        }
        let minv = table
            .dirs
            .iter()
            .map(|(_, _, y)| u.iter().zip(y).map(|(a, b)| a * b).sum::<f64>())
            .fold(f64::MAX, f64::min);
        println!("{w:?}: most negative visibility product {minv:.3}, DC {:.3}", u[0] * Y0);
        mins.push(minv);
    }
    assert!(mins[1] > mins[0] && mins[2] > mins[0], "windows reduce the negative lobes: {mins:?}");
}

#[test]
fn shadow_fields_haar_all_frequency_variant() {
    use penumbra_math::shadow_field::haar::{self, CubeTable, HaarField};
    let m = unit_sphere();
    let table = CubeTable::new(8);
    let n = table.n;
    // the transform is orthonormal and inverts exactly
    let mut x: Vec<f32> = (0..6 * n * n).map(|i| ((i * 7919) % 13) as f32 / 13.0).collect();
    let orig = x.clone();
    haar::forward(&mut x, n);
    let (e0, e1): (f32, f32) = (orig.iter().map(|v| v * v).sum(), x.iter().map(|v| v * v).sum());
    assert!((e0 - e1).abs() < 1e-3 * e0, "energy {e0} vs {e1}");
    haar::inverse(&mut x, n);
    assert!(x.iter().zip(&orig).all(|(a, b)| (a - b).abs() < 1e-5));
    let (r0, shells) = (8, 8);
    let (center, vr, maps) = haar::raw_maps(&m.positions, &m.indices, shells, r0, &table);
    let fixed = HaarField::build(center, vr, &maps, r0, &table, 0.05, false, 0.01);
    let adaptive = HaarField::build(center, vr, &maps, r0, &table, 0.05, true, 0.01);
    println!(
        "Haar 5% ({}x{} faces): fixed {} B, adaptive {} B, R per shell {:?}",
        n,
        n,
        fixed.bytes(),
        adaptive.bytes(),
        adaptive.resolutions()
    );
    assert!(adaptive.bytes() < fixed.bytes());
    assert!(adaptive.resolutions()[..4].iter().all(|&r| r == 1), "shells inside the sphere collapse");
    // The cache file (PSW1) round-trips exactly; cut or altered files are errors, not panics.
    for f in [&fixed, &adaptive] {
        let b = f.to_bytes();
        let back = HaarField::from_bytes(&b).unwrap();
        assert_eq!((back.n, back.center, back.bound_radius), (f.n, f.center, f.bound_radius));
        assert_eq!(back.resolutions(), f.resolutions());
        for (x, y) in back.shells.iter().zip(&f.shells) {
            assert_eq!((x.min, x.step, &x.samples), (y.min, y.step, &y.samples));
        }
        assert_eq!(back.to_bytes(), b);
        for cut in [3, 20, b.len() / 2, b.len() - 1] {
            assert!(HaarField::from_bytes(&b[..cut]).is_err(), "cut at {cut}");
        }
        let mut trailing = b.clone();
        trailing.push(0);
        assert!(HaarField::from_bytes(&trailing).is_err());
        let mut bad_n = b.clone();
        bad_n[4] = 3;
        assert!(HaarField::from_bytes(&bad_n).unwrap_err().contains("cube resolution"));
    }
    // Accuracy at points outside the sphere against ray-cast visibility, next to the
    // order-4 SH field of the same sphere: all frequency is sharper than order-4 SH.
    let sh = sphere_raw().to_fixed();
    let (mut eh, mut es) = (0.0f64, 0.0f64);
    // (at shell sample points, so both representations are compared without the interpolation
    // between samples 0.4 rad apart, which blurs both)
    for k in 0..12 {
        let (th, ph) = sample_angles(r0, 1 + k % 6, (3 * k) % 8);
        let dir = sf::polar_dir(th, ph);
        let p = dir * 0.2 * (5 + k % 3 + 1) as f64;
        let exact: Vec<f32> = table
            .dirs
            .iter()
            .map(|d| {
                let b = d.dot(-p);
                if b > 0.0 && p.length_squared() - b * b < 1.0 {
                    0.0
                } else {
                    1.0
                }
            })
            .collect();
        eh = eh.max(haar::l1(&fixed.map_at(p).unwrap(), &exact, &table));
        let o = sh.ocv(p).unwrap();
        let shmap: Vec<f32> = table
            .dirs
            .iter()
            .map(|d| {
                let mut y = [0.0; NCOEF];
                eval_basis_into(4, *d, &mut y);
                o.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>() as f32
            })
            .collect();
        es = es.max(haar::l1(&shmap, &exact, &table));
    }
    println!("largest eq.1 error against ray casting: Haar 5% {eh:.4}, SH order 4 {es:.4}");
    assert!(eh < es, "all-frequency {eh} vs SH {es}");
    // Two occluders: the product (wavelet triple product in the pixel domain) blocks both caps.
    let p = DVec3::ZERO;
    let (a, b) = (DVec3::new(1.4, 0.0, 0.0), DVec3::new(0.0, 0.0, 1.45));
    let prod = HaarField::product_map(&[(&fixed, a), (&fixed, b)], p, n);
    let exact: Vec<f32> = table
        .dirs
        .iter()
        .map(|d| {
            let hit = |c: DVec3| {
                let t = d.dot(c);
                t > 0.0 && c.length_squared() - t * t < 1.0
            };
            if hit(a) || hit(b) {
                0.0
            } else {
                1.0
            }
        })
        .collect();
    let e = haar::l1(&prod, &exact, &table);
    let vis: f64 = prod.iter().zip(&table.w).map(|(v, w)| *v as f64 * w).sum::<f64>() / (4.0 * PI);
    let vis_exact: f64 = exact.iter().zip(&table.w).map(|(v, w)| *v as f64 * w).sum::<f64>() / (4.0 * PI);
    println!("two occluders: product vs exact eq.1 error {e:.4}, visible fraction {vis:.3} vs {vis_exact:.3}");
    assert!(e < 0.1 && (vis - vis_exact).abs() < 0.05, "{e} {vis} {vis_exact}");
    // What the GPU reads: each sample's truncated map thresholded back to one bit per pixel,
    // pixel k at bit k % 32 of word k / 32; it disagrees with the ray-cast map on few pixels
    // (measured 3.5 % on the shell through the sphere's surface, where 5 % of 6 x 8 x 8 is 20
    // coefficients for a half-blocked map; a wrong bit order would be tens of per cent).
    let per = (6 * n * n).div_ceil(32);
    for c in [4usize, 7] {
        let bits = fixed.shell_bits(c);
        assert_eq!(bits.len(), r0 * r0 * per);
        let mut wrong = 0usize;
        for (idx, raw) in maps[c].iter().enumerate() {
            for (k, v) in raw.iter().enumerate() {
                let bit = (bits[idx * per + k / 32] >> (k % 32)) & 1;
                wrong += (bit as f32 != *v) as usize;
            }
        }
        let frac = wrong as f64 / (r0 * r0 * 6 * n * n) as f64;
        println!("shell {c}: binary maps differ from ray casting on {:.2} % of pixels", 100.0 * frac);
        assert!(frac < 0.05, "shell {c}: {frac}");
    }
}

/// Per-vertex self-visibility maps (the all-frequency variant's self-occlusion): a convex
/// sphere's vertices see their whole upper hemisphere and nothing below it; a torus vertex on
/// the inner side of the ring (facing the hole) sees the far side of the ring block part of its
/// upper hemisphere, one on the outer equator sees all of it.
#[test]
fn shadow_fields_haar_self_visibility_maps() {
    use penumbra_math::shadow_field::haar::{self_maps, CubeTable};
    let table = CubeTable::new(8);
    let per = table.dirs.len().div_ceil(32);
    let bit = |maps: &[u32], v: usize, k: usize| (maps[v * per + k / 32] >> (k % 32)) & 1 == 1;
    let s = penumbra_scene::MeshData::icosphere(1.0, 2);
    let maps = self_maps(&s.positions, &s.normals, &s.indices, &table);
    assert_eq!(maps.len(), s.positions.len() * per);
    for v in (0..s.positions.len()).step_by(7) {
        let n = s.normals[v].as_dvec3();
        for (k, d) in table.dirs.iter().enumerate() {
            let c = d.dot(n);
            if c > 0.05 {
                assert!(bit(&maps, v, k), "sphere vertex {v}: direction {d:?} (n.d {c}) blocked");
            } else if c < 0.0 {
                assert!(!bit(&maps, v, k), "sphere vertex {v}: direction {d:?} below the surface open");
            }
        }
    }
    let t = penumbra_scene::MeshData::torus(1.0, 0.3, 32, 16);
    let maps = self_maps(&t.positions, &t.normals, &t.indices, &table);
    let blocked_above = |v: usize| {
        let n = t.normals[v].as_dvec3();
        table.dirs.iter().enumerate().filter(|(k, d)| d.dot(n) > 0.05 && !bit(&maps, v, *k)).count()
    };
    // the vertex nearest the torus axis (+y: inner equator) and the one farthest (outer equator)
    let r = |v: usize| (t.positions[v].x.powi(2) + t.positions[v].z.powi(2)).sqrt();
    let inner = (0..t.positions.len()).min_by(|&a, &b| r(a).total_cmp(&r(b))).unwrap();
    let outer = (0..t.positions.len()).max_by(|&a, &b| r(a).total_cmp(&r(b))).unwrap();
    let (bi, bo) = (blocked_above(inner), blocked_above(outer));
    println!("torus: inner-equator vertex {bi} upper-hemisphere pixels blocked, outer {bo}");
    assert!(bi >= 10, "inner vertex sees the far side of the ring: {bi}");
    assert_eq!(bo, 0, "outer vertex sees its whole upper hemisphere");
}

/// A real emitter's source radiance field (`precompute_srf_through`): a point light under a
/// square plate (the fixture, light frame) is dark above the plate and unchanged below and
/// beside it; a sphere light half hidden by a half-plane keeps about half its projected
/// radiance, exactly the closed form where nothing hides it; no fixture is `rcv` bit for bit;
/// the field stores the shadow and extrapolates it beyond its outermost shell.
#[test]
fn srf_through_a_fixture_holds_its_shadow() {
    // a plate 0.5 above the light, 0.6 wide (two triangles)
    let plate =
        [Vec3::new(-0.3, -0.3, 0.5), Vec3::new(0.3, -0.3, 0.5), Vec3::new(0.3, 0.3, 0.5), Vec3::new(-0.3, 0.3, 0.5)];
    let caster = sf::RayCaster::new(&plate, &[0, 1, 2, 0, 2, 3]);
    let pt = LightSource::Point;
    for p in [DVec3::new(0.0, 0.0, 2.0), DVec3::new(0.2, -0.1, 1.5), DVec3::new(0.05, 0.0, 0.6)] {
        assert!(pt.rcv_through(p, Some(&caster)).iter().all(|&x| x == 0.0), "{p} is under the plate's shadow");
    }
    for p in [DVec3::new(0.0, 0.0, -2.0), DVec3::new(2.0, 0.0, 1.0), DVec3::new(0.0, 0.0, 0.4)] {
        assert_eq!(pt.rcv_through(p, Some(&caster)), pt.rcv(p), "{p} sees the light");
    }
    let sph = LightSource::Sphere { radius: 0.3 };
    let p = DVec3::new(0.0, 0.0, -3.0);
    assert_eq!(sph.rcv_through(p, None), sph.rcv(p));
    assert_eq!(sph.rcv_through(p, Some(&caster)), sph.rcv(p), "the plate is behind the light");
    // a half-plane x > 0 between p and the light hides half the cap
    let big = 50.0;
    let half =
        [Vec3::new(0.0, -big, -1.5), Vec3::new(big, -big, -1.5), Vec3::new(big, big, -1.5), Vec3::new(0.0, big, -1.5)];
    let hider = sf::RayCaster::new(&half, &[0, 1, 2, 0, 2, 3]);
    let open = sph.rcv(p);
    let hidden = sph.rcv_through(p, Some(&hider));
    let share = hidden[0] / open[0];
    assert!((share - 0.5).abs() < 0.02, "half the cap: {share}");
    // the projected radiance leans towards -x (the visible half)
    let at =
        |c: &[f64; NCOEF], d: DVec3| -> f64 { c.iter().zip(eval_basis(4, d.normalize())).map(|(a, b)| a * b).sum() };
    let (left, right) = (DVec3::new(-0.1, 0.0, 1.0), DVec3::new(0.1, 0.0, 1.0));
    // (order 4 barely resolves a 6-degree cap: a few percent)
    assert!(at(&hidden, left) > 1.02 * at(&hidden, right), "{} {}", at(&hidden, left), at(&hidden, right));
    assert!((at(&open, left) - at(&open, right)).abs() < 1e-9);

    // The field: 8 shells to reach 4, the plate in it; above the plate beyond the outermost
    // shell the extrapolated field is still dark, the analytic light is not.
    let raw = sf::precompute_srf_through(pt, Some(&caster), 4.0, &srf_params(), &|_| {}).unwrap();
    assert_eq!(raw.rays, (8 * 32 * 32) as u64);
    let f = raw.to_fixed();
    let above = DVec3::new(0.0, 0.0, 3.0);
    let below = DVec3::new(0.0, 0.0, -3.0);
    assert!(f.rcv(above).unwrap()[0].abs() < 1e-3 * pt.rcv(above)[0]);
    let b = f.rcv(below).unwrap()[0];
    assert!((b / pt.rcv(below)[0] - 1.0).abs() < 0.02, "below: {b} vs {}", pt.rcv(below)[0]);
    let far_above = DVec3::new(0.0, 0.0, 9.0);
    assert!(f.rcv(far_above).is_none());
    assert!(f.rcv_beyond(far_above, true).unwrap()[0].abs() < 1e-3 * pt.rcv(far_above)[0]);
    let far_below = DVec3::new(0.0, 0.1, -9.0);
    let fb = f.rcv_beyond(far_below, true).unwrap()[0];
    assert!((fb / pt.rcv(far_below)[0] - 1.0).abs() < 0.02, "{fb} vs {}", pt.rcv(far_below)[0]);
    // light frames: a fixture's light frame extrapolates its field
    let world = DMat4::from_rotation_translation(glam::DQuat::from_rotation_y(0.3), DVec3::new(1.0, 2.0, 3.0));
    let lf = LightFrame::with_world(Some(&f), pt, world, DVec3::ONE);
    assert!(lf.extrapolate && (lf.position - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
    let up_world = world.transform_point3(far_above);
    assert!(lf.rcv_world(up_world)[0].abs() < 1e-6, "dark far above the plate, in world");
}
