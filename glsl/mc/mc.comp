#version 460
#extension GL_GOOGLE_include_directive : require
// GPU Monte Carlo baseline ("mc"): per pixel, `spp` jittered primary rays traced through the
// kd-tree (closest hit) and, at the first hit, direct lighting from the environment with one
// environment sample (texel distribution proportional to luminance x solid angle, as the CPU
// reference's alias table) and one BRDF sample, combined by the power heuristic; shadow rays are
// any-hit queries through the same tree; a participating medium as the reference has it
// (attenuation from the eye, single scattering: medium_point below); sample points are randomized quasi-Monte Carlo
// (Owen-scrambled Sobol', include/qmc.glsl), not independent. Same estimator, BRDFs and conventions as
// penumbra_reference (render.rs, brdf.rs, sampling.rs); see passes/src/mc/mod.rs for what is left out.
// Progressive: accum.rgb sums samples, accum.a counts them; hdr = accum.rgb / accum.a.
layout(local_size_x = 8, local_size_y = 8) in;
layout(binding = 0) uniform usamplerBuffer kd_tris;
layout(binding = 1) uniform usamplerBuffer kd_nodes;
layout(binding = 2) uniform usamplerBuffer kd_refs;
layout(std430, binding = 3) readonly buffer Header { uint kd_hdr[]; };
// per triangle: (n0, material bits), (n1, 0), (n2, 0), (tangent, 0), (uv0, uv1), (uv2, 0, 0)
layout(std430, binding = 4) readonly buffer TriData { vec4 tri_data[]; };
// the scene's materials (passes/src/scene_gpu.rs material_table, read through material.glsl)
#include "common.glsl"
layout(std430, binding = 5) readonly buffer Materials { MaterialData mats[]; };
// env texels: rgb radiance at intensity 1 (pc.env_rot.z scales it), w = pmf of the texel
layout(std430, binding = 6) readonly buffer EnvTexels { vec4 env_texels[]; };
// env CDFs: marginal over rows (h + 1 floats), then per row the conditional (w + 1 floats)
layout(std430, binding = 7) readonly buffer EnvCdf { float env_cdf[]; };
layout(binding = 8, rgba32f) uniform image2D accum;
layout(binding = 9, rgba32f) uniform writeonly image2D hdr;
// local lights (penumbra_reference::lights): (position, kind 0 point / 1 spot / 2 sphere /
// 3 directional), (spot or directional axis, cos outer), (power: intensity or radiance, cos inner), (sphere radius, 0, 0, 0)
layout(std430, binding = 10) readonly buffer Lights { vec4 lights[]; };
// material texture maps (passes/src/textures.rs): layers resampled to 256^2, repeat, bilinear
layout(binding = 11) uniform sampler2DArray material_textures;
// with bit 3 of env_info.z (mc-denoised's ratio estimator): this dispatch's mean of the same
// samples without their shadow rays (every visibility 1), written beside `hdr`; else a stand-in
layout(binding = 12, rgba32f) uniform writeonly image2D unshadowed;
// the medium: (sigma_t, 1 when mc integrates it), (sigma_s, Henyey-Greenstein g), (eye, 0)
layout(std430, binding = 13) readonly buffer Medium { vec4 medium[]; };
layout(push_constant) uniform Push {
    mat4 inv_view_proj;
    uvec4 size_spp_seed;    // width, height, spp, frame seed
    uvec4 env_info;         // env width, env height, bit 0 reset | bit 1 env can be sampled | bit 2 pixel centres (no jitter) | bit 3 write `unshadowed`, light count
    vec4 env_rot;           // cos, sin of the environment rotation, its intensity (the frame's)
} pc;

#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"

#define M_PI 3.14159265358979323846
#define M_TAU 6.28318530717958647692

