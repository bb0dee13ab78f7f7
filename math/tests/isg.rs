//! Integral spherical Gaussian: exact integration, the paper's fit, the table, the patch
//! visibility integral and its extremes.

use glam::DVec3;
use penumbra_math::isg::*;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::OnceLock;

fn table() -> &'static IsgTable {
    static T: OnceLock<IsgTable> = OnceLock::new();
    T.get_or_init(IsgTable::default_table)
}

#[test]
fn exact_isg_matches_closed_forms() {
    for g in [1e-2, 0.5, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5] {
        let full = isg_exact(PI, PI, g);
        let want = hemisphere_integral(g);
        assert!(((full - want) / want).abs() < 1e-9, "gamma {g}: S(pi,pi) {full} vs {want}");
        // Symmetry about the lobe axis: each half holds half.
        let half_t = isg_exact(FRAC_PI_2, PI, g);
        let half_p = isg_exact(PI, FRAC_PI_2, g);
        assert!(((half_t / want) - 0.5).abs() < 1e-9, "gamma {g}: theta half {}", half_t / want);
        assert!(((half_p / want) - 0.5).abs() < 1e-9, "gamma {g}: phi half {}", half_p / want);
        // Quadrant: S(pi/2, pi/2) = 1/4 by symmetry.
        let q = isg_exact(FRAC_PI_2, FRAC_PI_2, g) / want;
        assert!((q - 0.25).abs() < 1e-9, "gamma {g}: quadrant {q}");
    }
    // A polar cap about the lobe axis: int exp(g(cos-1)) over the cap of half-angle a is
    // 2 pi (1 - exp(g (cos a - 1))) / g; a square patch is not a cap, but the exact ISG of a thin
    // patch around the axis must approach the SG value times the patch's solid angle.
    let g = 50.0;
    let h = 1e-3;
    let s = isg_exact(FRAC_PI_2 + h, FRAC_PI_2 + h, g)
        - isg_exact(FRAC_PI_2 - h, FRAC_PI_2 + h, g)
        - isg_exact(FRAC_PI_2 + h, FRAC_PI_2 - h, g)
        + isg_exact(FRAC_PI_2 - h, FRAC_PI_2 - h, g);
    assert!((s / (4.0 * h * h) - 1.0).abs() < 1e-4, "thin patch {}", s / (4.0 * h * h));
}

fn gammas() -> Vec<f64> {
    // 1 to 10000, 4 per decade, offset from the table levels (16 per decade) on purpose.
    (0..=16).map(|i| 10f64.powf(i as f64 / 4.0 + 0.03125)).filter(|g| *g <= 1e4).chain([1.0, 1e4]).collect()
}

#[test]
fn paper_fit_and_table_errors() {
    let gs = gammas();
    let fit = fit_error(&paper_fit, &gs, 41);
    let t = table();
    let tab = fit_error(&|th, ph, g| t.eval(th, ph, g), &gs, 41);
    println!(
        "paper two-sigmoid fit, gamma 1..1e4: max {:.4} (at gamma {:.1}), rms {:.5}",
        fit.max, fit.worst_gamma, fit.rms
    );
    println!(
        "table (16/decade, 65^2), gamma 1..1e4: max {:.5} (at gamma {:.1}), rms {:.6}",
        tab.max, tab.worst_gamma, tab.rms
    );
    for g in [1.0, 10.0, 100.0, 1000.0, 1e4] {
        let e = fit_error(&paper_fit, &[g], 41);
        println!("  paper fit at gamma {g}: max {:.4} rms {:.5} (g = {:.2})", e.max, e.rms, paper_g(g));
    }
    // The table is what the technique uses: it must be accurate everywhere.
    assert!(tab.max < 4e-3, "table max error {}", tab.max);
    assert!(tab.rms < 5e-4, "table rms error {}", tab.rms);
    // The paper's fit is much worse (this is why the table exists); if this ever fails the fit
    // got better than the table and could replace it.
    assert!(fit.max > 10.0 * tab.max, "fit {} vs table {}", fit.max, tab.max);
    // Outside the fit range: the table still tracks the exact ISG.
    let ext = fit_error(&|th, ph, g| t.eval(th, ph, g), &[1e-2, 0.03, 0.3, 3e4, 1e5, 3e5], 41);
    println!("table outside 1..1e4 (1e-2..3e5): max {:.5} rms {:.6}", ext.max, ext.rms);
    assert!(ext.max < 1e-2, "table outside the fit range: max {}", ext.max);
}

