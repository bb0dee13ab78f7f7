//! Non-negative least squares in normal-equation form (Lawson–Hanson active set).
//!
//! Minimises `|A x - y|^2` subject to `x >= 0` given the Gram matrix `Q = A^T A` and `b = A^T y`
//! (so the number of rows of `A`, e.g. environment-map texels, never enters the solver).

/// Solves `min_x>=0 x^T Q x / 2 - b^T x` for a symmetric positive semi-definite `n x n` row-major
/// `q`. Singular sub-problems (duplicate columns) are regularised with a relative `1e-12` ridge.
/// Returns the solution (all entries finite and `>= 0`).
///
/// # Panics
/// If `q.len() != b.len()^2`.
pub fn nnls_gram(q: &[f64], b: &[f64]) -> Vec<f64> {
    let n = b.len();
    assert_eq!(q.len(), n * n, "Gram matrix must be n x n");
    let mut x = vec![0.0; n];
    let mut passive = vec![false; n];
    let scale = (0..n).map(|i| q[i * n + i].abs()).fold(0.0, f64::max).max(1e-300);
    let tol = 1e-12 * scale * b.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300) / scale.sqrt();
    let grad =
        |x: &[f64]| -> Vec<f64> { (0..n).map(|i| b[i] - (0..n).map(|j| q[i * n + j] * x[j]).sum::<f64>()).collect() };
    for _outer in 0..(3 * n + 10) {
        let w = grad(&x);
        // most positive gradient among the active (zero) set
        let mut best = None;
        let mut wmax = tol;
        for i in 0..n {
            if !passive[i] && w[i] > wmax {
                wmax = w[i];
                best = Some(i);
            }
        }
        let Some(j) = best else { break };
        passive[j] = true;
        for _inner in 0..(3 * n + 10) {
            let idx: Vec<usize> = (0..n).filter(|&i| passive[i]).collect();
            let s_p = solve_spd(q, n, &idx, b);
            if s_p.iter().all(|&v| v > 0.0) {
                for (k, &i) in idx.iter().enumerate() {
                    x[i] = s_p[k];
                }
                break;
            }
            // step towards s until the first passive variable hits zero
            let mut alpha = 1.0f64;
            for (k, &i) in idx.iter().enumerate() {
                if s_p[k] <= 0.0 {
                    let denom = x[i] - s_p[k];
                    if denom > 0.0 {
                        alpha = alpha.min(x[i] / denom);
                    }
                }
            }
            for (k, &i) in idx.iter().enumerate() {
                x[i] += alpha * (s_p[k] - x[i]);
                if x[i] <= 1e-15 * (1.0 + x[i].abs()) || s_p[k] <= 0.0 && alpha >= 1.0 {
                    x[i] = 0.0;
                    passive[i] = false;
                }
            }
            if idx.iter().all(|&i| !passive[i]) {
                break;
            }
        }
    }
    for v in x.iter_mut() {
        if !(v.is_finite() && *v > 0.0) {
            *v = 0.0;
        }
    }
    x
}

/// Cholesky solve of `Q[idx, idx] s = b[idx]` with a tiny ridge for robustness.
fn solve_spd(q: &[f64], n: usize, idx: &[usize], b: &[f64]) -> Vec<f64> {
    let m = idx.len();
    let mut a = vec![0.0; m * m];
    for (r, &i) in idx.iter().enumerate() {
        for (c, &j) in idx.iter().enumerate() {
            a[r * m + c] = q[i * n + j];
        }
    }
    let tr = (0..m).map(|i| a[i * m + i]).sum::<f64>() / m.max(1) as f64;
    for i in 0..m {
        a[i * m + i] += 1e-12 * tr.max(1e-300);
    }
    let y: Vec<f64> = idx.iter().map(|&i| b[i]).collect();
    cholesky_solve(&mut a, m, y, Some(1e-300)).expect("a floored pivot never fails")
}

/// Solves `A x = y` for a symmetric positive definite `A` (row-major `n x n`, overwritten by its
/// lower Cholesky factor). A pivot at or below zero (or NaN) fails unless `floor` is given, which
/// then bounds every pivot from below.
pub(crate) fn cholesky_solve(a: &mut [f64], n: usize, mut y: Vec<f64>, floor: Option<f64>) -> Option<Vec<f64>> {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        let d = match floor {
            Some(f) => d.max(f),
            None if d > 0.0 => d,
            None => return None,
        }
        .sqrt();
        a[j * n + j] = d;
        for i in (j + 1)..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    for i in 0..n {
        for k in 0..i {
            y[i] -= a[i * n + k] * y[k];
        }
        y[i] /= a[i * n + i];
    }
    for i in (0..n).rev() {
        for k in (i + 1)..n {
            y[i] -= a[k * n + i] * y[k];
        }
        y[i] /= a[i * n + i];
    }
    Some(y)
}
