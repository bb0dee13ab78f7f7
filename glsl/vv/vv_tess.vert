#version 450
// vv dynamic tessellation shading, vertex stage: the vertex's radiance under the original and
// the Phong-blurred (alpha 256) lighting (eq. 17 terms; diffuse and specular, eq. 9 and 14), for the control shader's level.
#include "vv_data.glsl"

layout(location = 0) out vec3 v_world;
layout(location = 1) out vec3 v_normal;
layout(location = 3) out float v_delta;
layout(location = 4) out int v_vid;
// the model triangle (the control and evaluation stages' gl_PrimitiveID is not relied on)
layout(location = 6) out int v_tri;
// texture coordinate for the evaluation stage's material
layout(location = 7) out vec2 v_uv;

// The displayed value of a radiance (tonemap.comp: exposure, ACES fit, sRGB transfer), [0, 1].
vec3 vv_display(vec3 c) {
    vec3 x = max(c * cam.env_rot.z, vec3(0.0));
    x = clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
    return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, greaterThan(x, vec3(0.0031308)));
}

void main() {
    int t = gl_VertexIndex / 3, k = gl_VertexIndex % 3;
    int v = vv_tri_vertex(t, k);
    v_world = vv_vert(v, 0);
    v_normal = normalize(vv_vert(v, 1));
    v_vid = v;
    v_tri = t;
    v_uv = vv_vert_uv(v);
    MaterialData m = vv_material(v, v_uv);
    vec3 i0 = vv_eval_vertex(vv_sat_tex, v, v_world, v_normal, m);
    vec3 i1 = vv_eval_vertex(vv_sat_blur, v, v_world, v_normal, m);
    // eq. 17 in the paper's unit, the displayed value in [0, 1] (its radiance values are the
    // pixel values of the images whose PSNR it reports): both radiances through the display
    // mapping, then the luminance of the difference
    v_delta = abs(dot(vv_display(i0) - vv_display(i1), vec3(0.2126, 0.7152, 0.0722)));
    gl_Position = cam.view_proj * vec4(v_world, 1.0);
}
