#version 450
// ISG per-vertex shadowing (Iwasaki et al. 2012, section 5): the visibility integrals evaluated
// at the (deformed, world-space) mesh vertices; the raster (isg_vertex.vert/.frag) interpolates
// them and isg_shade_vertex.comp shades per pixel with them. Per vertex:
//   rgb: diffuse visibility, sum_k e_k V_k / sum_k e_k per channel (e_k: unshadowed SG-cosine
//        integral of lighting lobe k, V_k: ISG visible fraction of lobe k times the cosine SG);
//   a:   specular visibility, the light-weighted ISG visible share of G_j (eq. 9) for the vertex's
//        material (isg_lobes.glsl's glossy steps)
//        (base roughness; roughness maps are not applied per vertex) and view direction;
//        Ashikhmin-Shirley with flags bit 6: over its seven SG lobes (sg_as_lobes) in the frame
//        of the vertex's uv tangent, weighted by their BRDF weights' luminance, as per pixel.
#include "common.glsl"
#include "sg.glsl"
#include "brdf_ref.glsl"

layout(local_size_x = 64) in;

layout(set = 0, binding = 0) uniform Camera { CameraData cam; };
layout(set = 0, binding = 1) readonly buffer Materials { MaterialData mats[]; };
// 3 per vertex: world position + material index, world normal + flags (bit 0: two-sided,
// the normal is turned toward the eye; bit 1: skipped, no visible triangle uses it), world
// tangent (zero: none, brdf_frame takes Duff et al.'s basis vector) + 0
// (passes/src/isg/vertex.rs IsgVertex).
layout(set = 0, binding = 2) readonly buffer Verts { vec4 verts[]; };
layout(set = 0, binding = 3) writeonly buffer Out { vec4 vis_out[]; };
layout(set = 0, binding = 4) readonly buffer Lobes { vec4 lobes[]; };
#define ISG_TABLE_BINDING 5
#define ISG_NODES_BINDING 6
#define ISG_TRIS_BINDING 7
#define ISG_TRI_NODES_BINDING 8
#define ISG_MAX_SIDE 32
#include "isg.glsl"

layout(push_constant) uniform Push {
    uint vertex_count;
    uint lobe_count;
    int node_count;
    int tri_node_count;
    int patch_side;
    float lod;
    float min_fraction;
    uint flags;  // bit 4: isg_paper_fit, bit 5: isg_paper_rule (glsl/include/isg.glsl), bit 6: Ashikhmin-Shirley as seven SG lobes
} pc;

float visible(vec3 p, vec3 n, SG g) {
    return isg_visible(p, n, g.axis, g.lambda, pc.node_count, pc.tri_node_count, pc.patch_side, pc.lod);
}
#include "isg_lobes.glsl"

void main() {
    uint vi = gl_GlobalInvocationID.x;
    if (vi >= pc.vertex_count) return;
    isg_paper_fit = (pc.flags & 16u) != 0u;
    isg_paper_rule = (pc.flags & 32u) != 0u;
    vec4 a = verts[3u * vi], b = verts[3u * vi + 1u];
    if ((uint(b.w + 0.5) & 2u) != 0u) {  // no visible triangle uses it
        vis_out[vi] = vec4(1.0);
        return;
    }
    vec3 pos = a.xyz;
    vec3 n = b.xyz;
    float ln = length(n);
    n = ln > 0.0 ? n / ln : vec3(0.0, 1.0, 0.0);
    vec3 v = cam.eye.xyz - pos;
    v = length(v) > 0.0 ? normalize(v) : n;
    if ((uint(b.w + 0.5) & 1u) != 0u && dot(n, v) < 0.0) n = -n;
    MaterialData m = mats[uint(max(a.w, 0.0) + 0.5)];
    int kind = int(m.albedo_kind.w + 0.5);
    float ndv = max(dot(n, v), 1e-4);
    SG cosg = sg_clamped_cosine(n);
    vec3 p = pos + n * 1e-3 * max(1.0, length(pos));
    // The glossy kernels: Ashikhmin-Shirley's seven lobes (flags bit 6), weighted as
    // isg_shade.glsl's per pixel (lobes under 1 % of the total weight left out), or the BRDF's
    // one specular lobe, each times the cosine.
    const vec3 lum = vec3(0.2126, 0.7152, 0.0722);
    bool as7 = kind == 3 && (pc.flags & 64u) != 0u;
    int gcount = kind == 0 ? 0 : (as7 ? SG_AS_LOBES : 1);
    SG g[SG_AS_LOBES];
    vec3 w[SG_AS_LOBES];
    float wsum = 0.0;
    if (as7) {
        sg_as_lobes(brdf_frame(n, verts[3u * vi + 2u].xyz), v, m.extra.x, m.extra.w, m.spec_rough.rgb, g, w);
        for (int j = 0; j < SG_AS_LOBES; ++j) {
            g[j] = sg_product(g[j], cosg);
            wsum += dot(w[j], lum);
        }
    } else if (kind != 0) {
        vec3 r = reflect(-v, n);
        SG gs;
        if (kind == 1) {
            gs = sg_make(r, max(m.extra.x, 0.0) / (4.0 * ndv), 1.0);
        } else {
            float roughness = clamp(m.spec_rough.w, 0.02, 1.0);
            float mb = max(roughness * roughness, 1e-3);
            gs = sg_make(r, 2.0 / (mb * mb) / (4.0 * ndv), 1.0);
        }
        g[0] = sg_product(gs, cosg);
    }
    // Every visibility query through one call of isg_lobes_shadowed (one inlined traversal, as
    // isg_shade.glsl): query 0 the diffuse lobes through the clamped cosine, query 1 + j glossy
    // kernel j in isg_lobes.glsl's two glossy steps (the lighting lobes through it; its own
    // visible fraction when it is sharp or no lighting lobe reaches it).
    vec3 shadowed = vec3(0.0), unshadowed = vec3(0.0);
    float num = 0.0, den = 0.0;
    for (int q = 0; q <= gcount; ++q) {
        float wj = q > 0 && as7 ? dot(w[q - 1], lum) : 1.0;
        if (q > 0 && as7 && !(wj > 0.01 * wsum)) continue;
        SG kernel = q == 0 ? cosg : g[q - 1];
        float open = q > 0 ? isg_glossy_open(pc.lobe_count, kernel) : 0.0, sh = 0.0;
        for (int step = 0; step < 2; ++step) {
            if (q == 0 ? step != 0 : !isg_glossy_step(step, kernel, open)) continue;
            vec3 o;
            vec3 r = isg_lobes_shadowed(p, n, pc.lobe_count, pc.min_fraction, kernel, q == 0, step == 1, o);
            if (q == 0) {
                shadowed = r;
                unshadowed = o;
            } else {
                isg_glossy_fold(step, r, o, sh, open);
            }
        }
        if (q > 0) {
            num += wj * sh;
            den += wj * open;
        }
    }
    vec3 vd = vec3(1.0);
    for (int c = 0; c < 3; ++c) {
        if (unshadowed[c] > 0.0) vd[c] = clamp(shadowed[c] / unshadowed[c], 0.0, 1.0);
    }
    float vs = kind != 0 && den > 0.0 ? clamp(num / den, 0.0, 1.0) : 1.0;
    vis_out[vi] = vec4(vd, vs);
}
