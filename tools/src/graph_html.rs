//! `graph.html` beside `render`'s other dumps: the compiled graph of the last frame
//! ([`penumbra::engine::dump_html`]) with thumbnails of that frame's images.

use penumbra::engine::dump_html::HtmlImage;
use penumbra::FrameImages;
use penumbra_reference::image::png_rgb8_bytes;

/// Largest thumbnail side (pixels).
const THUMB: u32 = 160;

/// The frame's images as thumbnails: the final LDR image (`ldr`), and every dumped image
/// (`--dump-passes`: G-buffer, HDR) under its resource's name. Dumped images are mapped for
/// viewing: HDR radiance `x / (1 + x)`, everything else each channel's finite range to 0..1;
/// both with a 2.2 gamma.
pub fn thumbnails(img: &FrameImages) -> Vec<HtmlImage> {
    let (w, h) = (img.width, img.height);
    let step = w.max(h).div_ceil(THUMB).max(1);
    let (tw, th) = (w.div_ceil(step), h.div_ceil(step));
    let mut out = Vec::new();
    let mut push = |name: &str, texel: &dyn Fn(u32, u32) -> [f32; 3]| {
        let mut rgb = Vec::with_capacity((tw * th * 3) as usize);
        for y in 0..th {
            for x in 0..tw {
                let t = texel((x * step).min(w - 1), (y * step).min(h - 1));
                rgb.extend(t.map(|v| (v.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8));
            }
        }
        if let Ok(png) = png_rgb8_bytes(tw, th, &rgb) {
            out.push(HtmlImage { name: name.to_string(), png });
        }
    };
    if w == 0 || h == 0 {
        return Vec::new();
    }
    if img.ldr.len() >= (w * h * 4) as usize {
        push("ldr", &|x, y| {
            let i = ((y * w + x) * 4) as usize;
            // the LDR image is already display-encoded: undo the gamma applied above
            [0, 1, 2].map(|c| (img.ldr[i + c] as f32 / 255.0).powf(2.2))
        });
    }
    for (name, texels) in &img.dumps {
        if texels.len() < (w * h) as usize {
            continue;
        }
        let name = name.strip_prefix("dump:").unwrap_or(name);
        if name == "hdr" {
            push(name, &|x, y| {
                let p = texels[(y * w + x) as usize];
                [0, 1, 2].map(|c| if p[c].is_finite() { p[c].max(0.0) / (1.0 + p[c].max(0.0)) } else { 0.0 })
            });
        } else {
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for p in texels {
                for c in 0..3 {
                    if p[c].is_finite() {
                        lo[c] = lo[c].min(p[c]);
                        hi[c] = hi[c].max(p[c]);
                    }
                }
            }
            push(name, &|x, y| {
                let p = texels[(y * w + x) as usize];
                [0, 1, 2].map(|c| {
                    let r = hi[c] - lo[c];
                    if p[c].is_finite() && r > 0.0 {
                        (p[c] - lo[c]) / r
                    } else {
                        0.0
                    }
                })
            });
        }
    }
    out
}
