// The SG-prefiltered environment in a float buffer (passes::lighting::prefiltered_env,
// penumbra_math::envmap::prefilter): `pf[0]` level count, per level i at 1 + 4 i: lambda, width,
// height, offset of its RGB texels. Needs, declared by the includer: `pf[]`, `cam` (CameraData:
// env_rot, params.w intensity) and common.glsl. Shared by avs_shade.comp and isg_shade.glsl.
#ifndef PENUMBRA_PREFILTERED_GLSL
#define PENUMBRA_PREFILTERED_GLSL

vec3 pf_texel(int off, int w, int x, int y) {
    int i = off + 3 * (y * w + x);
    return vec3(pf[i], pf[i + 1], pf[i + 2]);
}

vec3 pf_level(int l, vec2 uv) {
    int w = int(pf[2 + 4 * l] + 0.5), h = int(pf[3 + 4 * l] + 0.5), off = int(pf[4 + 4 * l] + 0.5);
    vec2 f;
    ivec4 t = latlong_taps(uv.x * float(w) - 0.5, uv.y * float(h) - 0.5, w, h, f);
    vec3 a = mix(pf_texel(off, w, t.x, t.z), pf_texel(off, w, t.y, t.z), f.x);
    vec3 b = mix(pf_texel(off, w, t.x, t.w), pf_texel(off, w, t.y, t.w), f.x);
    return mix(a, b, f.y);
}

// Normalised Gamma_L(dir, lambda): the environment convolved with a unit-integral SG, linear
// in log(lambda) between the prefiltered levels (clamped at the ends).
vec3 pf_eval(vec3 dir, float lambda) {
    int levels = int(pf[0] + 0.5);
    if (levels <= 0) return vec3(0.0);
    vec2 uv = dir_to_latlong(dir, cam.env_rot.xy);
    float ll = log(max(lambda, 1e-6));
    int l = 0;
    while (l + 1 < levels && log(pf[1 + 4 * (l + 1)]) <= ll) ++l;
    if (l + 1 >= levels) return pf_level(levels - 1, uv) * cam.params.w;
    float l0 = log(pf[1 + 4 * l]), l1 = log(pf[1 + 4 * (l + 1)]);
    float t = clamp((ll - l0) / max(l1 - l0, 1e-6), 0.0, 1.0);
    return mix(pf_level(l, uv), pf_level(l + 1, uv), t) * cam.params.w;
}

#endif
