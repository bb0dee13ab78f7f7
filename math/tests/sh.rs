//! SH identities: reference values, orthonormality by quadrature, rotation against re-projection,
//! double and triple products against pointwise products.

use glam::{DMat3, DQuat, DVec3};
use penumbra_math::quad::{integrate_sphere_about, sphere_product_rule};
use penumbra_math::sh::*;

/// Small deterministic PRNG (xorshift) so tests need no extra crates.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn coeffs(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| 2.0 * self.next() - 1.0).collect()
    }
    fn rotation(&mut self) -> DMat3 {
        let q =
            DQuat::from_xyzw(self.next() - 0.5, self.next() - 0.5, self.next() - 0.5, self.next() - 0.5).normalize();
        DMat3::from_quat(q)
    }
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

#[test]
fn reference_values_and_convention() {
    let d = DVec3::new(0.36, 0.48, 0.8);
    let y = eval_basis(3, d);
    let c1 = 0.488_602_511_902_919_9; // sqrt(3/(4 pi))
    assert!((y[0] - 0.282_094_791_773_878_14).abs() < 1e-15);
    assert!((y[sh_index(1, -1)] + c1 * d.y).abs() < 1e-15);
    assert!((y[sh_index(1, 0)] - c1 * d.z).abs() < 1e-15);
    assert!((y[sh_index(1, 1)] + c1 * d.x).abs() < 1e-15);
    // band 2 (Sloan's table with Condon-Shortley phase)
    let c2 = 1.092_548_430_592_079_2; // sqrt(15/(4 pi))
    assert!((y[sh_index(2, -2)] - c2 * d.x * d.y).abs() < 1e-14);
    assert!((y[sh_index(2, -1)] + c2 * d.y * d.z).abs() < 1e-14);
    assert!((y[sh_index(2, 0)] - 0.315_391_565_252_520_05 * (3.0 * d.z * d.z - 1.0)).abs() < 1e-14);
    assert!((y[sh_index(2, 1)] + c2 * d.x * d.z).abs() < 1e-14);
    assert!((y[sh_index(2, 2)] - 0.546_274_215_296_039_6 * (d.x * d.x - d.y * d.y)).abs() < 1e-14);
}

#[test]
fn orthonormality_by_quadrature() {
    for order in [4usize, 8, 10] {
        let n = sh_count(order);
        // exact product rule for degree 2(order-1)
        let rule = sphere_product_rule(order);
        let mut gram = vec![0.0; n * n];
        for (d, w) in &rule {
            let y = eval_basis(order, *d);
            for i in 0..n {
                for j in 0..n {
                    gram[i * n + j] += w * y[i] * y[j];
                }
            }
        }
        let mut worst: f64 = 0.0;
        for i in 0..n {
            for j in 0..n {
                let e = if i == j { 1.0 } else { 0.0 };
                worst = worst.max((gram[i * n + j] - e).abs());
            }
        }
        println!("order {order}: max |<Y_i,Y_j> - delta_ij| = {worst:.2e}");
        assert!(worst < 1e-12);
    }
    // an independent check with the adaptive integrator (not a product rule)
    let i = sh_index(3, -2);
    let j = sh_index(3, 2);
    let a = integrate_sphere_about(DVec3::new(0.3, 0.1, 0.9), None, 1e-12, |d| eval_basis(4, d)[i].powi(2));
    let b = integrate_sphere_about(DVec3::new(0.3, 0.1, 0.9), None, 1e-12, |d| {
        let y = eval_basis(4, d);
        y[i] * y[j]
    });
    assert!((a - 1.0).abs() < 1e-10 && b.abs() < 1e-10, "{a} {b}");
}

#[test]
fn projection_round_trip() {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    for order in [1usize, 4, 8] {
        let c = rng.coeffs(sh_count(order));
        let p = project_fn(order, order + 2, |d| eval(&c, d));
        assert!(max_abs_diff(&c, &p) < 1e-12);
    }
}

