// The airlight model (Sun, Ramamoorthy, Narasimhan and Nayar 2005, the thesis's [21]) for the
// lit segments of Wyman and Ramsey's hybrid: the single scattering of a point light over a
// segment of a view ray in a homogeneous medium, without shadowing, in closed form up to a
// tabulated 2D function. With the light at distance D from the ray's line and delta the ray
// parameter of its foot, t = delta + D tan(theta), xi = pi/4 + theta/2:
//   integral sigma_s I p exp(-sigma_t (t + d)) / d^2 dt
//     = sigma_s I exp(-sigma_t delta) / (2 pi D) [F(sigma_t D, xi_1) - F(sigma_t D, xi_0)],
//   F(u, v) = integral_0^v exp(-u tan xi) 4 pi p(cos 2 xi) dxi,
// which Sun et al. tabulate for an isotropic phase; for the medium's Henyey-Greenstein g it is
// tabulated the same way (penumbra_passes::volumetric::airlight_table, built once per effect).
// A spot light's cone is handled by splitting the segment where the ray crosses the inner and
// outer cones: inside the inner cone the closed form applies, outside the outer one nothing
// scatters, and in the smooth falloff between them a 6-point Gauss-Legendre rule in theta
// integrates the exact integrand.
//
// The includer declares `air[]` (the table: AIR_ROWS rows of w = u / (1 + u) in [0, AIR_WMAX],
// AIR_COLS columns of s = sqrt(v / (pi / 2)) in [0, 1], F (1 + u) row-major).
#ifndef PENUMBRA_VOL_AIRLIGHT_GLSL
#define PENUMBRA_VOL_AIRLIGHT_GLSL
#include "vol.glsl"

#define AIR_ROWS 128
#define AIR_COLS 256
#define AIR_WMAX 0.999

float vol_air_F(float u, float v) {
    float w = clamp(u / (1.0 + u), 0.0, AIR_WMAX);
    float s = sqrt(clamp(v / (0.5 * PI), 0.0, 1.0));
    float fr = w / AIR_WMAX * float(AIR_ROWS - 1);
    float fc = s * float(AIR_COLS - 1);
    int r0 = min(int(fr), AIR_ROWS - 2), c0 = min(int(fc), AIR_COLS - 2);
    float ar = clamp(fr - float(r0), 0.0, 1.0), ac = clamp(fc - float(c0), 0.0, 1.0);
    int i = r0 * AIR_COLS + c0;
    float top = mix(air[i], air[i + 1], ac);
    float bottom = mix(air[i + AIR_COLS], air[i + AIR_COLS + 1], ac);
    // F (1 + u) tends to a constant as u grows: beyond the last row, dividing by the true u
    // extrapolates.
    return mix(top, bottom, ar) / (1.0 + u);
}

// Closed form over [t0, t1] (t1 may be +inf) for an unshadowed, unoccluded light of intensity I.
vec3 vol_air_closed(VolLight L, vec3 o, vec3 d, float t0, float t1, vec3 I) {
    vec3 lp = L.pos_kind.xyz;
    float delta = dot(lp - o, d);
    float D = max(length(lp - o - delta * d), 1e-4);
    float x0 = 0.25 * PI + 0.5 * atan((t0 - delta) / D);
    float x1 = isinf(t1) ? 0.5 * PI : 0.25 * PI + 0.5 * atan((t1 - delta) / D);
    vec3 st = L.sigma_t_g.rgb;
    vec3 r = vec3(0.0);
    for (int c = 0; c < 3; ++c) {
        float u = st[c] * D;
        r[c] = vol_air_F(u, x1) - vol_air_F(u, x0);
    }
    return L.sigma_s_bar.rgb * I * exp(-st * delta) / (2.0 * PI * D) * max(r, vec3(0.0));
}

