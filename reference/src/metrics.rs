//! Image metrics between a reference image A and a test image B (linear RGB radiance).
//!
//! Conventions (stated in every [`Comparison`]):
//! - Statistics run over the pixels where **both** images are finite; pixels with a NaN or
//!   infinite channel are counted per image ([`Comparison::non_finite_a`],
//!   [`Comparison::non_finite_b`]) and excluded, never propagated.
//! - MSE, RMSE, mean and max absolute error are over all channels of the compared pixels.
//! - **PSNR** is on linear radiance with peak = the largest finite channel value of the
//!   reference A (1.0 if A has none above 0): `10 log10(peak^2 / MSE)`. Identical images give
//!   `psnr_db = None` (JSON `null`) and `identical = true`.
//! - **Relative RMSE** is `sqrt(mean((b - a)^2 / (a^2 + 0.01)))` per channel (the "relMSE" of the
//!   denoising literature with epsilon 0.01, robust to black pixels).
//! - **FLIP** (NVIDIA's LDR FLIP via the `nv-flip` crate; the crate has no HDR-FLIP): both images
//!   are mapped to display sRGB by `x * 2^exposure`, clamp to [0, 1], the sRGB transfer function
//!   and 8-bit quantisation; exposure 0 by default, 67 pixels per degree. Mean FLIP is reported.
//! - The **false-colour difference** PNG shows the per-pixel mean absolute error over channels,
//!   divided by the 99th percentile of that quantity over the image (its maximum if the
//!   percentile is zero; [`Comparison::diff_scale`]) and clamped, through the magma colour map;
//!   pixels non-finite in either image are cyan.

use crate::image::{write_png_rgb8, Image, ImageError};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Pixels per degree used for FLIP (the FLIP paper's default: 0.7 m from a 0.7 m wide 4K monitor).
pub const FLIP_PIXELS_PER_DEGREE: f32 = 67.0;
/// Epsilon of the relative MSE denominator.
pub const REL_EPSILON: f64 = 0.01;

/// The result of comparing a reference image A with a test image B.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    /// Name (usually the path) of the reference image A.
    pub reference: String,
    /// Name (usually the path) of the test image B.
    pub test: String,
    pub width: u32,
    pub height: u32,
    /// Pixels finite in both images, over which the statistics run.
    pub pixels_compared: u64,
    /// Pixels of A with a NaN or infinite channel (excluded).
    pub non_finite_a: u64,
    /// Pixels of B with a NaN or infinite channel (excluded).
    pub non_finite_b: u64,
    /// True when every compared channel is bit-for-bit equal (and nothing was excluded).
    pub identical: bool,
    /// PSNR in dB on linear radiance; `None` (JSON null) when MSE = 0 (infinite PSNR).
    pub psnr_db: Option<f64>,
    /// The peak used by PSNR.
    pub psnr_peak: f64,
    /// How the peak was chosen.
    pub psnr_peak_rule: String,
    pub mse: f64,
    pub rmse: f64,
    /// Mean over the compared pixels and channels of the reference A.
    #[serde(default)]
    pub reference_mean: f64,
    /// RMSE divided by [`Comparison::reference_mean`]: the "RMS error in %" the ISG paper
    /// reports; unlike PSNR (whose peak is the brightest highlight) it does not hide errors in
    /// shadows behind a bright peak. Infinite when the reference is black and the images differ.
    #[serde(default)]
    pub rmse_rel_mean: f64,
    /// `sqrt(mean((b - a)^2 / (a^2 + 0.01)))` over channels.
    pub rel_rmse: f64,
    pub mean_abs_error: f64,
    pub max_abs_error: f64,
    /// Pixel (x, y) of the maximum absolute error.
    pub max_abs_error_at: [u32; 2],
    /// Mean FLIP error in [0, 1] (LDR FLIP after the tone mapping below).
    pub flip_mean: f64,
    /// Tone mapping applied before FLIP.
    pub flip_tonemap: String,
    pub flip_pixels_per_degree: f32,
    /// Error value mapped to the top of the colour map in the difference image (99th
    /// percentile of the per-pixel mean absolute error, or its maximum if that is zero).
    pub diff_scale: f64,
    /// When A is a reference render with its standard-error image beside it
    /// (`NAME_stderr.exr` next to `NAME.exr`): the RMS of A's per-pixel standard error over the
    /// compared pixels, i.e. the part of the RMSE explained by the reference's own noise.
    #[serde(default)]
    pub reference_noise_rms: Option<f64>,
}