#[test]
fn rotation_against_reprojection() {
    let mut rng = Rng(0xdead_beef_cafe_f00d);
    let mut rots: Vec<DMat3> = (0..6).map(|_| rng.rotation()).collect();
    // gimbal-degenerate cases: beta = 0, pi and tiny beta
    rots.push(DMat3::from_rotation_z(0.7));
    rots.push(DMat3::from_rotation_z(0.3) * DMat3::from_rotation_y(std::f64::consts::PI));
    rots.push(DMat3::from_rotation_z(1.1) * DMat3::from_rotation_y(1e-9) * DMat3::from_rotation_z(-0.4));
    rots.push(DMat3::from_rotation_x(std::f64::consts::FRAC_PI_2));
    for order in [4usize, 8] {
        let mut worst: f64 = 0.0;
        for r in &rots {
            let c = rng.coeffs(sh_count(order));
            let rot = ShRotation::new(order, *r);
            let rc = rot.apply(&c);
            let rt = r.transpose();
            let reproj = project_fn(order, order + 1, |d| eval(&c, rt * d));
            worst = worst.max(max_abs_diff(&rc, &reproj));
            // rotation preserves the L2 norm band by band
            for l in 0..order {
                let s = l * l;
                let e = 2 * l + 1;
                let n0: f64 = c[s..s + e].iter().map(|x| x * x).sum();
                let n1: f64 = rc[s..s + e].iter().map(|x| x * x).sum();
                assert!((n0 - n1).abs() < 1e-12 * (1.0 + n0));
            }
        }
        println!("order {order}: rotation vs re-projection max coefficient error {worst:.2e}");
        assert!(worst < 1e-12);
    }
    // composition: R1 then R2 equals R2*R1
    let (r1, r2) = (rng.rotation(), rng.rotation());
    let c = rng.coeffs(16);
    let a = ShRotation::new(4, r2).apply(&ShRotation::new(4, r1).apply(&c));
    let b = ShRotation::new(4, r2 * r1).apply(&c);
    assert!(max_abs_diff(&a, &b) < 1e-13);
}

/// Selection rules for real Gaunt coefficients, derived independently of the quadrature:
/// parity (l1+l2+l3 even), triangle inequality, and the azimuthal rule (|m3| = |m1| +- |m2| and an
/// even number of sine-type (m < 0) factors).
fn selection_rule_nonzero(i: usize, j: usize, k: usize) -> bool {
    let lm = |i: usize| {
        let l = (i as f64).sqrt() as i32;
        (l, i as i32 - l * l - l)
    };
    let (l1, m1) = lm(i);
    let (l2, m2) = lm(j);
    let (l3, m3) = lm(k);
    if (l1 + l2 + l3) % 2 != 0 || l3 > l1 + l2 || l3 < (l1 - l2).abs() {
        return false;
    }
    let neg = [m1, m2, m3].iter().filter(|m| **m < 0).count();
    if neg % 2 != 0 {
        return false;
    }
    let (a, b, c) = (m1.abs(), m2.abs(), m3.abs());
    // each |m| must be the sum or difference of the other two
    c == a + b || c == (a - b).abs() || a == b + c || b == a + c
}

#[test]
fn triple_product_tensor_order4() {
    let t = TripleProductTensor::new(4);
    let n = 16;
    let mut rule_count = 0;
    let mut unique_rule = 0;
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                if selection_rule_nonzero(i, j, k) {
                    rule_count += 1;
                    if i <= j && j <= k {
                        unique_rule += 1;
                    }
                }
            }
        }
    }
    println!(
        "order-4 triple-product tensor: {} non-zero entries of 4096 ({} up to permutation); selection rules allow {} ({})",
        t.nonzero_count(),
        t.unique_nonzero_count(),
        rule_count,
        unique_rule
    );
    // every quadrature non-zero must be allowed by the selection rules
    for &(i, j, k, _) in &t.entries {
        assert!(selection_rule_nonzero(i as usize, j as usize, k as usize), "({i},{j},{k})");
    }
    // The selection rules are necessary, not sufficient: a few Gaunt coefficients vanish
    // accidentally (zero 3j symbols), so the rule count is an upper bound.
    assert!(t.nonzero_count() <= rule_count && rule_count - t.nonzero_count() <= 12);
    // 77 distinct non-zero tripling coefficients for 4th-order SH, as stated by Ng et al. 2004 and
    // the adaptive-shadow-fields paper (an independent number); 353 counting all permutations.
    assert_eq!(t.unique_nonzero_count(), 77);
    assert_eq!(t.nonzero_count(), 353);
    // C_{0,j,k} = delta_jk / sqrt(4 pi)
    let y00 = 0.5 / std::f64::consts::PI.sqrt();
    for &(i, j, k, v) in &t.entries {
        if i == 0 {
            assert_eq!(j, k);
            assert!((v - y00).abs() < 1e-14);
        }
    }
}

#[test]
fn double_and_triple_product_vs_pointwise() {
    let mut rng = Rng(42);
    for order in [4usize, 6] {
        let t = TripleProductTensor::new(order);
        let f = rng.coeffs(sh_count(order));
        let g = rng.coeffs(sh_count(order));
        // projection of the pointwise product (degree 3(order-1) integrand: exact rule)
        let nq = (3 * order).div_ceil(2);
        let proj = project_fn(order, nq, |d| eval(&f, d) * eval(&g, d));
        let h = t.product(&f, &g);
        let e = max_abs_diff(&h, &proj);
        println!("order {order}: triple product vs projected pointwise product max error {e:.2e}");
        assert!(e < 1e-12);
        // double product
        let dp: f64 = sphere_product_rule(order).iter().map(|(d, w)| w * eval(&f, *d) * eval(&g, *d)).sum();
        assert!((dot(&f, &g) - dp).abs() < 1e-12);
    }
}
