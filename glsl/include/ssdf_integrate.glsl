// SG integrals over the visible region of an SSDF (paper section 6). GLSL mirror of
// penumbra_math::ssdf_integrate (read its module docs for the models and measured errors).
//
// USAGE: before including, define
//   SSDF_FETCH(k)  -> float: the SSDF value (radians, avs_maps.glsl convention) of texel
//                  k = i * r + j of the map being integrated, e.g.
//                  #define SSDF_FETCH(k) AVS_SSDF(ssdf_words, map_base_word, (k))
//                  or a call of your own function that interpolates several sample points' SSDFs.
//   SSDF_TABLE(i)  -> float (only for method (a)): entry i of the T(lambda, d) table,
//                  row-major [SSDF_N_LAMBDA][SSDF_N_W] as produced by
//                  penumbra_math::ssdf_integrate::AxisTable::generate().data, e.g.
//                  #define SSDF_TABLE(i) axis_table[(i)]
// Lobes are given in the map's LOCAL frame (avs_frame / avs_frame_hint: z = normal, x = tangent):
// axis (unit), sharpness lambda >= 0, amplitude mu. `cosine` multiplies the integrand by the
// cosine: (a) by the clamped-cosine SG fit (Wang et al. 2009), (b) by the exact max(0, w.z).
//
//   float ssdf_visible_axis(vec3 axis, float lambda, float mu, bool cosine, uint r)   // (a)
//       hemisphere integral of the lobe x T(lambda, corrected SSDF at the lobe axis)
//   float ssdf_visible_cells(vec3 axis, float lambda, float mu, bool cosine, uint r)  // (b)
//       adaptive cells (distance-field quadtree), 3x3 Gauss rule per visible cell, boundary
//       texels clipped by the iso-line theta = k phi + b of the linearised SSDF (eq. 5)
//   float ssdf_sample(float theta, float phi, uint r)   // corrected SSDF, bilinear
// For a sum of lobes (lighting SGs x BRDF SGs), call once per product lobe and add.
// Cost and accuracy (`penumbra bench hsdt`, lavapipe, error / unoccluded integral vs brute force
// over the binary map): (a) ~0.2-0.4 us per lobe, mean error 2-8% (max 15%) for lambda <= 10, < 0.03% for
// lambda >= 1e3; (b) ~1-2 ms per lobe (grows with the boundary length inside the lobe's support),
// mean error < 0.03%. (b) per pixel and lobe is too slow for full frames on a software device.
#ifndef PENUMBRA_SSDF_INTEGRATE_GLSL
#define PENUMBRA_SSDF_INTEGRATE_GLSL

#include "avs_maps.glsl"
#include "sg.glsl"

#define SSDF_N_LAMBDA 49u
#define SSDF_N_W 257u
#define SSDF_LOG_LAMBDA_MIN (-2.0)
#define SSDF_LOG_LAMBDA_MAX 4.0
#define SSDF_NO_BOUNDARY_READ 3.14

const float SSDF_GL3_X = 0.7745966692414834;
const float SSDF_GL3_W0 = 0.5555555555555556; // outer nodes
const float SSDF_GL3_W1 = 0.8888888888888888; // centre node

float ssdf_corrected(float d, float h) {
    if (abs(d) >= SSDF_NO_BOUNDARY_READ) return d > 0.0 ? float(AVS_PI) : -float(AVS_PI);
    if (abs(d) >= h) return d - sign(d) * 0.5 * h;
    return 0.5 * d;
}

float ssdf_raw(uint i, uint j, uint r) { return SSDF_FETCH(i * r + j); }
float ssdf_corr(uint i, uint j, uint r) { return ssdf_corrected(ssdf_raw(i, j, r), float(AVS_PI) / float(r)); }

