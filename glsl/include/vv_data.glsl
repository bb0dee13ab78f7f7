// vv technique: bindings, push constants and the two radiance evaluations (eq. 19 terms and
// eq. 21) shared by the vertex, tessellation and fragment shaders of passes/src/vv.
//
// Flat arrays live in 2D images of width 4096 (texelFetch): vv_points (RGBA32F homogeneous
// points of penumbra_math::vv::VectorizedVisibility), vv_ints (R32UI: seq_offsets,
// vertex_seqs, tri_offsets, loop_offsets, triples, triangle vertex ids at the offsets in
// pc.off0/off1), vv_verts (RGBA32F, 4 texels per model vertex: (world position, u), (normal, v),
// (albedo, albedo-map layer or -1), specular (rgb reflectance, w Phong exponent alpha of eq. 13;
// 0 = diffuse only)). Albedo maps come from the scene's texture array (material_textures), as
// material.glsl applies them.
#ifndef PENUMBRA_VV_DATA_GLSL
#define PENUMBRA_VV_DATA_GLSL
#include "common.glsl"
#include "vv_sat.glsl"

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) uniform sampler2D vv_points;
layout(set = 0, binding = 2) uniform usampler2D vv_ints;
layout(set = 0, binding = 3) uniform sampler2D vv_verts;
layout(set = 0, binding = 4) uniform sampler2D vv_sat_tex;
layout(set = 0, binding = 5) uniform sampler2D vv_sat_blur;
layout(set = 0, binding = 6) uniform sampler2DArray material_textures;
layout(push_constant) uniform Push {
    ivec4 sat;    // x W, y H, z hemisphere arcs, w mode (0 fragment3, 1 fragment1, 2 tessellation, 3 tessellation3)
    ivec4 off0;   // offsets in vv_ints: x seq_offsets, y vertex_seqs, z tri_offsets, w loop_offsets
    ivec4 off1;   // x triples, y triangle vertex ids, z max tessellation level
    vec4 par;     // x alpha', y zeta, z specular on (1) / off (0)
} pc;

ivec2 vv_tc(int i) {
    return ivec2(i & 4095, i >> 12);
}
int vv_int(int i) {
    return int(texelFetch(vv_ints, vv_tc(i), 0).r);
}
vec4 vv_point(int i) {
    return texelFetch(vv_points, vv_tc(i), 0);
}
vec3 vv_vert(int v, int k) {
    return texelFetch(vv_verts, vv_tc(4 * v + k), 0).xyz;
}
vec4 vv_vert_spec(int v) {
    return texelFetch(vv_verts, vv_tc(4 * v + 3), 0);
}
// (u, v, albedo-map layer) of model vertex v.
vec3 vv_vert_uv_layer(int v) {
    return vec3(texelFetch(vv_verts, vv_tc(4 * v), 0).w, texelFetch(vv_verts, vv_tc(4 * v + 1), 0).w,
                texelFetch(vv_verts, vv_tc(4 * v + 2), 0).w);
}
// The albedo at texture coordinate uv: the material's albedo times its albedo map (layer < 0:
// none), as material.glsl's material_at.
vec3 vv_albedo(vec3 albedo, float layer, vec2 uv) {
    return layer >= 0.0 ? max(albedo * textureLod(material_textures, vec3(uv, layer), 0.0).rgb, vec3(0.0)) : albedo;
}

// Specular (eq. 14-16) state of one radiance evaluation: the occluder loops clipped to the cap W
// around the reflected view direction and subtracted from W ∩ hemisphere, cap-weighted.
struct VvSpec {
    VvClip clip;
    VvAcc acc;
    vec3 r;        // map-space reflection direction (nudged)
    float cos_xi;  // cap W of the Phong lobe
    vec3 ks;
};

// False for a diffuse material or with specular off.
bool vv_spec_begin(vec3 s, vec3 n, vec4 spec, out VvSpec sp) {
    vv_acc_init4(sp.acc);
    sp.cos_xi = vv_phong_cap_cos(spec.w);
    vec3 view = normalize(cam.eye.xyz - s);
    // k_s (eq. 13-14, G = 1): the specular reflectance times (n . v)^2, the directional albedo
    // of the scene's normalised Blinn-Phong lobe (s + 2) / (8 pi) (n.h)^s cos(theta_i) for a
    // narrow lobe (the half-vector Jacobian 4 (v.h) and cos(theta_i) both ~ n . v)
    float nv = max(dot(n, view), 0.0);
    sp.ks = spec.rgb * (nv * nv);
    sp.r = vv_nudge(vv_to_map(reflect(-view, n), cam.env_rot.xy), sp.cos_xi);
    vv_clip_init(sp.r, sp.cos_xi, -1.0, pc.sat.z, sp.clip);
    return pc.par.z > 0.5 && spec.w > 0.0 && max(spec.r, max(spec.g, spec.b)) > 0.0;
}

