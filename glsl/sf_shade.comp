#version 450
// Shadow fields, per pixel: the G-buffer point's diffuse transfer (clamped cosine / pi, no
// self-occlusion at pixels) times every other object's visibility from its shadow field
// (triple products), double product with the environment SH; glossy materials add the
// prefiltered environment along the reflection, times the occluders' visibility there.
// Sky pixels show the environment.
#include "common.glsl"
#define SF_B0 7
#include "sf.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 2) uniform sampler2D gb_position;
layout(set = 0, binding = 3) uniform sampler2D gb_normal;
layout(set = 0, binding = 4) uniform sampler2D gb_uv_mat;
layout(set = 0, binding = 5) uniform sampler2D env_map;
layout(set = 0, binding = 6, rgba32f) uniform writeonly image2D hdr;
layout(push_constant) uniform Push { uint n_inst; uint tensor_count; } pc;

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

// Order-4 SH of max(n.w, 0) / pi: A_l / pi * Y_lm(n), A = (pi, 2pi/3, pi/4, 0), Condon-Shortley real SH.
void cosine_transfer(vec3 n, out float t[16]) {
    float x = n.x, y = n.y, z = n.z;
    // basis values (penumbra_math::sh convention)
    float b[16];
    b[0] = 0.282094792;
    b[1] = -0.488602512 * y;
    b[2] = 0.488602512 * z;
    b[3] = -0.488602512 * x;
    b[4] = 1.092548431 * x * y;
    b[5] = -1.092548431 * y * z;
    b[6] = 0.315391565 * (3.0 * z * z - 1.0);
    b[7] = -1.092548431 * x * z;
    b[8] = 0.546274215 * (x * x - y * y);
    // band 3 has A_3 = 0
    for (int e = 9; e < 16; e++) b[e] = 0.0;
    t[0] = b[0];
    for (int e = 1; e < 4; e++) t[e] = (2.0 / 3.0) * b[e];
    for (int e = 4; e < 9; e++) t[e] = 0.25 * b[e];
    for (int e = 9; e < 16; e++) t[e] = 0.0;
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (p.x >= size.x || p.y >= size.y) return;
    vec4 uvm = texelFetch(gb_uv_mat, p, 0);
    if (uvm.w < 0.5) {
        vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far_p = cam.inv_view_proj * vec4(ndc, 1.0, 1.0);
        vec3 dir = far_p.xyz / far_p.w - cam.eye.xyz;
        imageStore(hdr, p, vec4(env_lookup(dir, 0.0), 1.0));
        return;
    }
    vec3 pos = texelFetch(gb_position, p, 0).xyz;
    vec3 n = oct_decode(texelFetch(gb_normal, p, 0).xy);
    MaterialData m = mats[uint(uvm.z)];
    uint self_inst = uint(uvm.w + 0.5) - 1u;
    float u[16];
    cosine_transfer(n, u);
    sf_accumulate(pos, self_inst, pc.n_inst, pc.tensor_count, u);
    vec3 color = max(m.albedo_kind.rgb * sf_double(u), vec3(0.0));
    // Glossy materials: the prefiltered environment along the reflection (as the "env"
    // technique), shadowed by the occluders' visibility in that direction.
    int kind = int(m.albedo_kind.w + 0.5);
    if (kind != 0) {
        vec3 v = normalize(cam.eye.xyz - pos);
        float ndv = max(dot(n, v), 1e-4);
        float roughness = clamp(kind == 1 ? sqrt(2.0 / (m.extra.x + 2.0)) : m.spec_rough.w, 0.02, 1.0);
        vec3 r = reflect(-v, n);
        float vis = sf_visibility_along(pos, r, self_inst, pc.n_inst);
        color += vis * env_lookup(r, roughness * (cam.params.z - 1.0)) * env_brdf_approx(m.spec_rough.rgb, roughness, ndv);
    }
    imageStore(hdr, p, vec4(color, 1.0));
}
