#version 450
// L = L_s exp(-sigma_t d_s) + L_scatter (eq. 1): attenuates the technique's surface radiance
// along the view ray and adds the in-scattered radiance. Background pixels (no surface) see
// nothing through a medium with sigma_t > 0 (the reference's infinite-medium convention).
#include "vol.glsl"
layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Light { VolLight L; };
layout(set = 0, binding = 2) uniform sampler2D g_position;
layout(set = 0, binding = 3) uniform sampler2D hdr_in;
layout(set = 0, binding = 4) uniform sampler2D scatter;
layout(set = 0, binding = 5, rgba32f) uniform writeonly image2D hdr_out;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(cam.params.xy);
    if (p.x >= size.x || p.y >= size.y) return;
    vec4 gp = texelFetch(g_position, p, 0);
    vec3 st = L.sigma_t_g.rgb;
    vec3 tr;
    if (gp.w > 0.0) {
        tr = exp(-st * length(gp.xyz - cam.eye.xyz));
    } else {
        tr = vec3(st.r > 0.0 ? 0.0 : 1.0, st.g > 0.0 ? 0.0 : 1.0, st.b > 0.0 ? 0.0 : 1.0);
    }
    vec4 c = texelFetch(hdr_in, p, 0);
    vec3 s = texelFetch(scatter, p, 0).rgb;
    imageStore(hdr_out, p, vec4(c.rgb * tr + s, c.a));
}
