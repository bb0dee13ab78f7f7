//! Linear RGB float images and their EXR input/output.

use std::path::{Path, PathBuf};

/// Errors of image input/output and of image metrics. Every variant names the file involved.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{path}: file not found")]
    NotFound { path: PathBuf },
    #[error("{path}: cannot read: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a readable OpenEXR image: {message}")]
    Exr { path: PathBuf, message: String },
    #[error("{path}: unsupported channels {found:?} (need R, G and B, optionally A)")]
    UnsupportedChannels { path: PathBuf, found: Vec<String> },
    #[error("{path}: cannot write: {message}")]
    Write { path: PathBuf, message: String },
    #[error("size mismatch: {a_path} is {a_width}x{a_height} but {b_path} is {b_width}x{b_height}")]
    SizeMismatch { a_path: PathBuf, a_width: u32, a_height: u32, b_path: PathBuf, b_width: u32, b_height: u32 },
    #[error("{path}: empty image ({width}x{height})")]
    Empty { path: PathBuf, width: u32, height: u32 },
    #[error("{path}: pixel buffer has {len} pixels, expected {width}x{height}")]
    BadBuffer { path: PathBuf, width: u32, height: u32, len: usize },
}

/// A linear RGB float image, row-major, pixel (0, 0) at the top left.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

impl Image {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Image { width, height, pixels: vec![[0.0; 3]; width as usize * height as usize] }
    }

    /// An image whose pixel (x, y) is `f(x, y)`.
    pub fn from_fn(width: u32, height: u32, mut f: impl FnMut(u32, u32) -> [f32; 3]) -> Self {
        let mut pixels = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                pixels.push(f(x, y));
            }
        }
        Image { width, height, pixels }
    }

    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    pub fn set(&mut self, x: u32, y: u32, v: [f32; 3]) {
        let w = self.width as usize;
        self.pixels[y as usize * w + x as usize] = v;
    }

    /// Number of pixels with a NaN or infinite channel.
    pub fn non_finite_count(&self) -> usize {
        self.pixels.iter().filter(|p| !p.iter().all(|c| c.is_finite())).count()
    }

    /// Not empty, and holding `width x height` pixels (`path` names it in the error).
    pub(crate) fn check(&self, path: &Path) -> Result<(), ImageError> {
        if self.width == 0 || self.height == 0 {
            return Err(ImageError::Empty { path: path.into(), width: self.width, height: self.height });
        }
        if self.pixels.len() != self.width as usize * self.height as usize {
            return Err(ImageError::BadBuffer {
                path: path.into(),
                width: self.width,
                height: self.height,
                len: self.pixels.len(),
            });
        }
        Ok(())
    }

    /// Read the first RGB(A) layer of an OpenEXR file (half, float or uint samples, any
    /// compression the `exr` crate reads). Alpha is ignored.
    pub fn read_exr(path: impl AsRef<Path>) -> Result<Image, ImageError> {
        let path = path.as_ref();
        match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(ImageError::NotFound { path: path.into() })
            }
            Err(e) => return Err(ImageError::Io { path: path.into(), source: e }),
            Ok(m) if m.is_dir() => return Err(ImageError::Exr { path: path.into(), message: "is a directory".into() }),
            Ok(_) => {}
        }
        // Look at the channels first so that a missing R/G/B gets a clear message.
        let meta = exr::meta::MetaData::read_from_file(path, false)
            .map_err(|e| ImageError::Exr { path: path.into(), message: e.to_string() })?;
        let has_rgb = meta.headers.iter().any(|h| {
            let names: Vec<String> = h.channels.list.iter().map(|c| c.name.to_string()).collect();
            ["R", "G", "B"].iter().all(|n| names.iter().any(|m| m == n))
        });
        if !has_rgb {
            let found = meta.headers.iter().flat_map(|h| h.channels.list.iter().map(|c| c.name.to_string())).collect();
            return Err(ImageError::UnsupportedChannels { path: path.into(), found });
        }
        let img = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |res, _| {
                let (w, h) = (res.width(), res.height());
                (w, vec![[0.0f32; 3]; w * h])
            },
            |(w, px): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = [r, g, b];
            },
        )
        .map_err(|e| ImageError::Exr { path: path.into(), message: e.to_string() })?;
        let size = img.layer_data.size;
        let image = Image {
            width: size.width() as u32,
            height: size.height() as u32,
            pixels: img.layer_data.channel_data.pixels.1,
        };
        image.check(path)?;
        Ok(image)
    }

    /// Write as an RGB 32-bit float OpenEXR file (default compression of the `exr` crate).
    pub fn write_exr(&self, path: impl AsRef<Path>) -> Result<(), ImageError> {
        let path = path.as_ref();
        self.check(path)?;
        let w = self.width as usize;
        exr::prelude::write_rgb_file(path, w, self.height as usize, |x, y| {
            let p = self.pixels[y * w + x];
            (p[0], p[1], p[2])
        })
        .map_err(|e| ImageError::Write { path: path.into(), message: e.to_string() })
    }
}

/// Write an 8-bit RGB PNG (`rgb.len() == 3 * width * height`).
pub fn write_png_rgb8(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<(), ImageError> {
    let bytes = png_rgb8_bytes(width, height, rgb).map_err(|m| ImageError::Write { path: path.into(), message: m })?;
    std::fs::write(path, bytes).map_err(|e| ImageError::Write { path: path.into(), message: e.to_string() })
}

/// An 8-bit RGB PNG in memory (`rgb`: `width * height * 3` bytes, rows top first).
pub fn png_rgb8_bytes(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(rgb).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    Ok(out)
}