impl Comparison {
    /// A human-readable multi-line summary.
    pub fn summary(&self) -> String {
        let psnr = match self.psnr_db {
            Some(p) => format!("{p:.3} dB"),
            None => "inf (identical)".into(),
        };
        let mut s = format!(
            "A (reference): {}\nB (test):      {}\nsize:          {}x{} ({} pixels compared)\n",
            self.reference, self.test, self.width, self.height, self.pixels_compared
        );
        if self.non_finite_a + self.non_finite_b > 0 {
            s += &format!("non-finite:    {} pixels in A, {} in B (excluded)\n", self.non_finite_a, self.non_finite_b);
        }
        s += &format!(
            "PSNR:          {psnr} (peak {:.6} = {})\nRMSE:          {:.6e} ({:.4} of the reference's mean {:.6e})\nrel. RMSE:     {:.6e}\nmean |err|:    {:.6e}\nmax |err|:     {:.6e} at ({}, {})\nFLIP (mean):   {:.6} ({})",
            self.psnr_peak,
            self.psnr_peak_rule,
            self.rmse,
            self.rmse_rel_mean,
            self.reference_mean,
            self.rel_rmse,
            self.mean_abs_error,
            self.max_abs_error,
            self.max_abs_error_at[0],
            self.max_abs_error_at[1],
            self.flip_mean,
            self.flip_tonemap
        );
        if let Some(n) = self.reference_noise_rms {
            s += &format!(
                "\nref. noise:    {n:.6e} RMS standard error of A (RMSE / noise = {:.2})",
                if n > 0.0 { self.rmse / n } else { f64::INFINITY }
            );
        }
        s
    }
}

