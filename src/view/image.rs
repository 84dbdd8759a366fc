//! PNG output and image comparison.
//!
//! Takes: tightly packed RGBA8 frames (as [`crate::view::gpu::Renderer`]
//! returns them). Gives: PNG files (written into a render's temp directory,
//! which appears under its final name only when complete), PSNR and
//! differing-pixel statistics between two frames, and the fraction of a frame
//! left at the clear color (used to detect cracks between nodes).

use crate::error::{Error, IoContext, Result};
use std::path::Path;

fn check_len(rgba: &[u8], width: u32, height: u32) -> Result<()> {
    let want = width as u64 * height as u64 * 4;
    if rgba.len() as u64 != want {
        return Err(Error::Usage(format!("image of {width}x{height} pixels needs {want} RGBA bytes, got {}", rgba.len())));
    }
    Ok(())
}

/// Writes an RGBA8 image as PNG at `path`, in an existing directory (none is
/// created: a render's temp directory removed by an interruption stays
/// removed).
pub fn write_png(path: impl AsRef<Path>, width: u32, height: u32, rgba: &[u8]) -> Result<()> {
    use ::image::ImageEncoder;
    let path = path.as_ref();
    check_len(rgba, width, height)?;
    if width == 0 || height == 0 {
        return Err(Error::Usage(format!("{}: cannot write an empty {width}x{height} PNG", path.display())));
    }
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).ctx(path, "create")?);
    ::image::codecs::png::PngEncoder::new(&mut f).write_image(rgba, width, height, ::image::ExtendedColorType::Rgba8).map_err(|e| match e {
        ::image::ImageError::IoError(io) => Error::io(path, "write PNG", io),
        other => Error::Usage(format!("{}: cannot encode PNG: {other}", path.display())),
    })?;
    std::io::Write::flush(&mut f).ctx(path, "write PNG")
}

/// Reads a PNG (any color type) as RGBA8: `(width, height, rgba)`.
pub fn read_png(path: impl AsRef<Path>) -> Result<(u32, u32, Vec<u8>)> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).ctx(path, "read")?;
    let img = ::image::load_from_memory_with_format(&bytes, ::image::ImageFormat::Png)
        .map_err(|e| Error::Usage(format!("{}: not a readable PNG: {e}", path.display())))?
        .into_rgba8();
    Ok((img.width(), img.height(), img.into_raw()))
}

/// How two frames differ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageDiff {
    /// Peak signal-to-noise ratio over all RGBA channels, in dB;
    /// `f64::INFINITY` when the images are identical.
    pub psnr_db: f64,
    /// Fraction of pixels whose largest channel difference exceeds `tol`.
    pub differing_fraction: f64,
    /// Largest difference of any channel of any pixel.
    pub max_channel_diff: u8,
}

/// Compares two RGBA8 frames of `width` x `height`.
///
/// # Panics
/// If either slice is not `width * height * 4` bytes long.
pub fn compare(a: &[u8], b: &[u8], width: u32, height: u32, tol: u8) -> ImageDiff {
    let n = width as usize * height as usize;
    assert_eq!(a.len(), n * 4, "compare: first image is not {width}x{height} RGBA8");
    assert_eq!(b.len(), n * 4, "compare: second image is not {width}x{height} RGBA8");
    let mut sq = 0u64;
    let mut differing = 0usize;
    let mut max = 0u8;
    for (pa, pb) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        let mut px_max = 0u8;
        for k in 0..4 {
            let d = pa[k].abs_diff(pb[k]);
            sq += d as u64 * d as u64;
            px_max = px_max.max(d);
        }
        if px_max > tol {
            differing += 1;
        }
        max = max.max(px_max);
    }
    let psnr_db = if sq == 0 || n == 0 {
        f64::INFINITY
    } else {
        let mse = sq as f64 / (n * 4) as f64;
        10.0 * (255.0f64 * 255.0 / mse).log10()
    };
    ImageDiff { psnr_db, differing_fraction: if n == 0 { 0.0 } else { differing as f64 / n as f64 }, max_channel_diff: max }
}