#[test]
fn extremes_have_no_nan() {
    let t = table();
    for g in [0.0, 1e-6, 1e-2, 1.0, 1e4, 1e5, 1e7, f64::INFINITY, f64::NAN, -5.0] {
        for (th, ph) in [(0.0, 0.0), (PI, PI), (FRAC_PI_2, FRAC_PI_2), (-1.0, 7.0), (f64::NAN, 1.0)] {
            let v = t.eval(th, ph, g);
            assert!(v.is_finite() && (0.0..=1.0).contains(&v), "table({th},{ph},{g}) = {v}");
            let f = paper_fit(th, ph, g);
            assert!(f.is_nan() == th.is_nan() && (f.is_nan() || (0.0..=1.0).contains(&f)), "fit({th},{ph},{g}) = {f}");
        }
        let d = t.limiting_angle(g, 0.01);
        assert!(d.is_finite() && d > 0.0 && d <= FRAC_PI_2, "limiting angle {d} at {g}");
        let s = [Sphere { center: DVec3::new(0.0, 0.0, 2.0), radius: 0.5 }];
        let v = visible_fraction(t, DVec3::ZERO, DVec3::Z, DVec3::Z, g, &s, &IsgParams::default());
        assert!(v.is_finite() && (0.0..=1.0).contains(&v), "visible {v} at gamma {g}");
        let v = isg_exact(1.0, 2.0, g);
        assert!(v.is_finite(), "exact at {g}: {v}");
    }
    // Limiting angle shrinks with sharpness like 1/sqrt(gamma).
    let d100 = t.limiting_angle(100.0, 0.01);
    let d10k = t.limiting_angle(1e4, 0.01);
    assert!((d100 / d10k - 10.0).abs() < 0.5, "limiting angles {d100} {d10k}");
}

#[test]
fn cap_on_axis_matches_analytic() {
    // A sphere on the lobe axis subtends a cap of half-angle psi; the visible fraction of the
    // hemisphere integral is (exp(g (cos psi - 1)) - exp(-g)) / (1 - exp(-g)).
    let t = table();
    let params = IsgParams::default();
    for (g, psi) in [(10.0, 0.5), (100.0, 0.1), (100.0, 0.3), (1000.0, 0.05), (1e4, 0.02), (1e5, 0.01)] {
        let r: f64 = 1.0;
        let dist = r / f64::sin(psi);
        let s = [Sphere { center: DVec3::new(0.0, 0.0, dist), radius: r }];
        let v = visible_fraction(t, DVec3::ZERO, DVec3::Z, DVec3::Z, g, &s, &params);
        let want = ((g * (psi.cos() - 1.0)).exp() - (-g).exp()) / (1.0 - (-g).exp());
        let brute = visible_fraction_brute(DVec3::ZERO, DVec3::Z, DVec3::Z, g, &s, 400);
        println!("gamma {g} psi {psi}: patches {v:.4} brute {brute:.4} analytic {want:.4}");
        assert!((brute - want).abs() < 3e-3, "brute force {brute} vs {want}");
        assert!((v - want).abs() < 0.05, "gamma {g} psi {psi}: {v} vs {want}");
    }
}

#[test]
fn off_axis_spheres_match_brute_force() {
    let t = table();
    let params = IsgParams::default();
    let mut worst: f64 = 0.0;
    let mut sum = 0.0;
    let mut cnt = 0;
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for case in 0..40 {
        let g = 10f64.powf(0.5 + 3.5 * rnd());
        let axis = DVec3::new(rnd() - 0.5, rnd() - 0.5, 0.6 + rnd()).normalize();
        let width = (3.0 / g.sqrt()).min(1.0);
        let spheres: Vec<Sphere> = (0..3)
            .map(|_| {
                let dir = (axis + DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * 2.0 * width).normalize();
                let dist = 2.0 + 3.0 * rnd();
                Sphere { center: dir * dist, radius: dist * (0.3 * width * rnd() + 0.01).min(0.9) }
            })
            .collect();
        let v = visible_fraction(t, DVec3::ZERO, DVec3::Z, axis, g, &spheres, &params);
        let b = visible_fraction_brute(DVec3::ZERO, DVec3::Z, axis, g, &spheres, 300);
        worst = worst.max((v - b).abs());
        sum += (v - b).powi(2);
        cnt += 1;
        assert!(v.is_finite(), "case {case}");
    }
    let rms = (sum / cnt as f64).sqrt();
    println!("random spheres (40 cases, 16x16 patches): max |patch - brute| {worst:.4}, rms {rms:.4}");
    assert!(worst < 0.08 && rms < 0.03, "patch visibility error max {worst} rms {rms}");
}

