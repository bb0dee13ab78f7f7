//! Real spherical harmonics (SH) of arbitrary order.
//!
//! # Convention
//! * "Order" `n` means bands `l = 0 .. n-1`, i.e. `n^2` coefficients (order 4 = 16 coefficients,
//!   the "fourth order SH" of the shadow-field papers).
//! * Coefficient index `i = l*l + l + m`, `m = -l..=l` ([`sh_index`]).
//! * Directions are unit vectors `(x, y, z)` with `theta` measured from `+z` and `phi` from `+x`
//!   towards `+y` (a frame-free definition: callers rotate into this frame as needed).
//! * Real SH with the Condon–Shortley phase included (as in Sloan, "Stupid SH tricks"):
//!   `Y_l^m = sqrt(2) K_l^m cos(m phi) P_l^m(cos theta)` for `m > 0`,
//!   `Y_l^m = sqrt(2) K_l^|m| sin(|m| phi) P_l^|m|(cos theta)` for `m < 0`,
//!   `Y_l^0 = K_l^0 P_l^0(cos theta)`, `K_l^m = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)`, where
//!   `P_l^m` includes the `(-1)^m` phase. So `Y_0^0 = 0.282095`, `Y_1^{-1} = -0.488603 y`,
//!   `Y_1^0 = 0.488603 z`, `Y_1^1 = -0.488603 x`. The basis is orthonormal on the sphere.
//! * Evaluation is polynomial in `x, y, z` (no trigonometry): `sin^m(theta) cos(m phi) =
//!   Re((x + i y)^m)`.
//!
//! # Operations
//! * Projection: [`project_fn`] (exact product quadrature, exact for band-limited functions),
//!   [`project_samples`] (weighted samples, e.g. lat-long texels with their solid angles).
//! * Rotation: [`ShRotation`] via `R = Rz(alpha) Ry(beta) Rz(gamma)` and
//!   `Ry(beta) = Rx(-90) Rz(beta) Rx(90)`, the ZXZXZ method: z-rotations are closed-form per
//!   `(m, -m)` pair, the two fixed 90-degree x-rotation band matrices are computed once per order by
//!   exact quadrature. Exact to rounding (~1e-14) for any order.
//! * Double product `int f g = dot(f, g)` ([`dot`]).
//! * Triple product: [`TripleProductTensor`] holds `C_ijk = int Y_i Y_j Y_k` (exact quadrature,
//!   sparse), and `(f * g)_k = sum_ij C_ijk f_i g_j` is the projection of the pointwise product
//!   onto the same order. Order 4 has 353 non-zero entries, 77 distinct up to permutation (the
//!   count quoted by Ng et al. 2004 and the adaptive-shadow-fields paper).

use crate::quad::sphere_product_rule;
use glam::{DMat3, DVec3};
use std::f64::consts::PI;

/// Number of coefficients of an order-`order` expansion (`order^2`).
pub const fn sh_count(order: usize) -> usize {
    order * order
}

/// Index of `(l, m)`: `l*l + l + m`.
pub const fn sh_index(l: usize, m: i32) -> usize {
    ((l * l + l) as isize + m as isize) as usize
}

/// Order of a coefficient vector (`sqrt(len)`), or `None` if `len` is not a square.
pub fn order_of(len: usize) -> Option<usize> {
    let n = (len as f64).sqrt().round() as usize;
    (n * n == len).then_some(n)
}

/// Evaluates all `order^2` basis functions at unit direction `d` into `out`
/// (`out.len() >= order^2`).
pub fn eval_basis_into(order: usize, d: DVec3, out: &mut [f64]) {
    let (x, y, z) = (d.x, d.y, d.z);
    // C_m + i S_m = (x + i y)^m
    let mut cm = 1.0;
    let mut sm = 0.0;
    let mut qmm = 1.0; // Q_m^m = (-1)^m (2m-1)!!
    for m in 0..order {
        if m > 0 {
            let (c, s) = (x * cm - y * sm, x * sm + y * cm);
            cm = c;
            sm = s;
            qmm *= -((2 * m - 1) as f64);
        }
        let mut q_lm2 = 0.0;
        let mut q_lm1 = qmm;
        for l in m..order {
            let q = if l == m {
                qmm
            } else if l == m + 1 {
                (2 * m + 1) as f64 * z * qmm
            } else {
                ((2 * l - 1) as f64 * z * q_lm1 - (l + m - 1) as f64 * q_lm2) / (l - m) as f64
            };
            if l > m {
                q_lm2 = q_lm1;
                q_lm1 = q;
            }
            let k = norm_k(l, m);
            if m == 0 {
                out[sh_index(l, 0)] = k * q;
            } else {
                let f = std::f64::consts::SQRT_2 * k * q;
                out[sh_index(l, m as i32)] = f * cm;
                out[sh_index(l, -(m as i32))] = f * sm;
            }
        }
    }
}