/// Fraction of pixels exactly equal to `clear_rgba`.
///
/// # Panics
/// If `rgba` is not `width * height * 4` bytes long.
pub fn background_fraction(rgba: &[u8], width: u32, height: u32, clear_rgba: [u8; 4]) -> f64 {
    let n = width as usize * height as usize;
    assert_eq!(rgba.len(), n * 4, "background_fraction: image is not {width}x{height} RGBA8");
    if n == 0 {
        return 0.0;
    }
    rgba.chunks_exact(4).filter(|p| *p == clear_rgba).count() as f64 / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solid(w: u32, h: u32, c: [u8; 4]) -> Vec<u8> {
        c.repeat((w * h) as usize)
    }

    #[test]
    fn identical_images_have_infinite_psnr() {
        let a = solid(5, 3, [1, 2, 3, 255]);
        let d = compare(&a, &a, 5, 3, 0);
        assert_eq!(d.psnr_db, f64::INFINITY);
        assert_eq!(d.differing_fraction, 0.0);
        assert_eq!(d.max_channel_diff, 0);
    }

    #[test]
    fn psnr_and_differing_pixels() {
        let (w, h) = (4, 2);
        let a = solid(w, h, [100, 100, 100, 255]);
        let mut b = a.clone();
        // One pixel off by 10 in red, one off by 2 in blue.
        b[0] = 110;
        b[4 + 2] = 102;
        let d = compare(&a, &b, w, h, 5);
        assert_eq!(d.max_channel_diff, 10);
        assert_eq!(d.differing_fraction, 1.0 / 8.0);
        let mse = (100.0 + 4.0) / 32.0;
        assert!((d.psnr_db - 10.0 * (65025.0f64 / mse).log10()).abs() < 1e-9);
        // With tolerance 1 both pixels differ; with 10 none does.
        assert_eq!(compare(&a, &b, w, h, 1).differing_fraction, 2.0 / 8.0);
        assert_eq!(compare(&a, &b, w, h, 10).differing_fraction, 0.0);
        // Black against white: 0 dB.
        let k = solid(w, h, [0; 4]);
        let wh = solid(w, h, [255; 4]);
        assert!(compare(&k, &wh, w, h, 0).psnr_db.abs() < 1e-12);
    }

    #[test]
    fn background_fraction_counts_exact_matches() {
        let mut a = solid(2, 2, [7, 8, 9, 255]);
        a[4..8].copy_from_slice(&[7, 8, 9, 254]);
        assert_eq!(background_fraction(&a, 2, 2, [7, 8, 9, 255]), 0.75);
        assert_eq!(background_fraction(&a, 2, 2, [0, 0, 0, 255]), 0.0);
    }

    #[test]
    #[should_panic(expected = "not 3x3")]
    fn compare_rejects_wrong_sizes() {
        compare(&[0; 36], &[0; 32], 3, 3, 0);
    }

    #[test]
    fn png_round_trip_is_exact_and_creates_no_directory() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub").join("x.png");
        let (w, h) = (3u32, 2u32);
        let rgba: Vec<u8> = (0..w * h * 4).map(|i| (i * 11 % 256) as u8).collect();
        // A directory that is gone (a render's temp directory removed by an
        // interruption) is not created again.
        assert!(write_png(&path, w, h, &rgba).is_err());
        assert!(!path.parent().unwrap().exists());
        std::fs::create_dir(path.parent().unwrap()).unwrap();
        write_png(&path, w, h, &rgba).unwrap();
        assert_eq!(read_png(&path).unwrap(), (w, h, rgba.clone()));
        // Only the final file is left in the directory.
        let names: Vec<_> = std::fs::read_dir(path.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("x.png")]);
        // A wrong length is refused and leaves the old file intact.
        assert!(write_png(&path, w, h, &rgba[..10]).is_err());
        assert_eq!(read_png(&path).unwrap().2, rgba);
    }
}
