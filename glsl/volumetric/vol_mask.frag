#version 450
// Mover mask: marks covered pixels.
layout(location = 0) out vec4 o_mask;
void main() { o_mask = vec4(1.0); }
