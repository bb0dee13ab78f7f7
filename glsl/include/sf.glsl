// Shadow fields (glsl mirror of penumbra_math::shadow_field): dequantization, bilinear shell
// lookup, linear interpolation between the two nearest shells, block-diagonal SH rotation,
// sparse triple product. Buffers are declared by the including shader:
//   sf_data (uint words, 4 quantized coefficients each), sf_shells (SfShell), sf_inst (SfInst),
//   sf_tensor (SfEntry), and SF_TENSOR_COUNT entries.
#ifndef SF_GLSL
#define SF_GLSL
#include "sh16.glsl"

#define SF_PI 3.14159265358979

struct SfShell {
    uvec4 info;   // x data offset (uint words), y resolution R
    vec4 mn[4];   // per coefficient minimum
    vec4 st[4];   // per coefficient step
};

// Objects (indices 0 .. n_inst - 1) and local lights (n_inst .. n_inst + n_light - 1).
struct SfInst {
    mat4 world_to_local;  // object (light) frame of the field (inverse of the rigid world transform)
    vec4 center_step;     // xyz shell centre (object space), w shell radius step 0.2 Vr
    uvec4 info;           // x first shell, y shell count (0 = no field), z casts shadow, w 1 = light,
                          // 2 = light with a fixture (its field extrapolated beyond the last shell)
    vec4 center_world;    // xyz world position of the shell centre (entity sort key), w added to the
                          // sort distance (a light's fixture: at its light's position, just after it)
    vec4 light_a;         // lights: rgb power, w kind (0 point, 1 spot, 2 sphere)
    vec4 light_b;         // lights: x cos(inner), y cos(outer), z sphere radius
    vec4 medium;          // lights: xyz the medium's extinction sigma_t (0 without a medium)
    float rot[84];        // block-diagonal SH rotation local -> world (bands 0..3)
};

// Entities combined per point at most (penumbra_math::shadow_field::MAX_ENTITIES).
#define SF_MAX_ENT 48

struct SfEntry {
    uint ijk;  // i | j << 8 | k << 16
    float c;
};

// Bindings SF_B0 .. SF_B0 + 4 (the including shader defines SF_B0).
layout(set = 0, binding = SF_B0 + 0) readonly buffer SfData { uint sf_data[]; };
layout(set = 0, binding = SF_B0 + 1) readonly buffer SfShells { SfShell sf_shells[]; };
layout(set = 0, binding = SF_B0 + 2) readonly buffer SfInsts { SfInst sf_inst[]; };
layout(set = 0, binding = SF_B0 + 3) readonly buffer SfTensor { SfEntry sf_tensor[]; };
layout(set = 0, binding = SF_B0 + 4) readonly buffer SfLight { vec4 sf_light[16]; };

void sf_zero(out float o[16]) {
    for (int e = 0; e < 16; e++) o[e] = 0.0;
}

// Adds w * (dequantized sample idx of shell sh) to o.
void sf_add_sample(SfShell sh, uint idx, float w, inout float o[16]) {
    uint base = sh.info.x + idx * 4u;
    for (int q = 0; q < 4; q++) {
        uint word = sf_data[base + uint(q)];
        for (int b = 0; b < 4; b++) {
            int e = q * 4 + b;
            float v = float((word >> (8u * uint(b))) & 255u);
            o[e] += w * (sh.mn[q][b] + v * sh.st[q][b]);
        }
    }
}

