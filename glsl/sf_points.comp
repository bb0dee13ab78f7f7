#version 450
// Shadow fields, per point (vertex) radiance: the GPU mirror of the CPU path
// (penumbra_passes::shadow_fields::cpu). Each point carries its world position, receiver
// instance, albedo and object-space self-transfer. Output: linear RGB radiance (clamped at 0),
// w the unclamped minimum channel (negative-lobe measure).
#define SF_B0 0
#include "sf.glsl"

layout(local_size_x = 64) in;

struct SfPoint {
    vec4 pos_inst;  // xyz world position, w receiver instance
    vec4 albedo;
    float t[16];    // object-space self-transfer
};
layout(set = 0, binding = 5) readonly buffer Points { SfPoint points[]; };
layout(set = 0, binding = 6) writeonly buffer Out { vec4 outv[]; };
layout(push_constant) uniform Push { uint n_points; uint n_inst; uint tensor_count; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n_points) return;
    SfPoint pt = points[i];
    uint self_inst = min(uint(pt.pos_inst.w + 0.5), max(pc.n_inst, 1u) - 1u);
    float t[16];
    for (int e = 0; e < 16; e++) t[e] = pt.t[e];
    float u[16];
    sf_rotate(sf_inst[self_inst], t, u);
    sf_accumulate(pt.pos_inst.xyz, self_inst, pc.n_inst, pc.tensor_count, u);
    vec3 c = pt.albedo.rgb * sf_double(u);
    outv[i] = vec4(max(c, vec3(0.0)), min(c.r, min(c.g, c.b)));
}
