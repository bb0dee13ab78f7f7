//! The executor: allocates a compiled graph's resources (transients from a pool reused across
//! frames, persistent resources kept by name, imported ones as given), records every live pass
//! between timestamp queries and a debug label with its barriers in one `vkCmdPipelineBarrier2`,
//! submits, and collects results (readbacks, timings) when the frame's fence has signalled,
//! without stalling the frames still in flight.

use crate::context::{Context, GpuBuffer, GpuImage};
use crate::graph::compile::{Barrier, CompiledGraph, ResourceState};
use crate::graph::{BufferHandle, External, Graph, ImageDesc, ImageHandle, Origin, ResourceDesc};
use crate::profile::Profiler;
use anyhow::{bail, Context as _, Result};
use ash::vk;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::Instant;

pub use crate::record::{Bind, PhysBuffer, PhysImage, RecordContext};

/// Semaphores a frame's submission waits on and signals, each with its stage mask (binary
/// semaphores; e.g. a swapchain's acquire semaphore waited at `ALL_COMMANDS`, matching the
/// [`crate::Access::Present`] initial state, and a render-finished semaphore for the present).
#[derive(Clone, Debug, Default)]
pub struct SubmitSync {
    pub wait: Vec<(vk::Semaphore, vk::PipelineStageFlags2)>,
    pub signal: Vec<(vk::Semaphore, vk::PipelineStageFlags2)>,
}

/// The results of one frame, available once its fence signalled.
#[derive(Debug, Default)]
pub struct FrameOutput {
    pub frame: u64,
    /// Contents of the graph's readback buffers, by name.
    pub readbacks: BTreeMap<String, Vec<u8>>,
    /// GPU milliseconds per live pass, in recording order.
    pub gpu_ms: Vec<(String, f64)>,
    /// Where the frame's time went, for traces (`render --trace`).
    pub timeline: FrameTimeline,
}

/// The newest contents of a late readback ([`Graph::create_late_readback`]): what a finished
/// frame copied out, kept by the engine for the frames built after it ([`Engine::late_readback`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LateReadback {
    /// The frame that wrote it ([`FrameOutput::frame`]).
    pub frame: u64,
    pub bytes: Vec<u8>,
}

/// What building a frame may use of the engine: persistent resources, late readbacks, frame
/// numbers and the context; no submission. Techniques and effects declare their passes with one
/// (`Technique::add`), so building a frame cannot wait on the GPU; setup work that must wait gets
/// the engine itself, before the frame (`Technique::prepare`).
pub struct FrameStore<'a> {
    engine: &'a mut Engine,
}

impl<'a> FrameStore<'a> {
    pub fn new(engine: &'a mut Engine) -> Self {
        FrameStore { engine }
    }

    /// [`Engine::persistent_image`].
    pub fn persistent_image(&mut self, graph: &mut Graph, name: &str, desc: ImageDesc) -> ImageHandle {
        self.engine.persistent_image(graph, name, desc)
    }

    /// [`Engine::persistent_buffer`].
    pub fn persistent_buffer(&mut self, graph: &mut Graph, name: &str, size: u64) -> BufferHandle {
        self.engine.persistent_buffer(graph, name, size)
    }

    /// [`Engine::has_persistent_buffer`].
    pub fn has_persistent_buffer(&self, name: &str, size: u64) -> bool {
        self.engine.has_persistent_buffer(name, size)
    }

    /// [`Engine::late_readback`].
    pub fn late_readback(&self, name: &str) -> Option<&LateReadback> {
        self.engine.late_readback(name)
    }

    /// [`Engine::next_frame`]: the number the frame being built will get.
    pub fn next_frame(&self) -> u64 {
        self.engine.next_frame()
    }

    /// The device context.
    pub fn ctx(&self) -> &Arc<Context> {
        &self.engine.ctx
    }

    /// Whether passes are timed ([`Engine::timestamps`]).
    pub fn timestamps(&self) -> bool {
        self.engine.timestamps
    }
}

/// One frame's CPU spans in the engine and its passes' GPU intervals.
#[derive(Clone, Debug, Default)]
pub struct FrameTimeline {
    /// Engine work on the CPU for this frame: `graph compile`, `wait for slot` (the slot's
    /// previous frame), `record`, `queue submit`, `fence wait` (when its output was collected).
    pub cpu_spans: Vec<CpuSpan>,
    /// When the command buffer was handed to the queue (the GPU intervals start after it).
    pub submitted: Option<Instant>,
    /// Every timed pass: its start after the frame's first timestamp and its duration, in ms.
    pub gpu_intervals: Vec<GpuInterval>,
}

#[derive(Clone, Debug)]
pub struct CpuSpan {
    pub name: &'static str,
    pub start: Instant,
    pub ms: f64,
}

#[derive(Clone, Debug)]
pub struct GpuInterval {
    pub name: String,
    pub start_ms: f64,
    pub ms: f64,
}

#[derive(Clone, Debug, PartialEq, Eq, Hash)]
enum PoolKey {
    Image(ImageDesc, vk::ImageUsageFlags),
    /// Size, usage, host access.
    Buffer(u64, vk::BufferUsageFlags, HostAccess),
}

/// How the host touches a pooled buffer (its memory type follows).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum HostAccess {
    None,
    /// Host-initialised (written before submission): write-combined memory.
    Write,
    /// Read back after the frame: host-cached memory.
    Read,
}

enum PoolItem {
    Image(GpuImage),
    Buffer(GpuBuffer),
}

