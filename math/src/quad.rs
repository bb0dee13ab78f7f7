//! Numerical quadrature used to validate the closed forms (and usable by the reference renderer):
//! adaptive Gauss–Kronrod (G7/K15) on intervals, Gauss–Legendre rules, exact product rules on the
//! sphere, and an adaptive sphere integrator aligned with a lobe axis (so lobes of sharpness up
//! to 1e5 and more are resolved) and optionally clipped to a hemisphere.

use glam::DVec3;
use std::f64::consts::PI;

const XGK: [f64; 8] = [
    0.991_455_371_120_812_6,
    0.949_107_912_342_758_5,
    0.864_864_423_359_769_1,
    0.741_531_185_599_394_5,
    0.586_087_235_467_691_1,
    0.405_845_151_377_397_2,
    0.207_784_955_007_898_48,
    0.0,
];
const WGK: [f64; 8] = [
    0.022_935_322_010_529_224,
    0.063_092_092_629_978_56,
    0.104_790_010_322_250_19,
    0.140_653_259_715_525_92,
    0.169_004_726_639_267_9,
    0.190_350_578_064_785_42,
    0.204_432_940_075_298_89,
    0.209_482_141_084_727_82,
];
const WG: [f64; 4] =
    [0.129_484_966_168_869_7, 0.279_705_391_489_276_64, 0.381_830_050_505_118_9, 0.417_959_183_673_469_4];

/// One G7/K15 step on `[a, b]`: returns (Kronrod estimate, |Kronrod - Gauss| error estimate).
pub fn gk15<F: FnMut(f64) -> f64>(f: &mut F, a: f64, b: f64) -> (f64, f64) {
    let c = 0.5 * (a + b);
    let h = 0.5 * (b - a);
    let fc = f(c);
    let mut rk = fc * WGK[7];
    let mut rg = fc * WG[3];
    for j in 0..7 {
        let dx = h * XGK[j];
        let s = f(c - dx) + f(c + dx);
        rk += WGK[j] * s;
        if j % 2 == 1 {
            rg += WG[j / 2] * s;
        }
    }
    (rk * h, ((rk - rg) * h).abs())
}

/// Adaptive Gauss–Kronrod integral of `f` over `[a, b]` split first at the sorted `breaks`
/// (points strictly inside are used, others ignored). Globally adaptive: the interval with the
/// largest error estimate is bisected until the total estimate is below
/// `max(abs_tol, rel_tol * |I|)` or `max_intervals` is reached.
pub fn integrate_adaptive<F: FnMut(f64) -> f64>(
    mut f: F,
    a: f64,
    b: f64,
    breaks: &[f64],
    abs_tol: f64,
    rel_tol: f64,
    max_intervals: usize,
) -> f64 {
    if !(b > a) {
        return 0.0;
    }
    let mut pts = vec![a];
    let mut br: Vec<f64> = breaks.iter().copied().filter(|&x| x > a && x < b).collect();
    br.sort_by(|x, y| x.total_cmp(y));
    br.dedup();
    pts.extend(br);
    pts.push(b);
    // (a, b, value, err)
    let mut ivs: Vec<(f64, f64, f64, f64)> = pts
        .windows(2)
        .map(|w| {
            let (v, e) = gk15(&mut f, w[0], w[1]);
            (w[0], w[1], v, e)
        })
        .collect();
    loop {
        let total: f64 = ivs.iter().map(|x| x.2).sum();
        let err: f64 = ivs.iter().map(|x| x.3).sum();
        if err <= abs_tol.max(rel_tol * total.abs()) || ivs.len() >= max_intervals {
            return total;
        }
        let (imax, _) = ivs.iter().enumerate().max_by(|x, y| x.1 .3.total_cmp(&y.1 .3)).unwrap();
        let (lo, hi, _, _) = ivs[imax];
        let mid = 0.5 * (lo + hi);
        if !(mid > lo && mid < hi) {
            // cannot split further (interval at machine resolution)
            ivs[imax].3 = 0.0;
            continue;
        }
        let (v1, e1) = gk15(&mut f, lo, mid);
        let (v2, e2) = gk15(&mut f, mid, hi);
        ivs[imax] = (lo, mid, v1, e1);
        ivs.push((mid, hi, v2, e2));
    }
}

