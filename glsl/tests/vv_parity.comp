#version 450
// vv GLSL-vs-CPU parity (tests/vv.rs): for each case, n . ∫ l L_e over the hemisphere of n minus
// occluder loops, with the technique's own integration code (vv_sat.glsl: vv_add_hemisphere,
// vv_arc, vv_finish), against penumbra_math::vv_sat on the CPU.
//
// Cases (vec4 buffer): data[c].x = offset of case c's record; a record is (n.xyz, loop count),
// then per loop (point count, 0, 0, 0) and its points (xyz map-space unit directions, in the
// closed hemisphere of n; part A's orientation: counter-clockwise from outside around the
// occluded region, so they subtract). Result: one RGBA32F texel per case (rgb).
#include "common.glsl"
#include "vv_sat.glsl"

layout(local_size_x = 1) in;
layout(set = 0, binding = 0) uniform sampler2D sat;
layout(set = 0, binding = 1) readonly buffer Cases { vec4 data[]; };
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D result;
layout(push_constant) uniform Push {
    ivec4 p;   // x W, y H, z hemisphere arcs, w case count
    vec4 f;    // x alpha'
} pc;

void main() {
    int c = int(gl_GlobalInvocationID.x);
    if (c >= pc.p.w) return;
    int o = int(data[c].x);
    vec4 hd = data[o];
    vec3 n = vv_nudge(normalize(hd.xyz), 0.0);
    VvAcc acc;
    vv_acc_init(acc);
    vv_add_hemisphere(sat, pc.p.xy, pc.f.x, n, pc.p.z, acc);
    int k = o + 1;
    for (int l = 0; l < int(hd.w); l++) {
        int cnt = int(data[k].x);
        k++;
        if (cnt >= 2) {
            vec3 d0 = data[k].xyz;
            vec3 prev = d0;
            for (int i = 1; i < cnt; i++) {
                vec3 d = data[k + i].xyz;
                vv_arc(sat, pc.p.xy, pc.f.x, prev, d, acc);
                prev = d;
            }
            vv_arc(sat, pc.p.xy, pc.f.x, prev, d0, acc);
        }
        k += cnt;
    }
    imageStore(result, ivec2(c, 0), vec4(vv_finish(sat, pc.p.xy, n, acc), 1.0));
}