// ---- sample points: randomized quasi-Monte Carlo (include/qmc.glsl). Sample `qmc_index` of
// the pixel's sequence (the accumulator's count: a progressive image continues its sequence
// frame after frame; a reset starts a new one, scrambled by the frame's seed); each estimator
// dimension pair has its own scramble (QMC_DIM_*).
#include "qmc.glsl"
uint qmc_index;
uint qmc_pixel;
#define QMC_DIM_PIXEL 0u
// the surface's direct light from here: the environment's texel (1) and position in it (2),
// the BRDF's lobe (3) and direction (4), light k (5 + k) (vertex_direct); the medium's
// distance samples after them, 5 + lights each (radiance_samples)
#define QMC_DIM_SURFACE 1u
vec2 sample2(uint dim) { return qmc_2d(qmc_index, qmc_dim_seed(qmc_pixel, dim)); }

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

// ---- environment (EnvLight of the reference)
vec3 env_to_map(vec3 d) { float c = pc.env_rot.x, s = pc.env_rot.y; return vec3(c * d.x - s * d.z, d.y, s * d.x + c * d.z); }
vec3 env_to_world(vec3 d) { float c = pc.env_rot.x, s = pc.env_rot.y; return vec3(c * d.x + s * d.z, d.y, -s * d.x + c * d.z); }
uint env_texel(vec3 dw) {
    vec3 d = env_to_map(dw);
    float theta = acos(clamp(d.y, -1.0, 1.0));
    float phi = atan(d.x, -d.z);
    if (phi < 0.0) phi += M_TAU;
    float u = phi / M_TAU, v = theta / M_PI;
    int w = int(pc.env_info.x), h = int(pc.env_info.y);
    int i = clamp(int(u * float(w)), 0, w - 1);
    int j = clamp(int(v * float(h)), 0, h - 1);
    return uint(j * w + i);
}
float row_solid_angle(uint j) {
    float h = float(pc.env_info.y);
    return (cos(M_PI * float(j) / h) - cos(M_PI * float(j + 1u) / h)) * M_TAU / float(pc.env_info.x);
}
vec3 env_radiance(vec3 d) { return env_texels[env_texel(d)].rgb * pc.env_rot.z; }
float env_pdf(vec3 d) {
    if ((pc.env_info.z & 2u) == 0u) return 0.0;
    uint k = env_texel(d);
    return env_texels[k].w / row_solid_angle(k / pc.env_info.x);
}
// first index i in [lo, hi) with cdf[i + 1] > u (cdf[lo] = 0, cdf[hi] = 1)
uint cdf_search(uint base, uint n, float u) {
    uint lo = 0u, hi = n;
    while (lo + 1u < hi) {
        uint mid = (lo + hi) / 2u;
        if (env_cdf[base + mid] <= u) lo = mid; else hi = mid;
    }
    return lo;
}
bool env_sample(vec4 u, out vec3 d, out vec3 le, out float pdf) {
    if ((pc.env_info.z & 2u) == 0u) return false;
    uint w = pc.env_info.x, h = pc.env_info.y;
    uint j = cdf_search(0u, h, u.x);
    uint ix = cdf_search(h + 1u + j * (w + 1u), w, u.y);
    float phi = M_TAU * (float(ix) + u.z) / float(w);
    float c0 = cos(M_PI * float(j) / float(h)), c1 = cos(M_PI * float(j + 1u) / float(h));
    float cos_t = clamp(c0 + (c1 - c0) * u.w, -1.0, 1.0);
    float sin_t = sqrt(max(1.0 - cos_t * cos_t, 0.0));
    d = normalize(env_to_world(vec3(sin_t * sin(phi), cos_t, -sin_t * cos(phi))));
    uint k = env_texel(d);
    pdf = env_texels[k].w / row_solid_angle(k / w);
    if (!(pdf > 0.0)) return false;
    le = env_texels[k].rgb * pc.env_rot.z;
    return true;
}

#include "material.glsl"
#include "brdf_ref.glsl"

float power_heuristic(float a, float b) { float a2 = a * a, b2 = b * b; return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0; }

bool unoccluded_to(vec3 x, vec3 d, float tmax) {
    return kd_trace(x, d, 0.0, tmax, true).t < 0.0;
}

