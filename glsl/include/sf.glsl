// Shadow fields (glsl mirror of penumbra_math::shadow_field): dequantization, bilinear shell
// lookup, linear interpolation between the two nearest shells, block-diagonal SH rotation,
// sparse triple product. Buffers are declared by the including shader:
//   sf_data (uint words, 4 quantized coefficients each), sf_shells (SfShell), sf_inst (SfInst),
//   sf_tensor (SfEntry), and SF_TENSOR_COUNT entries.
#ifndef SF_GLSL
#define SF_GLSL

#define SF_PI 3.14159265358979

struct SfShell {
    uvec4 info;   // x data offset (uint words), y resolution R
    vec4 mn[4];   // per coefficient minimum
    vec4 st[4];   // per coefficient step
};

struct SfInst {
    mat4 world_to_local;  // object space of the field (inverse of the rigid world transform)
    vec4 center_step;     // xyz shell centre (object space), w shell radius step 0.2 Vr
    uvec4 info;           // x first shell, y shell count (0 = no field), z casts shadow
    float rot[84];        // block-diagonal SH rotation local -> world (bands 0..3)
};

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

// Bilinear lookup of shell sh at polar angles, scaled by w, added to o.
void sf_shell_lookup(SfShell sh, float theta, float phi, float w, inout float o[16]) {
    uint r = max(sh.info.y, 1u);
    float rf = float(r);
    float u = clamp(theta / SF_PI * rf - 0.5, 0.0, rf - 1.0);
    uint s0 = min(uint(floor(u)), r - 1u);
    uint s1 = min(s0 + 1u, r - 1u);
    float fs = u - float(s0);
    float v = fract(phi / (2.0 * SF_PI)) * rf;
    uint t0 = uint(floor(v)) % r;
    uint t1 = (t0 + 1u) % r;
    float ft = v - floor(v);
    sf_add_sample(sh, s0 * r + t0, w * (1.0 - fs) * (1.0 - ft), o);
    sf_add_sample(sh, s0 * r + t1, w * (1.0 - fs) * ft, o);
    sf_add_sample(sh, s1 * r + t0, w * fs * (1.0 - ft), o);
    sf_add_sample(sh, s1 * r + t1, w * fs * ft, o);
}

void sf_rotate(SfInst inst, float c[16], out float o[16]) {
    o[0] = inst.rot[0] * c[0];
    int off = 1;
    for (int l = 1; l < 4; l++) {
        int s = l * l;
        int bw = 2 * l + 1;
        for (int k = 0; k < bw; k++) {
            float acc = 0.0;
            for (int j = 0; j < bw; j++) acc += inst.rot[off + k * bw + j] * c[s + j];
            o[s + k] = acc;
        }
        off += bw * bw;
    }
}

// Visibility coefficients of instance `inst` at world point p, in world frame; false if the
// point is outside its outermost shell (or it has no field).
bool sf_ocv(SfInst inst, vec3 pw, out float o[16]) {
    sf_zero(o);
    uint nc = inst.info.y;
    if (nc == 0u || inst.info.z == 0u) return false;
    vec3 q = (inst.world_to_local * vec4(pw, 1.0)).xyz - inst.center_step.xyz;
    float len = length(q);
    float x = len / inst.center_step.w - 1.0;
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
    sf_shell_lookup(sf_shells[inst.info.x + c0], theta, phi, (c1 == c0) ? 1.0 : 1.0 - w, loc);
    if (c1 != c0 && w > 0.0) sf_shell_lookup(sf_shells[inst.info.x + c1], theta, phi, w, loc);
    sf_rotate(inst, loc, o);
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

// Occluded transfer at world point p of receiver instance `self_inst`: u = t (x) O_1 (x) ...
// over every other instance; returns the number of occluders applied.
uint sf_accumulate(vec3 p, uint self_inst, uint inst_count, uint tensor_count, inout float u[16]) {
    uint applied = 0u;
    for (uint j = 0u; j < inst_count; j++) {
        if (j == self_inst) continue;
        float o[16];
        if (!sf_ocv(sf_inst[j], p, o)) continue;
        float h[16];
        sf_triple(o, u, tensor_count, h);
        u = h;
        applied++;
    }
    return applied;
}

vec3 sf_double(float u[16]) {
    vec3 c = vec3(0.0);
    for (int e = 0; e < 16; e++) c += sf_light[e].rgb * u[e];
    return c;
}

// Order-4 real SH basis (penumbra_math::sh convention, Condon-Shortley phase) at unit d.
void sf_basis(vec3 d, out float y[16]) {
    float x = d.x, yy = d.y, z = d.z;
    y[0] = 0.282094792;
    y[1] = -0.488602512 * yy;
    y[2] = 0.488602512 * z;
    y[3] = -0.488602512 * x;
    y[4] = 1.092548431 * x * yy;
    y[5] = -1.092548431 * yy * z;
    y[6] = 0.315391565 * (3.0 * z * z - 1.0);
    y[7] = -1.092548431 * x * z;
    y[8] = 0.546274215 * (x * x - yy * yy);
    y[9] = -0.590043590 * yy * (3.0 * x * x - yy * yy);
    y[10] = 2.890611443 * x * yy * z;
    y[11] = -0.457045799 * yy * (5.0 * z * z - 1.0);
    y[12] = 0.373176333 * z * (5.0 * z * z - 3.0);
    y[13] = -0.457045799 * x * (5.0 * z * z - 1.0);
    y[14] = 1.445305721 * z * (x * x - yy * yy);
    y[15] = -0.590043590 * x * (x * x - 3.0 * yy * yy);
}

// Product over the other instances of their visibility in world direction d at point p
// (each clamped to [0, 1]): shadowing of the glossy environment term.
float sf_visibility_along(vec3 p, vec3 d, uint self_inst, uint inst_count) {
    float y[16];
    sf_basis(d, y);
    float v = 1.0;
    for (uint j = 0u; j < inst_count; j++) {
        if (j == self_inst) continue;
        float o[16];
        if (!sf_ocv(sf_inst[j], p, o)) continue;
        float s = 0.0;
        for (int e = 0; e < 16; e++) s += o[e] * y[e];
        v *= clamp(s, 0.0, 1.0);
    }
    return v;
}

#endif
