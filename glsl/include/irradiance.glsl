// The environment's diffuse irradiance from the lat-long map of passes::lighting::irradiance_env
// (exact cosine convolution, 64 x 32 directions: rows from pole to pole at v = j / (h - 1), columns
// at u = i / w; bilinear, wrapping in longitude). Needs, declared by the
// includer: `irr[]` (float buffer: width, height, then RGB texels), `cam` (CameraData: env_rot,
// params.w intensity) and common.glsl (dir_to_latlong).
#ifndef PENUMBRA_IRRADIANCE_GLSL
#define PENUMBRA_IRRADIANCE_GLSL

vec3 irr_texel(int w, int x, int y) {
    int i = 2 + 3 * (y * w + x);
    return vec3(irr[i], irr[i + 1], irr[i + 2]);
}

// E(n) = int L(w) max(0, n.w) dw, intensity applied; 0 without an environment.
vec3 irr_eval(vec3 n) {
    int w = int(irr[0] + 0.5), h = int(irr[1] + 0.5);
    if (w <= 0 || h <= 0) return vec3(0.0);
    vec2 uv = dir_to_latlong(normalize(n), cam.env_rot.xy);
    vec2 f;
    ivec4 t = latlong_taps(uv.x * float(w), uv.y * float(h - 1), w, h, f);
    vec3 a = mix(irr_texel(w, t.x, t.z), irr_texel(w, t.y, t.z), f.x);
    vec3 b = mix(irr_texel(w, t.x, t.w), irr_texel(w, t.y, t.w), f.x);
    return mix(a, b, f.y) * cam.params.w;
}

// The ratio estimator of the SG techniques' diffuse term: the map's irradiance at n times the
// visible share of the SG lobes' irradiance (shadowed / unshadowed, per channel; 1 where the
// lobes carry nothing), so the SG fit's error leaves the unshadowed term.
vec3 irr_ratio(vec3 n, vec3 shadowed, vec3 unshadowed) {
    vec3 share = vec3(1.0);
    for (int c = 0; c < 3; ++c)
        if (unshadowed[c] > 1e-12) share[c] = clamp(shadowed[c] / unshadowed[c], 0.0, 1.0);
    return irr_eval(n) * share;
}

#endif
