#version 450
// vv SAT build, pass 1: per row, the exact cell moments (x, y, z of l dω, and dω: 4 channel
// blocks of H + 1 rows) times the texel radiance, prefix-summed along the row with Kahan compensation (fp32). Row 0 and column 0 of
// the corner image are zero.
#include "common.glsl"

layout(local_size_x = 64) in;
layout(set = 0, binding = 0) readonly buffer Texels { vec4 texels[]; };
layout(set = 0, binding = 1, rgba32f) uniform writeonly image2D sat;
layout(push_constant) uniform Push { ivec2 size; } pc;

void main() {
    int y = int(gl_GlobalInvocationID.x);
    int W = pc.size.x, H = pc.size.y;
    if (y > H) return;
    if (y == 0) {
        for (int x = 0; x <= W; x++)
            for (int k = 0; k < 4; k++) imageStore(sat, ivec2(x, k * (H + 1)), vec4(0.0));
        return;
    }
    int row = y - 1;
    float t0 = PI * float(row) / float(H), t1 = PI * float(row + 1) / float(H);
    float tt = (t1 * 0.5 - sin(2.0 * t1) * 0.25) - (t0 * 0.5 - sin(2.0 * t0) * 0.25);
    float ty = (sin(t1) * sin(t1) - sin(t0) * sin(t0)) * 0.5;
    float tone = cos(t0) - cos(t1);
    precise vec3 sum[4], comp[4];
    for (int k = 0; k < 4; k++) {
        sum[k] = vec3(0.0);
        comp[k] = vec3(0.0);
        imageStore(sat, ivec2(0, k * (H + 1) + y), vec4(0.0));
    }
    float dp = 2.0 * PI / float(W);
    for (int x = 0; x < W; x++) {
        vec3 c = max(texels[row * W + x].rgb, vec3(0.0));
        float p0 = dp * float(x), p1 = dp * float(x + 1);
        float mx = tt * (cos(p0) - cos(p1));
        float my = ty * dp;
        float mz = -tt * (sin(p1) - sin(p0));
        vec3 v[4] = vec3[4](c * mx, c * my, c * mz, c * (tone * dp));
        for (int k = 0; k < 4; k++) {
            // Kahan summation
            vec3 yk = v[k] - comp[k];
            precise vec3 t = sum[k] + yk;
            comp[k] = (t - sum[k]) - yk;
            sum[k] = t;
            imageStore(sat, ivec2(x + 1, k * (H + 1) + y), vec4(sum[k], 0.0));
        }
    }
}
