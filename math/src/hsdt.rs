//! Hemispherical signed distance transform (HSDT, paper section 5, Algorithm 1): packed visibility
//! maps ([`crate::avs_maps`]) to signed spherical distance fields (SSDF, eq. 4).
//!
//! # Output
//! `r * r` values in texel order (`k = i * r + j`), **radians**: `+` the great-circle distance from
//! a visible texel centre to the nearest occluded texel centre, `-` the distance from an occluded
//! texel centre to the nearest visible one (eq. 4 with the map's texel centres as the sample set);
//! `+pi` / `-pi` ([`crate::avs_maps::NO_BOUNDARY`]) for all-visible / all-occluded maps. Distances
//! are on the whole sphere (`arccos(t . v)`, the paper's definition), so a boundary near the
//! other end of the horizon is found through the lower hemisphere when that is shorter.
//!
//! # Algorithm (exact, not an approximation)
//! Two separable phases as in Meijster et al. 2002, run twice (nearest occluded texel for visible
//! texels, nearest visible texel for occluded ones):
//! 1. **Latitude scans** (per row `i` = constant `theta`): a forward and a backward scan over `phi`
//!    give, for every texel, the column `g[i][j]` of the nearest feature texel in the same row by
//!    `|phi - phi'|`. This is exact for the spherical metric: for any query `(theta, phi)` the
//!    distance to `(theta', phi')` is increasing in `|phi - phi'|` (haversine
//!    `sin^2(d/2) = sin^2(dtheta/2) + sin(theta) sin(theta') sin^2(dphi/2)`, `sin >= 0` on
//!    `[0, pi]`, `|dphi| <= pi`), so row `i`'s best candidate for ANY query on column `j` is
//!    `g[i][j]`. (This is why the latitude scans come first, as the paper says.)
//! 2. **Longitude scans** (per column `j`): the lower envelope over the candidate rows `i'` of
//!    `f_i'(theta) = dist((theta, phi_j), (theta_i', phi_g))`, built by a forward scan with a
//!    stack and read out by a backward scan (Algorithm 1's `s`, `t`, `q`). Meijster's envelope
//!    needs (a) two candidates' functions to cross at most once and (b) the later candidate to win
//!    after the crossing. Both hold: `cos f_a - cos f_b = A cos(theta) + B sin(theta)` with
//!    `A = cos(theta_a) - cos(theta_b) > 0` for `theta_a < theta_b`, a sinusoid with at most one
//!    zero in `(0, pi)`, positive (a wins) at `theta = 0` and negative (b wins) at `theta = pi`.
//!    The separator (first query row where the newer candidate is at least as close) is found here
//!    by bisection on the same comparison; the GPU pass takes it in closed form
//!    ([`closed_form_separator`]), which differs only where the two distances agree to rounding,
//!    and reads phase 1's answer off the row's bits ([`nearest_in_row`]).
//!
//! Hence the HSDT equals the brute-force transform over texel centres up to floating-point
//! rounding (tests: max error ~1e-15 rad in f64; the GPU pass in f32 ~1e-6 rad, below fp16
//! rounding). Cost: `O(r^2)` per map (`O(r^2 log r)` worst case for the separator bisection).

use crate::avs_maps::{angle_between, check_res, texel_dir, VisMap, NO_BOUNDARY};

/// "No feature in this row" marker of the latitude scans.
pub const NONE: u16 = u16::MAX;

/// Phase 1 for one row and one feature state: `out[j]` = column of the nearest texel of row `i`
/// whose visibility is `feature` (ties: the lower column), or [`NONE`].
pub fn latitude_scan(map: &VisMap, i: u32, feature: bool, out: &mut [u16]) {
    let r = map.r as usize;
    let mut last = NONE;
    for (j, o) in out[..r].iter_mut().enumerate() {
        if map.get(i, j as u32) == feature {
            last = j as u16;
        }
        *o = last;
    }
    let mut s = NONE;
    for j in (0..r).rev() {
        if map.get(i, j as u32) == feature {
            s = j as u16;
        } else if s != NONE {
            let dg = if out[j] == NONE { usize::MAX } else { j - out[j] as usize };
            if (s as usize - j) < dg {
                out[j] = s;
            }
        }
    }
}

