// Volumetric single scattering (issue 7): shared light/medium block and helpers.
#ifndef PENUMBRA_VOL_GLSL
#define PENUMBRA_VOL_GLSL
#include "common.glsl"

struct VolLight {
    mat4 face_vp[6];       // light view-projection per shadow-map face (spot: face 0)
    vec4 pos_kind;         // xyz light position, w kind (0 point, 1 spot)
    vec4 dir_cos_outer;    // xyz spot axis, w cos(outer)
    vec4 power_cos_inner;  // rgb radiant intensity, w cos(inner)
    vec4 sigma_t_g;        // rgb extinction, w Henyey-Greenstein g
    vec4 sigma_s_bar;      // rgb scattering, w mean extinction
    vec4 sm;               // x face count (1 or 6), y near, z far, w tile size in texels
    uvec4 misc;            // x mode (0 every pixel, 1 masked pixels only), y samples, z has light, w frame id
    vec4 extra;            // x 1 = hybrid: shadow-map lookups only between the shadow volumes' front/back
};

float vol_hg(float cos_t, float g) {
    float d = max(1.0 + g * g - 2.0 * g * cos_t, 1e-12);
    return (1.0 - g * g) / (4.0 * PI * d * sqrt(d));
}

// Radiant intensity of the light towards point x (spot cone falloff as the reference).
vec3 vol_intensity(VolLight L, vec3 x) {
    vec3 v = x - L.pos_kind.xyz;
    float d = length(v);
    if (d <= 0.0) return vec3(0.0);
    vec3 I = L.power_cos_inner.rgb;
    if (L.pos_kind.w > 0.5) {
        float c = dot(v / d, L.dir_cos_outer.xyz);
        float e0 = L.dir_cos_outer.w, e1 = L.power_cos_inner.w;
        float f = e1 <= e0 ? (c >= e0 ? 1.0 : 0.0) : smoothstep(e0, e1, c);
        I *= f;
    }
    return I;
}

float vol_linear_depth(float d, float n, float f) {
    return n * f / (f - d * (f - n));
}

// 1 where x sees the light according to the shadow map (an atlas of 3x2 tiles for point lights).
float vol_visibility(VolLight L, sampler2D sm, vec3 x) {
    int faces = int(L.sm.x + 0.5);
    int face = 0;
    if (faces == 6) {
        vec3 v = x - L.pos_kind.xyz;
        vec3 a = abs(v);
        if (a.x >= a.y && a.x >= a.z) face = v.x >= 0.0 ? 0 : 1;
        else if (a.y >= a.z) face = v.y >= 0.0 ? 2 : 3;
        else face = v.z >= 0.0 ? 4 : 5;
    }
    vec4 c = L.face_vp[face] * vec4(x, 1.0);
    if (c.w <= 1e-6) return 1.0;
    vec3 ndc = c.xyz / c.w;
    if (any(greaterThan(abs(ndc.xy), vec2(1.0))) || ndc.z > 1.0) return 1.0;
    if (ndc.z < 0.0) return 1.0; // nearer than the shadow map's near plane: nothing in between
    float ts = L.sm.w;
    vec2 tile = faces == 6 ? vec2(float(face % 3), float(face / 3)) : vec2(0.0);
    vec2 px = clamp((ndc.xy * 0.5 + 0.5) * ts, vec2(0.5), vec2(ts - 0.5)) + tile * ts;
    float dm = texelFetch(sm, ivec2(px), 0).r;
    float zm = vol_linear_depth(dm, L.sm.y, L.sm.z);
    float zx = vol_linear_depth(ndc.z, L.sm.y, L.sm.z);
    return zx <= zm * 1.01 + 1e-3 ? 1.0 : 0.0;
}

// Single scattering along o + t d, t in [t_lo, t_hi] (t_lo >= 0, t_hi may be +inf): equiangular
// samples about the light combined (balance heuristic) with exponential-distance samples;
// deterministic stratification with the per-pixel offset j.
// Visibility is looked up only for t in [t_front, t_back] (the hybrid's shadowed interval;
// [0, inf] without it): outside, the ray is lit.
vec3 vol_inscatter_range(VolLight L, sampler2D sm, vec3 o, vec3 d, float t_lo, float t_hi, float j, float t_front, float t_back) {
    vec3 lp = L.pos_kind.xyz;
    float delta = dot(lp - o, d);
    float D = max(length(lp - o - delta * d), 1e-4);
    float ta = atan((t_lo - delta) / D);
    float tb = isinf(t_hi) ? 0.5 * PI : atan((t_hi - delta) / D);
    float span = tb - ta;
    if (!(span > 0.0)) return vec3(0.0);
    int n = int(max(L.misc.y, 2u));
    float sb = L.sigma_s_bar.w;
    float len = t_hi - t_lo;
    // Exponential strategy only where the medium is optically thick over the interval.
    float mass = isinf(len) ? 1.0 : 1.0 - exp(-sb * len);
    bool use_exp = sb > 0.0 && mass > 1e-6 && sb * (isinf(len) ? 1e30 : len) > 0.5;
    int ne = use_exp ? n / 2 : 0;
    int na = n - ne;
    vec3 sum = vec3(0.0);
    for (int i = 0; i < n; ++i) {
        bool eq = i < na;
        float u = eq ? (float(i) + j) / float(na) : (float(i - na) + j) / float(ne);
        float t;
        if (eq) {
            float th = ta + u * span;
            th = clamp(th, -0.5 * PI + 1e-6, 0.5 * PI - 1e-6);
            t = delta + D * tan(th);
        } else {
            t = t_lo - log(max(1.0 - u * mass, 1e-30)) / sb;
        }
        if (!(t >= t_lo) || t > t_hi || isinf(t)) continue;
        float r2 = D * D + (t - delta) * (t - delta);
        float pa = D / (span * r2);
        float pe = use_exp ? sb * exp(-sb * (t - t_lo)) / mass : 0.0;
        float pdf = float(na) * pa + float(ne) * pe;
        if (!(pdf > 0.0)) continue;
        vec3 x = o + t * d;
        vec3 I = vol_intensity(L, x);
        if (I == vec3(0.0)) continue;
        float dist = sqrt(r2);
        vec3 wi = (lp - x) / max(dist, 1e-6);
        float vis = (t >= t_front && t <= t_back) ? vol_visibility(L, sm, x) : 1.0;
        if (vis <= 0.0) continue;
        vec3 tr = exp(-L.sigma_t_g.rgb * (t + dist));
        vec3 f = L.sigma_s_bar.rgb * tr * I / max(r2, 1e-12) * vol_hg(dot(wi, d), L.sigma_t_g.w) * vis;
        sum += f / pdf;
    }
    return sum;
}

vec3 vol_inscatter(VolLight L, sampler2D sm, vec3 o, vec3 d, float tmax, float j, float t_front, float t_back) {
    return vol_inscatter_range(L, sm, o, d, 0.0, tmax, j, t_front, t_back);
}

#endif
