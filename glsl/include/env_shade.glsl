// Unshadowed environment lighting of a surface point (the `env` technique's, shared with the
// shadow-map baseline's ratio estimator): diffuse from the exact irradiance map, glossy by
// filtered importance sampling of the reference BRDF's specular lobe over the mip-filtered
// lat-long environment (env_glossy).
// Needs, declared by the includer: `cam` (CameraData: params.z mip count, params.w intensity,
// env_rot), `cam_dfg` (env_dfg.glsl) and `cam_irr` (the 32 x 16 irradiance map after it in the
// camera buffer: `uniform Camera { CameraData cam; vec4 cam_dfg[768]; vec4 cam_irr[512]; }`),
// `env_map` (sampler2D, the mip-filtered lat-long environment), and common.glsl (PI,
// dir_to_latlong, latlong_taps, MaterialData).

#include "env_dfg.glsl"
#include "env_background.glsl"
#include "brdf_ref.glsl"

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

// Number of lobe samples of env_glossy (a fixed Hammersley set: the same directions at every
// pixel, so the estimate is smooth, not noisy), by the lobe's GGX alpha. Measured on three spheres
// under sunset-dwab.exr (GGX roughness 0.7 and Blinn-Phong 40, patches against a converged
// reference, the lowest and highest channel ratio): 16 samples 0.79-1.02 with a whole level of
// blur, 0.85-0.98 with none; 32 samples 0.81-0.98 with a whole level, 0.86-0.99 with half (kept);
// 64 0.88-1.01; 256 0.97-1.01; the split sum this replaces, 0.57-1.14. Sharp lobes take more: the
// level of a sample's lookup comes down to the texels of a small bright source (studio.exr's key
// light), which 32 fixed directions then alias. isg_bunny (Blinn-Phong 1000, alpha 0.045) at
// 40x30, unshadowed against its converged reference: rmse/mean 0.097 with 32 samples (one
// highlight pixel 4.5 % low carries 88 % of the squared error), 0.030 with 128; every technique's
// shadowed cell there 0.123-0.130 -> 0.052-0.058. Broad lobes keep 32 (their lookups are blurred
// over many texels: the other scenes' env cells moved by under 0.003 with 128).
int env_glossy_samples(float alpha) {
    return alpha < 0.1 ? 128 : (alpha < 0.2 ? 64 : 32);
}

// The glossy part of the environment's reflected radiance towards v (unit, towards the eye) at a
// point of normal n, the reference BRDF's specular lobe (brdf_ref.glsl) integrated against the
// environment by filtered importance sampling (Krivanek and Colbert 2008): env_glossy_samples
// directions drawn from the lobe, each looked up in the (solid-angle weighted) mip chain at the
// level whose texels cover its share of the lobe's solid angle, half a level blurrier (GPU Gems 3
// ch. 20 adds a whole level; half kept more of a bright sun's energy in the lobe). Unlike a split
// sum (one lookup along the mirror direction times the lobe's albedo) it follows the lobe's
// stretch and its cut at the horizon at grazing angles. In the reference's shading frame of n and
// the tangent t (the G-buffer's; brdf_frame), so that Ashikhmin-Shirley's anisotropy runs along
// it; a caller without a tangent passes vec3(0.0), and Ashikhmin-Shirley is then taken as
// isotropic at the geometric mean of its exponents (vv's surfaces). Before the tangent reached
// it every technique drew that isotropic lobe (chess's ebony pieces: nu 5 times nv).
vec3 env_glossy(vec3 n, vec3 t, vec3 v, MaterialData m) {
    Brdf b = brdf_from_material(m);
    if (b.kind == 0u) return vec3(0.0);
    if (b.kind == 3u && dot(t, t) == 0.0) { b.nu = sqrt(b.nu * b.nv); b.nv = b.nu; }
    b.p_spec = 1.0;
    b.albedo = vec3(0.0);
    // Isotropic lobes keep a frame that varies smoothly with n alone: the fixed sample set turns
    // with the frame, and a uv tangent would turn it at every uv seam (the estimate jumping
    // there); only Ashikhmin-Shirley needs the tangent.
    vec3 tx, ty;
    if (b.kind == 3u && dot(t, t) > 0.0) {
        mat3 frame = brdf_frame(n, t);
        tx = frame[0];
        ty = frame[1];
    } else {
        vec3 ta = abs(n.x) > 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
        tx = normalize(cross(ta, n));
        ty = cross(n, tx);
    }
    vec3 wo = vec3(dot(v, tx), dot(v, ty), dot(v, n));
    if (wo.z <= 0.0) wo = normalize(vec3(wo.xy, 1e-4));
    vec2 size = vec2(textureSize(env_map, 0));
    // solid angle of a level-0 texel at the equator
    float texel = (2.0 * PI / size.x) * (PI / size.y);
    vec3 sum = vec3(0.0);
    int count = env_glossy_samples(env_alpha(m));
    for (int i = 0; i < count; ++i) {
        vec2 u = vec2((float(i) + 0.5) / float(count), float(bitfieldReverse(uint(i))) * 2.3283064365386963e-10);
        vec3 wi;
        if (!brdf_sample(b, wo, 0.0, u, wi)) continue;
        float pdf = brdf_pdf(b, wo, wi);
        if (!(pdf > 0.0)) continue;
        vec3 f = brdf_eval(b, wo, wi);
        float lod = max(0.5 * log2(1.0 / (float(count) * pdf * texel)) + 0.5, 0.0);
        vec3 d = tx * wi.x + ty * wi.y + n * wi.z;
        sum += f * (wi.z / pdf) * env_lookup(d, min(lod, cam.params.z - 1.0));
    }
    return sum / float(count);
}

// The environment's irradiance at normal n (intensity applied) from `cam_irr`,
// passes::lighting::camera_irradiance: the exact cosine convolution on 32 x 16 directions (rows
// from pole to pole at v = j / 15, columns at u = i / 32), bilinear. (The 9-coefficient SH used
// before rings under a small bright source: on studio.exr, whose brightest texel is 1466 times its
// mean, SH9 gave 0.2 to 6.2 times the exact irradiance over random normals, 25 % off on average.)
vec3 cam_irr_texel(int x, int y) {
    return cam_irr[y * 32 + x].rgb;
}

vec3 env_irradiance(vec3 n) {
    vec2 uv = dir_to_latlong(normalize(n), cam.env_rot.xy);
    vec2 f;
    ivec4 t = latlong_taps(uv.x * 32.0, uv.y * 15.0, 32, 16, f);
    vec3 a = mix(cam_irr_texel(t.x, t.z), cam_irr_texel(t.y, t.z), f.x);
    vec3 b = mix(cam_irr_texel(t.x, t.w), cam_irr_texel(t.y, t.w), f.x);
    return mix(a, b, f.y) * cam.params.w;
}

// Unshadowed environment radiance reflected towards v (unit, towards the eye) at a point of
// normal n and tangent t (env_glossy) with material m (texture maps already applied by
// material_at): its diffuse and its glossy part.
void env_unshadowed_parts(vec3 n, vec3 t, vec3 v, MaterialData m, out vec3 diffuse, out vec3 glossy) {
    diffuse = material_diffuse_albedo(m, dot(n, v)) / PI * env_irradiance(n);
    glossy = vec3(0.0);
    int kind = int(m.albedo_kind.w + 0.5);
    if (kind != 0) glossy = env_glossy(n, t, v, m);
}

vec3 env_unshadowed(vec3 n, vec3 t, vec3 v, MaterialData m) {
    vec3 d, g;
    env_unshadowed_parts(n, t, v, m, d, g);
    return d + g;
}
