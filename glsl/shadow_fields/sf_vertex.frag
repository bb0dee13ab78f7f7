#version 450
// Shadow fields, per-vertex display: the interpolated vertex radiance (before the albedo).
layout(location = 0) in vec3 v_radiance;
layout(location = 0) out vec4 out_radiance;

void main() {
    out_radiance = vec4(v_radiance, 1.0);
}
