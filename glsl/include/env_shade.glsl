// Unshadowed environment lighting of a surface point (the `env` technique's, shared with the
// shadow-map baseline's ratio estimator): diffuse from the 9-coefficient SH irradiance, glossy from
// the mip-filtered lat-long environment along the reflection direction times the reference
// BRDF's specular albedo (a split sum; env_dfg.glsl).
// Needs, declared by the includer: `cam` (CameraData: sh, params.z mip count, params.w
// intensity, env_rot) and `env_map` (sampler2D, the mip-filtered lat-long environment), and
// common.glsl (PI, dir_to_latlong, sh9_irradiance, MaterialData).

#include "env_dfg.glsl"
#include "env_background.glsl"

vec3 env_lookup(vec3 d, float lod) {
    vec2 uv = dir_to_latlong(normalize(d), cam.env_rot.xy);
    return textureLod(env_map, uv, lod).rgb * cam.params.w;
}

// The material's specular lobe as a GGX alpha: Cook-Torrance alpha = roughness^2 (the
// reference's); a Blinn-Phong exponent s as alpha = sqrt(2 / (s + 2)); Ashikhmin-Shirley's
// exponents nu, nv as that of their geometric mean; clamped to [4e-4, 1].
float env_alpha(MaterialData m) {
    int kind = int(m.albedo_kind.w + 0.5);
    float r = clamp(m.spec_rough.w, 0.0, 1.0);
    float s = kind == 3 ? sqrt(max(m.extra.x, 0.0) * max(m.extra.w, 0.0)) : m.extra.x;
    return clamp(kind == 1 || kind == 3 ? sqrt(2.0 / (max(s, 0.0) + 2.0)) : r * r, 4e-4, 1.0);
}

// The specular lobe's directional albedo at n.v = ndv, the reference's (env_dfg.glsl, generated
// by math/src/dfg.rs from the reference's lobes): Cook-Torrance as F0 x + y (Schlick), and
// Ashikhmin-Shirley (Schlick too) by the same table at its lobe width; Blinn-Phong, which has no
// Fresnel term, as specular z. (The analytic fit used before, Karis 2014's, was 12 % low for a
// rough metal and gave Blinn-Phong a Fresnel rise: 3.2x too bright at 60 degrees for s = 500.)
vec3 env_specular_albedo(MaterialData m, float ndv) {
    int kind = int(m.albedo_kind.w + 0.5);
    vec3 t = dfg_lookup(ndv, sqrt(env_alpha(m)));
    return kind == 1 ? m.spec_rough.rgb * t.z : m.spec_rough.rgb * t.x + t.y;
}

// The perceptual roughness (sqrt alpha) of the local lights' lobes, clamped to [0.02, 1].
float env_roughness(MaterialData m) {
    return clamp(sqrt(env_alpha(m)), 0.02, 1.0);
}

// The mip level whose box-filtered texels keep a small bright source's highlight at its peak:
// the GGX reflection lobe of alpha peaks at 1 / (4 pi alpha^2) per steradian, so a source's
// energy spread over a texel of 4 pi alpha^2 steradians (about 3.5 alpha radians on a side; a
// level-0 texel spans pi / H radians of latitude) has the highlight's radiance. Measured at
// 120x90 against converged references (RMSE over the mean; balls_on_dish without shadows /
// falling / trace_test / isg_bunny): 3.5 alpha 0.161 / 0.395 / 0.236 / 2.53, 1.3 alpha 0.183 /
// 0.409 / 0.253 / 5.90, 5.2 alpha 0.205 / 0.402 / 0.252 / 1.25; isg_bunny's sun highlight
// dominates its number whatever the level. (The previous lod = roughness x (mips - 1) left
// Cook-Torrance 0.25 about three levels too sharp: 0.192 on the unshadowed dish at 160x120.)
float env_lod(float alpha) {
    float h = float(textureSize(env_map, 0).y);
    return clamp(log2(max(3.5 * alpha * h / PI, 1.0)), 0.0, cam.params.z - 1.0);
}

// Unshadowed environment radiance reflected towards v (unit, towards the eye) at a point of
// normal n with material m (texture maps already applied by material_at): its diffuse and its
// glossy part.
void env_unshadowed_parts(vec3 n, vec3 v, MaterialData m, out vec3 diffuse, out vec3 glossy) {
    diffuse = m.albedo_kind.rgb / PI * sh9_irradiance(cam.sh, n) * cam.params.w;
    glossy = vec3(0.0);
    int kind = int(m.albedo_kind.w + 0.5);
    if (kind != 0) {
        float alpha = env_alpha(m);
        float ndv = max(dot(n, v), 1e-4);
        vec3 r = reflect(-v, n);
        glossy = env_lookup(r, env_lod(alpha)) * env_specular_albedo(m, ndv);
    }
}

vec3 env_unshadowed(vec3 n, vec3 v, MaterialData m) {
    vec3 d, g;
    env_unshadowed_parts(n, v, m, d, g);
    return d + g;
}
