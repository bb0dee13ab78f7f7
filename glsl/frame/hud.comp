#version 450
// The heads-up overlay (`penumbra view`, key H): RGBA8 texels drawn on the CPU
// (passes/src/hud.rs), blended over the tone-mapped image at `origin` by their alpha. Both are
// sRGB-encoded: the blend is a display blend, not a radiance one.

layout(local_size_x = 8, local_size_y = 8) in;
layout(push_constant) uniform Push {
    uvec2 size;   // overlay texels
    uvec2 origin; // where its top-left texel lands in the image
} pc;
layout(set = 0, binding = 0, rgba8) uniform image2D ldr;
layout(set = 0, binding = 1) readonly buffer Overlay { uint texels[]; };

void main() {
    uvec2 q = gl_GlobalInvocationID.xy;
    if (q.x >= pc.size.x || q.y >= pc.size.y) return;
    ivec2 p = ivec2(pc.origin + q);
    ivec2 size = imageSize(ldr);
    if (p.x >= size.x || p.y >= size.y) return;
    vec4 s = unpackUnorm4x8(texels[q.y * pc.size.x + q.x]);
    if (s.a <= 0.0) return;
    vec4 d = imageLoad(ldr, p);
    imageStore(ldr, p, vec4(mix(d.rgb, s.rgb, s.a), 1.0));
}
