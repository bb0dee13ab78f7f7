//! CPU images: material textures and environment-map loading (EXR, Radiance HDR).

use crate::error::SceneError;
use crate::limits::{Budget, Limits};
use crate::Environment;
use glam::{Vec2, Vec3, Vec4};
use std::path::Path;

/// A CPU texture in linear RGBA float, row-major, row 0 at v = 0 (glTF convention: uv (0,0)
/// is the top-left texel). Albedo maps store linear RGB (sRGB sources are converted on load);
/// roughness maps store roughness in the G channel (glTF metallicRoughness layout: G =
/// roughness, B = metallic).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub texels: Vec<[f32; 4]>,
}

/// Procedural texture patterns usable from scene files.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pattern {
    /// `scale` x `scale` checkerboard of colours `a` and `b`.
    Checker,
    /// `scale` stripes along u.
    Stripes,
    /// Smooth value noise with `scale` cells per unit uv, blending `a` and `b`.
    Noise,
}

impl Texture {
    /// Bilinear lookup with repeat wrapping.
    pub fn sample(&self, uv: Vec2) -> Vec4 {
        if self.width == 0 || self.height == 0 || self.texels.len() < (self.width * self.height) as usize {
            return Vec4::ONE;
        }
        let (w, h) = (self.width as f32, self.height as f32);
        let x = uv.x * w - 0.5;
        let y = uv.y * h - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: f32, j: f32| {
            let i = (i as i64).rem_euclid(self.width as i64) as usize;
            let j = (j as i64).rem_euclid(self.height as i64) as usize;
            Vec4::from_array(self.texels[j * self.width as usize + i])
        };
        let a = at(x0, y0).lerp(at(x0 + 1.0, y0), fx);
        let b = at(x0, y0 + 1.0).lerp(at(x0 + 1.0, y0 + 1.0), fx);
        a.lerp(b, fy)
    }

    /// A procedural texture of `size` x `size` texels.
    pub fn pattern(name: &str, pattern: Pattern, size: u32, scale: f32, a: Vec4, b: Vec4) -> Self {
        let size = size.clamp(1, 2048);
        let mut texels = Vec::with_capacity((size * size) as usize);
        for j in 0..size {
            for i in 0..size {
                let u = (i as f32 + 0.5) / size as f32;
                let v = (j as f32 + 0.5) / size as f32;
                let t = match pattern {
                    Pattern::Checker => (((u * scale).floor() + (v * scale).floor()) as i64).rem_euclid(2) as f32,
                    Pattern::Stripes => ((u * scale).floor() as i64).rem_euclid(2) as f32,
                    Pattern::Noise => value_noise(u * scale, v * scale, scale.round().max(1.0) as i64),
                };
                texels.push(a.lerp(b, t).to_array());
            }
        }
        Texture { name: name.into(), width: size, height: size, texels }
    }

    /// Load a PNG or JPEG (or any format the `image` features enable). `srgb` converts the
    /// colour channels from sRGB to linear (albedo maps); data maps (roughness) keep values.
    pub fn load(path: &Path, srgb: bool) -> Result<Self, SceneError> {
        Self::load_with(path, srgb, &Budget::new(Limits::default()))
    }

    /// Decodes an encoded image (PNG, JPEG) from memory within `budget`; `path` names it in
    /// messages.
    pub fn from_bytes_with(path: &Path, bytes: &[u8], srgb: bool, budget: &Budget) -> Result<Self, SceneError> {
        let img = decode_checked(path, "the texture", bytes, None, budget, 16)?;
        Ok(Self::from_dynamic(&path.display().to_string(), &img, srgb))
    }

    /// [`Texture::load`] checking the image's header against `budget` before decoding.
    pub fn load_with(path: &Path, srgb: bool, budget: &Budget) -> Result<Self, SceneError> {
        let bytes = budget.read_data_file(path, "texture file")?;
        let img = decode_checked(path, "the texture", &bytes, None, budget, 16)?;
        Ok(Self::from_dynamic(&path.display().to_string(), &img, srgb))
    }

    pub(crate) fn from_dynamic(name: &str, img: &image::DynamicImage, srgb: bool) -> Self {
        let rgba = img.to_rgba32f();
        let (width, height) = rgba.dimensions();
        let texels = rgba
            .pixels()
            .map(|p| {
                let c = p.0;
                if srgb {
                    [srgb_to_linear(c[0]), srgb_to_linear(c[1]), srgb_to_linear(c[2]), c[3]]
                } else {
                    c
                }
            })
            .collect();
        Texture { name: name.into(), width, height, texels }
    }
}