/// `K_l^m = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)`.
fn norm_k(l: usize, m: usize) -> f64 {
    let mut r = 1.0;
    for k in (l - m + 1)..=(l + m) {
        r /= k as f64;
    }
    ((2 * l + 1) as f64 / (4.0 * PI) * r).sqrt()
}

/// All `order^2` basis values at unit direction `d`.
pub fn eval_basis(order: usize, d: DVec3) -> Vec<f64> {
    let mut v = vec![0.0; sh_count(order)];
    eval_basis_into(order, d, &mut v);
    v
}

/// Value of the expansion `coeffs` at unit direction `d`.
///
/// # Panics
/// If `coeffs.len()` is not a square (use [`order_of`] to check).
pub fn eval(coeffs: &[f64], d: DVec3) -> f64 {
    let order = order_of(coeffs.len()).expect("SH coefficient count must be a square");
    eval_basis(order, d).iter().zip(coeffs).map(|(a, b)| a * b).sum()
}

/// Projects `f` onto order `order` with an exact product rule of `n_theta` Gauss–Legendre rings
/// (exact when `f` is band-limited to degree `<= 2 n_theta - order`; use `n_theta >= order` for
/// band-limited inputs, more for general functions).
pub fn project_fn<F: FnMut(DVec3) -> f64>(order: usize, n_theta: usize, mut f: F) -> Vec<f64> {
    project_samples(order, sphere_product_rule(n_theta).into_iter().map(|(d, w)| (d, w, f(d))))
}

/// Projects weighted samples `(direction, weight, value)` (e.g. lat-long texels with solid-angle
/// weights, or Monte Carlo samples with `weight = 1/(N pdf)`): `c_i = sum w f Y_i(d)`.
pub fn project_samples<I: IntoIterator<Item = (DVec3, f64, f64)>>(order: usize, samples: I) -> Vec<f64> {
    let mut c = vec![0.0; sh_count(order)];
    let mut y = vec![0.0; sh_count(order)];
    for (d, w, v) in samples {
        eval_basis_into(order, d, &mut y);
        for (ci, yi) in c.iter_mut().zip(&y) {
            *ci += w * v * yi;
        }
    }
    c
}

/// Double product integral `int_S2 f g = sum f_i g_i` (orthonormal basis).
pub fn dot(f: &[f64], g: &[f64]) -> f64 {
    f.iter().zip(g).map(|(a, b)| a * b).sum()
}

/// Matrix (row-major, `n x n`) of the coefficient map of a fixed rotation for each band,
/// computed by exact quadrature: `M_kj = int Y_k(d) Y_j(R^T d) dd`.
fn band_matrices_by_quadrature(order: usize, r: DMat3) -> Vec<Vec<f64>> {
    let rule = sphere_product_rule(order.max(1));
    let n = sh_count(order);
    let mut ya = vec![0.0; n];
    let mut yb = vec![0.0; n];
    let mut bands: Vec<Vec<f64>> = (0..order).map(|l| vec![0.0; (2 * l + 1) * (2 * l + 1)]).collect();
    let rt = r.transpose();
    for (d, w) in rule {
        eval_basis_into(order, d, &mut ya);
        eval_basis_into(order, rt * d, &mut yb);
        for (l, band) in bands.iter_mut().enumerate() {
            let s = l * l;
            let bw = 2 * l + 1;
            for k in 0..bw {
                for j in 0..bw {
                    band[k * bw + j] += w * ya[s + k] * yb[s + j];
                }
            }
        }
    }
    bands
}

/// Exact SH rotation of a given order: `apply(c)` gives the coefficients of `g(d) = f(R^T d)`,
/// i.e. the function `f` rotated by `R`.
#[derive(Clone, Debug)]
pub struct ShRotation {
    order: usize,
    /// ZYZ Euler angles `(alpha, beta, gamma)` with `R = Rz(alpha) Ry(beta) Rz(gamma)`.
    pub euler_zyz: (f64, f64, f64),
    xp90: Vec<Vec<f64>>,
    xm90: Vec<Vec<f64>>,
}

fn rz(a: f64) -> DMat3 {
    DMat3::from_rotation_z(a)
}

impl ShRotation {
    /// Prepares the rotation by the orthonormal matrix `r` (column-major glam matrix,
    /// `r * v` rotates `v`).
    pub fn new(order: usize, r: DMat3) -> Self {
        let euler_zyz = zyz_euler(r);
        let xp90 = band_matrices_by_quadrature(order, DMat3::from_rotation_x(PI / 2.0));
        // Rx(-90) = Rx(90)^T: band matrices are orthogonal, so transpose
        let xm90 = xp90
            .iter()
            .enumerate()
            .map(|(l, m)| {
                let bw = 2 * l + 1;
                let mut t = vec![0.0; bw * bw];
                for i in 0..bw {
                    for j in 0..bw {
                        t[i * bw + j] = m[j * bw + i];
                    }
                }
                t
            })
            .collect();
        Self { order, euler_zyz, xp90, xm90 }
    }

    /// Order this rotation was built for.
    pub fn order(&self) -> usize {
        self.order
    }

