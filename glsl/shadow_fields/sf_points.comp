#version 450
// Shadow fields, per point (vertex) radiance: the GPU mirror of the CPU path
// (penumbra_math::shadow_field::shade_points_with, Fig. 3 of the paper). Each point carries its
// world position, receiver instance, output slot, albedo and object-space self-transfer.
// Output at the point's slot: linear RGB radiance times the albedo (clamped at 0), w the
// unclamped minimum channel (negative-lobe measure). The display path uses albedo 1 and
// multiplies the (textured) albedo per pixel.
#define SF_B0 0
#include "sf.glsl"

layout(local_size_x = 64) in;

struct SfPoint {
    vec4 pos;     // xyz world position
    vec4 albedo;
    uvec4 ids;    // x receiver instance, y output slot
    float t[16];  // object-space self-transfer
};
layout(set = 0, binding = 5) readonly buffer Points { SfPoint points[]; };
layout(set = 0, binding = 6) buffer Out { vec4 outv[]; };
layout(push_constant) uniform Push { uint n_points; uint n_inst; uint tensor_count; uint n_light; uint window; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n_points) return;
    SfPoint pt = points[i];
    uint self_inst = min(pt.ids.x, max(pc.n_inst, 1u) - 1u);
    float t[16];
    for (int e = 0; e < 16; e++) t[e] = pt.t[e];
    float u[16];
    sf_rotate(self_inst, t, u);
    float none[16];
    sf_zero(none);
    vec3 unused;
    vec3 c = pt.albedo.rgb * sf_shade_point(pt.pos.xyz, vec3(0.0), self_inst, pc.n_inst, pc.n_light, pc.tensor_count, pc.window, u, false, none, unused);
    outv[pt.ids.y] = vec4(max(c, vec3(0.0)), min(c.r, min(c.g, c.b)));
}
