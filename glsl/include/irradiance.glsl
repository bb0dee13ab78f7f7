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
    float fx = uv.x * float(w);
    float fy = clamp(uv.y * float(h - 1), 0.0, float(h - 1));
    int x0 = int(floor(fx));
    int y0 = int(floor(fy));
    float ax = fx - float(x0), ay = fy - float(y0);
    int y1 = min(y0 + 1, h - 1);
    x0 -= w * int(floor(float(x0) / float(w)));  // wrap (GLSL % is undefined for negatives)
    x0 = clamp(x0, 0, w - 1);
    int x1 = x0 + 1 == w ? 0 : x0 + 1;
    vec3 a = mix(irr_texel(w, x0, y0), irr_texel(w, x1, y0), ax);
    vec3 b = mix(irr_texel(w, x0, y1), irr_texel(w, x1, y1), ax);
    return mix(a, b, ay) * cam.params.w;
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