struct InFlight {
    frame: u64,
    timeline: FrameTimeline,
    passes: Vec<String>,
    transients: Vec<(PoolKey, PoolItem)>,
    readbacks: Vec<(String, usize)>,
    /// How the frame's completion is seen: the slot's fence (penumbra submitted it) or a value
    /// of the engine's timeline semaphore (a host submitted the command buffer it was recorded
    /// into, [`Engine::record_into`]).
    done_at: Option<u64>,
}

/// What a host must signal when it submits a command buffer penumbra recorded into
/// ([`Engine::record_into`]): `semaphore` (a timeline semaphore of the engine's) to `value`, in
/// the same `vkQueueSubmit2` as the command buffer (a `VkSemaphoreSubmitInfo` with the stage
/// mask `ALL_COMMANDS`), on a queue of the engine's queue family. penumbra learns from it that
/// the frame is complete (readbacks, timings, resource reuse) and never waits on the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HostSignal {
    pub semaphore: vk::Semaphore,
    pub value: u64,
}

impl HostSignal {
    /// The signal as a `VkSemaphoreSubmitInfo` for the host's `vkQueueSubmit2`.
    pub fn submit_info(&self) -> vk::SemaphoreSubmitInfo<'static> {
        vk::SemaphoreSubmitInfo::default()
            .semaphore(self.semaphore)
            .value(self.value)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
    }
}

/// A frame recorded and ready to go on the GPU: what `submit_with` submits itself and
/// `record_into` hands to the host.
struct Recorded {
    compiled: CompiledGraph,
    slot: usize,
    timeline: FrameTimeline,
    pass_names: Vec<String>,
    transients: Vec<(PoolKey, PoolItem)>,
    readbacks: Vec<(String, usize)>,
    /// Persistent resources' states after the frame: (name, state).
    persistent_states: Vec<(String, ResourceState)>,
}

struct FrameSlot {
    cmd_pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    queries: vk::QueryPool,
    query_capacity: u32,
    in_flight: Option<InFlight>,
}

struct Persistent {
    desc: ResourceDesc,
    item: PoolItem,
    state: ResourceState,
}

/// Pool statistics (for tests and dumps).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolStats {
    pub created: usize,
    pub reused: usize,
    /// Freed after [`POOL_KEEP_FRAMES`] frames unused.
    pub evicted: usize,
}

/// Frames a pooled transient is kept without being used before it is freed.
pub const POOL_KEEP_FRAMES: u64 = 3;

/// Runs graphs on a [`Context`]. Keeps `frames_in_flight` frames on the GPU at once.
pub struct Engine {
    pub ctx: Arc<Context>,
    slots: Vec<FrameSlot>,
    next_slot: usize,
    frame: u64,
    /// Transients the GPU is done with, each with the frame it came back at.
    free: Vec<(PoolKey, PoolItem, u64)>,
    persistent: HashMap<String, Persistent>,
    pub profiler: Profiler,
    pub pool_stats: PoolStats,
    /// Write timestamps around every pass.
    pub timestamps: bool,
    /// Outputs of frames that finished during a submit that then failed (returned next time).
    pending: Vec<FrameOutput>,
    /// The newest late readback of every name (see [`Graph::create_late_readback`]).
    late: HashMap<String, LateReadback>,
    /// Submissions made with [`Engine::submit_wait`] so far (see [`Engine::waited_submissions`]).
    waited: u64,
    /// How long waiting for a frame may take before the GPU counts as hung (device lost).
    /// Default [`DEFAULT_FENCE_TIMEOUT`]: lavapipe takes over a minute for some frames.
    pub fence_timeout: std::time::Duration,
    /// The timeline semaphore hosts signal for frames recorded into their command buffers
    /// (`None` where the device has no `timelineSemaphore` enabled), and the last value given.
    host_timeline: Option<(vk::Semaphore, u64)>,
}

/// The default [`Engine::fence_timeout`].
pub const DEFAULT_FENCE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(600);

const MAX_QUERIES: u32 = 384;

/// Timestamp queries per pass: its start, its end, and a second write right after the start that
/// settles it. lavapipe (llvmpipe), as far as measured, takes a timestamp's time when its command
/// stream is next flushed, which the next timestamp write or barrier does: a pass whose start
/// no barrier follows (e.g. avs's HSDT, reading maps a previous submission wrote) had its start
/// taken after its work and timed near zero, its work in no pass's interval (2084 maps at r =
/// 128: 0.01-0.09 ms for about 700 ms of work). The second write flushes at once; on other
/// devices it is one more timestamp.
const QUERIES_PER_PASS: u32 = 3;
const QPP: usize = QUERIES_PER_PASS as usize;

