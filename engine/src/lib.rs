//! penumbra's engine: Vulkan context and memory, resources, the explicit render graph, the
//! executor with per-pass GPU timestamps, profiling and dumps.

pub mod access;
pub mod context;
pub mod dump;
pub mod dump_html;
pub mod exec;
pub mod glsl_compile;
pub mod graph;
pub mod profile;
pub mod record;
pub mod reflect;
pub mod resource;
pub mod shader;

pub use ash;
pub use ash::vk;
pub use context::{Context, ContextDesc, ExternalFeatures, GpuBuffer, GpuImage, TracerStructure, ValidationLog};
pub use exec::{
    Bind, CpuSpan, Engine, FrameOutput, FrameStore, FrameTimeline, GpuInterval, HostSignal, LateReadback, PhysBuffer,
    PhysImage, RecordContext, SubmitSync, DEFAULT_FENCE_TIMEOUT, POOL_KEEP_FRAMES,
};
pub use graph::{Access, BufferHandle, Graph, ImageDesc, ImageHandle, ImportedImage, PassKind};
