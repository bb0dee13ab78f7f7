//! The Vulkan context: instance, device choice, one graphics+compute queue, gpu-allocator memory,
//! debug-utils names and labels, and the validation-message log.
//!
//! Headless by default; a window surface can be used by passing the surface's instance
//! extensions in [`ContextDesc::instance_extensions`] (see `ash_window::enumerate_required_extensions`).
//! An application with its own instance/device uses [`Context::from_external`].

use anyhow::{anyhow, bail, Context as _, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc};
use gpu_allocator::MemoryLocation;
use std::ffi::{c_char, CStr, CString};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use crate::resource::ImageDesc;

/// Messages reported by the validation layer (or any debug-utils source).
#[derive(Default, Debug)]
pub struct ValidationLog {
    errors: AtomicUsize,
    warnings: AtomicUsize,
    messages: Mutex<Vec<String>>,
}

impl ValidationLog {
    pub fn error_count(&self) -> usize {
        self.errors.load(Ordering::SeqCst)
    }
    pub fn warning_count(&self) -> usize {
        self.warnings.load(Ordering::SeqCst)
    }
    /// Error messages (warnings are counted, not kept).
    pub fn errors(&self) -> Vec<String> {
        self.messages.lock().map(|m| m.clone()).unwrap_or_default()
    }
    fn push(&self, severity: vk::DebugUtilsMessageSeverityFlagsEXT, msg: String) {
        if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
            self.errors.fetch_add(1, Ordering::SeqCst);
            if let Ok(mut m) = self.messages.lock() {
                if m.len() < 1000 {
                    m.push(msg);
                }
            }
        } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
            self.warnings.fetch_add(1, Ordering::SeqCst);
        }
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut std::ffi::c_void,
) -> vk::Bool32 {
    if data.is_null() || user.is_null() {
        return vk::FALSE;
    }
    let log = &*(user as *const ValidationLog);
    let d = &*data;
    let msg =
        if d.p_message.is_null() { String::new() } else { CStr::from_ptr(d.p_message).to_string_lossy().into_owned() };
    // through `tracing` (target `penumbra::vulkan`): the CLI prints it, a host routes or
    // filters it, tests that provoke errors on purpose stay quiet; the log counts it either way
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        tracing::error!(target: "penumbra::vulkan", "{msg}");
    }
    log.push(severity, msg);
    vk::FALSE
}

/// How to create a [`Context`].
#[derive(Clone, Debug)]
pub struct ContextDesc {
    /// Directory of the on-disk Vulkan pipeline cache ([`default_pipeline_cache_dir`] by
    /// default: `$XDG_CACHE_HOME/penumbra` or `~/.cache/penumbra`; `None`: in memory only). One
    /// file per driver (vendor, device and the driver's pipeline-cache UUID in its name), read
    /// when the context is created and replaced atomically when it is dropped, so a second run
    /// skips pipeline compilation.
    pub pipeline_cache_dir: Option<std::path::PathBuf>,
    /// Enable the Khronos validation layer with synchronization validation.
    pub validation: bool,
    /// Extra instance extensions (e.g. for a window surface).
    pub instance_extensions: Vec<CString>,
    /// Pick the physical device whose name contains this (else: discrete > integrated > virtual > CPU).
    pub device_name: Option<String>,
    /// Enable VK_KHR_swapchain (for a window).
    pub swapchain: bool,
    /// The loop guard (a test and debugging mode): enable `bufferDeviceAddress` and keep a
    /// host-visible guard buffer into which shaders compiled by
    /// `ShaderLibrary::with_loop_guard` count their loop iterations
    /// ([`Context::loop_guard_counts`]).
    pub loop_guard: bool,
    /// The structure the compute ray tracer walks (`passes::kdtree::Structure`).
    pub tracer: TracerStructure,
}

/// Which acceleration structure the compute ray tracer builds and walks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TracerStructure {
    /// The device decides: a host-built threaded BVH on a CPU device (lavapipe, where its walk
    /// is 2-3x faster), the device-built kd-tree on a GPU.
    #[default]
    Auto,
    /// The kd-tree built on the device.
    KdTree,
    /// The threaded BVH built on the host.
    Bvh,
}

impl TracerStructure {
    /// `auto`, `kdtree` or `bvh`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "auto" => Some(TracerStructure::Auto),
            "kdtree" | "kd-tree" | "kd" => Some(TracerStructure::KdTree),
            "bvh" => Some(TracerStructure::Bvh),
            _ => None,
        }
    }
}

impl Default for ContextDesc {
    fn default() -> Self {
        ContextDesc {
            pipeline_cache_dir: default_pipeline_cache_dir(),
            validation: false,
            instance_extensions: Vec::new(),
            device_name: None,
            swapchain: false,
            loop_guard: false,
            tracer: TracerStructure::Auto,
        }
    }
}

/// `$XDG_CACHE_HOME/penumbra`, else `$HOME/.cache/penumbra`, else none.
pub fn default_pipeline_cache_dir() -> Option<std::path::PathBuf> {
    let base =
        std::env::var_os("XDG_CACHE_HOME").filter(|v| !v.is_empty()).map(std::path::PathBuf::from).or_else(|| {
            std::env::var_os("HOME").filter(|v| !v.is_empty()).map(|h| std::path::PathBuf::from(h).join(".cache"))
        })?;
    Some(base.join("penumbra"))
}

/// The largest pipeline-cache file read (a bigger one is ignored).
const PIPELINE_CACHE_MAX_BYTES: u64 = 256 << 20;

