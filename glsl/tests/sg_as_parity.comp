#version 450
// Test kernel: sg_as_lobes (glsl/include/sg.glsl, Ashikhmin-Shirley's seven SG lobes) in the
// frame brdf_frame (glsl/include/brdf_ref.glsl) for a list of queries, compared with
// penumbra_math::brdf::AshikhminShirley::sg7_hermite on the CPU (passes/src/kernels/isg.rs
// gpu_as_lobes, tests/isg.rs).
layout(local_size_x = 64) in;
#include "sg.glsl"
#include "brdf_ref.glsl"

// 4 per query: normal, tangent, direction to the eye, (nu, nv, f0, 0)
layout(set = 0, binding = 0) readonly buffer Queries { vec4 q[]; };
// 14 per query: per lobe (axis, lambda), (rgb weight, 0)
layout(set = 0, binding = 1) writeonly buffer Out { vec4 lobes_out[]; };

layout(push_constant) uniform Push { uint count; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    vec4 e = q[4u * i + 3u];
    SG g[SG_AS_LOBES];
    vec3 w[SG_AS_LOBES];
    sg_as_lobes(brdf_frame(q[4u * i].xyz, q[4u * i + 1u].xyz), q[4u * i + 2u].xyz, e.x, e.y, vec3(e.z), g, w);
    for (int k = 0; k < SG_AS_LOBES; ++k) {
        lobes_out[14u * i + 2u * uint(k)] = vec4(g[k].axis, g[k].lambda);
        lobes_out[14u * i + 2u * uint(k) + 1u] = vec4(w[k], 0.0);
    }
}
