//! Special functions not in `std`: `erf`/`erfc` (f64, accurate to a few ulp-ish, ~1e-15 absolute)
//! and helpers for numerically stable SG formulas.

/// `(1 - exp(-x)) / x` for `x >= 0`, computed with `expm1` (no cancellation for small `x`);
/// the limit `1` is returned at `x == 0`.
#[inline]
pub fn one_minus_exp_neg_over_x(x: f64) -> f64 {
    if x == 0.0 {
        1.0
    } else {
        -(-x).exp_m1() / x
    }
}

/// f32 version of [`one_minus_exp_neg_over_x`].
#[inline]
pub fn one_minus_exp_neg_over_x_f32(x: f32) -> f32 {
    one_minus_exp_neg_over_x(x as f64) as f32
}

/// Error function `erf(x) = 2/sqrt(pi) * int_0^x exp(-t^2) dt`.
///
/// `|x| < 3`: the positive series `erf(x) = 2/sqrt(pi) exp(-x^2) sum_n 2^n x^(2n+1) / (2n+1)!!`
/// (all terms positive, no cancellation); otherwise `1 - erfc(x)` with the continued fraction.
/// Absolute error about 1e-15.
pub fn erf(x: f64) -> f64 {
    if x.is_nan() {
        return x;
    }
    let ax = x.abs();
    if ax < 3.0 {
        let x2 = ax * ax;
        let mut term = ax;
        let mut sum = ax;
        let mut n = 0.0;
        loop {
            n += 1.0;
            term *= 2.0 * x2 / (2.0 * n + 1.0);
            sum += term;
            if term <= sum * 1e-17 || n > 200.0 {
                break;
            }
        }
        let r = std::f64::consts::FRAC_2_SQRT_PI * (-x2).exp() * sum;
        r.copysign(x)
    } else {
        (1.0 - erfc_cf(ax)).copysign(x)
    }
}

/// Complementary error function `1 - erf(x)`, accurate also where it is tiny (`x` large).
pub fn erfc(x: f64) -> f64 {
    if x.is_nan() {
        return x;
    }
    if x >= 3.0 {
        erfc_cf(x)
    } else {
        1.0 - erf(x)
    }
}

/// Continued fraction for erfc, x >= 3 (modified Lentz).
fn erfc_cf(x: f64) -> f64 {
    // erfc(x) = exp(-x^2)/sqrt(pi) * 1/(x + (1/2)/(x + 1/(x + (3/2)/(x + 2/(x + ...)))))
    let tiny = 1e-300;
    let mut f = x;
    let mut c = x;
    let mut d = 0.0;
    for k in 1..500 {
        let a = k as f64 * 0.5;
        d = x + a * d;
        if d.abs() < tiny {
            d = tiny;
        }
        c = x + a / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        let delta = c * d;
        f *= delta;
        if (delta - 1.0).abs() < 1e-16 {
            break;
        }
    }
    (-x * x).exp() / (f * std::f64::consts::PI.sqrt())
}
