#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_shader_viewport_layer_array : require
// Shadow-map baseline, depth maps: every shadow map is one layer of a D32 2D-array image,
// rasterized in one pass (the papers' baselines rasterize): each draw of a mesh instance is
// instanced once per layer, the vertex shader transforms by that layer's view-projection and
// routes the triangle with gl_Layer (Vulkan 1.2 shaderOutputLayer). Depth only: no fragment
// shader. Layers: the K environment directions (orthographic over the scene's bounding sphere),
// then 6 cube faces per local light (perspective, 90 degrees); the two groups are two images
// (their resolutions differ), each rasterized by its own pass: layer first_layer + instance of
// the table goes to the image's layer `instance`.
#include "common.glsl"

layout(location = 0) in vec3 in_pos;
layout(set = 0, binding = 0) readonly buffer Instances { InstanceData inst[]; };
// per layer: view-projection (4 columns), (kind 0 ortho / 1 perspective, near, far, texel size)
layout(set = 0, binding = 1) readonly buffer Layers { vec4 layers[]; };
layout(push_constant) uniform Push {
    uint instance;
    uint first_layer;
} pc;

void main() {
    uint l = pc.first_layer + uint(gl_InstanceIndex);
    mat4 vp = mat4(layers[5u * l], layers[5u * l + 1u], layers[5u * l + 2u], layers[5u * l + 3u]);
    gl_Position = vp * (inst[pc.instance].model * vec4(in_pos, 1.0));
    gl_Layer = gl_InstanceIndex;
}
