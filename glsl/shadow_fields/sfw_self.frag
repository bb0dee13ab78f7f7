#version 450
// All-frequency shadow fields, self-occlusion display: the interpolated per-vertex values.
layout(location = 0) in vec4 v_share;
layout(location = 1) in vec4 v_lights;
layout(location = 0) out vec4 out_share;
layout(location = 1) out vec4 out_lights;

void main() {
    out_share = v_share;
    out_lights = v_lights;
}
