//! Embedding penumbra in an application that owns its Vulkan instance, device, queue and
//! render target, in both modes: penumbra renders the default scene into the application's
//! image and submits the work itself (`Renderer::render`), then records the same frame into the
//! application's own command buffer (`Renderer::record_into`), between commands of the
//! application's, and the application submits it, signalling penumbra's timeline semaphore.
//!
//! Run: `cargo run --example embed`

use anyhow::{Context as _, Result};
use ash::vk;
use penumbra::engine::Context;
use penumbra::{target_image, RenderSettings, Renderer};
use penumbra_scene::Scene;

/// What the example saw: the mean of the tone-mapped target (0..255) when penumbra submitted,
/// and the bytes the application copied out of its image in its own command buffer after
/// penumbra's recorded passes, beside penumbra's readback of that frame.
pub struct Embedded {
    pub submitted_mean: f64,
    pub host_copy: Vec<u8>,
    pub penumbra_readback: Vec<u8>,
    /// penumbra names its objects and labels its passes on the application's device (the
    /// application enabled VK_EXT_debug_utils and said so).
    pub labelled: bool,
}

/// Runs both modes.
pub fn run() -> Result<Embedded> {
    // ---- the application's own Vulkan objects
    let entry = unsafe { ash::Entry::load()? };
    let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
    // VK_EXT_debug_utils where the loader has it: penumbra then names its objects and labels its
    // passes inside the application's frames (declared below), for RenderDoc and the like
    let debug_utils = unsafe { entry.enumerate_instance_extension_properties(None)? }
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));
    let instance_exts: Vec<_> = debug_utils.then_some(ash::ext::debug_utils::NAME.as_ptr()).into_iter().collect();
    let instance = unsafe {
        entry.create_instance(
            &vk::InstanceCreateInfo::default().application_info(&app).enabled_extension_names(&instance_exts),
            None,
        )?
    };
    let physical = unsafe { instance.enumerate_physical_devices()? }.into_iter().next().context("no Vulkan device")?;
    let family = unsafe { instance.get_physical_device_queue_family_properties(physical) }
        .iter()
        .position(|q| q.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE))
        .context("no graphics+compute queue")? as u32;
    // What penumbra needs from an external device (see Context::from_external).
    let exts = [ash::khr::push_descriptor::NAME.as_ptr()];
    // Optional: layered rendering (shaderOutputLayer), which technique `shadowmaps` (what `auto`
    // chooses for a lit scene) needs; declared to penumbra below.
    let mut avail12 = vk::PhysicalDeviceVulkan12Features::default();
    unsafe {
        instance.get_physical_device_features2(
            physical,
            &mut vk::PhysicalDeviceFeatures2::default().push_next(&mut avail12),
        )
    };
    let layered = avail12.shader_output_layer == vk::TRUE && avail12.shader_output_viewport_index == vk::TRUE;
    // timelineSemaphore: for recording into the application's command buffers (mode 2)
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
        .host_query_reset(true)
        .scalar_block_layout(true)
        .timeline_semaphore(true)
        .shader_output_layer(layered)
        .shader_output_viewport_index(layered);
    let mut f13 =
        vk::PhysicalDeviceVulkan13Features::default().synchronization2(true).dynamic_rendering(true).maintenance4(true);
    let prio = [1.0];
    let qci = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&prio)];
    let device = unsafe {
        instance.create_device(
            physical,
            &vk::DeviceCreateInfo::default()
                .queue_create_infos(&qci)
                .enabled_extension_names(&exts)
                .push_next(&mut f12)
                .push_next(&mut f13),
            None,
        )?
    };
    let queue = unsafe { device.get_device_queue(family, 0) };

    // The application's render target.
    let (w, h) = (96u32, 64u32);
    let usage = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_SRC;
    let image = unsafe {
        device.create_image(
            &vk::ImageCreateInfo::default()
                .image_type(vk::ImageType::TYPE_2D)
                .format(vk::Format::R8G8B8A8_UNORM)
                .extent(vk::Extent3D { width: w, height: h, depth: 1 })
                .mip_levels(1)
                .array_layers(1)
                .samples(vk::SampleCountFlags::TYPE_1)
                .usage(usage),
            None,
        )?
    };
    let req = unsafe { device.get_image_memory_requirements(image) };
    let props = unsafe { instance.get_physical_device_memory_properties(physical) };
    let type_index =
        (0..props.memory_type_count).find(|&i| req.memory_type_bits & (1 << i) != 0).context("no memory type")?;
    let memory = unsafe {
        device.allocate_memory(
            &vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(type_index),
            None,
        )?
    };
    unsafe { device.bind_image_memory(image, memory, 0)? };
    let view = unsafe {
        device.create_image_view(
            &vk::ImageViewCreateInfo::default()
                .image(image)
                .view_type(vk::ImageViewType::TYPE_2D)
                .format(vk::Format::R8G8B8A8_UNORM)
                .subresource_range(vk::ImageSubresourceRange {
                    aspect_mask: vk::ImageAspectFlags::COLOR,
                    base_mip_level: 0,
                    level_count: 1,
                    base_array_layer: 0,
                    layer_count: 1,
                }),
            None,
        )?
    };

    // ---- penumbra on the application's device
    let features = penumbra::engine::ExternalFeatures {
        shader_output_layer: layered,
        timeline_semaphore: true,
        debug_utils,
        ..Default::default()
    };
    let ctx = Context::from_external_with(
        entry.clone(),
        instance.clone(),
        physical,
        device.clone(),
        queue,
        family,
        features,
    )?;
    let labelled = ctx.debug_utils.is_some();
    let scene = Scene::default_scene();
    let mut renderer = Renderer::new(ctx, &scene, RenderSettings { width: w, height: h, ..Default::default() })?;
    let frame = scene.at(0.0, None);
    // ---- mode 1: penumbra submits. Render into the application's image and read it back (the
    // target is left in TRANSFER_SRC_OPTIMAL for the application's next use).
    let mut images = renderer.render(&frame, Some(target_image(image, view, w, h, usage)), true)?;
    images.extend(renderer.finish()?);
    let ldr = &images.first().context("no frame")?.ldr;
    let submitted_mean = ldr.iter().map(|&b| b as f64).sum::<f64>() / ldr.len().max(1) as f64;

    // ---- mode 2: the application records penumbra's passes into its own command buffer
    let pool =
        unsafe { device.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(family), None)? };
    let cmd = unsafe {
        device.allocate_command_buffers(
            &vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1),
        )?[0]
    };
    // a host-visible buffer the application copies its image into
    let bytes = (w * h * 4) as u64;
    let buffer = unsafe {
        device.create_buffer(
            &vk::BufferCreateInfo::default().size(bytes).usage(vk::BufferUsageFlags::TRANSFER_DST),
            None,
        )?
    };
    let breq = unsafe { device.get_buffer_memory_requirements(buffer) };
    let host_visible = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
    let btype = (0..props.memory_type_count)
        .find(|&i| {
            breq.memory_type_bits & (1 << i) != 0
                && props.memory_types[i as usize].property_flags.contains(host_visible)
        })
        .context("no host-visible memory type")?;
    let bmemory = unsafe {
        device.allocate_memory(
            &vk::MemoryAllocateInfo::default().allocation_size(breq.size).memory_type_index(btype),
            None,
        )?
    };
    unsafe { device.bind_buffer_memory(buffer, bmemory, 0)? };
    let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None)? };
    unsafe {
        device.begin_command_buffer(
            cmd,
            &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
        )?
    };
    // (the application's own passes would go here)
    // penumbra's passes; the target leaves them in TRANSFER_SRC_OPTIMAL, made visible to transfer
    // reads by penumbra's last barrier
    let recorded = renderer.record_into(&frame, Some(target_image(image, view, w, h, usage)), true, cmd)?;
    // the application's pass after penumbra's: copy its image into its buffer
    let region = vk::BufferImageCopy::default()
        .image_subresource(vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        })
        .image_extent(vk::Extent3D { width: w, height: h, depth: 1 });
    unsafe {
        device.cmd_copy_image_to_buffer(cmd, image, vk::ImageLayout::TRANSFER_SRC_OPTIMAL, buffer, &[region]);
        let to_host = vk::MemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::COPY)
            .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::HOST)
            .dst_access_mask(vk::AccessFlags2::HOST_READ);
        device.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&[to_host]));
        device.end_command_buffer(cmd)?;
        // one submission: the application's commands and penumbra's, signalling penumbra's
        // timeline value (and the application's own fence)
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
        let signals = [recorded.signal.submit_info()];
        let submit = [vk::SubmitInfo2::default().command_buffer_infos(&cmds).signal_semaphore_infos(&signals)];
        device.queue_submit2(queue, &submit, fence)?;
        device.wait_for_fences(&[fence], true, u64::MAX)?;
    }
    let host_copy = unsafe {
        let p = device.map_memory(bmemory, 0, bytes, vk::MemoryMapFlags::empty())?;
        let v = std::slice::from_raw_parts(p as *const u8, bytes as usize).to_vec();
        device.unmap_memory(bmemory);
        v
    };
    // penumbra learns from its semaphore that the frame is done: its images come back
    let mut later = recorded.done;
    later.extend(renderer.finish()?);
    let penumbra_readback = later.pop().context("the recorded frame did not come back")?.ldr;
    drop(renderer);

    unsafe {
        device.destroy_fence(fence, None);
        device.destroy_buffer(buffer, None);
        device.free_memory(bmemory, None);
        device.destroy_command_pool(pool, None);
        device.destroy_image_view(view, None);
        device.destroy_image(image, None);
        device.free_memory(memory, None);
        device.destroy_device(None);
        instance.destroy_instance(None);
    }
    Ok(Embedded { submitted_mean, host_copy, penumbra_readback, labelled })
}

#[allow(dead_code)]
fn main() -> Result<()> {
    let e = run()?;
    println!(
        "rendered the default scene into the application's image: penumbra submitting (mean value {:.1}), then \
         recorded into the application's command buffer ({} bytes copied out by the application, {})",
        e.submitted_mean,
        e.host_copy.len(),
        if e.host_copy == e.penumbra_readback {
            "identical to penumbra's readback"
        } else {
            "DIFFERENT from penumbra's readback"
        }
    );
    Ok(())
}
