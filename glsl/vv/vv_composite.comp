#version 450
// vv: the shaded objects (alpha 1 where drawn) over the env technique's image (background,
// objects the vv data does not cover).
layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0) uniform sampler2D base;
layout(set = 0, binding = 1) uniform sampler2D objects;
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D hdr;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(hdr);
    if (p.x >= size.x || p.y >= size.y) return;
    vec4 o = texelFetch(objects, p, 0);
    imageStore(hdr, p, o.a > 0.5 ? vec4(o.rgb, 1.0) : vec4(texelFetch(base, p, 0).rgb, 1.0));
}
