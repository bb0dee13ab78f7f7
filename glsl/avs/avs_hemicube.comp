#version 460
#extension GL_GOOGLE_include_directive : require
// Fig. 7 baseline of the avs technique ("the shadow map-based approach that replaces our adaptive
// visibility sampling by rendering shadow maps"): converts rasterized hemicubes (depth atlas, one
// row of 5 F x F tiles per point of the batch: +n, +t, -t, +b, -b; side faces only their upper
// half) into 1-bit hemispherical maps in the layout of include/avs_maps.glsl. One invocation per
// map word (32 texels): texel direction -> dominant face -> the face's view-projection -> depth
// texel; covered (depth < 1) = occluded.
#include "avs_maps.glsl"

layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform sampler2D atlas;
// 3 vec4 per point (position + offset, tangent, normal) as the avs points buffer
layout(std430, binding = 1) readonly buffer Points { vec4 pts[]; };
// 5 mat4 per point (faces in the order above)
layout(std430, binding = 2) readonly buffer Faces { mat4 faces[]; };
layout(std430, binding = 3) writeonly buffer Maps { uint maps[]; };
layout(push_constant) uniform Push {
    uint r;
    uint face_res;
    uint first;   // first point of the batch
    uint count;   // points in the batch
} pc;

void main() {
    uint words = avs_words_per_map(pc.r);
    uint w = gl_GlobalInvocationID.x, e = gl_GlobalInvocationID.y;
    if (w >= words || e >= pc.count) return;
    uint q = pc.first + e;
    vec4 p0 = pts[3u * q];
    vec3 t = pts[3u * q + 1u].xyz, n = pts[3u * q + 2u].xyz, b = cross(n, t);
    vec3 eye = p0.xyz + n * p0.w;
    float f = float(pc.face_res);
    uint bits = 0u;
    for (uint k = 0u; k < 32u; ++k) {
        uint texel = w * 32u + k;
        vec3 l = avs_texel_dir(texel / pc.r, texel % pc.r, pc.r);
        uint face = 0u;
        float m = l.z;
        if (abs(l.x) > m) { face = l.x > 0.0 ? 1u : 2u; m = abs(l.x); }
        if (abs(l.y) > m) { face = l.y > 0.0 ? 3u : 4u; }
        vec4 c = faces[5u * q + face] * vec4(eye + t * l.x + b * l.y + n * l.z, 1.0);
        vec2 ndc = c.xy / c.w;
        ivec2 tx = clamp(ivec2(floor((ndc * 0.5 + 0.5) * f)), ivec2(0), ivec2(int(pc.face_res) - 1));
        float depth = texelFetch(atlas, tx + ivec2(int(face * pc.face_res), int(e * pc.face_res)), 0).r;
        if (depth >= 1.0) bits |= 1u << k;
    }
    maps[q * words + w] = bits;
}
