#version 450
// vv SAT build, pass 2: per corner column, prefix sums down the rows (Kahan compensated).
layout(local_size_x = 64) in;
layout(set = 0, binding = 0, rgba32f) uniform image2D sat;
layout(push_constant) uniform Push { ivec2 size; } pc;

void main() {
    int x = int(gl_GlobalInvocationID.x);
    int W = pc.size.x, H = pc.size.y;
    if (x > W) return;
    for (int k = 0; k < 4; k++) {
        precise vec3 sum = vec3(0.0), comp = vec3(0.0);
        for (int y = 1; y <= H; y++) {
            ivec2 p = ivec2(x, k * (H + 1) + y);
            vec3 v = imageLoad(sat, p).rgb;
            vec3 yk = v - comp;
            precise vec3 t = sum + yk;
            comp = (t - sum) - yk;
            sum = t;
            imageStore(sat, p, vec4(sum, 0.0));
        }
    }
}