float ssdf_sample(float theta, float phi, uint r) {
    float h = float(AVS_PI) / float(r);
    float u = clamp(theta / h - 0.5, 0.0, float(r - 1u));
    float v = clamp(phi / h - 0.5, 0.0, float(r - 1u));
    uint i0 = min(uint(floor(u)), r - 1u), j0 = min(uint(floor(v)), r - 1u);
    uint i1 = min(i0 + 1u, r - 1u), j1 = min(j0 + 1u, r - 1u);
    float fu = u - float(i0), fv = v - float(j0);
    float a = mix(ssdf_corr(i0, j0, r), ssdf_corr(i0, j1, r), fv);
    float b = mix(ssdf_corr(i1, j0, r), ssdf_corr(i1, j1, r), fv);
    return mix(a, b, fu);
}

#ifdef SSDF_TABLE
float ssdf_table_lookup(float lambda, float d) {
    float x = clamp((log(max(lambda, 1e-30)) * 0.4342944819032518 - SSDF_LOG_LAMBDA_MIN)
                    / (SSDF_LOG_LAMBDA_MAX - SSDF_LOG_LAMBDA_MIN) * float(SSDF_N_LAMBDA - 1u),
                    0.0, float(SSDF_N_LAMBDA - 1u));
    float dd = clamp(d, -float(AVS_PI), float(AVS_PI)) / float(AVS_PI);
    float w = sign(dd) * pow(abs(dd), 1.0 / 3.0);
    float y = clamp((w + 1.0) * 0.5 * float(SSDF_N_W - 1u), 0.0, float(SSDF_N_W - 1u));
    uint l0 = min(uint(floor(x)), SSDF_N_LAMBDA - 2u), c0 = min(uint(floor(y)), SSDF_N_W - 2u);
    float fx = x - float(l0), fy = y - float(c0);
    float a = mix(SSDF_TABLE(l0 * SSDF_N_W + c0), SSDF_TABLE(l0 * SSDF_N_W + c0 + 1u), fy);
    float b = mix(SSDF_TABLE((l0 + 1u) * SSDF_N_W + c0), SSDF_TABLE((l0 + 1u) * SSDF_N_W + c0 + 1u), fy);
    return mix(a, b, fx);
}

// Method (a): SSDF at the lobe axis (Wang et al. 2009).
float ssdf_visible_axis(vec3 axis, float lambda, float mu, bool cosine, uint r) {
    SG g = sg_make(axis, lambda, mu);
    if (cosine) g = sg_product(g, sg_clamped_cosine(vec3(0.0, 0.0, 1.0)));
    float hemi = sg_hemisphere_integral(g, vec3(0.0, 0.0, 1.0));
    vec3 p = vec3(g.axis.xy, max(g.axis.z, 0.0));
    float l = length(p);
    p = l > 0.0 ? p / l : vec3(0.0, 0.0, 1.0);
    vec2 tp = avs_local_to_angles(p);
    return hemi * ssdf_table_lookup(g.lambda, ssdf_sample(tp.x, tp.y, r));
}
#endif

float ssdf_integrand(SG g, bool cosine, float theta, float phi) {
    vec3 w = avs_angles_to_local(theta, phi);
    return sg_eval(g, w) * (cosine ? max(w.z, 0.0) : 1.0);
}

// f(w) sin(theta) from sin/cos of theta and phi (shared between quadrature nodes)
float ssdf_integrand_sc(SG g, bool cosine, float st, float ct, float sp, float cp) {
    vec3 w = vec3(ct, st * cp, st * sp);
    return sg_eval(g, w) * (cosine ? max(w.z, 0.0) : 1.0) * st;
}

float ssdf_gl3_w(int k) { return k == 1 ? SSDF_GL3_W1 : SSDF_GL3_W0; }
float ssdf_gl3_x(int k) { return float(k - 1) * SSDF_GL3_X; }

// int f sin(theta) over [t0, t1] x [p0, p1], m x m composite 3x3 Gauss rule.
float ssdf_rect(SG g, bool cosine, float t0, float t1, float p0, float p1, uint m) {
    float dt = (t1 - t0) / float(m), dp = (p1 - p0) / float(m);
    float s = 0.0;
    for (uint a = 0u; a < m; a++) {
        float tc = t0 + (float(a) + 0.5) * dt;
        vec3 st3, ct3;
        for (int x = 0; x < 3; x++) {
            float t = tc + 0.5 * dt * ssdf_gl3_x(x);
            st3[x] = sin(t);
            ct3[x] = cos(t);
        }
        for (uint b = 0u; b < m; b++) {
            float pc = p0 + (float(b) + 0.5) * dp;
            for (int y = 0; y < 3; y++) {
                float ph = pc + 0.5 * dp * ssdf_gl3_x(y);
                float sp = sin(ph), cp = cos(ph);
                for (int x = 0; x < 3; x++) {
                    s += ssdf_gl3_w(x) * ssdf_gl3_w(y) * ssdf_integrand_sc(g, cosine, st3[x], ct3[x], sp, cp);
                }
            }
        }
    }
    return s * 0.25 * dt * dp;
}

