#version 450
// Shadow map from the light (depth only): one face of the spot frustum or of the point
// light's cube (tiles of an atlas, selected by the viewport).
#include "common.glsl"
layout(location = 0) in vec3 in_pos;
layout(set = 0, binding = 0) readonly buffer Instances { InstanceData inst[]; };
layout(push_constant) uniform Push { mat4 face_vp; } pc;
void main() {
    gl_Position = pc.face_vp * (inst[gl_InstanceIndex].model * vec4(in_pos, 1.0));
}
