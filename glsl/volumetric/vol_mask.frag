#version 450
// Mover mask: no colour; the pipeline's stencil state marks every covered pixel (REPLACE 1,
// no depth test, as the thesis builds its mask).
void main() {}