/// The pipeline-cache file of this device in `dir`, and whether `data` (a file's bytes) has
/// this device's header (`VkPipelineCacheHeaderVersionOne`: length, version 1, vendor, device,
/// pipelineCacheUUID); data of another driver is not handed to this one.
fn pipeline_cache_file(dir: &std::path::Path, props: &vk::PhysicalDeviceProperties) -> std::path::PathBuf {
    let uuid: String = props.pipeline_cache_uuid.iter().map(|b| format!("{b:02x}")).collect();
    dir.join(format!("pipelines-{:04x}-{:04x}-{uuid}.bin", props.vendor_id, props.device_id))
}

fn pipeline_cache_header_matches(data: &[u8], props: &vk::PhysicalDeviceProperties) -> bool {
    if data.len() < 32 {
        return false;
    }
    let u = |i: usize| u32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]);
    u(0) >= 32
        && u(4) == 1
        && u(8) == props.vendor_id
        && u(12) == props.device_id
        && data[16..32] == props.pipeline_cache_uuid
}

/// What an application enabled on the device it hands to [`Context::from_external_with`]
/// (Vulkan cannot be asked what a device was created with). The default is the required set
/// that [`Context::from_external`] documents, and no optional feature; penumbra checks the
/// claims against the physical device and refuses, listing every problem at once, when a
/// required one is missing or a claimed one is not supported.
#[derive(Clone, Copy, Debug)]
pub struct ExternalFeatures {
    /// `VK_KHR_push_descriptor` (required).
    pub push_descriptor: bool,
    /// Vulkan 1.3 `synchronization2`, `dynamicRendering` and `maintenance4` (required).
    pub vulkan13: bool,
    /// Vulkan 1.2 `scalarBlockLayout` and `hostQueryReset` (required).
    pub vulkan12: bool,
    /// Vulkan 1.2 `shaderOutputLayer` and `shaderOutputViewportIndex` (layered shadow maps;
    /// without them `shadowmaps` refuses to start and `auto` chooses another technique).
    pub shader_output_layer: bool,
    /// `tessellationShader` (vv's tessellation modes refuse without it).
    pub tessellation_shader: bool,
    /// `pipelineStatisticsQuery` (vv counts its tessellated triangles with it; without it the
    /// count is not kept).
    pub pipeline_statistics_query: bool,
    /// Vulkan 1.2 `timelineSemaphore` (recording into the host's command buffers,
    /// `Engine::record_into` / `Renderer::record_into`, refuses without it).
    pub timeline_semaphore: bool,
    /// The host's instance has `VK_EXT_debug_utils` enabled: penumbra names its objects and
    /// labels every pass in command buffers, so a capture tool (RenderDoc, Nsight) shows
    /// penumbra's passes by name inside the host's frame. Not checkable (the loader answers
    /// for the extension's commands whether or not the instance enabled it): declare it only
    /// when enabled.
    pub debug_utils: bool,
}

impl Default for ExternalFeatures {
    fn default() -> Self {
        ExternalFeatures {
            push_descriptor: true,
            vulkan13: true,
            vulkan12: true,
            shader_output_layer: false,
            tessellation_shader: false,
            pipeline_statistics_query: false,
            timeline_semaphore: false,
            debug_utils: false,
        }
    }
}

impl ExternalFeatures {
    /// Every problem with these claims on `physical`: required features not claimed, claimed
    /// features the device does not support (empty: usable).
    pub fn problems(&self, instance: &ash::Instance, physical: vk::PhysicalDevice) -> Vec<String> {
        let mut v = Vec::new();
        let props = unsafe { instance.get_physical_device_properties(physical) };
        if vk::api_version_major(props.api_version) == 1 && vk::api_version_minor(props.api_version) < 3 {
            v.push(format!(
                "the device supports Vulkan {}.{}, penumbra needs 1.3",
                vk::api_version_major(props.api_version),
                vk::api_version_minor(props.api_version)
            ));
        }
        let exts = unsafe { instance.enumerate_device_extension_properties(physical) }.unwrap_or_default();
        let has_push =
            exts.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|x| x == ash::khr::push_descriptor::NAME));
        let f10 = unsafe { instance.get_physical_device_features(physical) };
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
        {
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12).push_next(&mut f13);
            unsafe { instance.get_physical_device_features2(physical, &mut f2) };
        }
        let t = |b: vk::Bool32| b == vk::TRUE;
        let mut need = |claimed: bool, required: bool, supported: bool, name: &str| {
            if required && !claimed {
                v.push(format!("{name} is required but not declared as enabled"));
            } else if claimed && !supported {
                v.push(format!("{name} is declared as enabled but the device does not support it"));
            }
        };
        need(self.push_descriptor, true, has_push, "VK_KHR_push_descriptor");
        need(
            self.vulkan13,
            true,
            t(f13.synchronization2) && t(f13.dynamic_rendering) && t(f13.maintenance4),
            "Vulkan 1.3 synchronization2 + dynamicRendering + maintenance4",
        );
        need(
            self.vulkan12,
            true,
            t(f12.scalar_block_layout) && t(f12.host_query_reset),
            "Vulkan 1.2 scalarBlockLayout + hostQueryReset",
        );
        need(
            self.shader_output_layer,
            false,
            t(f12.shader_output_layer) && t(f12.shader_output_viewport_index),
            "shaderOutputLayer + shaderOutputViewportIndex",
        );
        need(self.tessellation_shader, false, t(f10.tessellation_shader), "tessellationShader");
        need(self.pipeline_statistics_query, false, t(f10.pipeline_statistics_query), "pipelineStatisticsQuery");
        need(self.timeline_semaphore, false, t(f12.timeline_semaphore), "timelineSemaphore");
        v
    }
}