/// Decodes an image after checking the dimensions in its header against `budget` (taking
/// `bytes_per_texel` per texel); the decoder's own allocation limit is set to match.
pub(crate) fn decode_checked(
    path: &Path,
    what: &str,
    bytes: &[u8],
    format: Option<image::ImageFormat>,
    budget: &Budget,
    bytes_per_texel: u64,
) -> Result<image::DynamicImage, SceneError> {
    let bad = |e: image::ImageError| SceneError::Image { path: path.to_path_buf(), message: e.to_string() };
    let reader = |bytes| -> Result<image::ImageReader<std::io::Cursor<&[u8]>>, SceneError> {
        let r = image::ImageReader::new(std::io::Cursor::new(bytes));
        Ok(match format {
            Some(f) => image::ImageReader::with_format(r.into_inner(), f),
            None => r.with_guessed_format().map_err(|e| SceneError::io(path, e))?,
        })
    };
    let (w, h) = reader(bytes)?.into_dimensions().map_err(bad)?;
    budget.image(path, what, w as u64, h as u64, bytes_per_texel)?;
    let mut r = reader(bytes)?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(budget.limits.max_image_dim);
    limits.max_image_height = Some(budget.limits.max_image_dim);
    limits.max_alloc = Some((w as u64 * h as u64 * bytes_per_texel).max(1 << 20));
    r.limits(limits);
    r.decode().map_err(bad)
}

/// sRGB transfer function inverse.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn hash2(x: i64, y: i64) -> f32 {
    let mut h = (x.wrapping_mul(374761393) ^ y.wrapping_mul(668265263)) as u64;
    h = (h ^ (h >> 13)).wrapping_mul(1274126177);
    h ^= h >> 16;
    (h & 0xffff) as f32 / 65535.0
}

/// Tileable value noise in [0,1] with period `period` cells.
fn value_noise(x: f32, y: f32, period: i64) -> f32 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (i, j) = (x0 as i64, y0 as i64);
    let h = |a: i64, b: i64| hash2(a.rem_euclid(period), b.rem_euclid(period));
    let (i1, j1) = (i.wrapping_add(1), j.wrapping_add(1));
    let a = h(i, j) + (h(i1, j) - h(i, j)) * s(fx);
    let b = h(i, j1) + (h(i1, j1) - h(i, j1)) * s(fx);
    a + (b - a) * s(fy)
}