// Bilinear lookups of shell c0 of instance `ii` at polar angles, scaled by w0, and (with `two`) of shell
// c1 scaled by w1, added to o: one loop over the 4 (8) samples with one call of sf_add_sample,
// whose trip count is not a constant, so the compiler inlines one copy, not eight (lavapipe
// compiles every inlined copy).
void sf_shells_lookup(uint ii, uint c0, uint c1, float w0, float w1, bool two, float theta, float phi, inout float o[16]) {
    uint count = two ? 8u : 4u;
    for (uint i = 0u; i < count; ++i) {
        SfShell sh = sf_shells[sf_inst[ii].info.x + (i < 4u ? c0 : c1)];
        float w = i < 4u ? w0 : w1;
        uint r = max(sh.info.y, 1u);
        float rf = float(r);
        float u = clamp(theta / SF_PI * rf - 0.5, 0.0, rf - 1.0);
        uint s0 = min(uint(floor(u)), r - 1u);
        float fs = u - float(s0);
        float v = fract(phi / (2.0 * SF_PI)) * rf;
        uint t0 = uint(floor(v)) % r;
        float ft = v - floor(v);
        bool hi_s = (i & 2u) != 0u, hi_t = (i & 1u) != 0u;
        uint sx = hi_s ? min(s0 + 1u, r - 1u) : s0, tx = hi_t ? (t0 + 1u) % r : t0;
        sf_add_sample(sh, sx * r + tx, w * (hi_s ? fs : 1.0 - fs) * (hi_t ? ft : 1.0 - ft), o);
    }
}

void sf_rotate(uint ii, float c[16], out float o[16]) {
    o[0] = sf_inst[ii].rot[0] * c[0];
    int off = 1;
    for (int l = 1; l < 4; l++) {
        int s = l * l;
        int bw = 2 * l + 1;
        for (int k = 0; k < bw; k++) {
            float acc = 0.0;
            for (int j = 0; j < bw; j++) acc += sf_inst[ii].rot[off + k * bw + j] * c[s + j];
            o[s + k] = acc;
        }
        off += bw * bw;
    }
}

// Visibility coefficients of instance `ii` at world point p, in world frame; false if the
// point is outside its outermost shell (or it has no field).
bool sf_ocv(uint ii, vec3 pw, out float o[16]) {
    sf_zero(o);
    uint nc = sf_inst[ii].info.y;
    if (nc == 0u || sf_inst[ii].info.z == 0u) return false;
    vec3 q = (sf_inst[ii].world_to_local * vec4(pw, 1.0)).xyz - sf_inst[ii].center_step.xyz;
    float len = length(q);
    float x = len / sf_inst[ii].center_step.w - 1.0;
    if (!(x <= float(nc - 1u))) return false;
    float theta = len > 0.0 ? acos(clamp(q.z / len, -1.0, 1.0)) : 0.0;
    float phi = len > 0.0 ? atan(q.y, q.x) : 0.0;
    if (phi < 0.0) phi += 2.0 * SF_PI;
    x = max(x, 0.0);
    uint c0 = min(uint(floor(x)), nc - 1u);
    uint c1 = min(c0 + 1u, nc - 1u);
    float w = x - float(c0);
    float loc[16];
    sf_zero(loc);
    sf_shells_lookup(ii, c0, c1, (c1 == c0) ? 1.0 : 1.0 - w, w, c1 != c0 && w > 0.0, theta, phi, loc);
    sf_rotate(ii, loc, o);
    return true;
}


// h = f (x) g by the sparse tensor.
void sf_triple(float f[16], float g[16], uint count, out float h[16]) {
    sf_zero(h);
    for (uint n = 0u; n < count; n++) {
        SfEntry en = sf_tensor[n];
        uint i = en.ijk & 255u, j = (en.ijk >> 8) & 255u, k = (en.ijk >> 16) & 255u;
        h[k] += en.c * f[i] * g[j];
    }
}

vec3 sf_double(float u[16]) {
    vec3 c = vec3(0.0);
    for (int e = 0; e < 16; e++) c += sf_light[e].rgb * u[e];
    return c;
}

// Product over the other instances (whose centres are nearer than max_dist) of their
// visibility in world direction d at point p (each clamped to [0, 1]): shadowing of the glossy
// environment term and of local lights' specular term.
float sf_visibility_along(vec3 p, vec3 d, uint self_inst, uint inst_count, float max_dist) {
    float y[16];
    sh16_basis(d, y);
    float v = 1.0;
    for (uint j = 0u; j < inst_count; j++) {
        if (j == self_inst) continue;
        if (!(distance(p, sf_inst[j].center_world.xyz) < max_dist)) continue;
        float o[16];
        if (!sf_ocv(j, p, o)) continue;
        float s = 0.0;
        for (int e = 0; e < 16; e++) s += o[e] * y[e];
        v *= clamp(s, 0.0, 1.0);
    }
    return v;
}

