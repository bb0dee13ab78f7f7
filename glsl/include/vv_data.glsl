// vv technique: bindings, push constants and the two radiance evaluations (eq. 19 terms and
// eq. 21) shared by the vertex, tessellation and fragment shaders of passes/src/vv.
//
// Flat arrays live in 2D images of width 4096 (texelFetch): vv_points (RGBA32F homogeneous
// points of penumbra_math::vv::VectorizedVisibility), vv_ints (R32UI: seq_offsets,
// vertex_seqs, tri_offsets, loop_offsets, triples, triangle vertex ids at the offsets in
// pc.off0/off1), vv_verts (RGBA32F, 3 texels per model vertex: (world position, u), (normal, v),
// (index of its object's material in `mats`, 0, 0, 0)). Materials are the scene's (the frame's
// table, so animated roughness follows), their maps applied by material.glsl's material_at.
#ifndef PENUMBRA_VV_DATA_GLSL
#define PENUMBRA_VV_DATA_GLSL
#include "common.glsl"
#include "vv_sat.glsl"

layout(set = 0, binding = 0) uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; };  // cam_dfg: env_dfg.glsl; cam_irr: env_shade.glsl
layout(set = 0, binding = 1) uniform sampler2D vv_points;
layout(set = 0, binding = 2) uniform usampler2D vv_ints;
layout(set = 0, binding = 3) uniform sampler2D vv_verts;
layout(set = 0, binding = 4) uniform sampler2D vv_sat_tex;
layout(set = 0, binding = 5) uniform sampler2D vv_sat_blur;
layout(set = 0, binding = 6) uniform sampler2DArray material_textures;
layout(set = 0, binding = 7) readonly buffer Materials { MaterialData mats[]; };
// the mip-filtered lat-long environment (env_shade.glsl's unshadowed glossy lookup)
layout(set = 0, binding = 8) uniform sampler2D env_map;
layout(set = 0, binding = 9) readonly buffer Lights { LightData lights[]; };
#include "material.glsl"
#include "env_shade.glsl"
#include "lights.glsl"
// The scene's kd-tree (include/kdtree.glsl): the local lights' shadow rays (pc.par.w = 1).
layout(set = 0, binding = 10) uniform usamplerBuffer kd_tris;
layout(set = 0, binding = 11) uniform usamplerBuffer kd_nodes;
layout(set = 0, binding = 12) uniform usamplerBuffer kd_refs;
layout(set = 0, binding = 13) readonly buffer KdHeader { uint kd_hdr[]; };
#define KD_HDR(i) kd_hdr[i]
#include "kdtree.glsl"
#include "light_rays.glsl"
layout(push_constant) uniform Push {
    ivec4 sat;    // x W, y H, z hemisphere arcs, w mode (0 fragment3, 1 fragment1, 2 tessellation, 3 tessellation3)
    ivec4 off0;   // offsets in vv_ints: x seq_offsets, y vertex_seqs, z tri_offsets, w loop_offsets
    ivec4 off1;   // x triples, y triangle vertex ids, z max tessellation level, w local lights
    vec4 par;     // x alpha', y zeta, z specular on (1) / off (0), w local lights' shadows traced (1) / from the loops (0)
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
    return texelFetch(vv_verts, vv_tc(3 * v + k), 0).xyz;
}
// Texture coordinate of model vertex v.
vec2 vv_vert_uv(int v) {
    return vec2(texelFetch(vv_verts, vv_tc(3 * v), 0).w, texelFetch(vv_verts, vv_tc(3 * v + 1), 0).w);
}
// Index of model vertex v's material.
int vv_vert_material(int v) {
    return int(texelFetch(vv_verts, vv_tc(3 * v + 2), 0).x + 0.5);
}
// The material of model vertex v at texture coordinate uv.
MaterialData vv_material(int v, vec2 uv) {
    return material_at(mats[vv_vert_material(v)], uv, material_textures);
}

// Specular (eq. 14-16) state of one radiance evaluation: the occluder loops clipped to the cap W
// around the reflected view direction, cap-weighted.
struct VvSpec {
    VvClip clip;
    VvAcc acc;
    vec3 r;        // map-space reflection direction (nudged)
    float cos_xi;  // cap W of the Phong lobe
};

