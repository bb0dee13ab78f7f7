// Hemispherical visibility maps and SSDFs of the adaptive-visibility-sampling technique (issue 8).
// Mirror of math/src/avs_maps.rs (read its module docs for the full description); same formulas in f32.
//
// Local frame: z = normal n, x = tangent t (the map's pole axis), y = bitangent b = n x t.
//   w(theta, phi) = (cos theta, sin theta cos phi, sin theta sin phi),   theta, phi in [0, pi]
// theta = polar angle from the tangent +x (rows, "latitudes" = circles around x),
// phi = azimuth around x from +y (phi = 0) through the normal +z (pi/2) to -y (pi) (columns).
// The rectangle [0,pi]^2 is exactly the upper hemisphere; normal = map centre (pi/2, pi/2).
// Poles theta = 0 (+x) and theta = pi (-x) lie on the horizon. phi = 0 and phi = pi are the two
// horizon halves: NOT adjacent, the map does not wrap in phi. Texel (i, j) (row i = theta, column
// j = phi) has centre ((i + 0.5) pi / r, (j + 0.5) pi / r), always strictly above the horizon.
//
// Visibility bits: map p = words [p * r*r/32, (p+1) * r*r/32); texel (i, j) = bit k = i*r + j,
// word k / 32, bit k % 32 (LSB first); 1 = visible (unoccluded), 0 = occluded.
// SSDF: r*r fp16 per map (packHalf2x16), map p = words [p * r*r/2, ...); texel k = i*r + j is
// word k / 2, low half for even k. Value: signed angular distance in radians between texel centres
// (+ visible: distance to the nearest occluded centre; - occluded: to the nearest visible centre;
// +-pi when the map has no boundary).
#ifndef PENUMBRA_AVS_MAPS_GLSL
#define PENUMBRA_AVS_MAPS_GLSL

#define AVS_PI 3.14159265358979323846
#define AVS_NO_BOUNDARY 3.14159265358979323846

// Accurate f32 sin on [-pi, pi] and asin on [-1, 1] (Vulkan only guarantees 2^-11 absolute for
// sin and leaves asin loose; lavapipe's asin is off by ~1e-3): odd Taylor polynomial to x^11 after
// folding to [-pi/2, pi/2] (error < 6e-8), Cephes asinf (~2.5e-7 relative).
float avs_sin(float x) {
    x = x > 0.5 * float(AVS_PI) ? float(AVS_PI) - x : (x < -0.5 * float(AVS_PI) ? -float(AVS_PI) - x : x);
    float z = x * x;
    return x * (1.0 + z * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0 + z * (1.0 / 362880.0 + z * (-1.0 / 39916800.0))))));
}
float avs_asin(float x) {
    float a = abs(x);
    float r;
    if (a > 0.5) {
        float z = 0.5 * (1.0 - a);
        float s = sqrt(z);
        float p = (((4.2163199048e-2 * z + 2.4181311049e-2) * z + 4.5470025998e-2) * z + 7.4953002686e-2) * z + 1.6666752422e-1;
        r = 0.5 * float(AVS_PI) - 2.0 * (s + s * z * p);
    } else {
        float z = a * a;
        float p = (((4.2163199048e-2 * z + 2.4181311049e-2) * z + 4.5470025998e-2) * z + 7.4953002686e-2) * z + 1.6666752422e-1;
        r = a + a * z * p;
    }
    return x < 0.0 ? -r : r;
}