// Window of the occluders' visibility (penumbra_math::shadow_field::Window): 0 none,
// 1 Hanning, 2 Lanczos (window width 4).
void sf_window(uint kind, inout float c[16]) {
    if (kind == 0u) return;
    vec3 s = kind == 1u ? vec3(0.853553391, 0.5, 0.146446609) : vec3(0.900316316, 0.636619772, 0.300105439);
    for (int e = 1; e < 4; e++) c[e] *= s.x;
    for (int e = 4; e < 9; e++) c[e] *= s.y;
    for (int e = 9; e < 16; e++) c[e] *= s.z;
}

// Analytic radiance coefficients (unit power, light frame) of light `ii` at light-frame
// point q (LightSource::rcv).
void sf_light_analytic(uint ii, vec3 q, out float o[16]) {
    sf_zero(o);
    float r2 = dot(q, q);
    if (!(r2 > 0.0)) return;
    float r = sqrt(r2);
    vec3 s = q / r;
    float y[16];
    sh16_basis(-s, y);
    int kind = int(sf_inst[ii].light_a.w + 0.5);
    if (kind == 2) {
        float a = sf_inst[ii].light_b.z;
        if (!(r > a)) return;
        float t = sqrt(max(1.0 - (a / r) * (a / r), 0.0));
        float ip[4] = float[4](1.0 - t, (1.0 - t * t) / 2.0, (t - t * t * t) / 2.0, (-0.25 - 1.25 * t * t * t * t + 1.5 * t * t) / 2.0);
        for (int l = 0; l < 4; l++)
            for (int m = 0; m < 2 * l + 1; m++) o[l * l + m] = 2.0 * SF_PI * ip[l] * y[l * l + m];
        return;
    }
    float f = 1.0;
    if (kind == 1) {
        float e0 = sf_inst[ii].light_b.y, e1 = sf_inst[ii].light_b.x;
        if (e1 <= e0) {
            f = s.z >= e0 ? 1.0 : 0.0;
        } else {
            float t = clamp((s.z - e0) / (e1 - e0), 0.0, 1.0);
            f = t * t * (3.0 - 2.0 * t);
        }
    }
    for (int e = 0; e < 16; e++) o[e] = f / r2 * y[e];
}

// Radiance coefficients (unit power, world frame) of light `ii` at world point pw: its source
// radiance field inside the outermost shell (linear in r^2 RCV between shells), analytic
// outside, or the outermost shell extrapolated for a light with a fixture (info.w == 2;
// ObjectField::rcv_beyond / LightFrame::rcv_world).
void sf_rcv(uint ii, vec3 pw, out float o[16]) {
    vec3 q = (sf_inst[ii].world_to_local * vec4(pw, 1.0)).xyz - sf_inst[ii].center_step.xyz;
    float len = length(q);
    uint nc = sf_inst[ii].info.y;
    float step = sf_inst[ii].center_step.w;
    float x = len / step - 1.0;
    float loc[16];
    if (nc == 0u || !(x <= float(nc - 1u)) && sf_inst[ii].info.w != 2u) {
        sf_light_analytic(ii, q, loc);
    } else if (!(len > 0.0)) {
        sf_zero(loc);
    } else {
        float theta = acos(clamp(q.z / len, -1.0, 1.0));
        float phi = atan(q.y, q.x);
        if (phi < 0.0) phi += 2.0 * SF_PI;
        x = clamp(x, 0.0, float(nc - 1u));
        uint c0 = min(uint(floor(x)), nc - 1u);
        uint c1 = min(c0 + 1u, nc - 1u);
        float w = c1 == c0 ? 0.0 : x - float(c0);
        float r0 = step * float(c0 + 1u), r1 = step * float(c1 + 1u);
        float inv = 1.0 / (len * len);
        sf_zero(loc);
        sf_shells_lookup(ii, c0, c1, (1.0 - w) * r0 * r0 * inv, w * r1 * r1 * inv, w > 0.0, theta, phi, loc);
    }
    sf_rotate(ii, loc, o);
}