/// An image with its memory and a view of all mips.
pub struct GpuImage {
    pub name: String,
    pub image: vk::Image,
    pub view: vk::ImageView,
    pub desc: ImageDesc,
    pub usage: vk::ImageUsageFlags,
    pub(crate) allocation: Option<Allocation>,
}

/// A buffer with its memory (mapped if host visible).
pub struct GpuBuffer {
    pub name: String,
    pub buffer: vk::Buffer,
    pub size: u64,
    pub usage: vk::BufferUsageFlags,
    pub host_visible: bool,
    /// With `UNIFORM_TEXEL_BUFFER` usage: a `R32G32B32A32_UINT` view of the buffer's whole
    /// 16-byte texels (at most `maxTexelBufferElements`), read in shaders as a `usamplerBuffer`
    /// ([`crate::record::Bind::TexelBuffer`]); destroyed with the buffer.
    pub texel_view: Option<vk::BufferView>,
    pub(crate) allocation: Option<Allocation>,
}

impl GpuBuffer {
    /// The property flags of the memory type the buffer lives in.
    pub fn memory_flags(&self) -> vk::MemoryPropertyFlags {
        self.allocation.as_ref().map(|a| a.memory_properties()).unwrap_or_default()
    }
}

/// A GPU object dropped without [`Context::destroy_image`] / [`Context::destroy_buffer`] keeps
/// its device memory until the context goes: say so, so that every owner frees on every path
/// (the test suite's output is searched for this line).
fn report_leak(kind: &str, name: &str) {
    if std::thread::panicking() {
        return;
    }
    eprintln!(
        "penumbra: {kind} '{name}' dropped without being destroyed (its memory leaks until the context is dropped)"
    );
}

impl Drop for GpuImage {
    fn drop(&mut self) {
        if self.allocation.is_some() {
            report_leak("image", &self.name);
        }
    }
}

impl Drop for GpuBuffer {
    fn drop(&mut self) {
        if self.allocation.is_some() {
            report_leak("buffer", &self.name);
        }
    }
}

impl GpuBuffer {
    /// The mapped bytes of a host-visible buffer.
    pub fn mapped(&self) -> Option<&[u8]> {
        let a = self.allocation.as_ref()?;
        let p = a.mapped_ptr()?;
        Some(unsafe { std::slice::from_raw_parts(p.as_ptr() as *const u8, self.size as usize) })
    }
    /// Writes `data` at the start of a host-visible buffer (only while the GPU does not use it).
    pub fn write(&mut self, data: &[u8]) -> Result<()> {
        let a = self.allocation.as_mut().ok_or_else(|| anyhow!("buffer '{}' has no memory", self.name))?;
        let s = a.mapped_slice_mut().ok_or_else(|| anyhow!("buffer '{}' is not host visible", self.name))?;
        if data.len() > s.len() {
            bail!("buffer '{}': {} bytes do not fit in {}", self.name, data.len(), s.len());
        }
        s[..data.len()].copy_from_slice(data);
        Ok(())
    }
}

pub struct Context {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    pub physical: vk::PhysicalDevice,
    pub device: ash::Device,
    pub queue: vk::Queue,
    pub queue_family: u32,
    pub device_name: String,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period: f64,
    pub timestamp_valid_bits: u32,
    pub push_descriptor: ash::khr::push_descriptor::Device,
    pub debug_utils: Option<ash::ext::debug_utils::Device>,
    debug_instance: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub validation: Arc<ValidationLog>,
    pub validation_enabled: bool,
    /// Vulkan 1.2 `shaderOutputLayer` (and `shaderOutputViewportIndex`) are enabled: a vertex
    /// shader may write `gl_Layer` (layered rendering of many shadow maps in one pass).
    /// [`Context::new`] enables them where the device has them; [`Context::from_external`]
    /// assumes the host did not.
    pub shader_output_layer: bool,
    /// `tessellationShader` is enabled (vv's tessellation modes).
    pub tessellation_shader: bool,
    /// `pipelineStatisticsQuery` is enabled (vv's triangle count).
    pub pipeline_statistics_query: bool,
    /// `timelineSemaphore` is enabled (frames recorded into a host's command buffers).
    pub timeline_semaphore: bool,
    /// `maxImageDimension2D`: the largest side of a 2D image on this device.
    pub max_image_dimension_2d: u32,
    /// `maxStorageBufferRange`: the most bytes one storage-buffer binding may span.
    pub max_storage_buffer_range: u32,
    /// `maxTexelBufferElements`: a buffer's texel view ([`GpuBuffer::texel_view`]) covers at
    /// most this many 16-byte texels.
    pub max_texel_buffer_elements: u32,
    /// The structure the compute ray tracer builds and walks ([`ContextDesc::tracer`]; `Auto`
    /// for a context made from an embedding application's device).
    pub tracer: TracerStructure,
    /// The loop guard's buffer and its device address ([`ContextDesc::loop_guard`]).
    loop_guard: Option<(GpuBuffer, u64)>,
    /// The Vulkan pipeline cache every pipeline of penumbra is created with.
    pub pipeline_cache: vk::PipelineCache,
    /// Where the cache is saved when the context is dropped (none: in memory only).
    pipeline_cache_file: Option<std::path::PathBuf>,
    /// Bytes of pipeline-cache data read from disk when the context was created (0: none).
    pub pipeline_cache_loaded: usize,
    allocator: ManuallyDrop<Mutex<Allocator>>,
    owned: bool,
}

fn device_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