// The exact integrand over [t0, t1] by 6-point Gauss-Legendre in theta (the cone's falloff).
vec3 vol_air_quadrature(VolLight L, vec3 o, vec3 d, float t0, float t1) {
    const float gx[6] = float[](-0.9324695142, -0.6612093865, -0.2386191861, 0.2386191861, 0.6612093865, 0.9324695142);
    const float gw[6] = float[](0.1713244924, 0.3607615730, 0.4679139346, 0.4679139346, 0.3607615730, 0.1713244924);
    vec3 lp = L.pos_kind.xyz;
    float delta = dot(lp - o, d);
    float D = max(length(lp - o - delta * d), 1e-4);
    float a = atan((t0 - delta) / D);
    float b = isinf(t1) ? 0.5 * PI : atan((t1 - delta) / D);
    vec3 sum = vec3(0.0);
    for (int k = 0; k < 6; ++k) {
        float th = clamp(0.5 * (a + b) + 0.5 * (b - a) * gx[k], -0.5 * PI + 1e-6, 0.5 * PI - 1e-6);
        float t = delta + D * tan(th);
        float dist = D / cos(th);
        vec3 x = o + t * d;
        vec3 wi = (lp - x) / max(dist, 1e-6);
        // dt / d^2 = dtheta / D
        sum += gw[k] * vol_intensity(L, x) * exp(-L.sigma_t_g.rgb * (t + dist)) * vol_hg(dot(wi, d), L.sigma_t_g.w);
    }
    return L.sigma_s_bar.rgb * sum * (0.5 * (b - a) / D);
}

// Ray parameters where o + t d crosses the nappe of the cone about `axis` (apex lp) whose
// half-angle has cosine c; appended to pts[n..].
void vol_cone_roots(vec3 w, vec3 d, vec3 axis, float c, float t0, float t1, inout float pts[6], inout int n) {
    float da = dot(d, axis), wa = dot(w, axis);
    float c2 = c * c;
    float A = da * da - c2, B = 2.0 * (da * wa - c2 * dot(d, w)), C = wa * wa - c2 * dot(w, w);
    float r[2];
    int m = 0;
    if (abs(A) < 1e-9) {
        if (abs(B) > 1e-12) { r[0] = -C / B; m = 1; }
    } else {
        float disc = B * B - 4.0 * A * C;
        if (disc >= 0.0) {
            float q = -0.5 * (B + (B >= 0.0 ? 1.0 : -1.0) * sqrt(disc));
            r[0] = q / A;
            r[1] = q != 0.0 ? C / q : r[0];
            m = 2;
        }
    }
    for (int k = 0; k < m; ++k) {
        float t = r[k];
        // The nappe on the axis's side (a cone of half-angle below 90 degrees has one).
        if (t > t0 && t < t1 && (wa + t * da) * c >= 0.0 && n < 6) pts[n++] = t;
    }
}

// Single scattering over the lit segment [t0, t1] (t1 may be +inf): closed form where the
// light's intensity is constant, quadrature in a spot's falloff.
vec3 vol_air_segment(VolLight L, vec3 o, vec3 d, float t0, float t1) {
    if (!(t1 > t0)) return vec3(0.0);
    vec3 I = L.power_cos_inner.rgb;
    if (L.pos_kind.w <= 0.5) return vol_air_closed(L, o, d, t0, t1, I);
    vec3 lp = L.pos_kind.xyz;
    vec3 axis = L.dir_cos_outer.xyz;
    float co = L.dir_cos_outer.w, ci = L.power_cos_inner.w;
    float pts[6];
    int n = 0;
    pts[n++] = t0;
    vol_cone_roots(o - lp, d, axis, co, t0, t1, pts, n);
    if (ci > co) vol_cone_roots(o - lp, d, axis, ci, t0, t1, pts, n);
    if (n < 6) pts[n++] = t1;
    // insertion sort
    for (int a = 1; a < n; ++a) {
        float v = pts[a];
        int b = a - 1;
        while (b >= 0 && pts[b] > v) { pts[b + 1] = pts[b]; --b; }
        pts[b + 1] = v;
    }
    vec3 sum = vec3(0.0);
    for (int k = 0; k + 1 < n; ++k) {
        float a = pts[k], b = pts[k + 1];
        if (!(b > a)) continue;
        // The piece's class from a point inside it (the cones are crossed only at the roots).
        float tm = isinf(b) ? a + max(1.0, abs(a)) * 4.0 : 0.5 * (a + b);
        vec3 v = o + tm * d - lp;
        float c = dot(normalize(v), axis);
        if (c >= ci && ci > co) sum += vol_air_closed(L, o, d, a, b, I);
        else if (c > co || (ci <= co && c >= co)) sum += ci > co ? vol_air_quadrature(L, o, d, a, b) : vol_air_closed(L, o, d, a, b, I);
    }
    return sum;
}

#endif