float smoothstep_ref(float e0, float e1, float x) {
    if (e1 <= e0) return x >= e0 ? 1.0 : 0.0;
    float t = clamp((x - e0) / (e1 - e0), 0.0, 1.0);
    return t * t * (3.0 - 2.0 * t);
}

// Orthonormal frame around n (Duff et al. 2017), as sampling.rs Frame::new(n, 0).
mat3 onb(vec3 n) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float b = n.x * n.y * a;
    vec3 t = vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    return mat3(t, cross(n, t), n);
}

// Distance along wi from x to sphere light k, or -1.
float sphere_hit(uint k, vec3 x, vec3 wi) {
    vec3 oc = x - lights[4u * k].xyz;
    float r = lights[4u * k + 3u].x;
    float b = dot(oc, wi), c = dot(oc, oc) - r * r;
    if (c <= 0.0) return -1.0;
    float disc = b * b - c;
    if (disc < 0.0) return -1.0;
    float t = -b - sqrt(disc);
    return t > 0.0 ? t : -1.0;
}

float sphere_one_minus(uint k, vec3 x) {
    vec3 v = lights[4u * k].xyz - x;
    float r = lights[4u * k + 3u].x;
    float sin2 = r * r / dot(v, v);
    return sin2 / (1.0 + sqrt(max(1.0 - sin2, 0.0)));
}

// Samples light k from p: direction, distance, radiance (or intensity / d^2), pdf (0: delta).
bool light_sample(uint k, vec3 p, vec2 u, out vec3 wi, out float dist, out vec3 li, out float pdf) {
    vec4 l0 = lights[4u * k], l1 = lights[4u * k + 1u], l2 = lights[4u * k + 2u];
    uint kind = uint(l0.w);
    if (kind == 3u) {
        // directional: irradiance l2 along -axis from infinitely far (no medium: the scene
        // loader refuses directional lights in one)
        wi = -l1.xyz;
        dist = 3.0e38;
        li = l2.rgb;
        pdf = 0.0;
        return true;
    }
    vec3 v = l0.xyz - p;
    float d2 = dot(v, v);
    if (kind < 2u) {
        if (d2 <= 0.0) return false;
        float d = sqrt(d2);
        wi = v / d;
        dist = d;
        float f = kind == 1u ? smoothstep_ref(l1.w, l2.w, dot(-wi, l1.xyz)) : 1.0;
        li = l2.rgb * (f / d2) * medium_transmittance(lights[4u * k + 3u].yzw, d);
        pdf = 0.0;
        return f > 0.0;
    }
    float r = lights[4u * k + 3u].x;
    if (d2 <= r * r) return false;
    float d = sqrt(d2);
    float one_minus = sphere_one_minus(k, p);
    float cos_t = 1.0 - u.x * one_minus;
    float sin_t = sqrt(max(1.0 - cos_t * cos_t, 0.0));
    float phi = M_TAU * u.y;
    wi = normalize(onb(v / d) * vec3(sin_t * cos(phi), sin_t * sin(phi), cos_t));
    float t = sphere_hit(k, p, wi);
    dist = t > 0.0 ? t : d - r;
    li = l2.rgb * medium_transmittance(lights[4u * k + 3u].yzw, dist);
    pdf = 1.0 / (M_TAU * one_minus);
    return true;
}

