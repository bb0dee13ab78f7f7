#version 450
// Hybrid (Wyman and Ramsey): distance along the view ray of every shadow-volume boundary
// fragment; blending keeps the front-most (rgb, MIN) and the back-most (a, MAX) per pixel.
// The geometry shader (vol_mask.geom) uses an infinite-far clip z = 0.5 (w - near), so the
// view depth is near / (1 - 2 z).
#include "common.glsl"
layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(push_constant) uniform Push { vec4 light_pos; uint use_prev; float widen; } pc;
layout(location = 0) out vec4 o_dist;
void main() {
    float n = pc.light_pos.w;
    vec2 ndc = gl_FragCoord.xy / cam.params.xy * 2.0 - 1.0;
    vec4 a = cam.inv_view_proj * vec4(ndc, 0.0, 1.0);
    float at_near = length(a.xyz / a.w - cam.eye.xyz);  // distance to the near plane along the ray
    float depth_view = n / max(1.0 - 2.0 * gl_FragCoord.z, 1e-7);
    float t = at_near * depth_view / n;
    o_dist = vec4(t, t, t, t);
}