// Whether world point p lies inside the outermost shell of object j's field.
bool sf_inside(uint ii, vec3 pw) {
    uint nc = sf_inst[ii].info.y;
    if (nc == 0u || sf_inst[ii].info.z == 0u) return false;
    vec3 q = (sf_inst[ii].world_to_local * vec4(pw, 1.0)).xyz - sf_inst[ii].center_step.xyz;
    return length(q) / sf_inst[ii].center_step.w - 1.0 <= float(nc - 1u);
}

// Radiance (before the albedo) at world point p of receiver `self_inst` with world-frame
// transfer u (penumbra_math::shadow_field::shade_point, Fig. 3 of the paper): the entities
// (other objects whose shells contain p, and lights) sorted by distance to their centres; each
// occluder multiplies u by its (windowed) visibility, each light adds its power times the double
// product of its radiance with the current u; the environment adds the double product with
// the final u.
// ng: the surface's geometric normal; a light whose centre lies below it is blocked by the
// surface (lights.glsl's rule; vec3(0.0) where the face is unknown: per-vertex transfer).
// With `two`, a second transfer u2 (the glossy lobe's, shadow_fields `glossy = transfer`) is
// multiplied by the same occluders' visibilities, and c2 is its double product with the
// environment (no lights: their glossy lobes are shaded pointwise).
vec3 sf_shade_point(vec3 p, vec3 ng, uint self_inst, uint inst_count, uint light_count, uint tensor_count, uint window, inout float u[16],
                    bool two, inout float u2[16], out vec3 c2) {
    uint ids[SF_MAX_ENT];
    float ds[SF_MAX_ENT];
    uint n = 0u;
    uint total = inst_count + light_count;
    for (uint j = 0u; j < total; j++) {
        if (j == self_inst) continue;
        if (j < inst_count && !sf_inside(j, p)) continue;
        float d = distance(p, sf_inst[j].center_world.xyz) + sf_inst[j].center_world.w;
        if (n == uint(SF_MAX_ENT) && !(d < ds[n - 1u])) continue;
        uint k = min(n, uint(SF_MAX_ENT) - 1u);
        while (k > 0u && ds[k - 1u] > d) {
            ds[k] = ds[k - 1u];
            ids[k] = ids[k - 1u];
            k--;
        }
        ds[k] = d;
        ids[k] = j;
        n = min(n + 1u, uint(SF_MAX_ENT));
    }
    vec3 c = vec3(0.0);
    for (uint k = 0u; k < n; k++) {
        uint j = ids[k];
        if (j < inst_count) {
            float o[16];
            if (!sf_ocv(j, p, o)) continue;
            sf_window(window, o);
            float h[16];
            sf_triple(o, u, tensor_count, h);
            u = h;
            if (two) {
                sf_triple(o, u2, tensor_count, h);
                u2 = h;
            }
        } else {
            if (ng != vec3(0.0) && dot(sf_inst[j].center_world.xyz - p, ng) <= 0.0) continue;
            float s[16];
            sf_rcv(j, p, s);
            float dp = 0.0;
            for (int e = 0; e < 16; e++) dp += s[e] * u[e];
            // Attenuated by the medium on the light's way to p (as the reference).
            vec3 tr = exp(-sf_inst[j].medium.xyz * distance(p, sf_inst[j].center_world.xyz));
            c += sf_inst[j].light_a.rgb * tr * dp;
        }
    }
    c2 = two ? sf_double(u2) : vec3(0.0);
    return c + sf_double(u);
}

#endif
