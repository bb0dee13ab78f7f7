//! The airlight table of the hybrid's lit segments (`glsl/include/vol_airlight.glsl`): Sun et
//! al.'s (2005) `F(u, v) = integral_0^v exp(-u tan xi) 4 pi p(cos 2 xi) dxi`, here for the
//! medium's Henyey-Greenstein phase `p` (Sun et al. tabulate the isotropic case, where
//! `4 pi p = 1`), built once per effect.

/// Rows (`w = u / (1 + u)` in `[0, WMAX]`), columns (`s = sqrt(v / (pi / 2))` in `[0, 1]`) and
/// the last row's `w`: the layout `vol_airlight.glsl` reads (`AIR_ROWS`, `AIR_COLS`, `AIR_WMAX`).
pub const ROWS: usize = 128;
pub const COLS: usize = 256;
pub const WMAX: f64 = 0.999;

/// `4 pi p(cos 2 xi)` for Henyey-Greenstein `g`.
fn phase4pi(g: f64, xi: f64) -> f64 {
    let c = (2.0 * xi).cos();
    let d = (1.0 + g * g - 2.0 * g * c).max(1e-12);
    (1.0 - g * g) / (d * d.sqrt())
}

fn integrand(u: f64, g: f64, xi: f64) -> f64 {
    let t = xi.tan();
    let e = if t.is_finite() { (-u * t).exp() } else { 0.0 };
    if u == 0.0 {
        phase4pi(g, xi)
    } else {
        e * phase4pi(g, xi)
    }
}

/// `F(u, v)` by composite Simpson with `n` (even) intervals (the test's reference).
pub fn f_numeric(u: f64, v: f64, g: f64, n: usize) -> f64 {
    let h = v / n as f64;
    let mut s = integrand(u, g, 0.0) + integrand(u, g, v);
    for i in 1..n {
        s += integrand(u, g, i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    s * h / 3.0
}

/// The row's `u`.
fn row_u(r: usize) -> f64 {
    let w = r as f64 / (ROWS - 1) as f64 * WMAX;
    w / (1.0 - w)
}

/// The column's `v`.
fn col_v(c: usize) -> f64 {
    let s = c as f64 / (COLS - 1) as f64;
    0.5 * std::f64::consts::PI * s * s
}

/// The table for phase asymmetry `g`: `F(u, v) (1 + u)`, row-major, `ROWS x COLS`.
pub fn table(g: f32) -> Vec<f32> {
    let g = (g as f64).clamp(-0.999, 0.999);
    let mut out = Vec::with_capacity(ROWS * COLS);
    for r in 0..ROWS {
        let u = row_u(r);
        let mut acc = 0.0f64;
        out.push(0.0);
        for c in 1..COLS {
            let (a, b) = (col_v(c - 1), col_v(c));
            // Simpson over 8 sub-intervals of the column.
            let n = 8;
            let h = (b - a) / n as f64;
            let mut s = integrand(u, g, a) + integrand(u, g, b);
            for i in 1..n {
                s += integrand(u, g, a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
            }
            acc += s * h / 3.0;
            out.push((acc * (1.0 + u)) as f32);
        }
    }
    out
}

/// `F(u, v)` from the table, bilinearly as the shader reads it.
pub fn lookup(table: &[f32], u: f64, v: f64) -> f64 {
    let w = (u / (1.0 + u)).clamp(0.0, WMAX);
    let s = (v / (0.5 * std::f64::consts::PI)).clamp(0.0, 1.0).sqrt();
    let fr = w / WMAX * (ROWS - 1) as f64;
    let fc = s * (COLS - 1) as f64;
    let (r0, c0) = ((fr as usize).min(ROWS - 2), (fc as usize).min(COLS - 2));
    let (ar, ac) = ((fr - r0 as f64).clamp(0.0, 1.0), (fc - c0 as f64).clamp(0.0, 1.0));
    let at = |r: usize, c: usize| table[r * COLS + c] as f64;
    let top = at(r0, c0) * (1.0 - ac) + at(r0, c0 + 1) * ac;
    let bottom = at(r0 + 1, c0) * (1.0 - ac) + at(r0 + 1, c0 + 1) * ac;
    // F (1 + u) tends to a constant as u grows: beyond the last row, dividing by the true u
    // extrapolates.
    (top * (1.0 - ar) + bottom * ar) / (1.0 + u)
}