    /// Rotates `coeffs` (extra coefficients beyond `order^2` are left unchanged).
    ///
    /// # Panics
    /// If `coeffs.len() < order^2`.
    pub fn apply(&self, coeffs: &[f64]) -> Vec<f64> {
        let (a, b, g) = self.euler_zyz;
        let mut c = coeffs.to_vec();
        rotate_z(self.order, g, &mut c);
        apply_bands(&self.xp90, &mut c);
        rotate_z(self.order, b, &mut c);
        apply_bands(&self.xm90, &mut c);
        rotate_z(self.order, a, &mut c);
        c
    }
}

fn apply_bands(bands: &[Vec<f64>], c: &mut [f64]) {
    for (l, m) in bands.iter().enumerate() {
        let s = l * l;
        let bw = 2 * l + 1;
        let src: Vec<f64> = c[s..s + bw].to_vec();
        for k in 0..bw {
            c[s + k] = (0..bw).map(|j| m[k * bw + j] * src[j]).sum();
        }
    }
}

/// Rotation about +z by `a` of coefficient vector `c` (in place).
pub fn rotate_z(order: usize, a: f64, c: &mut [f64]) {
    for l in 1..order {
        for m in 1..=l {
            let (s, co) = (m as f64 * a).sin_cos();
            let ip = sh_index(l, m as i32);
            let im = sh_index(l, -(m as i32));
            let (cp, cm) = (c[ip], c[im]);
            c[ip] = cp * co - cm * s;
            c[im] = cp * s + cm * co;
        }
    }
}

/// ZYZ Euler angles of a rotation matrix: `R = Rz(alpha) Ry(beta) Rz(gamma)`, computed so that the
/// reconstruction is accurate also near `beta = 0, pi` (each angle absorbs the rounding of the
/// previous ones).
pub fn zyz_euler(r: DMat3) -> (f64, f64, f64) {
    let (rxz, ryz) = (r.z_axis.x, r.z_axis.y);
    let alpha = if rxz == 0.0 && ryz == 0.0 { 0.0 } else { ryz.atan2(rxz) };
    let m1 = rz(-alpha) * r;
    let beta = m1.z_axis.x.atan2(m1.z_axis.z);
    let m2 = DMat3::from_rotation_y(-beta) * m1;
    let gamma = m2.x_axis.y.atan2(m2.x_axis.x);
    (alpha, beta, gamma)
}

/// Sparse triple-product tensor `C_ijk = int_S2 Y_i Y_j Y_k` of one order.
#[derive(Clone, Debug)]
pub struct TripleProductTensor {
    order: usize,
    /// Non-zero entries `(i, j, k, C_ijk)` over all index triples (all permutations included).
    pub entries: Vec<(u16, u16, u16, f64)>,
}

impl TripleProductTensor {
    /// Entries with `|C_ijk| <= threshold` are treated as zero.
    pub const THRESHOLD: f64 = 1e-12;

    /// Computes the tensor by an exact product quadrature (degree `3 (order - 1)`).
    pub fn new(order: usize) -> Self {
        let n = sh_count(order);
        let rule = sphere_product_rule((3 * order).div_ceil(2).max(1));
        let mut y = vec![0.0; n];
        // unique i <= j <= k
        let mut dense = vec![0.0; n * n * n];
        for (d, w) in rule {
            eval_basis_into(order, d, &mut y);
            for i in 0..n {
                let wi = w * y[i];
                for j in i..n {
                    let wij = wi * y[j];
                    for k in j..n {
                        dense[(i * n + j) * n + k] += wij * y[k];
                    }
                }
            }
        }
        let mut entries = Vec::new();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let mut s = [i, j, k];
                    s.sort();
                    let v = dense[(s[0] * n + s[1]) * n + s[2]];
                    if v.abs() > Self::THRESHOLD {
                        entries.push((i as u16, j as u16, k as u16, v));
                    }
                }
            }
        }
        Self { order, entries }
    }

    /// Order of the tensor.
    pub fn order(&self) -> usize {
        self.order
    }

    /// Number of non-zero entries over all `(i, j, k)`.
    pub fn nonzero_count(&self) -> usize {
        self.entries.len()
    }

    /// Number of distinct non-zero values up to index permutation (`i <= j <= k`).
    pub fn unique_nonzero_count(&self) -> usize {
        self.entries.iter().filter(|e| e.0 <= e.1 && e.1 <= e.2).count()
    }

    /// Triple product: coefficients of the projection of `f * g` onto this order,
    /// `h_k = sum_ij C_ijk f_i g_j`.
    ///
    /// # Panics
    /// If `f` or `g` has fewer than `order^2` coefficients.
    pub fn product(&self, f: &[f64], g: &[f64]) -> Vec<f64> {
        let mut h = vec![0.0; sh_count(self.order)];
        for &(i, j, k, c) in &self.entries {
            h[k as usize] += c * f[i as usize] * g[j as usize];
        }
        h
    }
}
