// Directional albedo of the reference's specular lobes (penumbra_math::dfg, generated from the
// reference's BRDFs and checked against them): 32 x 32 entries over (n.v, r = sqrt(alpha)), each
// x, y: Cook-Torrance (GGX, separable Smith G, Schlick F) as F0 x + y; z: normalized Blinn-Phong.
// Read from the camera uniform block, after the frame constants: the includer declares
// `uniform Camera { CameraData cam; vec4 cam_dfg[768]; }` (the 3072 floats back to back; a
// GLSL constant array of this size costs lavapipe over a minute per shader to compile).

const int DFG_N = 32;

float dfg_float(int k) { return cam_dfg[k >> 2][k & 3]; }

vec3 dfg_entry(int e) {
    int k = 3 * e;
    return vec3(dfg_float(k), dfg_float(k + 1), dfg_float(k + 2));
}

// The table at n.v = ndv, roughness r (both clamped to [0, 1]), bilinear.
vec3 dfg_lookup(float ndv, float r) {
    vec2 p = clamp(vec2(ndv, r), 0.0, 1.0) * float(DFG_N - 1);
    ivec2 i0 = min(ivec2(p), ivec2(DFG_N - 2));
    vec2 f = p - vec2(i0);
    int k = i0.y * DFG_N + i0.x;
    vec3 a = mix(dfg_entry(k), dfg_entry(k + 1), f.x);
    vec3 b = mix(dfg_entry(k + DFG_N), dfg_entry(k + DFG_N + 1), f.x);
    return mix(a, b, f.y);
}
