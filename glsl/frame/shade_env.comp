#version 450
// Environment- and local-light shading without shadows: the environment by env_shade.glsl
// (diffuse from 9-coefficient SH irradiance, specular from the mip-filtered environment map along
// the reflection direction with an analytic split-sum environment BRDF), local lights below.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;
layout(set = 0, binding = 7) readonly buffer Lights { LightData lights[]; };
layout(set = 0, binding = 8) uniform sampler2DArray material_textures;
#include "material.glsl"
#include "env_shade.glsl"
layout(push_constant) uniform Push { uint light_count; } pc;

// Radiance reflected from local lights, unshadowed. Point and spot lights: radiant intensity
// `power` (W/sr); sphere lights: emitted radiance `power`, treated as a point of intensity
// power * pi * r^2 (exact for a sphere's irradiance at normal incidence, far from it).
vec3 local_lights(vec3 pos, vec3 n, vec3 v, vec3 albedo, int kind, MaterialData m, float roughness) {
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < pc.light_count; ++i) {
        LightData l = lights[i];
        vec3 to_l = l.pos_kind.xyz - pos;
        float d2 = max(dot(to_l, to_l), 1e-8);
        vec3 wi = to_l * inversesqrt(d2);
        float ndl = dot(n, wi);
        if (ndl <= 0.0) continue;
        vec3 intensity = l.power_cos_inner.rgb;
        int lk = int(l.pos_kind.w + 0.5);
        if (lk == 1) {
            float c = dot(-wi, normalize(l.dir_cos_outer.xyz));
            intensity *= smoothstep(l.dir_cos_outer.w, l.power_cos_inner.w, c);
        } else if (lk == 2) {
            intensity *= PI * l.extra.x * l.extra.x;
        }
        intensity *= light_transmittance(l, sqrt(d2));
        vec3 f = albedo / PI;
        if (kind != 0) {
            vec3 h = normalize(wi + v);
            float ndh = max(dot(n, h), 0.0);
            float ndv = max(dot(n, v), 1e-4);
            vec3 F = m.spec_rough.rgb + (1.0 - m.spec_rough.rgb) * pow(1.0 - max(dot(wi, h), 0.0), 5.0);
            if (kind == 1) {
                float s = m.extra.x;
                f += F * (s + 2.0) / (8.0 * PI) * pow(ndh, s);  // as penumbra-math and the reference
            } else {
                float a = roughness * roughness;
                float a2 = a * a;
                float dd = ndh * ndh * (a2 - 1.0) + 1.0;
                float D = a2 / (PI * dd * dd);
                float k = a * 0.5;
                float G = ndl / (ndl * (1.0 - k) + k) * ndv / (ndv * (1.0 - k) + k);
                f += F * D * G / (4.0 * ndl * ndv);
            }
        }
        sum += f * intensity * ndl / d2;
    }
    return sum;
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
    int kind = int(m.albedo_kind.w + 0.5);
    // Spatially varying materials: albedo map multiplies albedo, roughness map (G) multiplies
    // roughness and the Phong exponent follows 2 / r^2 - 2 (as in the reference renderer).
    m = material_at(m, uvm.xy, material_textures);
    vec3 color = env_unshadowed(n, v, m);
    color += local_lights(pos, n, v, m.albedo_kind.rgb, kind, m, env_roughness(m));
    imageStore(hdr, p, vec4(color, 1.0));
}