// The Phong exponent alpha of eq. 13 of a material's specular lobe: its GGX alpha a (env_shade's
// env_alpha, the lobe the unshadowed glossy term is prefiltered with) as the Blinn-Phong
// exponent s = 2 / a^2 - 2, and Blinn-Phong's (n.h)^s as about (r.l)^(s / 4) (the half vector
// turns half as far); within [1, 4096] (a wider cap would leave the hemisphere, a narrower one is
// below fp32's reach in the SAT differences).
float vv_phong_alpha(MaterialData m) {
    float a = env_alpha(m);
    return clamp((2.0 / (a * a) - 2.0) / 4.0, 1.0, 4096.0);
}

// False for a diffuse material or with specular off.
bool vv_spec_begin(vec3 s, vec3 n, MaterialData m, out VvSpec sp) {
    vv_acc_init4(sp.acc);
    sp.cos_xi = vv_phong_cap_cos(vv_phong_alpha(m));
    vec3 view = normalize(cam.eye.xyz - s);
    sp.r = vv_nudge(vv_to_map(reflect(-view, n), cam.env_rot.xy), sp.cos_xi);
    vv_clip_init(sp.r, sp.cos_xi, -1.0, pc.sat.z, sp.clip);
    return pc.par.z > 0.5 && material_kind(m) != 0;
}

// gamma of eq. 15: the visible share of the cap W (clipped to the hemisphere of the normal),
// Cap-weighted (eq. 16) under the lighting, from the occluder loops clipped to W (in sp.acc).
// Exactly 1 when no occluder reaches W (the numerator is then the denominator's sum).
float vv_spec_gamma(sampler2D sat, vec3 nn, inout VvSpec sp) {
    ivec2 size = pc.sat.xy;
    VvAcc whole;
    vv_acc_init4(whole);
    vv_add_cap_in_hemisphere(sat, size, pc.par.x, sp.r, sp.cos_xi, nn, pc.sat.z, whole);
    float den = vv_lum(vv_cap_finish(sat, size, sp.r, sp.cos_xi, true, nn, whole));
    vv_add_cap_in_hemisphere(sat, size, pc.par.x, sp.r, sp.cos_xi, nn, pc.sat.z, sp.acc);
    float num = vv_lum(vv_cap_finish(sat, size, sp.r, sp.cos_xi, true, nn, sp.acc));
    return den > 0.0 ? clamp(num / den, 0.0, 1.0) : 1.0;
}

// ---- Local lights ----------------------------------------------------------------------------
// Traced (pc.par.w = 1, `light_shadows = traced`, default): shadow rays through the scene's
// kd-tree, a sphere light by lights.glsl's LIGHT_DISK_POINTS targets on its disk (soft shadows),
// as isg and avs shadow their local lights. From the loops (`light_shadows = loops`): the loops
// bound the occluded directions, so a light's direction is occluded when the loops' winding
// number about it is positive: each arc a -> b adds the angle it turns through seen from the
// direction (in the tangent plane there), a closed loop 2 pi per turn around it. Hard shadows (a
// sphere light counts as its centre); the loops carry no depth, so an occluder behind the light
// still shadows it (sun_and_spot: the cube darkened the floor the spot light lit in front of it).
// The first VV_MAX_LIGHTS lights (VvTechnique::limitations names the rest).
#define VV_MAX_LIGHTS 8
struct VvLights {
    vec3 dir[VV_MAX_LIGHTS];  // map-space unit direction to each light
    float wind[VV_MAX_LIGHTS];
    int count;
};

void vv_lights_begin(vec3 s, out VvLights L) {
    L.count = min(pc.off1.w, VV_MAX_LIGHTS);
    for (int k = 0; k < VV_MAX_LIGHTS; k++) {
        L.wind[k] = 0.0;
        L.dir[k] = k < L.count ? vv_to_map(normalize(light_vector(lights[k], s)), cam.env_rot.xy) : vec3(0.0, 1.0, 0.0);
    }
}

