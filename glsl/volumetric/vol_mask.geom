#version 450
// Mover mask: the triangle itself, and the boundary of its shadow volume with respect to the
// light: side quads extruded to infinity from silhouette edges (the triangle faces the light,
// its neighbour across the edge does not; open edges carry the triangle's own opposite vertex,
// i.e. count as silhouettes) and the back cap at infinity for triangles facing away. Clip z
// is an infinite-far projection (near plane kept) so nothing is lost to the far plane.
#include "common.glsl"
layout(triangles_adjacency) in;
layout(triangle_strip, max_vertices = 18) out;
layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(push_constant) uniform Push { vec4 light_pos; uint use_prev; } pc;
layout(location = 0) in vec3 v_world[];

vec4 clip_of(vec4 hp) {
    vec4 c = cam.view_proj * hp;
    c.z = 0.5 * (c.w - pc.light_pos.w * hp.w);  // light_pos.w carries the camera near plane
    return c;
}

bool faces(vec3 a, vec3 b, vec3 c) {
    vec3 n = cross(b - a, c - a);
    return dot(n, pc.light_pos.xyz - a) > 0.0;
}

void emit(vec4 hp) {
    gl_Position = clip_of(hp);
    EmitVertex();
}

void main() {
    vec3 p0 = v_world[0], p2 = v_world[2], p4 = v_world[4];
    vec3 lp = pc.light_pos.xyz;
    emit(vec4(p0, 1.0)); emit(vec4(p2, 1.0)); emit(vec4(p4, 1.0));
    EndPrimitive();
    bool f = faces(p0, p2, p4);
    if (!f) {
        emit(vec4(p0 - lp, 0.0)); emit(vec4(p2 - lp, 0.0)); emit(vec4(p4 - lp, 0.0));
        EndPrimitive();
        return;
    }
    for (int e = 0; e < 3; ++e) {
        vec3 a = v_world[2 * e], adj = v_world[2 * e + 1], b = v_world[(2 * e + 2) % 6];
        if (faces(a, adj, b)) continue;
        emit(vec4(a, 1.0)); emit(vec4(b, 1.0)); emit(vec4(a - lp, 0.0)); emit(vec4(b - lp, 0.0));
        EndPrimitive();
    }
}