impl Environment {
    /// Load a lat-long environment map from an OpenEXR (`.exr`) or Radiance (`.hdr`) file
    /// (intensity 1, rotation 0). Row 0 of the file is the +Y pole (see [`Environment`]).
    ///
    /// EXR: RGB or RGBA (alpha ignored), half/float/uint channels, scanline or tiled, every
    /// compression the `exr` crate decodes (none, RLE, ZIP, ZIPS, PIZ, PXR24, B44, B44A,
    /// DWAA, DWAB); the largest resolution level of the first layer with R, G and B. Anything
    /// else is an error naming the missing feature. Non-finite texels are an error.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        Self::load_with(path, &Budget::new(Limits::default()))
    }

    /// [`Environment::load`] checking the file's header against `budget` before decoding.
    pub fn load_with(path: &Path, budget: &Budget) -> Result<Self, SceneError> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let bytes = budget.read_data_file(path, "environment map file")?;
        let env = match ext.as_str() {
            "exr" => Self::from_exr_bytes_with(path, &bytes, budget)?,
            "hdr" | "pic" | "rgbe" => Self::from_hdr_bytes_with(path, &bytes, budget)?,
            _ => {
                return Err(SceneError::Unsupported {
                    path: path.to_path_buf(),
                    feature: "environment map format (expected .exr or .hdr)".into(),
                })
            }
        };
        if env.width == 0 || env.height == 0 {
            return Err(SceneError::invalid(path, "environment map is empty (0 texels)"));
        }
        if let Some(k) = env.texels.iter().position(|t| !t.iter().all(|c| c.is_finite())) {
            return Err(SceneError::invalid(
                path,
                format!(
                    "environment map texel ({}, {}) is NaN or infinite",
                    k as u32 % env.width,
                    k as u32 / env.width
                ),
            ));
        }
        Ok(env)
    }

    /// Decode an EXR from memory; `path` is only used in error messages.
    pub fn from_exr_bytes(path: &Path, bytes: &[u8]) -> Result<Self, SceneError> {
        Self::from_exr_bytes_with(path, bytes, &Budget::new(Limits::default()))
    }

    /// [`Environment::from_exr_bytes`], the header's sizes checked against `budget` first.
    pub fn from_exr_bytes_with(path: &Path, bytes: &[u8], budget: &Budget) -> Result<Self, SceneError> {
        use exr::prelude::*;
        // Every layer's size from the header, before any pixel is allocated.
        let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
            .map_err(|e| SceneError::Image { path: path.to_path_buf(), message: format!("EXR header: {e}") })?;
        for h in meta.headers.iter() {
            let size = h.layer_size;
            budget.image(path, "the environment map", size.width() as u64, size.height() as u64, 12)?;
        }
        struct Buf {
            w: usize,
            texels: Vec<[f32; 3]>,
        }
        let result = read()
            .no_deep_data()
            .largest_resolution_level()
            .specific_channels()
            .required("R")
            .required("G")
            .required("B")
            .collect_pixels(
                |res: Vec2<usize>, _: &(ChannelDescription, ChannelDescription, ChannelDescription)| Buf {
                    w: res.width(),
                    texels: vec![[0.0; 3]; res.width() * res.height()],
                },
                |buf: &mut Buf, pos: Vec2<usize>, (r, g, b): (f32, f32, f32)| {
                    let w = buf.w;
                    buf.texels[pos.y() * w + pos.x()] = [r, g, b];
                },
            )
            .first_valid_layer()
            .all_attributes()
            .non_parallel()
            .from_buffered(std::io::Cursor::new(bytes));
        let image = result.map_err(|e| match e {
            exr::error::Error::NotSupported(what) => {
                SceneError::Unsupported { path: path.to_path_buf(), feature: format!("EXR feature: {what}") }
            }
            exr::error::Error::Invalid(what) if what.contains("layer") || what.contains("channel") => {
                SceneError::Unsupported {
                    path: path.to_path_buf(),
                    feature: format!("EXR channel layout (needs R, G and B channels in one layer): {what}"),
                }
            }
            other => SceneError::Image { path: path.to_path_buf(), message: format!("EXR: {other}") },
        })?;
        let size = image.layer_data.size;
        Ok(Environment {
            width: size.width() as u32,
            height: size.height() as u32,
            texels: image.layer_data.channel_data.pixels.texels,
            intensity: 1.0,
            rotation: 0.0,
        })
    }

    /// Decode a Radiance RGBE (`.hdr`) image from memory.
    pub fn from_hdr_bytes(path: &Path, bytes: &[u8]) -> Result<Self, SceneError> {
        Self::from_hdr_bytes_with(path, bytes, &Budget::new(Limits::default()))
    }

    /// [`Environment::from_hdr_bytes`], the header's size checked against `budget` first.
    pub fn from_hdr_bytes_with(path: &Path, bytes: &[u8], budget: &Budget) -> Result<Self, SceneError> {
        // 12 bytes per texel kept, 16 while converting
        let img = decode_checked(path, "the environment map", bytes, Some(image::ImageFormat::Hdr), budget, 28)?;
        let rgb = img.to_rgb32f();
        let (width, height) = rgb.dimensions();
        Ok(Environment { width, height, texels: rgb.pixels().map(|p| p.0).collect(), intensity: 1.0, rotation: 0.0 })
    }

    /// Nearest-texel radiance seen in world direction `d`, with `rotation` (about +Y,
    /// counter-clockwise seen from above) and `intensity` applied.
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        self.radiance_at(d, self.state())
    }

    /// [`Environment::radiance`] with `state`'s rotation and intensity (a frame's, animated)
    /// instead of the loaded ones.
    pub fn radiance_at(&self, d: Vec3, state: crate::EnvironmentState) -> Vec3 {
        let local = glam::Quat::from_rotation_y(-state.rotation) * d;
        let (u, v) = Self::uv(local);
        let i = ((u * self.width as f32) as u32).min(self.width.saturating_sub(1));
        let j = ((v * self.height as f32) as u32).min(self.height.saturating_sub(1));
        Vec3::from_array(self.texels[(j * self.width + i) as usize]) * state.intensity
    }
}
