#version 450
// Environment-lit shading without shadows: diffuse from 9-coefficient SH irradiance, specular
// from the mip-filtered environment map along the reflection direction with an analytic
// split-sum environment BRDF (Karis 2014, mobile approximation).
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;

vec3 env_lookup(vec3 d, float lod) {
    vec2 uv = dir_to_latlong(normalize(d), cam.env_rot.xy);
    return textureLod(env_map, uv, lod).rgb * cam.params.w;
}

vec3 env_brdf_approx(vec3 f0, float roughness, float ndv) {
    const vec4 c0 = vec4(-1.0, -0.0275, -0.572, 0.022);
    const vec4 c1 = vec4(1.0, 0.0425, 1.04, -0.04);
    vec4 r = roughness * c0 + c1;
    float a004 = min(r.x * r.x, exp2(-9.28 * ndv)) * r.x + r.y;
    vec2 ab = vec2(-1.04, 1.04) * a004 + r.zw;
    return f0 * ab.x + ab.y;
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (p.x >= size.x || p.y >= size.y) return;
    vec4 uvm = texelFetch(gb_uv_mat, p, 0);
    if (uvm.w < 0.5) {
        // Sky: the environment seen through the pixel centre.
        vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
        vec3 dir = far_p.xyz / far_p.w - cam.eye.xyz;
        imageStore(hdr, p, vec4(env_lookup(dir, 0.0), 1.0));
        return;
    }
    vec3 pos = texelFetch(gb_position, p, 0).xyz;
    vec3 n = oct_decode(texelFetch(gb_normal, p, 0).xy);
    MaterialData m = mats[uint(uvm.z)];
    vec3 v = normalize(cam.eye.xyz - pos);
    float ndv = max(dot(n, v), 1e-4);
    vec3 albedo = m.albedo_kind.rgb;
    int kind = int(m.albedo_kind.w + 0.5);
    vec3 color = albedo / PI * sh9_irradiance(cam.sh, n) * cam.params.w;
    if (kind != 0) {
        float roughness = kind == 1 ? sqrt(2.0 / (m.extra.x + 2.0)) : m.spec_rough.w;
        roughness = clamp(roughness, 0.02, 1.0);
        vec3 r = reflect(-v, n);
        float lod = roughness * (cam.params.z - 1.0);
        color += env_lookup(r, lod) * env_brdf_approx(m.spec_rough.rgb, roughness, ndv);
    }
    imageStore(hdr, p, vec4(color, 1.0));
}