#[test]
fn blocker_extremes() {
    let t = table();
    let params = IsgParams::default();
    let p = DVec3::ZERO;
    let n = DVec3::Z;
    // Zero spheres.
    assert_eq!(visible_fraction(t, p, n, n, 100.0, &[], &params), 1.0);
    // Sphere containing the point / touching it: skipped (receiver's own proxy).
    let inside = [Sphere { center: DVec3::new(0.0, 0.0, 0.2), radius: 0.5 }];
    assert_eq!(visible_fraction(t, p, n, n, 100.0, &inside, &params), 1.0);
    let touching = [Sphere { center: DVec3::new(0.0, 0.0, 0.5), radius: 0.5 }];
    assert_eq!(visible_fraction(t, p, n, n, 100.0, &touching, &params), 1.0);
    // Blocker behind the surface: no shadow.
    let behind = [Sphere { center: DVec3::new(0.0, 0.0, -2.0), radius: 0.5 }];
    assert_eq!(visible_fraction(t, p, n, n, 1.0, &behind, &params), 1.0);
    // Huge blocker just above: almost everything blocked for a sharp lobe.
    let big = [Sphere { center: DVec3::new(0.0, 0.0, 10.0), radius: 9.9 }];
    let v = visible_fraction(t, p, n, n, 1000.0, &big, &params);
    assert!(v < 0.01, "big blocker {v}");
    // Lobe at the horizon, blocker on the horizon in the lobe direction.
    let ax = DVec3::X;
    let h = [Sphere { center: DVec3::new(3.0, 0.0, 0.0), radius: 0.6 }];
    let v = visible_fraction(t, p, n, ax, 200.0, &h, &params);
    let b = visible_fraction_brute(p, n, ax, 200.0, &h, 300);
    assert!((v - b).abs() < 0.05 && v < 0.9, "horizon {v} vs {b}");
    // Degenerate inputs.
    let bad = [Sphere { center: DVec3::splat(f64::NAN), radius: 1.0 }, Sphere { center: DVec3::X, radius: -1.0 }];
    assert_eq!(visible_fraction(t, p, n, n, 10.0, &bad, &params), 1.0);
    let v = visible_fraction(t, p, DVec3::ZERO, DVec3::ZERO, 10.0, &big, &params);
    assert!(v.is_finite());
}

/// Two triangles of the rectangle `[-a, a] x [-b, b]` at height `h` above the origin (normal Z).
fn quad(a: f64, b: f64, h: f64) -> [Triangle; 2] {
    let (p00, p10, p11, p01) = (DVec3::new(-a, -b, h), DVec3::new(a, -b, h), DVec3::new(a, b, h), DVec3::new(-a, b, h));
    [[p00, p10, p11], [p00, p11, p01]]
}

