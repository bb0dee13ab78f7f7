#version 460
// Fig. 7 baseline of the avs technique: one hemicube face of one sample point, depth only.
layout(location = 0) in vec3 position;
layout(push_constant) uniform Push { mat4 view_proj; } pc;
void main() { gl_Position = pc.view_proj * vec4(position, 1.0); }