/// sRGB transfer function of a linear value in [0, 1].
pub fn srgb_encode(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Tone map a linear image to 8-bit sRGB: `x * 2^exposure`, clamp, sRGB, quantise.
/// Non-finite channels map to 0.
pub fn to_srgb8(img: &Image, exposure: f32) -> Vec<u8> {
    let scale = exposure.exp2();
    img.pixels
        .iter()
        .flat_map(|p| p.iter().copied())
        .map(|c| {
            let c = if c.is_finite() { (c * scale).clamp(0.0, 1.0) } else { 0.0 };
            (srgb_encode(c) * 255.0 + 0.5).floor().clamp(0.0, 255.0) as u8
        })
        .collect()
}

fn check_same_size(a: &Image, an: &str, b: &Image, bn: &str) -> Result<(), ImageError> {
    a.check(std::path::Path::new(an))?;
    b.check(std::path::Path::new(bn))?;
    if a.width != b.width || a.height != b.height {
        return Err(ImageError::SizeMismatch {
            a_path: an.into(),
            a_width: a.width,
            a_height: a.height,
            b_path: bn.into(),
            b_width: b.width,
            b_height: b.height,
        });
    }
    Ok(())
}

/// Mean FLIP between two same-size images after [`to_srgb8`] with `exposure`.
pub fn flip_mean(a: &Image, b: &Image, exposure: f32) -> f64 {
    let ra = nv_flip::FlipImageRgb8::with_data(a.width, a.height, &to_srgb8(a, exposure));
    let rb = nv_flip::FlipImageRgb8::with_data(b.width, b.height, &to_srgb8(b, exposure));
    let err = nv_flip::flip(ra, rb, FLIP_PIXELS_PER_DEGREE);
    let v = err.to_vec();
    v.iter().map(|&e| e as f64).sum::<f64>() / v.len().max(1) as f64
}

/// Compare a reference `a` with a test image `b`; `a_name`/`b_name` label them in errors and
/// in the result.
pub fn compare(a: &Image, a_name: &str, b: &Image, b_name: &str) -> Result<Comparison, ImageError> {
    check_same_size(a, a_name, b, b_name)?;
    let mut n = 0u64;
    let (mut se, mut rel, mut ae, mut sum_a) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut max_ae = 0.0f64;
    let mut max_at = [0u32; 2];
    let mut identical = true;
    let mut peak = 0.0f64;
    let (mut nfa, mut nfb) = (0u64, 0u64);
    for (i, (pa, pb)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        let fa = pa.iter().all(|c| c.is_finite());
        let fb = pb.iter().all(|c| c.is_finite());
        nfa += (!fa) as u64;
        nfb += (!fb) as u64;
        if fa {
            for &c in pa {
                peak = peak.max(c as f64);
            }
        }
        if !(fa && fb) {
            identical = false;
            continue;
        }
        n += 1;
        for c in 0..3 {
            let (x, y) = (pa[c] as f64, pb[c] as f64);
            if pa[c] != pb[c] {
                identical = false;
            }
            let d = y - x;
            sum_a += x;
            se += d * d;
            rel += d * d / (x * x + REL_EPSILON);
            ae += d.abs();
            if d.abs() > max_ae {
                max_ae = d.abs();
                max_at = [(i % a.width as usize) as u32, (i / a.width as usize) as u32];
            }
        }
    }
    let m = (3 * n).max(1) as f64;
    let mse = se / m;
    let reference_mean = sum_a / m;
    let rmse_rel_mean = if mse == 0.0 {
        0.0
    } else if reference_mean > 0.0 {
        mse.sqrt() / reference_mean
    } else {
        f64::INFINITY
    };
    let peak_rule;
    if peak <= 0.0 {
        peak = 1.0;
        peak_rule = "1.0 (reference has no positive finite value)".to_string();
    } else {
        peak_rule = "max finite channel value of the reference A".to_string();
    }
    let psnr_db = if mse > 0.0 { Some(10.0 * (peak * peak / mse).log10()) } else { None };
    let exposure = 0.0;
    Ok(Comparison {
        reference: a_name.into(),
        test: b_name.into(),
        width: a.width,
        height: a.height,
        pixels_compared: n,
        non_finite_a: nfa,
        non_finite_b: nfb,
        identical: identical && n > 0,
        psnr_db,
        psnr_peak: peak,
        psnr_peak_rule: peak_rule,
        mse,
        rmse: mse.sqrt(),
        reference_mean,
        rmse_rel_mean,
        rel_rmse: (rel / m).sqrt(),
        mean_abs_error: ae / m,
        max_abs_error: max_ae,
        max_abs_error_at: max_at,
        flip_mean: flip_mean(a, b, exposure),
        flip_tonemap: format!(
            "LDR FLIP on x*2^{exposure} clamped to [0,1], sRGB-encoded, 8-bit; {FLIP_PIXELS_PER_DEGREE} px/deg"
        ),
        flip_pixels_per_degree: FLIP_PIXELS_PER_DEGREE,
        diff_scale: diff_scale(a, b),
        reference_noise_rms: None,
    })
}

/// RMS over channels of a standard-error image, over the pixels finite in `a` and `b`.
pub fn noise_rms(a: &Image, b: &Image, se: &Image) -> Option<f64> {
    if se.width != a.width || se.height != a.height || se.pixels.len() != a.pixels.len() {
        return None;
    }
    let (mut s, mut n) = (0.0f64, 0u64);
    for ((pa, pb), e) in a.pixels.iter().zip(&b.pixels).zip(&se.pixels) {
        if pa.iter().chain(pb.iter()).chain(e.iter()).all(|c| c.is_finite()) {
            s += e.iter().map(|&c| (c as f64) * (c as f64)).sum::<f64>();
            n += 3;
        }
    }
    (n > 0).then(|| (s / n as f64).sqrt())
}

/// `DIR/NAME_stderr.exr` for `DIR/NAME.exr`.
pub fn stderr_path(p: &Path) -> Option<std::path::PathBuf> {
    let stem = p.file_stem()?.to_str()?;
    Some(p.with_file_name(format!("{stem}_stderr.exr")))
}

fn pixel_error(pa: &[f32; 3], pb: &[f32; 3]) -> Option<f64> {
    if pa.iter().chain(pb.iter()).all(|c| c.is_finite()) {
        Some((0..3).map(|c| (pb[c] as f64 - pa[c] as f64).abs()).sum::<f64>() / 3.0)
    } else {
        None
    }
}

/// The 99th percentile of the per-pixel error (the maximum if that is zero), so that a few
/// fireflies do not turn the rest of the difference image black.
fn diff_scale(a: &Image, b: &Image) -> f64 {
    let mut e: Vec<f64> = a.pixels.iter().zip(&b.pixels).filter_map(|(pa, pb)| pixel_error(pa, pb)).collect();
    if e.is_empty() {
        return 0.0;
    }
    e.sort_by(|x, y| x.total_cmp(y));
    let p99 = e[((e.len() - 1) as f64 * 0.99) as usize];
    if p99 > 0.0 {
        p99
    } else {
        e[e.len() - 1]
    }
}

/// The false-colour difference image as 8-bit RGB: per-pixel mean absolute error / `scale`
/// through the magma colour map, cyan where either image is non-finite.
pub fn diff_rgb8(a: &Image, b: &Image, scale: f64) -> Vec<u8> {
    let lut = nv_flip::magma_lut().to_vec();
    let mut out = Vec::with_capacity(a.pixels.len() * 3);
    for (pa, pb) in a.pixels.iter().zip(&b.pixels) {
        match pixel_error(pa, pb) {
            Some(e) => {
                let t = if scale > 0.0 { (e / scale).clamp(0.0, 1.0) } else { 0.0 };
                let i = ((t * 255.0).round() as usize).min(255);
                out.extend_from_slice(&lut[3 * i..3 * i + 3]);
            }
            None => out.extend_from_slice(&[0, 255, 255]),
        }
    }
    out
}

/// Write the false-colour difference PNG of two same-size images (scale: see module docs).
pub fn write_diff_png(a: &Image, b: &Image, path: &Path) -> Result<f64, ImageError> {
    check_same_size(a, "A", b, "B")?;
    let scale = diff_scale(a, b);
    write_png_rgb8(path, a.width, a.height, &diff_rgb8(a, b, scale))?;
    Ok(scale)
}

/// Read two EXR files, compare them (A = reference) and optionally write the false-colour
/// difference PNG.
pub fn compare_files(
    a: impl AsRef<Path>,
    b: impl AsRef<Path>,
    diff_png: Option<&Path>,
) -> Result<Comparison, ImageError> {
    let (a, b) = (a.as_ref(), b.as_ref());
    let ia = Image::read_exr(a)?;
    let ib = Image::read_exr(b)?;
    let mut c = compare(&ia, &a.display().to_string(), &ib, &b.display().to_string())?;
    if let Some(sp) = stderr_path(a).filter(|sp| sp.is_file()) {
        let se = Image::read_exr(&sp)?;
        c.reference_noise_rms = noise_rms(&ia, &ib, &se);
    }
    if let Some(p) = diff_png {
        write_png_rgb8(p, ia.width, ia.height, &diff_rgb8(&ia, &ib, c.diff_scale))?;
    }
    Ok(c)
}
