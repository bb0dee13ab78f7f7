#version 450
// ISG shading with per-vertex visibility (Iwasaki et al. 2012, per-vertex shadowing): the
// visibilities of isg_vertex.comp interpolated by the raster (isg_vertex.vert/.frag); see
// glsl/include/isg_shade.glsl.
#define ISG_PER_VERTEX 1
#include "isg_shade.glsl"
