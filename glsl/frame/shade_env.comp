#version 450
// Environment- and local-light shading without shadows: the environment by env_shade.glsl
// (diffuse from the exact irradiance map, glossy by filtered importance sampling of the BRDF's lobe
// over the mip-filtered environment map), local lights below.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; };  // cam_dfg: env_dfg.glsl; cam_irr: env_shade.glsl
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
#include "lights.glsl"
layout(push_constant) uniform Push { uint light_count; } pc;

// Radiance reflected from local lights (lights.glsl), unshadowed.
vec3 local_lights(vec3 pos, vec3 n, vec3 t, vec3 ng, vec3 v, vec3 albedo, MaterialData m) {
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < pc.light_count; ++i) {
        LightData l = lights[i];
        vec3 wi;
        float dist, ndl;
        vec3 e = light_incident(l, pos, n, ng, wi, dist, ndl);
        if (ndl <= 0.0) continue;
        vec3 f = light_brdf(wi, n, t, v, albedo, m);
        sum += f * e * ndl;
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
        imageStore(hdr, p, vec4(env_background(dir), 1.0));
        return;
    }
    vec4 gp = texelFetch(gb_position, p, 0);
    vec3 pos = gp.xyz, ng = gb_geometric_normal(gp.w);
    vec4 en = texelFetch(gb_normal, p, 0);
    vec3 n = oct_decode(en.xy), tg = oct_decode(en.zw);
    MaterialData m = mats[uint(uvm.z)];
    vec3 v = normalize(cam.eye.xyz - pos);
    // Spatially varying materials: albedo map multiplies albedo, roughness map (G) multiplies
    // roughness and the Phong exponent follows 2 / r^2 - 2 (as in the reference renderer).
    m = material_at(m, uvm.xy, material_textures);
    vec3 color = env_unshadowed(n, tg, v, m);
    color += local_lights(pos, n, tg, ng, v, m.albedo_kind.rgb, m);
    imageStore(hdr, p, vec4(material_reflected(color, n, v) + material_emission(m), 1.0));
}
