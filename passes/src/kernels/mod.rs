//! GPU test kernels: shaders that evaluate a technique's GLSL building blocks on given inputs so
//! that tests (and `penumbra bench hsdt`) can compare them with their CPU twins in `math`. No
//! technique uses them; they live apart from the production passes (shaders in `glsl/tests/`).

pub mod hsdt;
pub mod isg;
pub mod loop_probe;
pub mod qmc;
pub mod vv;
