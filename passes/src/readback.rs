//! The `readback` transfer pass: copies images into host-visible buffers returned by the engine
//! after the frame (EXR/PNG output, tests, per-pass image dumps).

use penumbra_engine::graph::access::format_texel_bytes;
use penumbra_engine::{vk, Access, BufferHandle, Graph, ImageHandle, PassKind};

/// Copies each `(image, readback name)` (mip 0) into a readback buffer of that name, all in one
/// pass called `name`. Returns the buffer handles.
pub fn add(graph: &mut Graph, name: &str, images: &[(ImageHandle, &str)]) -> Vec<BufferHandle> {
    let mut jobs = Vec::new();
    for (img, rb_name) in images {
        let d = graph.image_desc(*img).clone();
        let size = d.width as u64 * d.height as u64 * format_texel_bytes(d.format);
        let buf = graph.create_readback(rb_name, size);
        jobs.push((*img, buf, d));
    }
    let mut p = graph.pass(name, PassKind::Transfer);
    let mut out = Vec::new();
    let mut declared = Vec::new();
    for (img, buf, d) in jobs {
        let img = p.read(img, Access::TransferSrc);
        let buf = p.write(buf, Access::TransferDst);
        out.push(buf);
        declared.push((img, buf, d));
    }
    p.record(move |rc| {
        for (img, buf, d) in &declared {
            let src = rc.image(*img)?;
            let dst = rc.buffer(*buf)?;
            let region = vk::BufferImageCopy::default()
                .image_subresource(vk::ImageSubresourceLayers {
                    aspect_mask: d.aspect(),
                    mip_level: 0,
                    base_array_layer: 0,
                    layer_count: 1,
                })
                .image_extent(vk::Extent3D { width: d.width, height: d.height, depth: 1 });
            let from = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
            unsafe { rc.device().cmd_copy_image_to_buffer(rc.cmd, src.image, from, dst.buffer, &[region]) };
        }
        Ok(())
    });
    out
}
