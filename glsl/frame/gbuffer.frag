#version 450
#include "common.glsl"

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(std430, set = 0, binding = 2) readonly buffer Materials { MaterialData mats[]; };
layout(set = 0, binding = 3) uniform sampler2DArray material_textures;
#include "material.glsl"

layout(location = 0) in vec3 v_world;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec2 v_uv;
layout(location = 3) in vec4 v_clip;
layout(location = 4) in vec4 v_prev_clip;
layout(location = 5) flat in uvec2 v_ids;

layout(location = 0) out vec4 o_position;  // world position, geometric normal (common.glsl gb_pack_geometric_normal; > 0)
layout(location = 1) out vec4 o_normal;    // octahedral normal.xy, octahedral tangent.xy
layout(location = 2) out vec4 o_uv_mat;    // uv, material index, instance id + 1 (0 = sky)
layout(location = 3) out vec2 o_motion;    // pixels moved since the previous frame

void main() {
    vec3 n = normalize(v_normal);
    // dP/du and dP/dv from screen-space derivatives of position and uv: the material's normal map
    // bends the normal in their frame; the tangent (dP/du) is the local frame of anisotropic BRDFs.
    vec3 dp1 = dFdx(v_world), dp2 = dFdy(v_world);
    // Two-sided shading as the reference's (render.rs, mc.comp): the face's normal (v_world is
    // linear over the triangle) on the vertex normal's side, then turned towards the viewer, and
    // the vertex normal on its side. (Flipping by gl_FrontFacing instead shaded a front-facing
    // triangle whose interpolated normal faces away, at a silhouette, from behind: black.)
    vec3 ng = cross(dp1, dp2);
    ng = dot(ng, ng) > 1e-30 ? normalize(ng) : n;
    if (dot(ng, n) < 0.0) ng = -ng;
    if (dot(ng, cam.eye.xyz - v_world) < 0.0) ng = -ng;
    if (dot(n, ng) < 0.0) n = -n;
    vec2 duv1 = dFdx(v_uv), duv2 = dFdy(v_uv);
    float det = duv1.x * duv2.y - duv1.y * duv2.x;
    float sg = det < 0.0 ? -1.0 : 1.0;
    vec3 dpdu = (dp1 * duv2.y - dp2 * duv1.y) * sg;
    vec3 dpdv = (dp2 * duv1.x - dp1 * duv2.x) * sg;
    n = material_normal(mats[v_ids.x], v_uv, material_textures, n, dpdu, dpdv);
    // never below the eye's horizon (an interpolated normal at a silhouette, a normal map)
    n = material_facing_normal(n, normalize(cam.eye.xyz - v_world));
    vec3 t = dpdu * sg;  // dP/du times det's magnitude, as before normal maps
    t -= n * dot(n, t);
    if (dot(t, t) < 1e-20) {
        // no usable uv: Duff et al. 2017's basis vector of n, the reference's tangent then
        // (sampling.rs Frame::new, brdf_ref.glsl brdf_frame): Ashikhmin-Shirley's anisotropy
        // runs along it in both
        float s = n.z >= 0.0 ? 1.0 : -1.0;
        float a = -1.0 / (s + n.z);
        t = vec3(1.0 + s * n.x * n.x * a, s * n.x * n.y * a, -s * n.x);
    }
    t = normalize(t);
    o_position = vec4(v_world, gb_pack_geometric_normal(ng));
    o_normal = vec4(oct_encode(n), oct_encode(t));
    o_uv_mat = vec4(v_uv, float(v_ids.x), float(v_ids.y + 1u));
    vec2 ndc = v_clip.xy / v_clip.w;
    vec2 prev_ndc = v_prev_clip.xy / v_prev_clip.w;
    o_motion = (ndc - prev_ndc) * 0.5 * cam.params.xy;
}