#[test]
fn thin_quad_matches_analytic_solid_angle_and_irradiance() {
    let t = table();
    let p = DVec3::ZERO;
    let n = DVec3::Z;
    for (a, b, h) in [(0.5, 0.5, 1.0), (1.0, 0.4, 0.5), (2.0, 2.0, 0.5), (0.2, 0.3, 1.0)] {
        let tris = quad(a, b, h);
        // Solid angle of the centred rectangle: 4 asin(a b / sqrt((a^2 + h^2)(b^2 + h^2))).
        let omega = 4.0 * (a * b / ((a * a + h * h) * (b * b + h * h)).sqrt()).asin();
        // A nearly constant lobe (gamma = 1e-2): the occluded fraction is omega / 2 pi (to 1%).
        let g = 1e-2;
        let want = 1.0 - omega / (2.0 * PI);
        let brute = visible_fraction_brute_with_triangles(p, n, n, g, &[], &tris, 400);
        let mut errs = Vec::new();
        for side in [12, 16, 24, 48] {
            let params = IsgParams { patch_side: side, ..Default::default() };
            let v = visible_fraction_with_triangles(t, p, n, n, g, &[], &tris, &params);
            errs.push((side, v - want));
        }
        println!("quad {a}x{b} at {h}: solid angle {omega:.4}: analytic visible {want:.4}, brute {brute:.4}, patches {errs:?}");
        assert!((brute - want).abs() < 0.01 * (1.0 - want) + 2e-3, "brute force {brute} vs analytic {want}");
        for (side, e) in &errs {
            // Discretization: patch centres decide, so the outline is off by up to half a patch
            // (a wide quad leaves a visible band of 1-2 patches at 16 x 16: error ~0.12; 0.006
            // at 48 x 48).
            assert!(e.abs() < 3.0 / *side as f64, "side {side}: error {e}");
        }
        // Irradiance under a uniform sky: the cosine SG's visible fraction against 1 - F, with
        // F the point-to-parallel-rectangle form factor (four corner rectangles).
        let f_corner = |x: f64, y: f64| {
            let (xa, yb) = (x / h, y / h);
            (xa / (1.0 + xa * xa).sqrt() * (yb / (1.0 + xa * xa).sqrt()).atan()
                + yb / (1.0 + yb * yb).sqrt() * (xa / (1.0 + yb * yb).sqrt()).atan())
                / (2.0 * PI)
        };
        let form = 4.0 * f_corner(a, b);
        // (48 x 48 patches and epsilon 1e-4: the discretization is tested above; this isolates
        // the cosine SG. With epsilon 0.01 the limiting angle of the cosine lobe is below pi/2
        // and the outer patches, which extend to the horizon, carry its tail: the 2 x 2 quad,
        // whose visible band lies in that tail, then gets 0.028 for 0.078.)
        let params = IsgParams { patch_side: 48, epsilon: 1e-4, ..Default::default() };
        let lc = penumbra_math::sg::CLAMPED_COSINE_LAMBDA;
        let v = visible_fraction_with_triangles(t, p, n, n, lc, &[], &tris, &params);
        let brute = visible_fraction_brute_with_triangles(p, n, n, lc, &[], &tris, 400);
        println!("  irradiance: cosine-SG visible {v:.4} (brute {brute:.4}) vs analytic 1 - F = {:.4}", 1.0 - form);
        // The patches integrate the cosine SG to the discretization error; the cosine SG itself
        // (lambda 2.133, sharper than the cosine) overestimates occlusion near the normal by up
        // to ~0.05 of the irradiance here.
        assert!((v - brute).abs() < 0.015, "irradiance patches {v} vs brute force {brute}");
        assert!((v - (1.0 - form)).abs() < 0.06, "irradiance visible {v} vs {}", 1.0 - form);
    }
}

#[test]
fn random_triangles_match_brute_force_and_extremes() {
    let t = table();
    let params = IsgParams::default();
    let mut seed = 777u64;
    let mut rnd = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut worst, mut sum) = (0.0f64, 0.0);
    for case in 0..30 {
        let g = 10f64.powf(-1.0 + 4.5 * rnd());
        let axis = DVec3::new(rnd() - 0.5, rnd() - 0.5, 0.3 + rnd()).normalize();
        let width = (3.0 / g.sqrt()).min(1.2);
        let tris: Vec<Triangle> = (0..4)
            .map(|_| {
                let c = (axis + DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * 2.0 * width).normalize()
                    * (1.0 + 2.0 * rnd());
                let s = c.length() * width * (0.2 + rnd());
                [0, 1, 2].map(|_| c + DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * s)
            })
            .collect();
        let v = visible_fraction_with_triangles(t, DVec3::ZERO, DVec3::Z, axis, g, &[], &tris, &params);
        let b = visible_fraction_brute_with_triangles(DVec3::ZERO, DVec3::Z, axis, g, &[], &tris, 300);
        assert!(v.is_finite() && (0.0..=1.0).contains(&v), "case {case}: {v}");
        worst = worst.max((v - b).abs());
        sum += (v - b).powi(2);
    }
    let rms = (sum / 30.0).sqrt();
    println!("random triangles (30 cases, 16x16 patches): max |patch - brute| {worst:.4}, rms {rms:.4}");
    assert!(worst < 0.1 && rms < 0.04, "triangle visibility error max {worst} rms {rms}");
    // Extremes: a triangle through the point (its plane contains it), below the surface, on the
    // horizon, degenerate.
    let (p, n) = (DVec3::ZERO, DVec3::Z);
    let flat = [[DVec3::new(-1.0, -1.0, 0.0), DVec3::new(1.0, -1.0, 0.0), DVec3::new(0.0, 1.0, 0.0)]];
    assert_eq!(visible_fraction_with_triangles(t, p, n, n, 10.0, &[], &flat, &params), 1.0);
    let below = [[DVec3::new(-1.0, -1.0, -0.5), DVec3::new(1.0, -1.0, -0.5), DVec3::new(0.0, 1.0, -0.1)]];
    assert_eq!(visible_fraction_with_triangles(t, p, n, n, 1.0, &[], &below, &params), 1.0);
    let wall = [[DVec3::new(2.0, -1.0, -0.2), DVec3::new(2.0, 1.0, -0.2), DVec3::new(2.0, 0.0, 1.0)]];
    let v = visible_fraction_with_triangles(t, p, n, DVec3::X, 300.0, &[], &wall, &params);
    let b = visible_fraction_brute_with_triangles(p, n, DVec3::X, 300.0, &[], &wall, 300);
    assert!(v < 0.8 && (v - b).abs() < 0.08, "horizon wall {v} vs {b}");
    let degenerate = [[DVec3::Z, DVec3::Z, DVec3::Z], [DVec3::splat(f64::NAN), DVec3::Z, DVec3::X]];
    assert_eq!(visible_fraction_with_triangles(t, p, n, n, 10.0, &[], &degenerate, &params), 1.0);
    // A huge sheet just above blocks everything, at every sharpness.
    let sheet = quad(100.0, 100.0, 0.1);
    for g in [1e-2, 1.0, 1e3, 1e5] {
        let v = visible_fraction_with_triangles(t, p, n, n, g, &[], &sheet, &params);
        assert!(v < 0.02, "sheet at gamma {g}: {v}");
    }
}

