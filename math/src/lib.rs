//! Spherical math shared by penumbra's techniques and the CPU reference renderer.
//! Pure CPU code, no Vulkan: it builds and tests fast.
