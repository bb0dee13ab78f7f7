#version 460
#extension GL_GOOGLE_include_directive : require
// Shadow-map baseline ("shadowmaps"): the environment replaced by K directional lights at
// stratified importance samples of it (weights L / (K pdf)), each with an orthographic depth map
// (shadowmaps/shadowmaps_depth.comp); per G-buffer pixel: sum over k of BRDF x cos x lit fraction (3x3 PCF,
// slope-scaled bias) x weight. Sky pixels show the environment.
layout(local_size_x = 8, local_size_y = 8) in;
layout(binding = 0) uniform sampler2D gb_position;
layout(binding = 1) uniform sampler2D gb_normal;
layout(binding = 2) uniform sampler2D gb_uv_mat;
#include "common.glsl"
// the scene's materials (passes/src/scene_gpu.rs material_table, read through material.glsl)
layout(std430, binding = 3) readonly buffer Materials { MaterialData mats[]; };
layout(std430, binding = 4) readonly buffer Maps { vec4 maps[]; };
layout(std430, binding = 5) readonly buffer Depth { float depth[]; };
layout(std430, binding = 6) readonly buffer EnvTexels { vec4 env_texels[]; };
layout(binding = 7, rgba32f) uniform writeonly image2D hdr;
layout(binding = 8) uniform sampler2DArray material_textures;
layout(push_constant) uniform Push {
    mat4 inv_view_proj;
    uvec4 size_count;   // width, height, K, S
    uvec4 env_info;     // env width, env height, visibility on, 0
    vec4 env_rot;       // cos, sin of the environment rotation
    vec4 sphere;        // scene bounding sphere centre, radius
} pc;

#define M_PI 3.14159265358979323846
#define M_TAU 6.28318530717958647692
#include "material.glsl"
#include "brdf_ref.glsl"

vec3 env_radiance(vec3 dw) {
    float c = pc.env_rot.x, s = pc.env_rot.y;
    vec3 d = vec3(c * dw.x - s * dw.z, dw.y, s * dw.x + c * dw.z);
    float theta = acos(clamp(d.y, -1.0, 1.0));
    float phi = atan(d.x, -d.z);
    if (phi < 0.0) phi += M_TAU;
    int w = int(pc.env_info.x), h = int(pc.env_info.y);
    int i = clamp(int(phi / M_TAU * float(w)), 0, w - 1);
    int j = clamp(int(theta / M_PI * float(h)), 0, h - 1);
    return env_texels[j * w + i].rgb;
}

float lit(uint k, vec3 p, float cos_i) {
    uint s = pc.size_count.w;
    vec3 wi = maps[4u * k].xyz, right = maps[4u * k + 2u].xyz, up = maps[4u * k + 3u].xyz;
    float r = pc.sphere.w;
    vec3 q = p - pc.sphere.xyz;
    float dp = 1.01 * r - dot(q, wi);
    vec2 uv = vec2(dot(q, right), dot(q, up)) / r;
    vec2 t = (uv * 0.5 + 0.5) * float(s) - 0.5;
    float texel = 2.0 * r / float(s);
    float tan_i = sqrt(max(1.0 - cos_i * cos_i, 0.0)) / max(cos_i, 0.05);
    float bias = texel * (1.5 + 1.5 * min(tan_i, 20.0)) + 1e-4 * r;
    float sum = 0.0;
    for (int dy = -1; dy <= 1; dy++) {
        for (int dx = -1; dx <= 1; dx++) {
            ivec2 c = clamp(ivec2(round(t)) + ivec2(dx, dy), ivec2(0), ivec2(int(s) - 1));
            float d = depth[(k * s + uint(c.y)) * s + uint(c.x)];
            sum += dp - bias <= d ? 1.0 : 0.0;
        }
    }
    return sum / 9.0;
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = pc.size_count.x, h = pc.size_count.y;
    if (px.x >= int(w) || px.y >= int(h)) return;
    vec4 uvm = texelFetch(gb_uv_mat, px, 0);
    vec2 ndc = (vec2(px) + 0.5) / vec2(w, h) * 2.0 - 1.0;
    vec4 nr = pc.inv_view_proj * vec4(ndc, 0.0, 1.0);
    vec4 fr = pc.inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 o = nr.xyz / nr.w;
    vec3 d = normalize(fr.xyz / fr.w - o);
    if (uvm.w < 0.5) {
        imageStore(hdr, px, vec4(env_radiance(d), 1.0));
        return;
    }
    vec3 p = texelFetch(gb_position, px, 0).xyz;
    vec4 en = texelFetch(gb_normal, px, 0);
    vec3 ns = oct_decode(en.xy);
    vec3 tg = oct_decode(en.zw);
    vec3 wo_w = -d;
    if (dot(ns, wo_w) < 0.0) ns = -ns;   // two-sided
    vec3 tt = tg - ns * dot(ns, tg);
    if (dot(tt, tt) > 1e-12) tt = normalize(tt);
    else {
        float s = ns.z >= 0.0 ? 1.0 : -1.0;
        float a = -1.0 / (s + ns.z);
        float bb = ns.x * ns.y * a;
        tt = vec3(1.0 + s * ns.x * ns.x * a, s * bb, -s * ns.x);
    }
    vec3 bt = cross(ns, tt);
    vec3 wo = vec3(dot(wo_w, tt), dot(wo_w, bt), dot(wo_w, ns));
    uint mi = uint(uvm.z + 0.5);
    Brdf b = brdf_from_material(material_at(mats[mi], uvm.xy, material_textures));
    vec3 l = vec3(0.0);
    for (uint k = 0u; k < pc.size_count.z; k++) {
        vec3 wi = maps[4u * k].xyz;
        vec3 lw = vec3(dot(wi, tt), dot(wi, bt), dot(wi, ns));
        if (lw.z <= 0.0 || wo.z <= 0.0) continue;
        vec3 f = brdf_eval(b, wo, lw) * lw.z;
        if (f == vec3(0.0)) continue;
        float v = pc.env_info.z != 0u ? lit(k, p, lw.z) : 1.0;
        l += f * maps[4u * k + 1u].rgb * v;
    }
    imageStore(hdr, px, vec4(l, 1.0));
}
