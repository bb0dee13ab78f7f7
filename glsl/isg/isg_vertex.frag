#version 450
// ISG per-vertex mode: the interpolated visibilities (see isg_vertex.vert).
layout(location = 0) in vec4 v_vis;
layout(location = 0) out vec4 o_vis;

void main() {
    o_vis = v_vis;
}