// ---- the participating medium (penumbra_reference render.rs `sample` and `direct` with
// Scatter::Medium): homogeneous, filling space from the eye; the surface's light and the
// environment behind are attenuated by exp(-sigma_t t), t counted from the eye; single
// scattering with one distance sample per strategy combined by the balance heuristic (the
// transmittance, pdf ~ exp(-mean(sigma_t) t) on [0, t_hit], and per point, spot or sphere light
// equiangular sampling, Kulla and Fajardo 2012), at each the environment, the local lights and
// a Henyey-Greenstein phase sample combined by the power heuristic.
// medium[0]: sigma_t, on (1: this technique integrates the medium); [1]: sigma_s, g; [2]: eye.
#define MC_INF 3.0e38
vec3 med_transmittance(float t) {
    vec3 st = medium[0].rgb;
    return t >= 1.0e30 ? vec3(st.r > 0.0 ? 0.0 : 1.0, st.g > 0.0 ? 0.0 : 1.0, st.b > 0.0 ? 0.0 : 1.0) : exp(-st * t);
}
float hg_phase(float cos_t) {
    float g = medium[1].w;
    float d = max(1.0 + g * g - 2.0 * g * cos_t, 1e-12);
    return (1.0 - g * g) / (4.0 * M_PI * d * sqrt(d));
}
// A direction wi with pdf hg_phase(dot(wi, d)) (render.rs Scatter::Medium::sample).
vec3 hg_sample(vec3 d, vec2 u) {
    float g = medium[1].w;
    float cos_t;
    if (abs(g) < 1e-3) {
        cos_t = 1.0 - 2.0 * u.x;
    } else {
        float s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.x);
        cos_t = clamp((1.0 + g * g - s * s) / (2.0 * g), -1.0, 1.0);
    }
    float sin_t = sqrt(max(1.0 - cos_t * cos_t, 0.0));
    float phi = M_TAU * u.y;
    return normalize(onb(d) * vec3(sin_t * cos(phi), sin_t * sin(phi), cos_t));
}
// The part [t0, t1] of o + t d, t in [0, t_max), that light k can light: all of it, or for a
// spot light (cos outer > 0: a convex cone) the ray's interval inside its cone (the breakpoints
// are the roots of ((x - c).a)^2 = cos^2 |x - c|^2; each piece between them tested at its
// middle). Returns false when no part is.
bool light_range(uint k, vec3 o, vec3 d, float t_max, out vec2 r) {
    float t_end = min(t_max, 1.0e6);
    r = vec2(0.0, t_end);
    if (uint(lights[4u * k].w) != 1u) return true;
    vec3 c = lights[4u * k].xyz, a = normalize(lights[4u * k + 1u].xyz);
    float co = lights[4u * k + 1u].w;
    if (!(co > 0.0)) return true;
    vec3 w = o - c;
    float da = dot(d, a), wa = dot(w, a), c2 = co * co;
    float qa = da * da - c2, qb = 2.0 * (da * wa - c2 * dot(d, w)), qc = wa * wa - c2 * dot(w, w);
    float b0 = 0.0, b1 = t_end, b2 = t_end, b3 = t_end;  // breakpoints, sorted below
    float disc = qb * qb - 4.0 * qa * qc;
    if (abs(qa) > 1e-12 && disc >= 0.0) {
        float sq = sqrt(disc);
        float r1 = (-qb - sq) / (2.0 * qa), r2 = (-qb + sq) / (2.0 * qa);
        b1 = clamp(min(r1, r2), 0.0, t_end);
        b2 = clamp(max(r1, r2), 0.0, t_end);
    } else if (abs(qa) <= 1e-12 && abs(qb) > 1e-12) {
        b1 = clamp(-qc / qb, 0.0, t_end);
    }
    float lo = 1.0e30, hi = -1.0;
    for (int i = 0; i < 3; i++) {
        float s0 = i == 0 ? b0 : (i == 1 ? b1 : b2);
        float s1 = i == 0 ? b1 : (i == 1 ? b2 : b3);
        if (!(s1 > s0)) continue;
        vec3 x = w + d * (0.5 * (s0 + s1));
        float xa = dot(x, a);
        if (xa >= 0.0 && xa * xa >= c2 * dot(x, x)) {
            lo = min(lo, s0);
            hi = max(hi, s1);
        }
    }
    if (!(hi > lo)) return false;
    r = vec2(lo, hi);
    return true;
}
// Equiangular sampling (Kulla and Fajardo 2012; render.rs Equiangular) towards light k's
// position along o + t d over the part light_range gives: (delta, h, theta_a, theta_b), the
// range in `r`; false for a directional light or an empty range. (The reference samples
// [0, t_hit] whole; a spot light's cone here: the same estimate, most of whose samples are lit.)
bool equiangular(uint k, vec3 o, vec3 d, float t_max, out vec4 e, out vec2 r) {
    e = vec4(0.0);
    if (uint(lights[4u * k].w) == 3u || !light_range(k, o, d, t_max, r)) return false;
    vec3 c = lights[4u * k].xyz;
    float delta = dot(c - o, d);
    float h = max(length(o + d * delta - c), 1e-4);
    float ta = atan((r.x - delta) / h);
    float tb = r.y >= 1.0e6 ? 0.5 * M_PI : atan((r.y - delta) / h);
    e = vec4(delta, h, ta, tb);
    return tb - ta > 1e-6;
}
float equiangular_pdf(vec4 e, vec2 r, float t) {
    if (!(t >= r.x && t < r.y)) return 0.0;
    float x = t - e.x;
    return e.y / ((e.w - e.z) * (e.y * e.y + x * x));
}
// Distance sample `s` of single scattering along o + t d, t in [0, t_max) (from the eye): s = 0
// the transmittance (pdf ~ exp(-mean(sigma_t) t)), s = 1 + k equiangular towards light k; the
// point's weight sigma_s Tr(t) over the balance heuristic's summed pdfs (false: no sample);
// its sample dimension `dim`.
bool medium_point(uint s, uint dim, vec3 o, vec3 d, float t_max, out float t, out vec3 w) {
    vec3 st = medium[0].rgb;
    float sb = (st.r + st.g + st.b) / 3.0;
    float sbt = sb * t_max;
    float mass = t_max >= 1.0e30 ? 1.0 : (sbt < 1e-4 ? sbt * (1.0 - 0.5 * sbt) : 1.0 - exp(-sbt));
    uint nlights = pc.env_info.w;
    float u = sample2(dim).x;
    t = -1.0;
    w = vec3(0.0);
    if (s == 0u) {
        if (!(mass > 0.0 && sb > 0.0)) return false;
        t = -log(max(1.0 - u * mass, 1e-30)) / sb;
    } else {
        vec4 e;
        vec2 r;
        if (!equiangular(s - 1u, o, d, t_max, e, r)) return false;
        t = clamp(e.x + e.y * tan(e.z + u * (e.w - e.z)), r.x, r.y);
    }
    if (!(t >= 0.0 && t < t_max)) return false;
    // the balance heuristic over every strategy: f / the sum of their pdfs
    float p = (mass > 0.0 && sb > 0.0) ? sb * exp(-sb * t) / mass : 0.0;
    for (uint k = 0u; k < nlights; k++) {
        vec4 e;
        vec2 r;
        if (equiangular(k, o, d, t_max, e, r)) p += equiangular_pdf(e, r, t);
    }
    if (!(p > 0.0) || isinf(p)) return false;
    w = med_transmittance(t) * medium[1].rgb / p;
    return true;
}

