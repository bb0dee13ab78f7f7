#version 450
// vv per-fragment shading: fragment3 (eq. 19, three evaluations blended barycentrically) or
// fragment1 (eq. 21, the interpolated vectorized visibility evaluated once).
#include "vv_data.glsl"

layout(location = 0) in vec3 v_world;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec3 v_bary;
layout(location = 3) flat in ivec3 v_vids;
layout(location = 4) in vec2 v_uv;
layout(location = 0) out vec4 o_color;

void main() {
    vec3 n = normalize(v_normal);
    vec3 lambda = max(v_bary, vec3(0.0));
    lambda /= max(lambda.x + lambda.y + lambda.z, 1e-6);
    MaterialData m = vv_material(v_vids.x, v_uv);
    // the material's normal map (as the G-buffer applies it for the other techniques)
    vec3 dp1 = dFdx(v_world), dp2 = dFdy(v_world);
    vec3 ng = cross(dp1, dp2);
    if (dot(ng, ng) > 1e-30) vv_face_normal = normalize(dot(ng, n) < 0.0 ? -ng : ng);
    vec2 duv1 = dFdx(v_uv), duv2 = dFdy(v_uv);
    float sg = duv1.x * duv2.y - duv1.y * duv2.x < 0.0 ? -1.0 : 1.0;
    vec3 dpdu = (dp1 * duv2.y - dp2 * duv1.y) * sg;
    n = material_normal(m, v_uv, material_textures, n, dpdu, (dp2 * duv1.x - dp1 * duv2.x) * sg);
    n = material_facing_normal(n, normalize(cam.eye.xyz - v_world));  // as the G-buffer's
    // the G-buffer's tangent (dP/du times det), made a frame with n where it is shaded
    vec3 tt = dpdu * sg;
    tt -= n * dot(n, tt);
    vv_tangent = dot(tt, tt) >= 1e-20 ? normalize(tt) : brdf_frame(n, vec3(0.0))[0];
    bool three = pc.sat.w == 0 || vv_tri_fallback(gl_PrimitiveID);
    vec3 c = vv_eval_on_triangle(vv_sat_tex, three, gl_PrimitiveID, v_vids, lambda, v_world, n, m);
    o_color = vec4(c, 1.0);
}
