#version 450
// vv dynamic tessellation shading: the radiance interpolated from the tessellated vertices.
layout(location = 0) in vec3 e_color;
layout(location = 0) out vec4 o_color;

void main() {
    o_color = vec4(e_color, 1.0);
}