/// Phase 1 answered for one texel from the row's bits, as the GPU pass does (`glsl/hsdt/hsdt.comp`
/// `nearest_in_row`): the column of the texel of row `i` nearest to column `j` by `|dphi|` (ties:
/// the lower column) whose visibility is `feature`, or [`NONE`]; the highest such bit at or below
/// the texel and the lowest above it, a word at a time. Equals [`latitude_scan`]'s `out[j]`.
pub fn nearest_in_row(map: &VisMap, i: u32, j: u32, feature: bool) -> u16 {
    let r = map.r as usize;
    let (start, k, end) = (i as usize * r, i as usize * r + j as usize, (i as usize + 1) * r);
    let word = |w: usize| if feature { map.bits[w] } else { !map.bits[w] };
    let mut below = NONE;
    let mut w = k / 32;
    let mut x = word(w) & (((2u64 << (k % 32)) - 1) as u32);
    while x == 0 && w > start / 32 {
        w -= 1;
        x = word(w);
    }
    if x != 0 {
        let b = w * 32 + 31 - x.leading_zeros() as usize;
        if b >= start {
            below = (b - start) as u16;
        }
    }
    if below == j as u16 {
        return below;
    }
    let mut above = NONE;
    let mut w = k / 32;
    let mut x = word(w) & !(((2u64 << (k % 32)) - 1) as u32);
    while x == 0 && w < (end - 1) / 32 {
        w += 1;
        x = word(w);
    }
    if x != 0 {
        let b = w * 32 + x.trailing_zeros() as usize;
        if b < end {
            above = (b - start) as u16;
        }
    }
    match (below, above) {
        (NONE, a) => a,
        (b, NONE) => b,
        (b, a) => {
            if j - b as u32 <= a as u32 - j {
                b
            } else {
                a
            }
        }
    }
}

/// A candidate's haversine weight for column `j`: `sin(theta_row) sin^2((j - col) h / 2)`, so
/// that the haversine from texel `(i, j)` is `sin^2((theta_i - theta_row) / 2) + sin(theta_i) w`.
pub fn haversine_weight(r: u32, j: u32, row: u32, col: u32) -> f64 {
    let h = std::f64::consts::PI / r as f64;
    let s = (0.5 * h * (j as f64 - col as f64)).sin();
    ((row as f64 + 0.5) * h).sin() * s * s
}

/// The separator in closed form, as the GPU pass computes it (`glsl/hsdt/hsdt.comp`): for an
/// older candidate (row `s`, weight `ws`, [`haversine_weight`]) and a newer one (row `u > s`,
/// weight `wu`) of the same column, the first query row where the newer one is at least as close
/// (`r` if none). With `m = (theta_s + theta_u) / 2` and `sg = sin((theta_s - theta_u) / 2) < 0`,
/// `hav_u(i) - hav_s(i) = sin(theta_i - m) sg + sin(theta_i) (wu - ws)` (`sin^2 a - sin^2 b =
/// sin(a + b) sin(a - b)`) `= alpha sin(theta_i) - beta cos(theta_i)` with `alpha = cos(m) sg + wu -
/// ws` and `beta = sin(m) sg < 0`, which is `<= 0` exactly for `theta_i >= atan2(-beta, -alpha)`.
/// Every term is a product of small exact factors, so where it decides differently from the
/// comparison of the two haversines the two distances agree to rounding (test
/// `closed_form_separator_matches_bisection`).
pub fn closed_form_separator(r: u32, s: u32, ws: f64, u: u32, wu: f64) -> u32 {
    let h = std::f64::consts::PI / r as f64;
    let m = 0.5 * (s + u + 1) as f64 * h;
    let sg = (0.5 * h * (s as f64 - u as f64)).sin();
    let alpha = m.cos() * sg + (wu - ws);
    let beta = m.sin() * sg;
    let th = (-beta).atan2(-alpha);
    ((th / h - 0.5).ceil().max(0.0) as u32).min(r)
}

fn hav_to_angle(h: f64) -> f64 {
    2.0 * h.clamp(0.0, 1.0).sqrt().asin()
}

/// Phase 2 for column `j`: `g(i')` is the nearest-feature column of row `i'` (phase 1, [`NONE`] if
/// the row has none); writes the distance (radians) from each texel `(i, j)` to its nearest
/// feature into `out[i]`, or `None` if no row has a feature.
pub fn longitude_scan(r: u32, j: u32, g: impl Fn(u32) -> u16, out: &mut [f64]) -> Option<()> {
    longitude_scan_with(&SinTables::new(r), j, g, out)
}

/// `sin(k h / 2)` and `sin((k + 0.5) h)` for `k < r`: the haversine of two texel centres from
/// index differences (what the GPU pass keeps in shared memory).
pub struct SinTables {
    r: u32,
    half: Vec<f64>,
    row: Vec<f64>,
}

impl SinTables {
    /// Tables for resolution `r`.
    pub fn new(r: u32) -> SinTables {
        let h = std::f64::consts::PI / r as f64;
        SinTables {
            r,
            half: (0..r).map(|k| (0.5 * k as f64 * h).sin()).collect(),
            row: (0..r).map(|k| ((k as f64 + 0.5) * h).sin()).collect(),
        }
    }