// Visible part of a boundary texel: linearised SSDF dc + gt (theta - tc) + gp (phi - pc) > 0.
float ssdf_clipped(SG g, bool cosine, float t0, float t1, float p0, float p1, float dc, float gt, float gp, uint m) {
    float tc = 0.5 * (t0 + t1), pc = 0.5 * (p0 + p1);
    bool theta_major = abs(gt) >= abs(gp); // iso-line theta = k phi + b
    float o0 = theta_major ? p0 : t0, o1 = theta_major ? p1 : t1;
    float i0 = theta_major ? t0 : p0, i1 = theta_major ? t1 : p1;
    float go = theta_major ? gp : gt, gi = theta_major ? gt : gp;
    float oc = theta_major ? pc : tc, ic = theta_major ? tc : pc;
    float dout = (o1 - o0) / float(m);
    float s = 0.0;
    for (uint a = 0u; a < m; a++) {
        float ocell = o0 + (float(a) + 0.5) * dout;
        for (int x = 0; x < 3; x++) {
            float o = ocell + 0.5 * dout * ssdf_gl3_x(x);
            float so = sin(o), co = cos(o);
            float cr = ic - (dc + go * (o - oc)) / gi;
            float lo = gi > 0.0 ? max(cr, i0) : i0;
            float hi = gi > 0.0 ? i1 : min(cr, i1);
            if (hi <= lo) continue;
            float din = (hi - lo) / float(m);
            float inner = 0.0;
            for (uint b = 0u; b < m; b++) {
                float icell = lo + (float(b) + 0.5) * din;
                for (int y = 0; y < 3; y++) {
                    float inn = icell + 0.5 * din * ssdf_gl3_x(y);
                    float si = sin(inn), ci = cos(inn);
                    inner += ssdf_gl3_w(y) * (theta_major ? ssdf_integrand_sc(g, cosine, si, ci, so, co)
                                                           : ssdf_integrand_sc(g, cosine, so, co, si, ci));
                }
            }
            s += ssdf_gl3_w(x) * 0.5 * dout * inner * 0.5 * din;
        }
    }
    return s;
}

float ssdf_support_angle(float lambda) {
    if (lambda <= 0.0) return float(AVS_PI);
    float c = 1.0 - 20.7 / lambda;
    return c <= -1.0 ? float(AVS_PI) : acos(c);
}