/// The paper's patch rule (`PatchRule::Paper`) marks every patch a sphere's cap overlaps: a
/// superset of the centre rule's patches, so never more visible, and against brute force it errs
/// on the dark side (a patch's band around each outline); the paper's sigmoid fit
/// (`IsgModel::PaperFit`) departs from the table by the fit's own error.
#[test]
fn paper_rule_and_fit_bracket_the_default() {
    let t = table();
    let mut seed = 4242u64;
    let mut rnd = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let (p, n) = (DVec3::ZERO, DVec3::Z);
    let (mut darker, mut brute_err_centre, mut brute_err_paper, mut fit_err, mut count) =
        (0, 0.0f64, 0.0f64, 0.0f64, 0);
    for k in 0..300 {
        let spheres: Vec<Sphere> = (0..1 + k % 4)
            .map(|_| Sphere {
                center: DVec3::new(rnd() - 0.5, rnd() - 0.5, 0.3 + rnd()) * 3.0,
                radius: 0.05 + 0.4 * rnd(),
            })
            .collect();
        let axis = DVec3::new(rnd() - 0.5, rnd() - 0.5, 0.2 + rnd()).normalize();
        let gamma = [0.5, 2.133, 10.0, 100.0, 1000.0][k % 5];
        let centre = IsgParams { patch_side: 16, ..Default::default() };
        let paper = IsgParams { rule: PatchRule::Paper, ..centre };
        let fit = IsgParams { model: IsgModel::PaperFit, ..centre };
        let vc = visible_fraction(t, p, n, axis, gamma, &spheres, &centre);
        let vp = visible_fraction(t, p, n, axis, gamma, &spheres, &paper);
        let vf = visible_fraction(t, p, n, axis, gamma, &spheres, &fit);
        assert!(vp <= vc + 1e-12, "case {k}: paper rule {vp} more visible than the centre rule {vc}");
        for v in [vc, vp, vf] {
            assert!(v.is_finite() && (0.0..=1.0).contains(&v), "case {k}: {v}");
        }
        if vc < 0.999 {
            let brute = visible_fraction_brute(p, n, axis, gamma, &spheres, 300);
            darker += (vp < vc - 1e-9) as usize;
            brute_err_centre += (vc - brute).powi(2);
            brute_err_paper += (vp - brute).powi(2);
            fit_err = fit_err.max((vf - vc).abs());
            count += 1;
        }
    }
    let rms = |s: f64| (s / count.max(1) as f64).sqrt();
    println!(
        "{count} occluded cases: paper rule darker in {darker}; rms error against brute force: centre {:.4}, paper {:.4}; sigmoid fit vs table: max {fit_err:.4}",
        rms(brute_err_centre),
        rms(brute_err_paper)
    );
    assert!(count > 100 && darker > count / 4, "the rules barely differ ({darker} of {count})");
    // the centre rule is the more accurate one at 16 x 16 patches (why it is the default)
    assert!(
        rms(brute_err_centre) < rms(brute_err_paper),
        "centre {} vs paper {}",
        rms(brute_err_centre),
        rms(brute_err_paper)
    );
    // Measured 0.60: below gamma ~ 100 the appendix's slopes (g(1) = 17.6) make the sigmoids far
    // sharper than the lobe (`paper_fit_and_table_errors`), so the fit's visibility is off by
    // much more than the table's; this is why the table is the default.
    assert!(fit_err > 0.1, "sigmoid fit vs table: {fit_err}: the fit got good, reconsider the default");
}
