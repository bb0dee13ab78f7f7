#version 450
// vv specular cap ratio, GLSL-vs-CPU parity (tests/vv.rs): per case, gamma of eq. 15 (cap W of
// cosine cos_xi around r; numerator over W ∩ hemisphere of n minus the occluder loops clipped to
// W, denominator over W, both weighted by Cap of eq. 16) with the technique's own code
// (vv_sat.glsl: vv_clip_*, vv_add_cap_in_hemisphere, vv_add_cap, vv_cap_finish), against
// penumbra_math::vv_sat::cap_ratio on the CPU.
//
// Cases (vec4 buffer): data[c].x = offset of case c's record; a record is (n.xyz, loop count),
// (r.xyz, cos_xi), then per loop (point count, 0, 0, 0) and its points (map-space unit
// directions in the closed hemisphere of n, clockwise seen from the centre around the occluded
// region, as the synthesized loops of the shading shaders). Result: RGBA32F image of
// (cases x 3) texels: row 0 gamma, row 1 numerator, row 2 denominator (rgb).
#include "common.glsl"
#include "vv_sat.glsl"

layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform sampler2D sat;
layout(set = 0, binding = 1) readonly buffer Cases { vec4 data[]; };
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D result;
layout(push_constant) uniform Push {
    ivec4 p;   // x W, y H, z circle arcs, w case count
    vec4 f;    // x alpha'
} pc;

void main() {
    int c = int(gl_GlobalInvocationID.x);
    if (c >= pc.p.w) return;
    ivec2 size = pc.p.xy;
    float alpha = pc.f.x;
    int o = int(data[c].x);
    vec4 hd = data[o];
    vec4 rc = data[o + 1];
    float cx = rc.w;
    vec3 n = vv_nudge(normalize(hd.xyz), 0.0);
    vec3 r = vv_nudge(normalize(rc.xyz), cx);
    VvAcc num;
    vv_acc_init4(num);
    VvClip clip;
    vv_clip_init(r, cx, -1.0, pc.p.z, clip);
    int k = o + 2;
    for (int l = 0; l < int(hd.w); l++) {
        int cnt = int(data[k].x);
        k++;
        for (int i = 0; i < cnt; i++) vv_clip_push(sat, size, alpha, clip, data[k + i].xyz, num);
        vv_clip_end(sat, size, alpha, clip, num);
        k += cnt;
    }
    vv_add_cap_in_hemisphere(sat, size, alpha, r, cx, n, pc.p.z, num);
    vec3 nu = vv_cap_finish(sat, size, r, cx, true, n, num);
    VvAcc den;
    vv_acc_init4(den);
    vv_add_cap(sat, size, alpha, r, cx, pc.p.z, den);
    vec3 de = vv_cap_finish(sat, size, r, cx, false, n, den);
    vec3 g;
    for (int i = 0; i < 3; i++) g[i] = de[i] > 1e-12 ? clamp(nu[i] / de[i], 0.0, 1.0) : 1.0;
    imageStore(result, ivec2(c, 0), vec4(g, 1.0));
    imageStore(result, ivec2(c, 1), vec4(nu, 1.0));
    imageStore(result, ivec2(c, 2), vec4(de, 1.0));
}
