#version 450
// Test kernel: measures the driver's per-invocation loop limit (llvmpipe/lavapipe in Mesa 22.3
// ends every loop of an invocation once its loops have run 65535 iterations in total). Two loops
// with trip counts from push constants (the compiler cannot unroll or fold them): the first runs
// `first` iterations, the second `second`; each counts the iterations it really ran. A driver
// without a limit reports both counts in full. passes::kernels::loop_probe, tests/engine_probe.rs.
layout(local_size_x = 1) in;

layout(set = 0, binding = 0) writeonly buffer Out { uint counts[]; };

layout(push_constant) uniform Push {
    uint first;
    uint second;
} pc;

void main() {
    uint a = 0u;
    for (uint i = 0u; i < pc.first; ++i) {
        a += 1u;
    }
    uint b = 0u;
    for (uint i = 0u; i < pc.second; ++i) {
        b += 1u;
    }
    counts[0] = a;
    counts[1] = b;
}
