#version 460
#extension GL_GOOGLE_include_directive : require
// G-buffer culling of sample points (Wang et al., section 6 "Optimization": "we use rasterized
// frame buffer to collect sample points; only these points that may be used for shading are taken
// for further adaptive computation"). Per covered pixel, the neighbours the shading would pick
// (include/avs_gather.glsl, same radius and weights) among ALL candidate points; their bits are
// set in `used` (bit i = candidate i). The technique reads the bits back at the start of the next
// frame (one frame late) and traces only the flagged points; the first frame traces all.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform sampler2D gb_position;
layout(set = 0, binding = 1) uniform sampler2D gb_normal;
layout(set = 0, binding = 2) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 3) readonly buffer Points { vec4 pts[]; };
layout(set = 0, binding = 4) readonly buffer Grid { uint grid[]; };
layout(set = 0, binding = 5) buffer Used { uint used[]; };
layout(push_constant) uniform Push {
    float radius;
    float alpha;
    float inv_scale;
    uint max_neighbours;
} pc;

#include "avs_gather.glsl"

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(gb_uv_mat, 0);
    if (px.x >= size.x || px.y >= size.y) return;
    if (texelFetch(gb_uv_mat, px, 0).w < 0.5) return;
    vec3 pos = texelFetch(gb_position, px, 0).xyz;
    vec3 n = oct_decode(texelFetch(gb_normal, px, 0).xy);
    avs_gather(pos, n, pc.radius, pc.alpha, pc.inv_scale, pc.max_neighbours);
    for (uint q = 0u; q < nb_count; ++q) atomicOr(used[nb_slot[q] >> 5u], 1u << (nb_slot[q] & 31u));
}