void vv_lights_arc(inout VvLights L, vec3 a, vec3 b) {
    for (int k = 0; k < L.count; k++) {
        vec3 d = L.dir[k];
        L.wind[k] += atan(dot(d, cross(a, b)), dot(a, b) - dot(a, d) * dot(b, d));
    }
}

// The shaded triangle's face normal on its vertex normals' side, set by the stage that knows it
// (fragment: from derivatives; tessellation evaluation: from the patch's corners); vec3(0.0)
// where unknown (the vertex stage). Light from below the face is blocked by it (lights.glsl).
vec3 vv_face_normal = vec3(0.0);

// The shaded point's tangent (dP/du, any length; brdf_ref.glsl brdf_frame makes the frame), set
// by the fragment stages from derivatives as the G-buffer computes it; vec3(0.0) where unknown
// (tessellation and vertex stages): Ashikhmin-Shirley is then isotropic at the geometric mean of
// its exponents (env_glossy, light_brdf).
vec3 vv_tangent = vec3(0.0);

// Unoccluded fraction of light l seen from s (face normal ng) by shadow rays through the kd-tree.
float vv_light_traced(LightData l, vec3 s, vec3 ng) {
    return light_rays_visibility(l, s + ng * 1e-3 * max(1.0, length(s)));
}

// Radiance reflected from the visible local lights.
vec3 vv_lights_end(VvLights L, vec3 s, vec3 n, MaterialData m) {
    vec3 sum = vec3(0.0);
    vec3 v = normalize(cam.eye.xyz - s);
    bool traced = pc.par.w > 0.5;
    vec3 ng = vv_face_normal == vec3(0.0) ? n : vv_face_normal;
    for (int k = 0; k < L.count; k++) {
        if (!traced && L.wind[k] > PI) continue;  // inside an occluded region
        vec3 wi;
        float dist, ndl;
        vec3 e = light_incident(lights[k], s, n, ng, wi, dist, ndl);
        if (ndl <= 0.0) continue;
        float vis = traced ? vv_light_traced(lights[k], s, ng) : 1.0;
        if (vis <= 0.0) continue;
        sum += light_brdf(wi, n, vv_tangent, v, m.albedo_kind.rgb, m) * e * ndl * vis;
    }
    return sum;
}

// The radiance of one evaluation: the diffuse integral over the visible directions (eq. 9,
// loop sum `diffuse_sum`, before the intensity) plus the scene material's unshadowed glossy
// reflection (env_shade.glsl's env_glossy: the BRDF lobe importance-sampled over the mip-filtered
// environment, as the `env` technique draws it) times gamma (eq. 14: L_s = k_s gamma U with k_s U the unshadowed glossy term),
// plus the visible local lights.
vec3 vv_radiance(vec3 diffuse_sum, vec3 s, vec3 n, MaterialData m, bool glossy, float gamma, VvLights L) {
    vec3 v = normalize(cam.eye.xyz - s);
    n = material_facing_normal(n, v);  // the G-buffer's rule, for evaluations at vertices too
    vec3 c = material_diffuse_albedo(m, dot(n, v)) / PI * max(diffuse_sum, vec3(0.0)) * cam.params.w + vv_lights_end(L, s, n, m);
    if (glossy) {
        vec3 d, g;
        env_unshadowed_parts(n, vv_tangent, v, m, d, g);
        c += g * gamma;
    }
    return material_reflected(c, n, v) + material_emission(m);
}

int vv_tri_vertex(int t, int k) {
    return vv_int(pc.off1.y + 3 * t + k);
}

// Interpolated axis of one triple (eq. 21, penumbra_math::vv::interpolate): the barycentric blend
// of its three points' directions from s, normalized (n where they cancel).
vec3 vv_triple_axis(int j, vec3 lambda, vec3 s, vec3 n) {
    vec3 a = vec3(0.0);
    for (int k = 0; k < 3; k++) {
        vec4 q = vv_point(vv_int(pc.off1.x + 3 * j + k));
        vec3 d = q.xyz - q.w * s;
        float l = length(d);
        if (l > 1e-12) a += lambda[k] * (d / l);
    }
    float al = length(a);
    return al > 1e-12 ? a / al : n;
}