/// Gauss–Legendre nodes and weights on `[-1, 1]` (Newton iteration on P_n; accurate to ~1e-15).
/// Exact for polynomials of degree `<= 2n - 1`.
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 {
                1.0
            } else if n == 1 {
                z
            } else {
                p1
            };
            let pnm1 = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (z * pn - pnm1) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-16 {
                break;
            }
        }
        // recompute derivative at converged z
        let (mut p0, mut p1) = (1.0, z);
        for k in 2..=n {
            let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
            p0 = p1;
            p1 = p2;
        }
        if n > 1 {
            dp = n as f64 * (z * p1 - p0) / (z * z - 1.0);
        } else {
            dp = 1.0;
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        let wi = 2.0 / ((1.0 - z * z) * dp * dp);
        w[i] = wi;
        w[n - 1 - i] = wi;
    }
    (x, w)
}

/// Product quadrature on the unit sphere: `n` Gauss–Legendre nodes in `z = cos(theta)` times `2n`
/// equispaced azimuths. Exact for spherical polynomials (e.g. products of spherical harmonics)
/// of total degree `<= 2n - 1`. Returns `(direction, weight)`; weights sum to `4 pi`.
pub fn sphere_product_rule(n: usize) -> Vec<(DVec3, f64)> {
    let (zs, ws) = gauss_legendre(n);
    let nphi = 2 * n.max(1);
    let mut out = Vec::with_capacity(n * nphi);
    for (z, w) in zs.iter().zip(ws.iter()) {
        let r = (1.0 - z * z).max(0.0).sqrt();
        for j in 0..nphi {
            let phi = 2.0 * PI * (j as f64 + 0.5) / nphi as f64;
            out.push((DVec3::new(r * phi.cos(), r * phi.sin(), *z), w * 2.0 * PI / nphi as f64));
        }
    }
    out
}

/// Any unit vector orthonormal frame `(t, b)` completing `n` (Duff et al. 2017).
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), DVec3::new(b, sign + n.y * n.y * a, -n.y))
}

/// Adaptive integral over the sphere (or the hemisphere `dot(normal, w) > 0`) of `f`, in polar
/// coordinates about `axis`: the outer variable is `x = 1 - cos(t)` in `[0, 2]` (t = angle from
/// `axis`), with geometric breakpoints `2^-k` towards `x = 0` so a lobe of any sharpness around
/// `axis` is resolved; the inner variable is the azimuth about `axis`, integrated exactly over the
/// arc inside the hemisphere. Both levels are adaptive Gauss–Kronrod with relative tolerance `rel_tol`.
pub fn integrate_sphere_about<F: FnMut(DVec3) -> f64>(
    axis: DVec3,
    normal: Option<DVec3>,
    rel_tol: f64,
    mut f: F,
) -> f64 {
    let axis = axis.normalize();
    let (c, s, e1, e2) = match normal {
        Some(n) => {
            let n = n.normalize();
            let c = axis.dot(n);
            let perp = n - axis * c;
            let s = axis.cross(n).length();
            let e1 = if s > 1e-300 { perp / perp.length() } else { orthonormal_basis(axis).0 };
            let e2 = axis.cross(e1);
            (c, s, e1, e2)
        }
        None => {
            let (t, b) = orthonormal_basis(axis);
            (1.0, 0.0, t, b)
        }
    };
    let clipped = normal.is_some();
    let mut breaks: Vec<f64> = (1..60).map(|k| 2f64.powi(-k)).collect();
    breaks.push(1.0);
    if clipped {
        breaks.push(1.0 - s);
        breaks.push(1.0 + s);
    }
    let outer = |x: f64| -> f64 {
        let ct = 1.0 - x;
        let st = (x * (2.0 - x)).max(0.0).sqrt();
        // azimuth range inside the hemisphere: cos(phi) > q
        let half = if !clipped {
            PI
        } else if s * st == 0.0 {
            if c * ct > 0.0 {
                PI
            } else {
                0.0
            }
        } else {
            let q = -c * ct / (s * st);
            if q <= -1.0 {
                PI
            } else if q >= 1.0 {
                0.0
            } else {
                q.acos()
            }
        };
        if half == 0.0 {
            return 0.0;
        }
        let inner = |phi: f64| -> f64 {
            let w = axis * ct + (e1 * phi.cos() + e2 * phi.sin()) * st;
            f(w)
        };
        // f is borrowed mutably inside; use a local closure wrapper
        integrate_adaptive(inner, -half, half, &[0.0], 0.0, rel_tol, 200)
    };
    // `outer` captures `f` mutably through `inner`; wrap in RefCell-free form via a loop closure
    integrate_adaptive(outer, 0.0, 2.0, &breaks, 0.0, rel_tol, 2000)
}
