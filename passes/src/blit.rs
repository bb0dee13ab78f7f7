//! The `blit` transfer pass: copies a colour image into another of any blittable colour format
//! and size (`vkCmdBlitImage`, which also swizzles and converts, e.g. RGBA8 -> a BGRA8
//! swapchain image). Used when the output target cannot be a storage image.

use penumbra_engine::{vk, Access, Graph, ImageHandle, PassKind};

/// Adds the pass `name` blitting mip 0 of `src` over the whole of `dst` (linear filter when the
/// sizes differ). Returns the new version of `dst`.
pub fn add(graph: &mut Graph, name: &str, src: ImageHandle, dst: ImageHandle) -> ImageHandle {
    let (s, d) = (graph.image_desc(src).clone(), graph.image_desc(dst).clone());
    let mut p = graph.pass(name, PassKind::Transfer);
    let src = p.read(src, Access::TransferSrc);
    let dst = p.write(dst, Access::TransferDst);
    p.record(move |rc| {
        let (si, di) = (rc.image(src)?, rc.image(dst)?);
        let layers =
            |aspect_mask| vk::ImageSubresourceLayers { aspect_mask, mip_level: 0, base_array_layer: 0, layer_count: 1 };
        let corner = |w: u32, h: u32| [vk::Offset3D::default(), vk::Offset3D { x: w as i32, y: h as i32, z: 1 }];
        let region = vk::ImageBlit::default()
            .src_subresource(layers(s.aspect()))
            .src_offsets(corner(s.width, s.height))
            .dst_subresource(layers(d.aspect()))
            .dst_offsets(corner(d.width, d.height));
        let filter = if (s.width, s.height) == (d.width, d.height) { vk::Filter::NEAREST } else { vk::Filter::LINEAR };
        let (from, to) = (vk::ImageLayout::TRANSFER_SRC_OPTIMAL, vk::ImageLayout::TRANSFER_DST_OPTIMAL);
        unsafe { rc.device().cmd_blit_image(rc.cmd, si.image, from, di.image, to, &[region], filter) };
        Ok(())
    });
    dst
}