    /// Haversine `sin^2(d/2)` between texel centres `(i1, j1)` and `(i2, j2)`.
    pub fn hav(&self, i1: u32, j1: u32, i2: u32, j2: u32) -> f64 {
        let a = self.half[i1.abs_diff(i2) as usize];
        let b = self.half[j1.abs_diff(j2) as usize];
        a * a + self.row[i1 as usize] * self.row[i2 as usize] * b * b
    }
}

/// [`longitude_scan`] with precomputed tables.
pub fn longitude_scan_with(tab: &SinTables, j: u32, g: impl Fn(u32) -> u16, out: &mut [f64]) -> Option<()> {
    let r = tab.r;
    let ru = r as usize;
    let f = |qi: usize, c: u32| tab.hav(qi as u32, j, c, g(c) as u32);
    let mut s: Vec<u32> = Vec::with_capacity(ru);
    let mut t: Vec<usize> = Vec::with_capacity(ru);
    for u in 0..r {
        if g(u) == NONE {
            continue;
        }
        // pop candidates that `u` beats (or ties) at the start of their region
        while let (Some(&sq), Some(&tq)) = (s.last(), t.last()) {
            if f(tq, sq) >= f(tq, u) {
                s.pop();
                t.pop();
            } else {
                break;
            }
        }
        match (s.last(), t.last()) {
            (None, _) => {
                s.push(u);
                t.push(0);
            }
            (Some(&sq), Some(&tq)) => {
                // first query row in (tq, r) where u is at least as close as sq (bisection;
                // the predicate is monotone, see the module docs)
                let (mut lo, mut hi) = (tq + 1, ru);
                while lo < hi {
                    let mid = (lo + hi) / 2;
                    if f(mid, u) <= f(mid, sq) {
                        hi = mid;
                    } else {
                        lo = mid + 1;
                    }
                }
                if lo < ru {
                    s.push(u);
                    t.push(lo);
                }
            }
            _ => unreachable!(),
        }
    }
    if s.is_empty() {
        return None;
    }
    let mut q = s.len() - 1;
    for i in (0..ru).rev() {
        out[i] = hav_to_angle(f(i, s[q]));
        if i == t[q] && q > 0 {
            q -= 1;
        }
    }
    Some(())
}

/// The HSDT of one map (f64 distances, see the module docs for the sign convention).
pub fn hsdt_f64(map: &VisMap) -> Vec<f64> {
    let r = map.r;
    check_res(r).expect("resolution");
    let ru = r as usize;
    // g[feature][i * r + j]
    let mut g = [vec![NONE; ru * ru], vec![NONE; ru * ru]];
    for (fi, feature) in [false, true].into_iter().enumerate() {
        for i in 0..r {
            latitude_scan(map, i, feature, &mut g[fi][i as usize * ru..(i as usize + 1) * ru]);
        }
    }
    let mut out = vec![0.0; ru * ru];
    let mut col = [vec![0.0; ru], vec![0.0; ru]];
    let tab = SinTables::new(r);
    for j in 0..r {
        let mut has = [false; 2];
        for fi in 0..2 {
            let gg = &g[fi];
            has[fi] = longitude_scan_with(&tab, j, |i| gg[i as usize * ru + j as usize], &mut col[fi]).is_some();
        }
        for i in 0..r {
            let k = i as usize * ru + j as usize;
            out[k] = if map.get(i, j) {
                if has[0] {
                    col[0][i as usize]
                } else {
                    NO_BOUNDARY
                }
            } else if has[1] {
                -col[1][i as usize]
            } else {
                -NO_BOUNDARY
            };
        }
    }
    out
}

/// The HSDT of one map as f32 (what the GPU pass computes before fp16 packing).
pub fn hsdt(map: &VisMap) -> Vec<f32> {
    hsdt_f64(map).into_iter().map(|v| v as f32).collect()
}

/// Exact SSDF by brute force over all texel-centre pairs, `O(r^4)` (tests and the bench only).
pub fn ssdf_brute_force(map: &VisMap) -> Vec<f64> {
    let r = map.r;
    let mut vis = Vec::new();
    let mut occ = Vec::new();
    for i in 0..r {
        for j in 0..r {
            if map.get(i, j) {
                vis.push(texel_dir(i, j, r))
            } else {
                occ.push(texel_dir(i, j, r))
            }
        }
    }
    let mut out = Vec::with_capacity((r * r) as usize);
    for i in 0..r {
        for j in 0..r {
            let v = texel_dir(i, j, r);
            let (set, sign) = if map.get(i, j) { (&occ, 1.0) } else { (&vis, -1.0) };
            if set.is_empty() {
                out.push(sign * NO_BOUNDARY);
                continue;
            }
            let mut best = -2.0;
            let mut arg = set[0];
            for &t in set.iter() {
                let d = t.dot(v);
                if d > best {
                    best = d;
                    arg = t;
                }
            }
            out.push(sign * angle_between(arg, v));
        }
    }
    out
}