// L_s = k_s gamma U (eq. 14) with gamma of eq. 15 and the unshadowed glossy term U taken over the
// same cap kernel: U = (2 pi / (alpha + 1)) * (∫_W Cap L_e) / (∫_W Cap dω), the kernel's
// average radiance times the normalised Phong lobe's integral; k_s = ks (alpha + 1) / (2 pi)
// (energy-normalised Phong, ks of vv_spec_begin). The denominator of gamma cancels:
// L_s = ks * ∫_{V ∩ W} Cap L_e / (pi (1 - cos xi)^2). Before the environment intensity.
vec3 vv_spec_end(sampler2D sat, vec3 nn, inout VvSpec sp) {
    ivec2 size = pc.sat.xy;
    vv_add_cap_in_hemisphere(sat, size, pc.par.x, sp.r, sp.cos_xi, nn, pc.sat.z, sp.acc);
    vec3 num = vv_cap_finish(sat, size, sp.r, sp.cos_xi, true, nn, sp.acc);
    float d = 1.0 - sp.cos_xi;
    return sp.ks * max(num, vec3(0.0)) / (PI * max(d * d, 1e-12));
}
int vv_tri_vertex(int t, int k) {
    return vv_int(pc.off1.y + 3 * t + k);
}

// Radiance (diffuse, eq. 9/12, plus specular, eq. 14-16, when spec.w > 0) with the visibility
// of model vertex v synthesized at s (eq. 3).
vec3 vv_eval_vertex(sampler2D sat, int v, vec3 s, vec3 n, vec3 albedo, vec4 spec) {
    ivec2 size = pc.sat.xy;
    vec2 cs = cam.env_rot.xy;
    vec3 nn = vv_nudge(vv_to_map(n, cs), 0.0);
    VvAcc acc;
    vv_acc_init(acc);
    vv_add_hemisphere(sat, size, pc.par.x, nn, pc.sat.z, acc);
    VvSpec sp;
    bool glossy = vv_spec_begin(s, n, spec, sp);
    int first = vv_int(pc.off0.y + 2 * v), count = vv_int(pc.off0.y + 2 * v + 1);
    for (int k = first; k < first + count; k++) {
        int p0 = vv_int(pc.off0.x + k), p1 = vv_int(pc.off0.x + k + 1);
        if (p1 - p0 < 2) continue;
        // one call site per integration (every function is inlined)
        vec3 d0 = vec3(0.0), prev = vec3(0.0);
        for (int i = p0; i <= p1; i++) {
            vec3 d = i == p1 ? d0 : vv_to_map(vv_synth(vv_point(i), s, n, n), cs);
            if (i == p0) d0 = d;
            else vv_arc(sat, size, pc.par.x, prev, d, acc);
            if (glossy && i < p1) vv_clip_push(sat, size, pc.par.x, sp.clip, d, sp.acc);
            prev = d;
        }
        if (glossy) vv_clip_end(sat, size, pc.par.x, sp.clip, sp.acc);
    }
    vec3 c = albedo / PI * max(vv_finish(sat, size, nn, acc), vec3(0.0));
    if (glossy) c += vv_spec_end(sat, nn, sp);
    return c * cam.params.w;
}

// Interpolated direction of one triple (eq. 21, penumbra_math::vv::interpolate).
vec3 vv_triple_dir(int j, vec3 lambda, vec3 s, vec3 n) {
    vec3 a = vec3(0.0);
    for (int k = 0; k < 3; k++) {
        vec4 q = vv_point(vv_int(pc.off1.x + 3 * j + k));
        vec3 d = q.xyz - q.w * s;
        float l = length(d);
        if (l > 1e-12) a += lambda[k] * (d / l);
    }
    float al = length(a);
    return vv_synth(vec4(al > 1e-12 ? a / al : n, 0.0), vec3(0.0), n, n);
}

// Radiance with the interpolated vectorized visibility of triangle t (eq. 21), evaluated once
// (diffuse and, when spec.w > 0, specular).
vec3 vv_eval_interp(sampler2D sat, int t, vec3 lambda, vec3 s, vec3 n, vec3 albedo, vec4 spec) {
    ivec2 size = pc.sat.xy;
    vec2 cs = cam.env_rot.xy;
    vec3 nn = vv_nudge(vv_to_map(n, cs), 0.0);
    VvAcc acc;
    vv_acc_init(acc);
    vv_add_hemisphere(sat, size, pc.par.x, nn, pc.sat.z, acc);
    VvSpec sp;
    bool glossy = vv_spec_begin(s, n, spec, sp);
    int l0 = vv_int(pc.off0.z + t), l1 = vv_int(pc.off0.z + t + 1);
    for (int l = l0; l < l1; l++) {
        int a0 = vv_int(pc.off0.w + l), a1 = vv_int(pc.off0.w + l + 1);
        if (a1 - a0 < 2) continue;
        vec3 d0 = vec3(0.0), prev = vec3(0.0);
        for (int j = a0; j <= a1; j++) {
            vec3 d = j == a1 ? d0 : vv_to_map(vv_triple_dir(j, lambda, s, n), cs);
            if (j == a0) d0 = d;
            else vv_arc(sat, size, pc.par.x, prev, d, acc);
            if (glossy && j < a1) vv_clip_push(sat, size, pc.par.x, sp.clip, d, sp.acc);
            prev = d;
        }
        if (glossy) vv_clip_end(sat, size, pc.par.x, sp.clip, sp.acc);
    }
    vec3 c = albedo / PI * max(vv_finish(sat, size, nn, acc), vec3(0.0));
    if (glossy) c += vv_spec_end(sat, nn, sp);
    return c * cam.params.w;
}

// Eq. 19: three syntheses, three evaluations, blended barycentrically.
vec3 vv_eval_three(sampler2D sat, ivec3 vids, vec3 lambda, vec3 s, vec3 n, vec3 albedo, vec4 spec) {
    vec3 c = vec3(0.0);
    for (int k = 0; k < 3; k++) c += lambda[k] * vv_eval_vertex(sat, vids[k], s, n, albedo, spec);
    return c;
}
#endif
