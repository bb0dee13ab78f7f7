//! Embedding penumbra in an application that owns its Vulkan instance, device, queue and
//! render target: penumbra renders the default scene into the application's image.
//!
//! Run: `cargo run --example embed`

use anyhow::{Context as _, Result};
use ash::vk;
use penumbra::engine::Context;
use penumbra::{target_image, RenderSettings, Renderer};
use penumbra_scene::Scene;

/// Returns the mean of the tone-mapped target (0..255).
pub fn run() -> Result<f64> {
    // ---- the application's own Vulkan objects
    let entry = unsafe { ash::Entry::load()? };
    let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
    let instance = unsafe { entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app), None)? };
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
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
        .host_query_reset(true)
        .scalar_block_layout(true)
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
    let features = penumbra::engine::ExternalFeatures { shader_output_layer: layered, ..Default::default() };
    let ctx = Context::from_external_with(
        entry.clone(),
        instance.clone(),
        physical,
        device.clone(),
        queue,
        family,
        features,
    )?;
    let scene = Scene::default_scene();
    let mut renderer = Renderer::new(ctx, &scene, RenderSettings { width: w, height: h, ..Default::default() })?;
    let frame = scene.at(0.0, None);
    // Render into the application's image and read it back (the target is left in
    // TRANSFER_SRC_OPTIMAL for the application's next use).
    let mut images = renderer.render(&frame, Some(target_image(image, view, w, h, usage)), true)?;
    images.extend(renderer.finish()?);
    let ldr = &images.first().context("no frame")?.ldr;
    let mean = ldr.iter().map(|&b| b as f64).sum::<f64>() / ldr.len().max(1) as f64;
    drop(renderer);

    unsafe {
        device.destroy_image_view(view, None);
        device.destroy_image(image, None);
        device.free_memory(memory, None);
        device.destroy_device(None);
        instance.destroy_instance(None);
    }
    Ok(mean)
}

#[allow(dead_code)]
fn main() -> Result<()> {
    let mean = run()?;
    println!("rendered the default scene into the application's image; mean value {mean:.1}");
    Ok(())
}