// ---- direct light at a scattering vertex: a surface point (its BRDF in the shading frame, the
// cosine included) or a point of the medium (the Henyey-Greenstein phase function towards -d).
struct Vertex {
    bool surface;
    vec3 x;         // shadow rays' origin (a surface point offset along ng)
    vec3 p;         // the point lights are sampled from
    vec3 ng;        // surface: the geometric normal on the viewer's side
    mat3 to_world;  // surface: the shading frame
    vec3 wo;        // surface: towards the viewer, local
    vec3 d;         // medium: the ray's direction
};
// f (times the cosine on a surface) and the pdf of scattering into world direction wi.
void vertex_eval(Vertex v, Brdf b, vec3 wi, out vec3 f, out float pdf) {
    f = vec3(0.0);
    pdf = 0.0;
    if (v.surface) {
        if (dot(wi, v.ng) <= 0.0) return;
        vec3 lw = transpose(v.to_world) * wi;
        pdf = brdf_pdf(b, v.wo, lw);
        if (lw.z > 0.0 && v.wo.z > 0.0) f = brdf_eval(b, v.wo, lw) * lw.z;
    } else {
        pdf = hg_phase(dot(wi, v.d));
        f = vec3(pdf);
    }
}
// Direct light at v with sample dimensions dim (environment texel and position), dim + 2 (BRDF
// lobe), dim + 3 (BRDF or phase direction), dim + 4 + k (light k): the environment, one
// sample per light and a BRDF (phase) sample, combined by the power heuristic. Adds to l and
// to lu (the same with every shadow ray unoccluded). Every shadow ray goes through one kd_trace
// call site (slot j: 0 the environment sample, 1 .. nlights one sample per light, nlights + 1
// the BRDF sample towards the environment, then one per sphere light the BRDF sample hits), and
// this function has one call site: lavapipe compiles every inlined copy of the traversal.
void vertex_direct(Vertex v, Brdf b, uint dim, inout vec3 l, inout vec3 lu) {
    vec3 ws = vec3(0.0, 0.0, 1.0), fs = vec3(0.0);
    float pdf_s = 0.0;
    if (v.surface) {
        vec3 wl;
        if (brdf_sample(b, v.wo, sample2(dim + 2u).x, sample2(dim + 3u), wl)) {
            ws = normalize(v.to_world * wl);
            vertex_eval(v, b, ws, fs, pdf_s);
        }
    } else {
        ws = hg_sample(v.d, sample2(dim + 3u));
        vertex_eval(v, b, ws, fs, pdf_s);
    }
    bool bs = pdf_s > 0.0 && fs != vec3(0.0);
    uint nlights = pc.env_info.w;
    for (uint j = 0u; j < 2u + 2u * nlights; j++) {
        vec3 wi = ws, c = vec3(0.0);
        float tmax = MC_INF;
        if (j <= nlights) {
            // a light's sample: le over its pdf (pdf 0: a delta light), weighted against the BRDF's
            vec3 le = vec3(0.0);
            float pdf_l = 0.0;
            if (j == 0u) {
                if (!env_sample(vec4(sample2(dim), sample2(dim + 1u)), wi, le, pdf_l)) le = vec3(0.0);
            } else {
                uint k = j - 1u;
                float ldist;
                if (light_sample(k, v.p, sample2(dim + 4u + k), wi, ldist, le, pdf_l)) {
                    tmax = ldist * (1.0 - 1e-4);
                } else {
                    le = vec3(0.0);
                }
            }
            if (le != vec3(0.0)) {
                vec3 f;
                float pdf;
                vertex_eval(v, b, wi, f, pdf);
                if (f != vec3(0.0)) c = pdf_l == 0.0 ? f * le : f * le * (power_heuristic(pdf_l, pdf) / pdf_l);
            }
        } else if (j == nlights + 1u) {
            if (bs) c = fs * env_radiance(ws) * (((pc.env_info.z & 2u) != 0u ? power_heuristic(pdf_s, env_pdf(ws)) : 1.0) / pdf_s);
        } else {
            uint k = j - nlights - 2u;
            float t = bs && uint(lights[4u * k].w) == 2u ? sphere_hit(k, v.p, ws) : -1.0;
            if (t > 0.0) {
                float pdf_l = 1.0 / (M_TAU * sphere_one_minus(k, v.p));
                vec3 le = lights[4u * k + 2u].rgb * medium_transmittance(lights[4u * k + 3u].yzw, t);
                c = fs * le * (power_heuristic(pdf_s, pdf_l) / pdf_s);
                tmax = t * (1.0 - 1e-4);
            }
        }
        if (c != vec3(0.0)) {
            lu += c;
            if (unoccluded_to(v.x, wi, tmax)) l += c;
        }
    }
}