impl Engine {
    pub fn new(ctx: Arc<Context>, frames_in_flight: usize) -> Result<Self> {
        let mut slots = Vec::new();
        for i in 0..frames_in_flight.max(1) {
            let d = &ctx.device;
            let cmd_pool = unsafe {
                d.create_command_pool(
                    &vk::CommandPoolCreateInfo::default()
                        .queue_family_index(ctx.queue_family)
                        .flags(vk::CommandPoolCreateFlags::TRANSIENT),
                    None,
                )?
            };
            let cmd = unsafe {
                d.allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(cmd_pool)
                        .level(vk::CommandBufferLevel::PRIMARY)
                        .command_buffer_count(1),
                )?[0]
            };
            let fence = unsafe { d.create_fence(&vk::FenceCreateInfo::default(), None)? };
            let queries = unsafe {
                d.create_query_pool(
                    &vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(MAX_QUERIES),
                    None,
                )?
            };
            ctx.set_name(cmd_pool, &format!("frame_slot{i}.cmd_pool"));
            ctx.set_name(cmd, &format!("frame_slot{i}.cmd"));
            ctx.set_name(fence, &format!("frame_slot{i}.fence"));
            ctx.set_name(queries, &format!("frame_slot{i}.timestamps"));
            slots.push(FrameSlot { cmd_pool, cmd, fence, queries, query_capacity: MAX_QUERIES, in_flight: None });
        }
        let host_timeline = if ctx.timeline_semaphore {
            let mut ti = vk::SemaphoreTypeCreateInfo::default().semaphore_type(vk::SemaphoreType::TIMELINE);
            let sem =
                unsafe { ctx.device.create_semaphore(&vk::SemaphoreCreateInfo::default().push_next(&mut ti), None)? };
            ctx.set_name(sem, "host_frames.timeline");
            Some((sem, 0))
        } else {
            None
        };
        Ok(Engine {
            host_timeline,
            ctx,
            slots,
            next_slot: 0,
            frame: 0,
            free: Vec::new(),
            persistent: HashMap::new(),
            profiler: Profiler::default(),
            pool_stats: PoolStats::default(),
            fence_timeout: DEFAULT_FENCE_TIMEOUT,
            timestamps: true,
            pending: Vec::new(),
            late: HashMap::new(),
            waited: 0,
        })
    }

    /// Frames submitted so far.
    pub fn frame_index(&self) -> u64 {
        self.frame
    }

    /// Declares a persistent image in `graph`, carrying its state from the previous frame.
    /// A changed description (e.g. a resize) starts it afresh.
    pub fn persistent_image(&mut self, graph: &mut Graph, name: &str, desc: ImageDesc) -> ImageHandle {
        let state = self.persistent_state(name, &ResourceDesc::Image(desc.clone()));
        graph.persistent_image(name, desc, state)
    }

    /// Whether a persistent buffer `name` of `size` bytes survives from earlier frames (a
    /// declaration now would not be new), without declaring it.
    pub fn has_persistent_buffer(&self, name: &str, size: u64) -> bool {
        let d = ResourceDesc::Buffer(crate::graph::BufferDesc { size, host_visible: false });
        self.persistent.get(name).is_some_and(|p| p.desc == d)
    }

    /// Declares a persistent buffer in `graph`.
    pub fn persistent_buffer(&mut self, graph: &mut Graph, name: &str, size: u64) -> BufferHandle {
        let d = ResourceDesc::Buffer(crate::graph::BufferDesc { size, host_visible: false });
        let state = self.persistent_state(name, &d);
        graph.persistent_buffer(name, size, state)
    }

    fn persistent_state(&mut self, name: &str, desc: &ResourceDesc) -> Option<ResourceState> {
        match self.persistent.get(name) {
            Some(p) if &p.desc == desc => Some(p.state.clone()),
            Some(_) => {
                // Described differently now: drop it once the GPU is done with it.
                if let Some(p) = self.persistent.remove(name) {
                    self.wait_in_flight();
                    self.destroy_item(p.item);
                }
                None
            }
            None => None,
        }
    }

    /// Returns transients to the pool (the GPU no longer uses them).
    fn give_back(&mut self, items: Vec<(PoolKey, PoolItem)>) {
        let now = self.frame;
        self.free.extend(items.into_iter().map(|(k, i)| (k, i, now)));
    }

    /// Frees pooled transients no frame took for [`POOL_KEEP_FRAMES`] frames: a pool that
    /// only grows would hold every size a technique ever asked for (sizes that follow the
    /// scene, such as avs's sample points, differ every frame).
    fn evict_unused(&mut self) {
        let now = self.frame;
        let (keep, old): (Vec<_>, Vec<_>) = std::mem::take(&mut self.free)
            .into_iter()
            .partition(|(_, _, at)| now.saturating_sub(*at) <= POOL_KEEP_FRAMES);
        self.free = keep;
        self.pool_stats.evicted += old.len();
        for (_, item, _) in old {
            self.destroy_item(item);
        }
    }

    /// Transients pooled now (free for the next frames).
    pub fn pooled(&self) -> usize {
        self.free.len()
    }

    fn destroy_item(&self, item: PoolItem) {
        match item {
            PoolItem::Image(i) => self.ctx.destroy_image(i),
            PoolItem::Buffer(b) => self.ctx.destroy_buffer(b),
        }
    }

    fn take(&mut self, key: PoolKey, name: &str) -> Result<PoolItem> {
        if let Some(pos) = self.free.iter().position(|(k, _, _)| *k == key) {
            self.pool_stats.reused += 1;
            let (_, item, _) = self.free.swap_remove(pos);
            // Re-label the pooled object with its current use.
            match &item {
                PoolItem::Image(i) => {
                    self.ctx.set_name(i.image, name);
                    self.ctx.set_name(i.view, &format!("{name}.view"));
                }
                PoolItem::Buffer(b) => self.ctx.set_name(b.buffer, name),
            }
            return Ok(item);
        }
        self.pool_stats.created += 1;
        let pooled = || {
            let (bytes, allocations, reserved) = self.ctx.memory_report();
            format!(
                "creating transient '{name}' ({} pooled for reuse; the device holds {:.1} MiB in {allocations} allocations, {:.1} MiB reserved)",
                self.free.len(),
                bytes as f64 / (1u64 << 20) as f64,
                reserved as f64 / (1u64 << 20) as f64
            )
        };
        Ok(match &key {
            PoolKey::Image(desc, usage) => {
                PoolItem::Image(self.ctx.create_image(name, desc, *usage).with_context(pooled)?)
            }
            PoolKey::Buffer(size, usage, host) => PoolItem::Buffer(
                match host {
                    HostAccess::Read => self.ctx.create_readback_buffer(name, *size, *usage),
                    _ => self.ctx.create_buffer(name, *size, *usage, *host == HostAccess::Write),
                }
                .with_context(pooled)?,
            ),
        })
    }

    /// Waits for a slot's frame and collects its output.
    fn retire(&mut self, slot: usize) -> Result<Option<FrameOutput>> {
        let Some(f) = self.slots[slot].in_flight.take() else { return Ok(None) };
        let d = &self.ctx.device;
        let s = &self.slots[slot];
        let timeout_ns = u64::try_from(self.fence_timeout.as_nanos()).unwrap_or(u64::MAX);
        let wait_start = Instant::now();
        let waited = match (f.done_at, self.host_timeline) {
            (Some(value), Some((sem, _))) => unsafe {
                let (sems, values) = ([sem], [value]);
                d.wait_semaphores(&vk::SemaphoreWaitInfo::default().semaphores(&sems).values(&values), timeout_ns)
            },
            _ => unsafe { d.wait_for_fences(&[s.fence], true, timeout_ns) },
        };
        match waited {
            Ok(()) => {}
            Err(vk::Result::TIMEOUT) => {
                let frame = f.frame;
                self.slots[slot].in_flight = Some(f);
                // A GPU that does not finish is as good as lost: the caller gets the device-lost
                // kind (exit code 4 on the command line), not a wait that never returns.
                let host = if self.slots[slot].in_flight.as_ref().is_some_and(|f| f.done_at.is_some()) {
                    " (or the host never submitted the command buffer it was recorded into)"
                } else {
                    ""
                };
                return Err(anyhow::Error::new(vk::Result::ERROR_DEVICE_LOST).context(format!(
                    "frame {frame} did not finish within {:.0} s (Engine::fence_timeout): the GPU hung{host}",
                    self.fence_timeout.as_secs_f64()
                )));
            }
            Err(e) => return Err(anyhow::Error::new(e).context(format!("waiting for frame {}", f.frame))),
        }
        if f.done_at.is_none() {
            unsafe { d.reset_fences(&[s.fence])? };
        }
        let mut out = FrameOutput { frame: f.frame, timeline: f.timeline, ..Default::default() };
        out.timeline.cpu_spans.push(CpuSpan {
            name: "fence wait",
            start: wait_start,
            ms: wait_start.elapsed().as_secs_f64() * 1e3,
        });
        if self.timestamps && !f.passes.is_empty() {
            let n = f.passes.len() as u32 * QUERIES_PER_PASS;
            let mut ts = vec![0u64; n as usize];
            unsafe {
                d.get_query_pool_results(
                    s.queries,
                    0,
                    &mut ts,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
                .context("reading timestamps")?;
            }
            let mask = if self.ctx.timestamp_valid_bits >= 64 {
                u64::MAX
            } else {
                (1u64 << self.ctx.timestamp_valid_bits) - 1
            };
            for (i, name) in f.passes.iter().enumerate() {
                let (b, e) = (ts[QPP * i], ts[QPP * i + 1]);
                let ticks = (e & mask).wrapping_sub(b & mask) & mask;
                let ms = ticks as f64 * self.ctx.timestamp_period * 1e-6;
                self.profiler.add_gpu(name, ms);
                out.gpu_ms.push((name.clone(), ms));
                let start = (b & mask).wrapping_sub(ts[0] & mask) & mask;
                out.timeline.gpu_intervals.push(GpuInterval {
                    name: name.clone(),
                    start_ms: start as f64 * self.ctx.timestamp_period * 1e-6,
                    ms,
                });
            }
            self.profiler.end_frame();
        }
        for (name, idx) in &f.readbacks {
            if let (_, PoolItem::Buffer(b)) = &f.transients[*idx] {
                let bytes = b.mapped().map(|m| m.to_vec()).unwrap_or_default();
                match name.strip_prefix(crate::graph::LATE_READBACK_PREFIX) {
                    Some(late) => {
                        if self.late.get(late).is_none_or(|l| l.frame <= f.frame) {
                            self.late.insert(late.to_string(), LateReadback { frame: f.frame, bytes });
                        }
                    }
                    None => {
                        out.readbacks.insert(name.clone(), bytes);
                    }
                }
            }
        }
        self.give_back(f.transients);
        Ok(Some(out))
    }

    /// Finds or allocates the Vulkan object of every live resource.
    fn resolve(
        &mut self,
        graph: &Graph,
        compiled: &CompiledGraph,
        images: &mut [Option<PhysImage>],
        buffers: &mut [Option<PhysBuffer>],
        transients: &mut Vec<(PoolKey, PoolItem)>,
        readbacks: &mut Vec<(String, usize)>,
    ) -> Result<()> {
        for (i, (res, info)) in graph.resources.iter().zip(compiled.resources.iter()).enumerate() {
            if info.first_pass.is_none() {
                continue;
            }
            match (&res.origin, &res.desc, res.external) {
                (Origin::Imported { .. }, ResourceDesc::Image(d), External::Image(image, view)) => {
                    images[i] = Some(PhysImage { image, view, desc: d.clone() });
                }
                (Origin::Imported { .. }, ResourceDesc::Buffer(b), External::Buffer(buffer)) => {
                    buffers[i] = Some(PhysBuffer { buffer, size: b.size, texel_view: None });
                }
                (Origin::Imported { .. }, _, _) => bail!("imported resource '{}' has no Vulkan handle", res.name),
                (Origin::Persistent { .. }, desc, _) => {
                    if !self.persistent.contains_key(&res.name) {
                        let item = match desc {
                            ResourceDesc::Image(d) => {
                                let usage = info.image_usage
                                    | vk::ImageUsageFlags::SAMPLED
                                    | vk::ImageUsageFlags::STORAGE
                                    | vk::ImageUsageFlags::TRANSFER_SRC
                                    | vk::ImageUsageFlags::TRANSFER_DST;
                                let usage = if crate::graph::access::is_depth_format(d.format) {
                                    info.image_usage | vk::ImageUsageFlags::SAMPLED
                                } else {
                                    usage
                                };
                                PoolItem::Image(self.ctx.create_image(&res.name, d, usage)?)
                            }
                            ResourceDesc::Buffer(b) => PoolItem::Buffer(self.ctx.create_buffer(
                                &res.name,
                                b.size,
                                info.buffer_usage
                                    | vk::BufferUsageFlags::STORAGE_BUFFER
                                    | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
                                    | vk::BufferUsageFlags::TRANSFER_SRC
                                    | vk::BufferUsageFlags::TRANSFER_DST,
                                false,
                            )?),
                        };
                        self.persistent.insert(
                            res.name.clone(),
                            Persistent { desc: desc.clone(), item, state: ResourceState::default() },
                        );
                    }
                    let p = &self.persistent[&res.name];
                    match &p.item {
                        PoolItem::Image(img) => {
                            if !img.usage.contains(info.image_usage) {
                                bail!(
                                    "persistent image '{}' was created without usage {:?}",
                                    res.name,
                                    info.image_usage
                                );
                            }
                            images[i] = Some(PhysImage { image: img.image, view: img.view, desc: img.desc.clone() })
                        }
                        PoolItem::Buffer(b) => {
                            if !b.usage.contains(info.buffer_usage) {
                                bail!(
                                    "persistent buffer '{}' was created without usage {:?}",
                                    res.name,
                                    info.buffer_usage
                                );
                            }
                            buffers[i] = Some(PhysBuffer { buffer: b.buffer, size: b.size, texel_view: b.texel_view })
                        }
                    }
                }
                (_, ResourceDesc::Image(d), _) => {
                    let key = PoolKey::Image(d.clone(), info.image_usage);
                    let item = self.take(key.clone(), &res.name)?;
                    if let PoolItem::Image(img) = &item {
                        images[i] = Some(PhysImage { image: img.image, view: img.view, desc: d.clone() });
                    }
                    transients.push((key, item));
                }
                (origin, ResourceDesc::Buffer(b), _) => {
                    let extra = match origin {
                        Origin::Readback => vk::BufferUsageFlags::TRANSFER_DST,
                        _ => vk::BufferUsageFlags::empty(),
                    };
                    let host = match (origin, b.host_visible) {
                        (Origin::Readback, _) => HostAccess::Read,
                        (_, true) => HostAccess::Write,
                        (_, false) => HostAccess::None,
                    };
                    let key = PoolKey::Buffer(b.size, info.buffer_usage | extra, host);
                    let mut item = self.take(key.clone(), &res.name)?;
                    if let PoolItem::Buffer(buf) = &mut item {
                        if let Some(data) = &res.init_data {
                            buf.write(data)?;
                        }
                        buffers[i] = Some(PhysBuffer { buffer: buf.buffer, size: b.size, texel_view: buf.texel_view });
                    }
                    if matches!(origin, Origin::Readback) {
                        readbacks.push((res.name.clone(), transients.len()));
                    }
                    transients.push((key, item));
                }
            }
        }
        Ok(())
    }

    /// Compiles, records and submits a frame. Returns the outputs of frames that completed
    /// meanwhile (the oldest in-flight frame when every slot is busy). On a graph or recording
    /// error nothing is submitted and every problem is reported together.
    pub fn submit(&mut self, graph: Graph) -> Result<(CompiledGraph, Vec<FrameOutput>)> {
        self.submit_with(graph, &SubmitSync::default())
    }

    /// Waits until the frame slot the next [`Engine::submit`] will use is free (its frame has
    /// completed; the output is returned by that submit). A window acquires its swapchain image
    /// after this, so the acquire semaphore of that slot is no longer waited on by the GPU.
    pub fn wait_next_slot(&mut self) -> Result<()> {
        if let Some(o) = self.retire(self.next_slot)? {
            self.pending.push(o);
        }
        Ok(())
    }

    /// Collects every frame in flight whose fence has already signalled, without waiting (their
    /// outputs are returned by the next [`Engine::submit`] or [`Engine::drain`]): late readbacks
    /// of frames the GPU finished while the CPU built the next one become available to it.
    pub fn poll(&mut self) -> Result<()> {
        for i in 0..self.slots.len() {
            let slot = (self.next_slot + i) % self.slots.len();
            let Some(f) = &self.slots[slot].in_flight else { continue };
            let done = match (f.done_at, self.host_timeline) {
                (Some(value), Some((sem, _))) => unsafe { self.ctx.device.get_semaphore_counter_value(sem) }
                    .map(|v| v >= value)
                    .map_err(|e| anyhow::Error::new(e).context("polling a host-submitted frame's semaphore"))?,
                _ => unsafe { self.ctx.device.get_fence_status(self.slots[slot].fence) }
                    .map_err(|e| anyhow::Error::new(e).context("polling a frame's fence"))?,
            };
            if !done {
                // frames finish in submission order: the later ones are not done either
                break;
            }
            if let Some(o) = self.retire(slot)? {
                self.pending.push(o);
            }
        }
        Ok(())
    }

    /// The newest contents of the late readback `name` (declared with
    /// [`Graph::create_late_readback`]) among the frames collected so far, and the frame that
    /// wrote it; never waits. `None` until such a frame has been collected.
    pub fn late_readback(&self, name: &str) -> Option<&LateReadback> {
        self.late.get(name)
    }

    /// How many submissions [`Engine::submit_wait`] has made and waited for. Building a frame
    /// should make none (tests check by this count); the one exception is avs when asked for its
    /// waited GPU adaptation rounds (`adaptation = rounds`, or a fresh point set's with `late`).
    pub fn waited_submissions(&self) -> u64 {
        self.waited
    }

    /// The number the next submitted frame gets ([`FrameOutput::frame`]).
    pub fn next_frame(&self) -> u64 {
        self.frame
    }

    /// The frame slot the next submit uses (0..frames in flight): index per-slot objects such as
    /// acquire semaphores with it.
    pub fn next_slot(&self) -> usize {
        self.next_slot
    }

    /// [`Engine::submit`] with semaphores to wait on and signal (a swapchain's acquire and
    /// render-finished semaphores).
    pub fn submit_with(&mut self, graph: Graph, sync: &SubmitSync) -> Result<(CompiledGraph, Vec<FrameOutput>)> {
        let mut rec = self.record(graph, None)?;
        let d = &self.ctx.device;
        let s = &self.slots[rec.slot];
        let cmd_infos = [vk::CommandBufferSubmitInfo::default().command_buffer(s.cmd)];
        let sem = |&(semaphore, stage): &(vk::Semaphore, vk::PipelineStageFlags2)| {
            vk::SemaphoreSubmitInfo::default().semaphore(semaphore).stage_mask(stage)
        };
        let waits: Vec<_> = sync.wait.iter().map(sem).collect();
        let signals: Vec<_> = sync.signal.iter().map(sem).collect();
        let submit = [vk::SubmitInfo2::default()
            .command_buffer_infos(&cmd_infos)
            .wait_semaphore_infos(&waits)
            .signal_semaphore_infos(&signals)];
        let ts_submit = Instant::now();
        if let Err(e) = unsafe { d.queue_submit2(self.ctx.queue, &submit, s.fence) } {
            self.give_back(std::mem::take(&mut rec.transients));
            return Err(anyhow::Error::new(e).context("vkQueueSubmit2"));
        }
        rec.timeline.cpu_spans.push(CpuSpan {
            name: "queue submit",
            start: ts_submit,
            ms: ts_submit.elapsed().as_secs_f64() * 1e3,
        });
        rec.timeline.submitted = Some(ts_submit);
        // (on a failed submit the frames collected meanwhile stay pending for the next call)
        let done = std::mem::take(&mut self.pending);
        Ok((self.commit(rec, None), done))
    }

    /// Records `graph` into the host's command buffer `cmd` (begun, outside a render pass, on
    /// the engine's queue family) instead of submitting it: the host's frame graph runs
    /// penumbra's passes inside its own submission. Imported resources enter and leave in the
    /// states their [`crate::graph::External`] declarations give, as in a frame penumbra
    /// submits; pipeline, descriptor and push-constant state the host bound before is not kept
    /// (bind again after). The host must submit `cmd` once, signalling the returned
    /// [`HostSignal`] in the same submission; the frame's outputs then come back from a later
    /// `submit`/`record_into`/`poll`+`drain` as for any frame. Returns the compiled graph, the
    /// outputs of frames that completed meanwhile, and the signal. The frame counts as
    /// submitted from here (persistent resources take their final states), so `cmd` must be
    /// submitted: a host that cannot submit it signals the value itself (`vkSignalSemaphore`,
    /// else penumbra waits up to [`Engine::fence_timeout`] for it) and drops this engine, whose
    /// persistent resources are then in states it no longer knows. Needs `timelineSemaphore`
    /// ([`crate::context::ExternalFeatures::timeline_semaphore`]).
    pub fn record_into(
        &mut self,
        graph: Graph,
        cmd: vk::CommandBuffer,
    ) -> Result<(CompiledGraph, Vec<FrameOutput>, HostSignal)> {
        let Some((semaphore, last)) = self.host_timeline else {
            bail!(
                "recording into a host's command buffer needs the Vulkan 1.2 feature timelineSemaphore \
                 enabled on the device (ExternalFeatures::timeline_semaphore)"
            );
        };
        let rec = self.record(graph, Some(cmd))?;
        let done = std::mem::take(&mut self.pending);
        let value = last + 1;
        self.host_timeline = Some((semaphore, value));
        Ok((self.commit(rec, Some(value)), done, HostSignal { semaphore, value }))
    }

    /// Compiles `graph`, waits for the next slot's previous frame, resolves the resources and
    /// records every live pass: into the slot's own command buffer (`host_cmd` none; begun and
    /// ended here) or into the host's. On a graph or recording error nothing is left to submit
    /// and every problem is reported together.
    fn record(&mut self, mut graph: Graph, host_cmd: Option<vk::CommandBuffer>) -> Result<Recorded> {
        let t0 = Instant::now();
        self.evict_unused();
        let compiled = graph.compile()?;
        self.profiler.add_cpu("graph compile", t0.elapsed().as_secs_f64() * 1e3);
        let mut timeline = FrameTimeline::default();
        timeline.cpu_spans.push(CpuSpan { name: "graph compile", start: t0, ms: t0.elapsed().as_secs_f64() * 1e3 });

        let slot = self.next_slot;
        let tw = Instant::now();
        if let Some(o) = self.retire(slot)? {
            self.pending.push(o);
        }
        timeline.cpu_spans.push(CpuSpan { name: "wait for slot", start: tw, ms: tw.elapsed().as_secs_f64() * 1e3 });
        let t1 = Instant::now();

        // ---- resolve resources
        let n = graph.resources.len();
        let mut images: Vec<Option<PhysImage>> = vec![None; n];
        let mut buffers: Vec<Option<PhysBuffer>> = vec![None; n];
        let mut transients: Vec<(PoolKey, PoolItem)> = Vec::new();
        let mut readbacks = Vec::new();
        let names: Vec<String> = graph.resources.iter().map(|r| r.name.clone()).collect();
        if let Err(e) = self.resolve(&graph, &compiled, &mut images, &mut buffers, &mut transients, &mut readbacks) {
            // Nothing was recorded: the transients taken so far go back to the pool.
            self.give_back(transients);
            return Err(e);
        }

        // ---- record
        let mut records = graph.take_records();
        let live: Vec<usize> = compiled.live_passes().map(|(i, _)| i).collect();
        // A frame with more passes than the slot's timestamp pool holds gets a bigger pool (the
        // slot's previous frame is complete: its queries were read when it was retired).
        let needed = (live.len() as u32) * QUERIES_PER_PASS;
        if self.timestamps && needed > self.slots[slot].query_capacity {
            let cap = needed.next_power_of_two();
            let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(cap);
            let q = unsafe { self.ctx.device.create_query_pool(&info, None)? };
            unsafe { self.ctx.device.destroy_query_pool(self.slots[slot].queries, None) };
            self.ctx.set_name(q, &format!("frame_slot{slot}.timestamps"));
            self.slots[slot].queries = q;
            self.slots[slot].query_capacity = cap;
        }
        let d = &self.ctx.device;
        let s = &self.slots[slot];
        let cmd = host_cmd.unwrap_or(s.cmd);
        if host_cmd.is_none() {
            unsafe {
                d.reset_command_pool(s.cmd_pool, vk::CommandPoolResetFlags::empty())?;
                d.begin_command_buffer(
                    cmd,
                    &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
                )?;
            }
        }
        let timestamps = self.timestamps && needed <= s.query_capacity;
        if timestamps {
            unsafe { d.cmd_reset_query_pool(cmd, s.queries, 0, needed) };
        }
        let mut errors: Vec<String> = Vec::new();
        let mut pass_names = Vec::new();
        for (qi, &pi) in live.iter().enumerate() {
            let cp = &compiled.passes[pi];
            self.ctx.begin_label(cmd, &cp.name);
            if timestamps {
                unsafe {
                    let q = qi as u32 * QUERIES_PER_PASS;
                    d.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, s.queries, q);
                    // settles the pass's start (see QUERIES_PER_PASS)
                    d.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, s.queries, q + 2);
                };
            }
            emit_barriers(d, cmd, &cp.barriers, &images, &buffers);
            let mut rc = RecordContext {
                ctx: &self.ctx,
                cmd,
                pass: &cp.name,
                declared: cp.uses.iter().map(|u| (u.0, u.1)).collect(),
                images: &images,
                buffers: &buffers,
                names: &names,
            };
            if let Some(f) = records.get_mut(pi).and_then(|r| r.take()) {
                if let Err(e) = f(&mut rc) {
                    errors.push(format!("pass '{}': {e:#}", cp.name));
                }
            }
            if timestamps {
                unsafe {
                    d.cmd_write_timestamp2(
                        cmd,
                        vk::PipelineStageFlags2::ALL_COMMANDS,
                        s.queries,
                        qi as u32 * QUERIES_PER_PASS + 1,
                    )
                };
            }
            self.ctx.end_label(cmd);
            pass_names.push(cp.name.clone());
        }
        emit_barriers(d, cmd, &compiled.final_barriers, &images, &buffers);
        if host_cmd.is_none() {
            if let Err(e) = unsafe { d.end_command_buffer(cmd) } {
                self.give_back(transients);
                return Err(anyhow::Error::new(e).context("vkEndCommandBuffer"));
            }
        }
        self.profiler.add_cpu("record", t1.elapsed().as_secs_f64() * 1e3);
        timeline.cpu_spans.push(CpuSpan { name: "record", start: t1, ms: t1.elapsed().as_secs_f64() * 1e3 });
        if !errors.is_empty() {
            self.give_back(transients);
            let host =
                if host_cmd.is_some() { " (the host's command buffer holds a partial frame: reset it)" } else { "" };
            bail!(
                "recording failed, frame not submitted{host}; {} error(s):\n  - {}",
                errors.len(),
                errors.join("\n  - ")
            );
        }
        let persistent_states = graph
            .resources
            .iter()
            .zip(compiled.resources.iter())
            .filter(|(res, info)| matches!(res.origin, Origin::Persistent { .. }) && info.first_pass.is_some())
            .map(|(res, info)| (res.name.clone(), info.final_state.clone()))
            .collect();
        Ok(Recorded {
            compiled,
            slot,
            timeline,
            pass_names: if timestamps { pass_names } else { Vec::new() },
            transients,
            readbacks,
            persistent_states,
        })
    }

    /// Makes a recorded frame the slot's frame in flight (submitted, or handed to the host to
    /// signal `done_at`): persistent resources take their final states, the frame number and
    /// slot advance.
    fn commit(&mut self, rec: Recorded, done_at: Option<u64>) -> CompiledGraph {
        for (name, state) in rec.persistent_states {
            if let Some(p) = self.persistent.get_mut(&name) {
                p.state = state;
            }
        }
        self.slots[rec.slot].in_flight = Some(InFlight {
            frame: self.frame,
            timeline: rec.timeline,
            passes: rec.pass_names,
            transients: rec.transients,
            readbacks: rec.readbacks,
            done_at,
        });
        self.frame += 1;
        self.next_slot = (rec.slot + 1) % self.slots.len();
        rec.compiled
    }

    /// Waits for every frame in flight, keeping their outputs for the next `submit`/`drain`. A
    /// frame that does not finish (a hung GPU, a host that never submitted) falls back to
    /// waiting for the whole device (within the driver's own limits).
    fn wait_in_flight(&mut self) {
        for i in 0..self.slots.len() {
            let slot = (self.next_slot + i) % self.slots.len();
            match self.retire(slot) {
                Ok(Some(o)) => self.pending.push(o),
                Ok(None) => {}
                Err(_) => {
                    let _ = self.ctx.wait_idle();
                    return;
                }
            }
        }
    }

    /// Waits for every frame in flight and returns their outputs in submission order.
    pub fn drain(&mut self) -> Result<Vec<FrameOutput>> {
        let mut out = std::mem::take(&mut self.pending);
        for i in 0..self.slots.len() {
            let slot = (self.next_slot + i) % self.slots.len();
            if let Some(o) = self.retire(slot)? {
                out.push(o);
            }
        }
        out.sort_by_key(|o| o.frame);
        Ok(out)
    }

    /// Submits `graph` and waits for it alone; returns its output (readbacks, GPU times). Outputs
    /// of other frames that complete meanwhile stay queued for the next `submit`/`drain`, so a
    /// technique can run a round of GPU work whose results it needs on the CPU inside a frame
    /// without taking the caller's results. It does not count as a frame: the next submit gets
    /// the frame number this one had.
    pub fn submit_wait(&mut self, graph: Graph) -> Result<FrameOutput> {
        self.waited += 1;
        let slot = self.next_slot;
        let (_, done) = self.submit(graph)?;
        self.pending.extend(done);
        let out =
            self.retire(slot)?.ok_or_else(|| anyhow::anyhow!("submit_wait: the submitted frame is not in flight"));
        self.frame -= 1;
        out
    }
}