impl Context {
    /// Creates an instance and a device of its own.
    pub fn new(desc: &ContextDesc) -> Result<Arc<Context>> {
        let entry = unsafe { ash::Entry::load() }.map_err(|e| {
            anyhow!("cannot load the Vulkan loader ({e}); install libvulkan1 and a driver (mesa-vulkan-drivers)")
        })?;
        let layer_name = c"VK_LAYER_KHRONOS_validation";
        let layers_avail = unsafe { entry.enumerate_instance_layer_properties()? };
        let has_layer = layers_avail.iter().any(|l| l.layer_name_as_c_str() == Ok(layer_name));
        if desc.validation && !has_layer {
            bail!("validation requested but VK_LAYER_KHRONOS_validation is not installed (apt-get install vulkan-validationlayers)");
        }
        let ext_avail = unsafe { entry.enumerate_instance_extension_properties(None)? };
        let has_ext = |n: &CStr| ext_avail.iter().any(|e| e.extension_name_as_c_str() == Ok(n));
        let debug_ext = ash::ext::debug_utils::NAME;
        let has_debug = has_ext(debug_ext);
        let mut exts: Vec<*const c_char> = desc.instance_extensions.iter().map(|e| e.as_ptr()).collect();
        if has_debug {
            exts.push(debug_ext.as_ptr());
        }
        let layers: Vec<*const c_char> = if desc.validation { vec![layer_name.as_ptr()] } else { vec![] };
        let app = vk::ApplicationInfo::default()
            .application_name(c"penumbra")
            .engine_name(c"penumbra")
            .api_version(vk::API_VERSION_1_3);
        let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
        let validation = Arc::new(ValidationLog::default());
        let severity = vk::DebugUtilsMessageSeverityFlagsEXT::ERROR | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING;
        let types = vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
            | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
            | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE;
        let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(severity)
            .message_type(types)
            .pfn_user_callback(Some(debug_callback))
            .user_data(Arc::as_ptr(&validation) as *mut std::ffi::c_void);
        let mut ci = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_extension_names(&exts)
            .enabled_layer_names(&layers);
        if desc.validation {
            ci = ci.push_next(&mut features);
        }
        if has_debug {
            // Also catches messages from vkCreateInstance/vkDestroyInstance.
            ci = ci.push_next(&mut messenger_info);
        }
        let instance = unsafe { entry.create_instance(&ci, None) }.context("vkCreateInstance")?;
        let debug_instance = if has_debug {
            let di = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(severity)
                .message_type(types)
                .pfn_user_callback(Some(debug_callback))
                .user_data(Arc::as_ptr(&validation) as *mut std::ffi::c_void);
            let m = unsafe { di.create_debug_utils_messenger(&info, None) }.context("debug messenger")?;
            Some((di, m))
        } else {
            None
        };

        // ---- physical device
        let phys = unsafe { instance.enumerate_physical_devices()? };
        let mut candidates = Vec::new();
        let mut rejected = Vec::new();
        for p in phys {
            let props = unsafe { instance.get_physical_device_properties(p) };
            let name = props.device_name_as_c_str().map(|c| c.to_string_lossy().into_owned()).unwrap_or_default();
            if vk::api_version_minor(props.api_version) < 3 && vk::api_version_major(props.api_version) == 1 {
                rejected.push(format!("{name}: Vulkan 1.3 required"));
                continue;
            }
            let dev_exts = unsafe { instance.enumerate_device_extension_properties(p)? };
            let has = |n: &CStr| dev_exts.iter().any(|e| e.extension_name_as_c_str() == Ok(n));
            if !has(ash::khr::push_descriptor::NAME) {
                rejected.push(format!("{name}: VK_KHR_push_descriptor missing"));
                continue;
            }
            let qf = unsafe { instance.get_physical_device_queue_family_properties(p) };
            let Some(family) = qf.iter().position(|q| {
                q.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE) && q.timestamp_valid_bits > 0
            }) else {
                rejected.push(format!("{name}: no graphics+compute queue with timestamps"));
                continue;
            };
            if let Some(want) = &desc.device_name {
                if !name.to_lowercase().contains(&want.to_lowercase()) {
                    rejected.push(format!("{name}: not '{want}'"));
                    continue;
                }
            }
            candidates.push((
                device_rank(props.device_type),
                p,
                family as u32,
                name,
                props,
                qf[family].timestamp_valid_bits,
            ));
        }
        candidates.sort_by_key(|c| c.0);
        let Some((_, physical, queue_family, device_name, props, ts_bits)) = candidates.into_iter().next() else {
            bail!(
                "no usable Vulkan device: {}",
                if rejected.is_empty() { "none found".into() } else { rejected.join("; ") }
            );
        };