// This dispatch's sums: radiance (rgb) and samples (a, the accumulator's count), the same
// samples' unshadowed estimate, and the moments of their luminances (s^2, s u, u^2).
vec4 acc;
vec3 acc_u;
vec3 moments;
void accumulate(vec3 c, vec3 cu) {
    if (!any(isinf(c)) && !any(isnan(c)) && !any(isinf(cu)) && !any(isnan(cu))) {
        acc.rgb += c;
        acc_u += cu;
        float ls = luminance(c), lu = luminance(cu);
        moments += vec3(ls * ls, ls * lu, lu * lu);
    }
    acc.a += 1.0;
}

// Samples `first` .. `first + count` of the radiance through `ndc` (one primary ray, its hit
// shaded `count` times: the pixel centres' samples share it), each with the same estimate with
// every shadow ray taken as unoccluded (the denominator of mc-denoised's ratio estimator:
// shadowed over unshadowed with the same samples, Heitz et al. 2018), accumulated.
void radiance_samples(vec2 ndc, uint first, uint count) {
    vec4 nr = pc.inv_view_proj * vec4(ndc, 0.0, 1.0);
    vec4 fr = pc.inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 o = nr.xyz / nr.w;
    vec3 d = normalize(fr.xyz / fr.w - o);
    KdHit hit = kd_trace(o, d, 0.0, 3.0e38, false);
    // the medium counts from the eye, t0 before the near plane the ray starts on (render.rs)
    bool med = medium[0].w != 0.0;
    float t_eye = med ? max(dot(o - medium[2].xyz, d), 0.0) : 0.0;
    vec3 oe = o - d * t_eye;
    float t_hit = hit.t < 0.0 ? MC_INF : hit.t + t_eye;
    vec3 surface_tr = med ? med_transmittance(t_hit) : vec3(1.0);
    bool surf = hit.t >= 0.0;
    vec3 sky = vec3(0.0);
    if (!surf) {
        // the sky: with a medium, its in-scattering per sample (vertex_direct's one call site is
        // below, shared with the surfaces; the surface's setup then reads triangle 0, unused)
        sky = env_radiance(d);
        if (!med) {
            for (uint s = 0u; s < count; s++) accumulate(sky, sky);
            return;
        }
    }
    uint ti = surf ? hit.tri : 0u;
    vec3 p0 = KD_TRI(3u * ti).xyz, p1 = KD_TRI(3u * ti + 1u).xyz, p2 = KD_TRI(3u * ti + 2u).xyz;
    vec3 p = o + d * (surf ? hit.t : 0.0);
    float b1 = clamp(hit.b1, 0.0, 1.0), b2 = clamp(hit.b2, 0.0, 1.0);
    float b0 = max(1.0 - b1 - b2, 0.0);
    vec4 t0 = tri_data[6u * ti], t1 = tri_data[6u * ti + 1u], t2 = tri_data[6u * ti + 2u], t3 = tri_data[6u * ti + 3u];
    vec3 ng = normalize(cross(p1 - p0, p2 - p0));
    vec3 ns = t0.xyz * b0 + t1.xyz * b1 + t2.xyz * b2;
    ns = dot(ns, ns) > 0.0 ? normalize(ns) : ng;
    if (dot(ns, ng) < 0.0) ng = -ng;          // trust the vertex normals' side (reference)
    vec3 wo_w = -d;
    if (dot(ng, wo_w) < 0.0) ng = -ng;        // two-sided: towards the viewer
    if (dot(ns, ng) < 0.0) ns = -ns;
    // render.rs brdf_at: the material with its maps at the interpolated uv, then Brdf::new; its
    // normal map bends ns in the triangle's dP/du, dP/dv frame (render.rs normal_at)
    uint mi = floatBitsToUint(t0.w);
    vec4 t4 = tri_data[6u * ti + 4u];
    vec2 uv0 = t4.xy, uv1 = t4.zw, uv2 = tri_data[6u * ti + 5u].xy;
    vec2 uv = uv0 * b0 + uv1 * b1 + uv2 * b2;
    MaterialData mat = material_at(mats[mi], uv, material_textures);
    {
        vec2 d1 = uv1 - uv0, d2 = uv2 - uv0;
        float det = d1.x * d2.y - d1.y * d2.x;
        if (abs(det) > 1e-12) {
            vec3 e1 = p1 - p0, e2 = p2 - p0;
            ns = material_normal(mat, uv, material_textures, ns, (e1 * d2.y - e2 * d1.y) / det, (e2 * d1.x - e1 * d2.x) / det);
        }
    }
    ns = material_facing_normal(ns, wo_w);  // render.rs facing_normal
    // shading frame (sampling.rs Frame::new)
    mat3 to_world = brdf_frame(ns, t3.xyz);
    vec3 wo = wo_w * to_world;
    Brdf b = brdf_from_material(mat);
    vec3 x = p + ng * (3e-5 * (1.0 + max(max(abs(p.x), abs(p.y)), abs(p.z))));
    // what the surface emits towards the eye (direct lighting only: it lights nothing)
    vec3 emitted = material_emission(mat);
    Vertex sv = Vertex(true, x, p, ng, to_world, wo, d);
    // with a medium, vertices 1 .. 1 + nlights are its distance samples (medium_point)
    uint nv = med ? 2u + pc.env_info.w : 1u;
    for (uint s = 0u; s < count; s++) {
        qmc_index = first + s;
        vec3 l = surf ? emitted : sky, lu = l, lm = vec3(0.0);
        for (uint vi = 0u; vi < nv; vi++) {
            Vertex v = sv;
            vec3 w = vec3(1.0);
            // vertex_direct's dimensions, then (medium) the distance's
            uint dim = QMC_DIM_SURFACE + vi * (5u + pc.env_info.w);
            if (vi == 0u) {
                if (!surf) continue;
            } else {
                float t;
                if (!medium_point(vi - 1u, dim + 4u + pc.env_info.w, oe, d, t_hit, t, w)) continue;
                v = Vertex(false, oe + d * t, oe + d * t, ng, to_world, wo, d);
            }
            vec3 lv = vec3(0.0), luv = vec3(0.0);
            vertex_direct(v, b, dim, lv, luv);
            if (vi == 0u) {
                l += lv;
                lu += luv;
            } else {
                lm += w * lv;
            }
        }
        accumulate(med ? surface_tr * l + lm : l, lu);
    }
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uint w = pc.size_spp_seed.x, h = pc.size_spp_seed.y;
    if (px.x >= w || px.y >= h) return;
    // the sequence's seed: the pixel and the seed of the frame that started the accumulation
    qmc_pixel = qmc_hash(qmc_hash(px.y * w + px.x) ^ qmc_hash(pc.size_spp_seed.w * 0x9E3779B9u + 17u));
    acc = (pc.env_info.z & 1u) != 0u ? vec4(0.0) : imageLoad(accum, ivec2(px));
    acc_u = vec3(0.0);
    moments = vec3(0.0);
    uint first = uint(acc.a);
    uint spp = pc.size_spp_seed.z;
    vec2 size = vec2(float(w), float(h));
    if ((pc.env_info.z & 4u) != 0u) {
        // pixel centres: one primary ray for all of the dispatch's samples
        radiance_samples(2.0 * (vec2(px) + 0.5) / size - 1.0, first, spp);
    } else {
        for (uint s = 0u; s < spp; s++) {
            qmc_index = first + s;
            radiance_samples(2.0 * (vec2(px) + sample2(QMC_DIM_PIXEL)) / size - 1.0, first + s, 1u);
        }
    }
    imageStore(accum, ivec2(px), acc);
    if ((pc.env_info.z & 8u) != 0u) {
        // alpha: the variance of the visible fraction R = S / U of this frame's mean (the ratio
        // estimator's, by the delta method: Var(s - R u) / (n U^2)); 0 where every shadow ray
        // agreed (nothing blocked, or everything), however noisy the lighting's samples
        float n = float(max(pc.size_spp_seed.z, 1u));
        float ms = luminance(acc.rgb) / n, mu = luminance(acc_u) / n;
        float var_r = 0.0;
        if (mu > 0.0) {
            float r = ms / mu;
            vec3 m = moments / n;
            var_r = max(m.x - 2.0 * r * m.y + r * r * m.z, 0.0) / (n * mu * mu);
        }
        imageStore(unshadowed, ivec2(px), vec4(acc_u / n, var_r));
    }
    imageStore(hdr, ivec2(px), vec4(acc.a > 0.0 ? acc.rgb / acc.a : vec3(0.0), 1.0));
}
