#version 450
// Mover mask: the triangle itself, and the boundary of its shadow volume with respect to the
// light: side quads extruded to infinity from silhouette edges (the triangle faces the light,
// its neighbour across the edge does not; open edges carry the triangle's own opposite vertex,
// i.e. count as silhouettes) and the back cap at infinity for triangles facing away. Clip z
// is an infinite-far projection (near plane kept) so nothing is lost to the far plane.
// Each side is pushed away from the volume by `widen` radians as seen from the light (1.5
// shadow-map texels: the march's nearest-texel visibility moves the shadow boundary by up to
// 0.71 texel); the exact side and the sliver between the silhouette edge and the pushed side
// are drawn too, so both volumes stay closed: every pixel whose samples' shadow-map lookups can
// change is covered, also from an eye inside a volume.
#include "common.glsl"
layout(triangles_adjacency) in;
layout(triangle_strip, max_vertices = 27) out;
layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(push_constant) uniform Push { vec4 light_pos; uint use_prev; float widen; } pc;
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
        // Outward normal of the plane through the light and the edge (away from the triangle's
        // third vertex).
        vec3 c = v_world[(2 * e + 4) % 6];
        vec3 n = cross(a - lp, b - lp);
        float nl = length(n);
        vec3 o = nl > 0.0 ? n / nl : vec3(0.0);
        if (dot(o, c - a) > 0.0) o = -o;
        vec3 a2 = a + o * (pc.widen * length(a - lp));
        vec3 b2 = b + o * (pc.widen * length(b - lp));
        // One strip: the exact side (closes the volume with the caps, for an eye inside it),
        // the sliver at the silhouette, the pushed side.
        emit(vec4(a - lp, 0.0)); emit(vec4(b - lp, 0.0));
        emit(vec4(a, 1.0)); emit(vec4(b, 1.0)); emit(vec4(a2, 1.0)); emit(vec4(b2, 1.0));
        emit(vec4(a2 - lp, 0.0)); emit(vec4(b2 - lp, 0.0));
        EndPrimitive();
    }
}