/// Max and mean absolute difference of two fields (radians).
pub fn field_error(a: &[f64], b: &[f64]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let mut mx: f64 = 0.0;
    let mut sum = 0.0;
    for (x, y) in a.iter().zip(b) {
        let e = (x - y).abs();
        mx = mx.max(e);
        sum += e;
    }
    (mx, sum / a.len().max(1) as f64)
}

/// A random visibility map of resolution `r`: 1 to 8 spherical-cap occluders with angular radii
/// 0.05..0.85 rad and centres anywhere above (or slightly below) the horizon (the bench's maps).
pub fn random_cap_map(r: u32, seed: u64) -> VisMap {
    use glam::DVec3;
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    let mut next = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let n = 1 + (next() * 8.0) as usize;
    let caps: Vec<(DVec3, f64)> = (0..n)
        .map(|_| {
            let z = -0.2 + 1.2 * next();
            let a = std::f64::consts::TAU * next();
            let rr = (1.0 - z * z).max(0.0).sqrt();
            (DVec3::new(rr * a.cos(), rr * a.sin(), z), (0.05 + 0.8 * next()).cos())
        })
        .collect();
    VisMap::from_dir_fn(r, |w| caps.iter().all(|(c, ca)| w.dot(*c) < *ca))
}

/// Test maps: named random and adversarial visibility maps of resolution `r` (shared by the CPU
/// tests, the GPU test and the bench). Deterministic for a given `seed`.
pub fn test_maps(r: u32, seed: u64) -> Vec<(String, VisMap)> {
    use glam::DVec3;
    let mut rng = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut maps = Vec::new();
    let last = r - 1;
    maps.push(("all visible".to_string(), VisMap::filled(r, true)));
    maps.push(("all occluded".to_string(), VisMap::filled(r, false)));
    maps.push(("single visible texel".to_string(), VisMap::from_fn(r, |i, j| i == r / 3 && j == r / 2 + 1)));
    maps.push(("single occluded texel (hole)".to_string(), VisMap::from_fn(r, |i, j| !(i == r / 2 && j == r / 5))));
    maps.push(("visible texel at the +x pole".to_string(), VisMap::from_fn(r, |i, j| i == 0 && j == 3)));
    maps.push(("occluded texel at the -x pole".to_string(), VisMap::from_fn(r, |i, j| !(i == last && j == last))));
    maps.push(("polar cap occluded".to_string(), VisMap::from_fn(r, |i, _| i >= 3)));
    maps.push(("seam column phi=0 occluded".to_string(), VisMap::from_fn(r, |_, j| j != 0)));
    maps.push(("seam columns phi=0 visible, phi=pi occluded".to_string(), VisMap::from_fn(r, |_, j| j < r / 2)));
    maps.push(("seam: visible only at both phi edges".to_string(), VisMap::from_fn(r, |_, j| j == 0 || j == last)));
    maps.push(("thin sliver row".to_string(), VisMap::from_fn(r, |i, _| i != r / 2 + 1)));
    maps.push(("thin sliver column".to_string(), VisMap::from_fn(r, |_, j| j != r / 2 - 2)));
    maps.push(("diagonal sliver".to_string(), VisMap::from_fn(r, |i, j| i != j)));
    maps.push(("checkerboard".to_string(), VisMap::from_fn(r, |i, j| (i + j) % 2 == 0)));
    maps.push(("horizon ring occluded".to_string(), VisMap::from_dir_fn(r, |w| w.z > 0.3)));
    // random spherical-cap occluders (world-like blobs of many sizes)
    for k in 0..4 {
        let caps: Vec<(DVec3, f64)> = (0..(2 + 3 * k))
            .map(|_| {
                let z = next();
                let a = std::f64::consts::TAU * next();
                let s = (1.0 - z * z).sqrt();
                (DVec3::new(s * a.cos(), s * a.sin(), z), 0.05 + 0.6 * next())
            })
            .collect();
        maps.push((
            format!("random caps {k}"),
            VisMap::from_dir_fn(r, |w| caps.iter().all(|(c, a)| w.dot(*c) < a.cos())),
        ));
    }
    // random noise at two densities
    for (k, p) in [0.5, 0.97].into_iter().enumerate() {
        let mut m = VisMap::filled(r, false);
        for i in 0..r {
            for j in 0..r {
                m.set(i, j, next() < p);
            }
        }
        maps.push((format!("random noise {k} (p visible {p})"), m));
    }
    maps
}
