#version 450
// All-frequency shadow fields, per-vertex self-occlusion (passes/src/shadow_fields/wavelet.rs):
// one workgroup of 64 per vertex slot. From the vertex's binary self-visibility cube map
// (object frame, precomputed) and this frame's world transform: the visible share of the
// environment's L cos at the vertex (rgb; 1 where nothing reaches it), and the self-visibility
// toward each of the first 4 local lights (bilinear in the map). The sfw_self raster pass
// interpolates both across the triangles; sfw_shade.comp multiplies them in.
#include "common.glsl"
#include "lights.glsl"

layout(local_size_x = 64) in;

struct SfwInst {
    mat4 world_to_local;
    vec4 center_step;
    uvec4 info;
    vec4 center_world;
    mat4 local_to_world;
};
layout(set = 0, binding = 0) readonly buffer Slots { uvec4 slots[]; };  // x first word of the vertex's map, y instance
layout(set = 0, binding = 1) readonly buffer Verts { vec4 verts[]; };  // per slot: object position, object normal
layout(set = 0, binding = 2) readonly buffer SelfMaps { uint self_maps[]; };
layout(set = 0, binding = 3) readonly buffer SfwInsts { SfwInst sfw_inst[]; };
layout(set = 0, binding = 4) readonly buffer SfwDirs { vec4 sfw_dirs[]; };
layout(set = 0, binding = 5) readonly buffer Lights { LightData lights[]; };
layout(set = 0, binding = 6) writeonly buffer Out { vec4 outs[]; };  // per slot: share rgb, light visibility
layout(push_constant) uniform Push { uint count; uint n; uint light_count; uint pad; } pc;

shared vec4 s_red[128];

#include "sfw_cube.glsl"

float bit(uint off, uint texel) {
    return float((self_maps[off + (texel >> 5)] >> (texel & 31u)) & 1u);
}

void main() {
    uint slot = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (slot >= pc.count) return;  // uniform over the workgroup
    uint lane = gl_LocalInvocationIndex;
    uvec4 info = slots[slot];
    SfwInst inst = sfw_inst[info.y];
    vec3 pw = (inst.local_to_world * vec4(verts[2u * slot].xyz, 1.0)).xyz;
    vec3 nw = normalize(transpose(mat3(inst.world_to_local)) * verts[2u * slot + 1u].xyz);
    mat3 to_local = mat3(inst.world_to_local);
    uint total = 6u * pc.n * pc.n;
    vec3 sh = vec3(0.0), un = vec3(0.0);
    for (uint i = lane; i < total; i += 64u) {
        vec3 d = sfw_dirs[i].xyz;
        float c = dot(nw, d);
        if (c <= 0.0) continue;
        vec3 L = sfw_dirs[total + i].rgb * c;
        uint face;
        vec2 xy;
        cube_coords(normalize(to_local * d), pc.n, face, xy);
        uvec2 ij = min(uvec2(xy), uvec2(pc.n - 1u));
        sh += L * bit(info.x, face * pc.n * pc.n + ij.y * pc.n + ij.x);
        un += L;
    }
    s_red[lane] = vec4(sh, 0.0);
    s_red[64u + lane] = vec4(un, 0.0);
    barrier();
    for (uint stride = 32u; stride > 0u; stride >>= 1) {
        if (lane < stride) {
            s_red[lane] += s_red[lane + stride];
            s_red[64u + lane] += s_red[64u + lane + stride];
        }
        barrier();
    }
    if (lane != 0u) return;
    vec3 share = vec3(1.0);
    for (int c = 0; c < 3; c++)
        if (s_red[64][c] > 1e-12) share[c] = clamp(s_red[0][c] / s_red[64][c], 0.0, 1.0);
    vec4 lv = vec4(1.0);
    for (uint j = 0u; j < min(pc.light_count, 4u); j++) {
        vec3 to_l = light_vector(lights[j], pw);
        if (!(dot(to_l, to_l) > 0.0)) continue;
        vec3 l = normalize(to_local * normalize(to_l));
        uint face;
        vec2 xy;
        cube_coords(l, pc.n, face, xy);
        uint n = pc.n;
        vec2 cc = clamp(xy - 0.5, vec2(0.0), vec2(float(n - 1u)));
        uvec2 i0 = min(uvec2(floor(cc)), uvec2(n - 1u));
        uvec2 i1 = min(i0 + 1u, uvec2(n - 1u));
        vec2 f = cc - vec2(i0);
        uint base = face * n * n;
        float a = mix(bit(info.x, base + i0.y * n + i0.x), bit(info.x, base + i0.y * n + i1.x), f.x);
        float b = mix(bit(info.x, base + i1.y * n + i0.x), bit(info.x, base + i1.y * n + i1.x), f.x);
        lv[j] = mix(a, b, f.y);
    }
    outs[2u * slot] = vec4(share, 1.0);
    outs[2u * slot + 1u] = lv;
}