// Radiance (diffuse, eq. 9/12, plus specular, eq. 14-16, for a glossy material) with the
// vectorized visibility of model vertex `id` synthesized at s (eq. 3; interp false), or with the
// interpolated vectorized visibility of triangle `id` (eq. 21, interp true: each triple's
// direction from vv_triple_axis). One body for both: every function is inlined, and lavapipe
// compiles every inlined copy (two copies of this one made vv_shade.frag twice as slow to build).
vec3 vv_eval(sampler2D sat, bool interp, int id, vec3 lambda, vec3 s, vec3 n, MaterialData m) {
    ivec2 size = pc.sat.xy;
    vec2 cs = cam.env_rot.xy;
    vec3 nn = vv_nudge(vv_to_map(n, cs), 0.0);
    VvAcc acc;
    vv_acc_init(acc);
    vv_add_hemisphere(sat, size, pc.par.x, nn, pc.sat.z, acc);
    VvSpec sp;
    bool glossy = vv_spec_begin(s, n, m, sp);
    VvLights L;
    vv_lights_begin(s, L);
    // the loops: [r0, r1) into the loop offsets at `base` (each loop's points p0 ..= p1, the last
    // one closing it)
    int r0, r1, base;
    if (interp) {
        r0 = vv_int(pc.off0.z + id) & 0x7fffffff;
        r1 = vv_int(pc.off0.z + id + 1) & 0x7fffffff;
        base = pc.off0.w;
    } else {
        r0 = vv_int(pc.off0.y + 2 * id);
        r1 = r0 + vv_int(pc.off0.y + 2 * id + 1);
        base = pc.off0.x;
    }
    for (int k = r0; k < r1; k++) {
        int p0 = vv_int(base + k), p1 = vv_int(base + k + 1);
        if (p1 - p0 < 2) continue;
        // one call site per integration
        vec3 d0 = vec3(0.0), prev = vec3(0.0);
        for (int i = p0; i <= p1; i++) {
            vec3 d = d0;
            if (i != p1) {
                vec4 q = interp ? vec4(vv_triple_axis(i, lambda, s, n), 0.0) : vv_point(i);
                d = vv_to_map(vv_synth(q, interp ? vec3(0.0) : s, n, n), cs);
            }
            if (i == p0) d0 = d;
            else {
                vv_arc(sat, size, pc.par.x, prev, d, acc);
                vv_lights_arc(L, prev, d);
            }
            if (glossy && i < p1) vv_clip_push(sat, size, pc.par.x, sp.clip, d, sp.acc);
            prev = d;
        }
        if (glossy) vv_clip_end(sat, size, pc.par.x, sp.clip, sp.acc);
    }
    return vv_radiance(vv_finish(sat, size, nn, acc), s, n, m, glossy, glossy ? vv_spec_gamma(sat, nn, sp) : 1.0, L);
}

// Eq. 3's synthesized visibility of model vertex v at s.
vec3 vv_eval_vertex(sampler2D sat, int v, vec3 s, vec3 n, MaterialData m) {
    return vv_eval(sat, false, v, vec3(0.0), s, n, m);
}

// Bit 31 of triangle t's first loop offset: its correspondence is unsound
// (VvSettings::fallback) and the interpolated modes shade it by eq. 19.
bool vv_tri_fallback(int t) {
    return vv_int(pc.off0.z + t) < 0;
}

// A point of triangle t (vertices vids, barycentrics lambda; a fragment or a tessellated
// vertex): eq. 19 (three = true: three syntheses, three evaluations, blended barycentrically) or
// eq. 21 (the interpolated vectorized visibility of t evaluated once), through one call of
// vv_eval.
vec3 vv_eval_on_triangle(sampler2D sat, bool three, int t, ivec3 vids, vec3 lambda, vec3 s, vec3 n, MaterialData m) {
    int count = three ? 3 : 1;
    vec3 c = vec3(0.0);
    for (int k = 0; k < count; k++) c += (three ? lambda[k] : 1.0) * vv_eval(sat, !three, three ? vids[k] : t, lambda, s, n, m);
    return c;
}

#endif