        // ---- device
        let mut dev_exts = vec![ash::khr::push_descriptor::NAME.as_ptr()];
        if desc.swapchain {
            dev_exts.push(ash::khr::swapchain::NAME.as_ptr());
        }
        let avail = unsafe { instance.get_physical_device_features(physical) };
        let f10 = vk::PhysicalDeviceFeatures::default()
            .tessellation_shader(avail.tessellation_shader == vk::TRUE)
            .geometry_shader(avail.geometry_shader == vk::TRUE)
            .shader_storage_image_write_without_format(avail.shader_storage_image_write_without_format == vk::TRUE)
            .fill_mode_non_solid(avail.fill_mode_non_solid == vk::TRUE)
            .sampler_anisotropy(avail.sampler_anisotropy == vk::TRUE)
            .pipeline_statistics_query(avail.pipeline_statistics_query == vk::TRUE);
        let mut avail12 = vk::PhysicalDeviceVulkan12Features::default();
        {
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut avail12);
            unsafe { instance.get_physical_device_features2(physical, &mut f2) };
        }
        let shader_output_layer =
            avail12.shader_output_layer == vk::TRUE && avail12.shader_output_viewport_index == vk::TRUE;
        let timeline_semaphore = avail12.timeline_semaphore == vk::TRUE;
        if desc.loop_guard && avail12.buffer_device_address != vk::TRUE {
            bail!("the loop guard needs bufferDeviceAddress, which {device_name} does not have");
        }
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
            .buffer_device_address(desc.loop_guard)
            .host_query_reset(true)
            .scalar_block_layout(true)
            .timeline_semaphore(timeline_semaphore)
            .shader_output_layer(shader_output_layer)
            .shader_output_viewport_index(shader_output_layer);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
            .synchronization2(true)
            .dynamic_rendering(true)
            .maintenance4(true);
        let prio = [1.0f32];
        let qci = [vk::DeviceQueueCreateInfo::default().queue_family_index(queue_family).queue_priorities(&prio)];
        let dci = vk::DeviceCreateInfo::default()
            .queue_create_infos(&qci)
            .enabled_extension_names(&dev_exts)
            .enabled_features(&f10)
            .push_next(&mut f12)
            .push_next(&mut f13);
        let device = unsafe { instance.create_device(physical, &dci, None) }.context("vkCreateDevice")?;
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let ctx = Self::assemble(
            entry,
            instance,
            physical,
            device,
            queue,
            queue_family,
            device_name,
            props.limits.timestamp_period as f64,
            ts_bits,
            debug_instance,
            validation,
            desc.validation,
            true,
            desc.loop_guard,
            ExternalFeatures {
                shader_output_layer,
                tessellation_shader: avail.tessellation_shader == vk::TRUE,
                pipeline_statistics_query: avail.pipeline_statistics_query == vk::TRUE,
                timeline_semaphore,
                ..Default::default()
            },
            desc.pipeline_cache_dir.clone(),
        )?;
        let mut ctx = ctx;
        ctx.tracer = desc.tracer;
        Ok(Arc::new(ctx))
    }

    /// Wraps an application's instance/device/queue. The device must have been created with
    /// Vulkan 1.3 `synchronization2`, `dynamicRendering` and `maintenance4`, Vulkan 1.2 `hostQueryReset` and
    /// `scalarBlockLayout`, and `VK_KHR_push_descriptor`. penumbra does not destroy them. It
    /// assumes `shaderOutputLayer` is off (technique `shadowmaps` then refuses to start and `auto`
    /// chooses another); declare optional features with [`Context::from_external_with`]. Pass a
    /// clone of your `Entry`: the loader library must outlive your own use of the handles.
    pub fn from_external(
        entry: ash::Entry,
        instance: ash::Instance,
        physical: vk::PhysicalDevice,
        device: ash::Device,
        queue: vk::Queue,
        queue_family: u32,
    ) -> Result<Arc<Context>> {
        Self::from_external_with(entry, instance, physical, device, queue, queue_family, ExternalFeatures::default())
    }

    /// [`Context::from_external`] for a device created with the optional features in `features`
    /// enabled (penumbra cannot query what a device was created with).
    pub fn from_external_with(
        entry: ash::Entry,
        instance: ash::Instance,
        physical: vk::PhysicalDevice,
        device: ash::Device,
        queue: vk::Queue,
        queue_family: u32,
        features: ExternalFeatures,
    ) -> Result<Arc<Context>> {
        let mut problems = features.problems(&instance, physical);
        // the queue penumbra submits to (or records for): graphics and compute (transfer implied)
        let families = unsafe { instance.get_physical_device_queue_family_properties(physical) };
        match families.get(queue_family as usize) {
            None => {
                problems.push(format!("queue family {queue_family} does not exist ({} on this device)", families.len()))
            }
            Some(q) if !q.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE) => problems.push(
                format!("queue family {queue_family} has {:?}: penumbra needs GRAPHICS and COMPUTE", q.queue_flags),
            ),
            Some(_) => {}
        }
        if !problems.is_empty() {
            bail!(
                "the application's device cannot run penumbra ({} problem(s)): {}",
                problems.len(),
                problems.join("; ")
            );
        }
        let props = unsafe { instance.get_physical_device_properties(physical) };
        let name = props.device_name_as_c_str().map(|c| c.to_string_lossy().into_owned()).unwrap_or_default();
        let qf = unsafe { instance.get_physical_device_queue_family_properties(physical) };
        let bits = qf.get(queue_family as usize).map(|q| q.timestamp_valid_bits).unwrap_or(0);
        let ctx = Self::assemble(
            entry,
            instance,
            physical,
            device,
            queue,
            queue_family,
            name,
            props.limits.timestamp_period as f64,
            bits,
            None,
            Arc::new(ValidationLog::default()),
            false,
            false,
            false,
            features,
            // An embedding host's context keeps its pipeline cache in memory.
            None,
        )?;
        Ok(Arc::new(ctx))
    }

    fn assemble(
        entry: ash::Entry,
        instance: ash::Instance,
        physical: vk::PhysicalDevice,
        device: ash::Device,
        queue: vk::Queue,
        queue_family: u32,
        device_name: String,
        timestamp_period: f64,
        timestamp_valid_bits: u32,
        debug_instance: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
        validation: Arc<ValidationLog>,
        validation_enabled: bool,
        owned: bool,
        loop_guard: bool,
        features: ExternalFeatures,
        pipeline_cache_dir: Option<std::path::PathBuf>,
    ) -> Result<Context> {
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: loop_guard,
            allocation_sizes: Default::default(),
        })
        .context("gpu-allocator")?;
        let push_descriptor = ash::khr::push_descriptor::Device::new(&instance, &device);
        let max_image_dimension_2d =
            unsafe { instance.get_physical_device_properties(physical) }.limits.max_image_dimension2_d;
        let max_storage_buffer_range =
            unsafe { instance.get_physical_device_properties(physical) }.limits.max_storage_buffer_range;
        let max_texel_buffer_elements =
            unsafe { instance.get_physical_device_properties(physical) }.limits.max_texel_buffer_elements;
        let debug_utils = (debug_instance.is_some() || features.debug_utils)
            .then(|| ash::ext::debug_utils::Device::new(&instance, &device));
        // The pipeline cache, seeded from disk when this driver's file is there and sound.
        let props = unsafe { instance.get_physical_device_properties(physical) };
        let pipeline_cache_file = pipeline_cache_dir.map(|d| pipeline_cache_file(&d, &props));
        let initial: Vec<u8> = pipeline_cache_file
            .as_ref()
            .and_then(|f| {
                let len = std::fs::metadata(f).ok()?.len();
                if len > PIPELINE_CACHE_MAX_BYTES {
                    return None;
                }
                std::fs::read(f).ok()
            })
            .filter(|d| pipeline_cache_header_matches(d, &props))
            .unwrap_or_default();
        let pipeline_cache = unsafe {
            device
                .create_pipeline_cache(&vk::PipelineCacheCreateInfo::default().initial_data(&initial), None)
                .or_else(|_| device.create_pipeline_cache(&vk::PipelineCacheCreateInfo::default(), None))
        }
        .context("vkCreatePipelineCache")?;
        let mut ctx = Context {
            entry,
            instance,
            physical,
            device,
            queue,
            queue_family,
            device_name,
            timestamp_period,
            timestamp_valid_bits,
            push_descriptor,
            debug_utils,
            debug_instance,
            validation,
            validation_enabled,
            shader_output_layer: features.shader_output_layer,
            tessellation_shader: features.tessellation_shader,
            pipeline_statistics_query: features.pipeline_statistics_query,
            timeline_semaphore: features.timeline_semaphore,
            max_image_dimension_2d,
            max_storage_buffer_range,
            max_texel_buffer_elements,
            tracer: TracerStructure::Auto,
            pipeline_cache,
            pipeline_cache_file,
            pipeline_cache_loaded: initial.len(),
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            owned,
            loop_guard: None,
        };
        if loop_guard {
            let slots = 1024u64;
            let bytes = slots * (crate::glsl_compile::LOOP_GUARD_SLOT_WORDS * 4) as u64;
            let buf = ctx.create_readback_buffer(
                "loop_guard",
                bytes,
                vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
            )?;
            let address = unsafe {
                ctx.device.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(buf.buffer))
            };
            ctx.loop_guard = Some((buf, address));
            ctx.reset_loop_guard();
        }
        Ok(ctx)
    }

    /// How many shader slots the loop guard buffer holds (0 without it).
    pub fn loop_guard_slots(&self) -> usize {
        self.loop_guard.as_ref().map_or(0, |g| g.0.size as usize / (crate::glsl_compile::LOOP_GUARD_SLOT_WORDS * 4))
    }

    /// The loop guard buffer's device address ([`ContextDesc::loop_guard`]).
    pub fn loop_guard_address(&self) -> Option<u64> {
        self.loop_guard.as_ref().map(|g| g.1)
    }

    /// The loop guard's counts per shader slot (`ShaderLibrary::loop_guard_slot`): the most loop
    /// iterations one invocation ran, how many invocations reached 32768 and 65535, and 1 when
    /// any invocation of the shader returned (0: it did not run). Read
    /// after the frames were waited for (`Engine::finish`); the shaders write the buffer through
    /// its device address, outside the graph's declared accesses, and the guard is a debugging
    /// aid, not a synchronised output.
    pub fn loop_guard_counts(&self) -> Option<Vec<[u32; 4]>> {
        let bytes = self.loop_guard.as_ref()?.0.mapped()?;
        let words: Vec<u32> = bytes
            .chunks_exact(4)
            .map(|c| u32::from_le(unsafe { std::ptr::read_volatile(c.as_ptr() as *const u32) }))
            .collect();
        Some(words.chunks_exact(crate::glsl_compile::LOOP_GUARD_SLOT_WORDS).map(|s| [s[0], s[1], s[2], s[3]]).collect())
    }

    /// Sets the loop guard's counts to zero (while no frame is in flight).
    pub fn reset_loop_guard(&self) {
        let Some((buf, _)) = self.loop_guard.as_ref() else { return };
        if let Some(p) = buf.allocation.as_ref().and_then(|a| a.mapped_ptr()) {
            let words = p.as_ptr() as *mut u32;
            for i in 0..buf.size as usize / 4 {
                // device memory that shaders write through its address: volatile, never a &mut
                unsafe { std::ptr::write_volatile(words.add(i), 0) };
            }
        }
    }

    /// The driver's name and version (`VkPhysicalDeviceDriverProperties`, Vulkan 1.2), e.g.
    /// "llvmpipe: Mesa 22.3.6 (LLVM 15.0.6)".
    pub fn driver_info(&self) -> String {
        let mut driver = vk::PhysicalDeviceDriverProperties::default();
        let mut props = vk::PhysicalDeviceProperties2::default().push_next(&mut driver);
        unsafe { self.instance.get_physical_device_properties2(self.physical, &mut props) };
        let name = driver.driver_name_as_c_str().map(|c| c.to_string_lossy().into_owned()).unwrap_or_default();
        let info = driver.driver_info_as_c_str().map(|c| c.to_string_lossy().into_owned()).unwrap_or_default();
        format!("{name}: {info}")
    }

    /// Names a Vulkan object for validation messages and capture tools.
    pub fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        if let Some(du) = &self.debug_utils {
            let Ok(n) = CString::new(name) else { return };
            let info = vk::DebugUtilsObjectNameInfoEXT::default().object_handle(handle).object_name(&n);
            unsafe {
                let _ = du.set_debug_utils_object_name(&info);
            }
        }
    }

    pub fn begin_label(&self, cmd: vk::CommandBuffer, name: &str) {
        if let Some(du) = &self.debug_utils {
            let Ok(n) = CString::new(name) else { return };
            let label = vk::DebugUtilsLabelEXT::default().label_name(&n);
            unsafe { du.cmd_begin_debug_utils_label(cmd, &label) };
        }
    }

    pub fn end_label(&self, cmd: vk::CommandBuffer) {
        if let Some(du) = &self.debug_utils {
            unsafe { du.cmd_end_debug_utils_label(cmd) };
        }
    }

    fn allocate(
        &self,
        name: &str,
        req: vk::MemoryRequirements,
        location: MemoryLocation,
        linear: bool,
    ) -> Result<Allocation> {
        let mut a = self.allocator.lock().map_err(|_| anyhow!("allocator lock poisoned"))?;
        a.allocate(&AllocationCreateDesc {
            name,
            requirements: req,
            location,
            linear,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        })
        .with_context(|| format!("allocating memory for '{name}'"))
    }

    /// Creates a 2D image (all mips/layers in one view).
    pub fn create_image(&self, name: &str, desc: &ImageDesc, usage: vk::ImageUsageFlags) -> Result<GpuImage> {
        if desc.width == 0 || desc.height == 0 {
            bail!("image '{name}' has a zero extent {}x{}", desc.width, desc.height);
        }
        let ci = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_2D)
            .format(desc.format)
            .extent(vk::Extent3D { width: desc.width, height: desc.height, depth: 1 })
            .mip_levels(desc.mip_levels)
            .array_layers(desc.array_layers)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        let image =
            unsafe { self.device.create_image(&ci, None) }.with_context(|| format!("vkCreateImage '{name}'"))?;
        let req = unsafe { self.device.get_image_memory_requirements(image) };
        let allocation = match self.allocate(name, req, MemoryLocation::GpuOnly, false) {
            Ok(a) => a,
            Err(e) => {
                unsafe { self.device.destroy_image(image, None) };
                return Err(e);
            }
        };
        unsafe { self.device.bind_image_memory(image, allocation.memory(), allocation.offset())? };
        let view_type = if desc.array_layers > 1 || desc.array_view {
            vk::ImageViewType::TYPE_2D_ARRAY
        } else {
            vk::ImageViewType::TYPE_2D
        };
        let vci =
            vk::ImageViewCreateInfo::default().image(image).view_type(view_type).format(desc.format).subresource_range(
                vk::ImageSubresourceRange {
                    aspect_mask: desc.aspect(),
                    base_mip_level: 0,
                    level_count: desc.mip_levels,
                    base_array_layer: 0,
                    layer_count: desc.array_layers,
                },
            );
        // a view only where the usage allows one (a transfer-only image has none: null)
        let viewable = vk::ImageUsageFlags::SAMPLED
            | vk::ImageUsageFlags::STORAGE
            | vk::ImageUsageFlags::COLOR_ATTACHMENT
            | vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
            | vk::ImageUsageFlags::INPUT_ATTACHMENT
            | vk::ImageUsageFlags::TRANSIENT_ATTACHMENT;
        let view = if usage.intersects(viewable) {
            match unsafe { self.device.create_image_view(&vci, None) } {
                Ok(v) => v,
                Err(e) => {
                    unsafe { self.device.destroy_image(image, None) };
                    if let Ok(mut a) = self.allocator.lock() {
                        let _ = a.free(allocation);
                    }
                    return Err(anyhow::Error::new(e).context(format!("vkCreateImageView '{name}'")));
                }
            }
        } else {
            vk::ImageView::null()
        };
        self.set_name(image, name);
        if view != vk::ImageView::null() {
            self.set_name(view, &format!("{name}.view"));
        }
        Ok(GpuImage { name: name.to_string(), image, view, desc: desc.clone(), usage, allocation: Some(allocation) })
    }

    /// Creates a buffer; host-visible ones are persistently mapped (write-combined memory, which
    /// the device may read fast and the host should only write: readbacks take
    /// [`Context::create_readback_buffer`]).
    pub fn create_buffer(
        &self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        host_visible: bool,
    ) -> Result<GpuBuffer> {
        let loc = if host_visible { MemoryLocation::CpuToGpu } else { MemoryLocation::GpuOnly };
        self.create_buffer_at(name, size, usage, loc)
    }

    /// A persistently mapped buffer the device writes and the host reads: host-cached memory
    /// where the device has it. (Reading `CpuToGpu` memory, uncached and on a discrete GPU often
    /// device-local behind the PCIe BAR, took about 200 ms per 640x480 RGBA32F frame on an
    /// NVIDIA H200; lavapipe's memory is host memory either way.)
    pub fn create_readback_buffer(&self, name: &str, size: u64, usage: vk::BufferUsageFlags) -> Result<GpuBuffer> {
        self.create_buffer_at(name, size, usage, MemoryLocation::GpuToCpu)
    }

    fn create_buffer_at(
        &self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        loc: MemoryLocation,
    ) -> Result<GpuBuffer> {
        let host_visible = loc != MemoryLocation::GpuOnly;
        let size = size.max(4);
        let ci = vk::BufferCreateInfo::default().size(size).usage(usage).sharing_mode(vk::SharingMode::EXCLUSIVE);
        let buffer =
            unsafe { self.device.create_buffer(&ci, None) }.with_context(|| format!("vkCreateBuffer '{name}'"))?;
        let req = unsafe { self.device.get_buffer_memory_requirements(buffer) };
        let allocation = match self.allocate(name, req, loc, true) {
            Ok(a) => a,
            Err(e) => {
                unsafe { self.device.destroy_buffer(buffer, None) };
                return Err(e);
            }
        };
        if let Err(e) = unsafe { self.device.bind_buffer_memory(buffer, allocation.memory(), allocation.offset()) } {
            unsafe { self.device.destroy_buffer(buffer, None) };
            if let Ok(mut al) = self.allocator.lock() {
                let _ = al.free(allocation);
            }
            return Err(anyhow::Error::from(e).context(format!("vkBindBufferMemory '{name}'")));
        }
        let mut b = GpuBuffer {
            name: name.to_string(),
            buffer,
            size,
            usage,
            host_visible,
            texel_view: None,
            allocation: Some(allocation),
        };
        self.set_name(buffer, name);
        let texels = (size / 16).min(self.max_texel_buffer_elements as u64);
        if usage.contains(vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER) && texels > 0 {
            let ci = vk::BufferViewCreateInfo::default()
                .buffer(buffer)
                .format(vk::Format::R32G32B32A32_UINT)
                .offset(0)
                .range(texels * 16);
            match unsafe { self.device.create_buffer_view(&ci, None) } {
                Ok(v) => b.texel_view = Some(v),
                Err(e) => {
                    self.destroy_buffer(b);
                    return Err(anyhow::Error::from(e).context(format!("vkCreateBufferView '{name}'")));
                }
            }
        }
        Ok(b)
    }

    /// A host-visible buffer holding `data` (meshes, constants): contents visible to the GPU at
    /// the next queue submission.
    pub fn create_buffer_with_data(&self, name: &str, data: &[u8], usage: vk::BufferUsageFlags) -> Result<GpuBuffer> {
        let mut b = self.create_buffer(name, data.len() as u64, usage, true)?;
        b.write(data)?;
        Ok(b)
    }

    pub fn destroy_image(&self, mut img: GpuImage) {
        unsafe {
            self.device.destroy_image_view(img.view, None);
            self.device.destroy_image(img.image, None);
        }
        if let Some(a) = img.allocation.take() {
            if let Ok(mut al) = self.allocator.lock() {
                let _ = al.free(a);
            }
        }
    }

    pub fn destroy_buffer(&self, mut buf: GpuBuffer) {
        if let Some(v) = buf.texel_view.take() {
            unsafe { self.device.destroy_buffer_view(v, None) };
        }
        unsafe { self.device.destroy_buffer(buf.buffer, None) };
        if let Some(a) = buf.allocation.take() {
            if let Ok(mut al) = self.allocator.lock() {
                let _ = al.free(a);
            }
        }
    }

    pub fn wait_idle(&self) -> Result<()> {
        unsafe { self.device.device_wait_idle()? };
        Ok(())
    }

    /// Device memory held through the allocator now: (bytes allocated, live allocations, bytes
    /// of memory blocks reserved). A renderer dropped returns the counts to what they were
    /// before it was created (tests check it: no leak); a renderer running for hours keeps them
    /// flat (the soak bench).
    pub fn memory_report(&self) -> (u64, usize, u64) {
        match self.allocator.lock() {
            Ok(a) => {
                let r = a.generate_report();
                (r.total_allocated_bytes, r.allocations.len(), r.total_capacity_bytes)
            }
            Err(_) => (0, 0, 0),
        }
    }

    /// Creates a shader module from SPIR-V bytes (as embedded by build.rs).
    pub fn create_shader_module(&self, name: &str, spirv: &[u8]) -> Result<vk::ShaderModule> {
        let words = ash::util::read_spv(&mut std::io::Cursor::new(spirv))
            .with_context(|| format!("shader '{name}' is not SPIR-V"))?;
        let ci = vk::ShaderModuleCreateInfo::default().code(&words);
        let m = unsafe { self.device.create_shader_module(&ci, None) }
            .with_context(|| format!("shader module '{name}'"))?;
        self.set_name(m, name);
        Ok(m)
    }
}