/// Converts compiled barriers to one `vkCmdPipelineBarrier2`.
fn emit_barriers(
    d: &ash::Device,
    cmd: vk::CommandBuffer,
    barriers: &[Barrier],
    images: &[Option<PhysImage>],
    buffers: &[Option<PhysBuffer>],
) {
    if barriers.is_empty() {
        return;
    }
    let mut ib = Vec::new();
    let mut bb = Vec::new();
    for b in barriers {
        let r = b.resource as usize;
        if b.image {
            let Some(img) = images.get(r).and_then(|i| i.as_ref()) else { continue };
            ib.push(
                vk::ImageMemoryBarrier2::default()
                    .src_stage_mask(b.src_stage)
                    .src_access_mask(b.src_access)
                    .dst_stage_mask(b.dst_stage)
                    .dst_access_mask(b.dst_access)
                    .old_layout(b.old_layout)
                    .new_layout(b.new_layout)
                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .image(img.image)
                    .subresource_range(vk::ImageSubresourceRange {
                        aspect_mask: img.desc.aspect(),
                        base_mip_level: 0,
                        level_count: img.desc.mip_levels,
                        base_array_layer: 0,
                        layer_count: img.desc.array_layers,
                    }),
            );
        } else {
            let Some(buf) = buffers.get(r).and_then(|b| *b) else { continue };
            bb.push(
                vk::BufferMemoryBarrier2::default()
                    .src_stage_mask(b.src_stage)
                    .src_access_mask(b.src_access)
                    .dst_stage_mask(b.dst_stage)
                    .dst_access_mask(b.dst_access)
                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .buffer(buf.buffer)
                    .offset(0)
                    .size(vk::WHOLE_SIZE),
            );
        }
    }
    let dep = vk::DependencyInfo::default().image_memory_barriers(&ib).buffer_memory_barriers(&bb);
    unsafe { d.cmd_pipeline_barrier2(cmd, &dep) };
}

impl Drop for Engine {
    fn drop(&mut self) {
        // penumbra's own frames, not the whole device (a host's device runs the host's work too)
        self.wait_in_flight();
        for i in 0..self.slots.len() {
            if let Some(f) = self.slots[i].in_flight.take() {
                self.give_back(f.transients);
            }
        }
        for (_, item, _) in std::mem::take(&mut self.free) {
            self.destroy_item(item);
        }
        for (_, p) in std::mem::take(&mut self.persistent) {
            self.destroy_item(p.item);
        }
        let d = &self.ctx.device;
        for s in &self.slots {
            unsafe {
                d.destroy_query_pool(s.queries, None);
                d.destroy_fence(s.fence, None);
                d.destroy_command_pool(s.cmd_pool, None);
            }
        }
        if let Some((sem, _)) = self.host_timeline {
            unsafe { d.destroy_semaphore(sem, None) };
        }
    }
}