// Method (b): adaptive cells with iso-line boundaries (eq. 5).
float ssdf_visible_cells(vec3 axis, float lambda, float mu, bool cosine, uint r) {
    SG g = sg_make(axis, lambda, mu);
    float h = float(AVS_PI) / float(r);
    float sl = sqrt(max(g.lambda, 0.0));
    uint b0 = max(r / 8u, 1u);
    while (b0 > 1u && float(b0) * h * sl > 1.5) b0 /= 2u;
    uint m = uint(clamp(ceil(h * sl / 1.5), 1.0, 16.0));
    float ts = ssdf_support_angle(g.lambda);
    float ta = acos(clamp(g.axis.x, -1.0, 1.0));
    float pa = atan(g.axis.z, g.axis.y);
    // bounding box of the support cap in (theta, phi), in blocks (conservative)
    float bh = float(b0) * h;
    uint nb = r / b0;
    uint bi_lo = uint(clamp(floor((ta - ts) / bh), 0.0, float(nb - 1u)));
    uint bi_hi = uint(clamp(floor((ta + ts) / bh), 0.0, float(nb - 1u)));
    uint bj_lo = 0u, bj_hi = nb - 1u;
    if (ts < 0.5 * float(AVS_PI) && ta - ts > 0.0 && ta + ts < float(AVS_PI)) {
        float dphi = asin(min(1.0, sin(ts) / sin(ta)));
        float pc = pa < -0.5 * float(AVS_PI) ? pa + 2.0 * float(AVS_PI) : pa;
        float lo = pc - dphi, hi = pc + dphi;
        if (hi < 0.0 || lo > float(AVS_PI)) return 0.0;
        bj_lo = uint(clamp(floor(lo / bh), 0.0, float(nb - 1u)));
        bj_hi = uint(clamp(floor(hi / bh), 0.0, float(nb - 1u)));
    }
    float total = 0.0;
    uint stack[24];
    for (uint bi = bi_lo; bi <= bi_hi; bi++) {
        for (uint bj = bj_lo; bj <= bj_hi; bj++) {
            int sp = 0;
            stack[0] = (bi * b0) | ((bj * b0) << 8u) | (b0 << 16u);
            sp = 1;
            while (sp > 0) {
                sp--;
                uint e = stack[sp];
                uint i0 = e & 0xFFu, j0 = (e >> 8u) & 0xFFu, b = e >> 16u;
                float t0 = float(i0) * h, t1 = float(i0 + b) * h;
                float p0 = float(j0) * h, p1 = float(j0 + b) * h;
                float tcb = 0.5 * (t0 + t1), pcb = 0.5 * (p0 + p1);
                // distance bounds: ds^2 = dtheta^2 + sin^2(theta) dphi^2 <= dtheta^2 + dphi^2
                float corner = 0.7071067811865476 * float(b) * h;
                if (avs_angular_distance(vec2(tcb, pcb), vec2(ta, pa)) - corner > ts) continue;
                uint off = b > 1u ? b / 2u - 1u : 0u;
                uint ci = i0 + off, cj = j0 + off;
                float d = ssdf_raw(ci, cj, r);
                if (b > 1u) {
                    float reach = 1.4142135623730951 * (float(b / 2u) + 1.5) * h;
                    if (d >= reach) {
                        total += ssdf_rect(g, cosine, t0, t1, p0, p1, 1u);
                    } else if (d > -reach) {
                        uint hb = b / 2u;
                        stack[sp++] = i0 | (j0 << 8u) | (hb << 16u);
                        stack[sp++] = i0 | ((j0 + hb) << 8u) | (hb << 16u);
                        stack[sp++] = (i0 + hb) | (j0 << 8u) | (hb << 16u);
                        stack[sp++] = (i0 + hb) | ((j0 + hb) << 8u) | (hb << 16u);
                    }
                    continue;
                }
                uint i = i0, j = j0;
                bool vis = d > 0.0;
                bool uniform_ = (i == 0u || (ssdf_raw(i - 1u, j, r) > 0.0) == vis)
                             && (i + 1u >= r || (ssdf_raw(i + 1u, j, r) > 0.0) == vis)
                             && (j == 0u || (ssdf_raw(i, j - 1u, r) > 0.0) == vis)
                             && (j + 1u >= r || (ssdf_raw(i, j + 1u, r) > 0.0) == vis);
                if (uniform_) {
                    if (vis) total += ssdf_rect(g, cosine, t0, t1, p0, p1, m);
                    continue;
                }
                float dc = ssdf_corrected(d, h);
                uint im = i > 0u ? i - 1u : 0u, ip = min(i + 1u, r - 1u);
                uint jm = j > 0u ? j - 1u : 0u, jp = min(j + 1u, r - 1u);
                float gt = (ssdf_corr(ip, j, r) - ssdf_corr(im, j, r)) / (float(ip - im) * h);
                float gp = (ssdf_corr(i, jp, r) - ssdf_corr(i, jm, r)) / (float(jp - jm) * h);
                if (max(abs(gt), abs(gp)) < 1e-6) {
                    if (vis) total += ssdf_rect(g, cosine, t0, t1, p0, p1, m);
                    continue;
                }
                total += ssdf_clipped(g, cosine, t0, t1, p0, p1, dc, gt, gp, m);
            }
        }
    }
    return total;
}

#endif