impl Context {
    /// Writes the pipeline cache to its file (atomically: a temporary file renamed over it),
    /// unless nothing was added since it was read. Called when the context is dropped.
    pub fn save_pipeline_cache(&self) -> Result<()> {
        let Some(file) = &self.pipeline_cache_file else { return Ok(()) };
        let data =
            unsafe { self.device.get_pipeline_cache_data(self.pipeline_cache) }.context("vkGetPipelineCacheData")?;
        if data.is_empty() || data.len() == self.pipeline_cache_loaded {
            return Ok(());
        }
        let dir = file.parent().unwrap_or(std::path::Path::new("."));
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let tmp = file.with_extension(format!("tmp.{}", std::process::id()));
        std::fs::write(&tmp, &data).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, file).with_context(|| format!("cannot replace {}", file.display()))?;
        Ok(())
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        if let Err(e) = self.save_pipeline_cache() {
            tracing::warn!("the pipeline cache was not saved: {e:#}");
        }
        unsafe {
            // a host's device is the host's to wait on: every engine on this context waited for
            // its own frames when it was dropped
            if self.owned {
                let _ = self.device.device_wait_idle();
            }
            self.device.destroy_pipeline_cache(self.pipeline_cache, None);
            if let Some((buf, _)) = self.loop_guard.take() {
                self.destroy_buffer(buf);
            }
            ManuallyDrop::drop(&mut self.allocator);
            if self.owned {
                self.device.destroy_device(None);
                if let Some((di, m)) = self.debug_instance.take() {
                    di.destroy_debug_utils_messenger(m, None);
                }
                self.instance.destroy_instance(None);
            }
        }
    }
}