// Accurate f32 atan2(y, x) for y >= 0 (in [0, pi], ~1e-7 rad): Cephes atanf on a ratio <= 1.
float avs_atan2_upper(float y, float x) {
    float ax = abs(x);
    bool swap = y > ax;
    float t = swap ? ax / y : y / max(ax, 1e-37);
    float base = 0.0;
    if (t > 0.41421356) {
        base = 0.25 * float(AVS_PI);
        t = (t - 1.0) / (t + 1.0);
    }
    float z = t * t;
    float a = base + ((((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * t + t);
    a = swap ? 0.5 * float(AVS_PI) - a : a;
    return x < 0.0 ? float(AVS_PI) - a : a;
}

uint avs_words_per_map(uint r) { return r * r / 32u; }
uint avs_ssdf_words_per_map(uint r) { return r * r / 2u; }
float avs_texel_angle(uint r) { return float(AVS_PI) / float(r); }
float avs_texel_theta(uint i, uint r) { return (float(i) + 0.5) * (float(AVS_PI) / float(r)); }
float avs_texel_phi(uint j, uint r) { return (float(j) + 0.5) * (float(AVS_PI) / float(r)); }

vec3 avs_angles_to_local(float theta, float phi) {
    float st = sin(theta);
    return vec3(cos(theta), st * cos(phi), st * sin(phi));
}

// Texel centre direction in the local frame (row i = theta, column j = phi).
vec3 avs_texel_dir(uint i, uint j, uint r) {
    float h = float(AVS_PI) / float(r);
    return avs_angles_to_local((float(i) + 0.5) * h, (float(j) + 0.5) * h);
}

// (theta, phi) of a unit local direction; only meaningful for w.z >= 0.
vec2 avs_local_to_angles(vec3 w) {
    return vec2(acos(clamp(w.x, -1.0, 1.0)), atan(w.z > 0.0 ? w.z : 0.0, w.y));
}

// Texel containing a unit local direction; returns false below the horizon (w.z < 0).
// Directions on texel edges go to the higher index, clamped to r - 1.
bool avs_dir_to_texel(vec3 w, uint r, out uvec2 ij) {
    ij = uvec2(0u);
    if (w.z < 0.0) return false;
    vec2 tp = avs_local_to_angles(w) * (float(r) / float(AVS_PI));
    ij = uvec2(clamp(ivec2(tp), ivec2(0), ivec2(int(r) - 1)));
    return true;
}

// Solid angle of a texel of row i (steradians).
float avs_texel_solid_angle(uint i, uint r) {
    float h = float(AVS_PI) / float(r);
    return 2.0 * sin((float(i) + 0.5) * h) * sin(0.5 * h) * h;
}

// Great-circle distance between (theta1, phi1) and (theta2, phi2) (haversine form).
float avs_angular_distance(vec2 a, vec2 b) {
    // h = sin^2(d/2) and c = cos^2(d/2) = 1 - h, each without cancellation where it is small, so
    // both tiny and near-pi distances keep full f32 accuracy
    float x = 0.5 * (a.x - b.x);
    float s1 = avs_sin(x);
    float c1 = avs_sin(0.5 * float(AVS_PI) - abs(x));
    float s2 = avs_sin(0.5 * (a.y - b.y));
    float w = avs_sin(a.x) * avs_sin(b.x) * s2 * s2;
    float h = s1 * s1 + w;
    float c = c1 * c1 - w;
    return h <= 0.5 ? 2.0 * avs_asin(sqrt(clamp(h, 0.0, 1.0)))
                    : float(AVS_PI) - 2.0 * avs_asin(sqrt(clamp(c, 0.0, 1.0)));
}

// Local frame from the normal alone (Duff et al. 2017), same as Frame::from_normal:
// columns t (x, pole axis), b (y), n (z). world = m * local, local = transpose(m) * world.
mat3 avs_frame(vec3 n) {
    n = normalize(n);
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float bb = n.x * n.y * a;
    vec3 t = vec3(1.0 + s * n.x * n.x * a, s * bb, -s * n.x);
    return mat3(t, cross(n, t), n);
}

// Frame whose tangent is `hint` orthogonalized against n (Frame::from_normal_hint).
mat3 avs_frame_hint(vec3 n, vec3 hint) {
    n = normalize(n);
    vec3 t = hint - n * dot(n, hint);
    float l = length(t);
    if (!(l > 1e-4 * max(length(hint), 1e-30))) return avs_frame(n);
    t /= l;
    return mat3(t, cross(n, t), n);
}

// Bit test on a packed map stored in any uint array: use the macro with the array name,
// e.g. AVS_VIS_BIT(vis_words, map_base_word, i * r + j).
#define AVS_VIS_BIT(arr, base, k) (((arr[(base) + ((k) >> 5u)] >> ((k) & 31u)) & 1u) == 1u)
// fp16 SSDF fetch from a uint array: AVS_SSDF(arr, base_word, k).
#define AVS_SSDF(arr, base, k) (((k) & 1u) == 0u ? unpackHalf2x16(arr[(base) + ((k) >> 1u)]).x : unpackHalf2x16(arr[(base) + ((k) >> 1u)]).y)

#endif
