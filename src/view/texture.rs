//! The store's texture for the viewer: decoded, mipmapped, fitted to the
//! RAM budget.
//!
//! Takes: a store whose manifest lists textures (copies of the input's
//! `comment TextureFile` images, see [`crate::manifest::TextureRef`]) and
//! the viewer's `--ram`. Gives: the first texture's mip chain as RGBA8
//! sRGB levels ([`MipChain`]), ready for [`crate::view::gpu::Renderer::set_texture`].
//!
//! Choices:
//! * Mipmaps are made here, on the CPU, by a box filter in linear light
//!   (sRGB bytes decoded, averaged, encoded; odd sides split unevenly), so
//!   a far, minified atlas neither shimmers nor darkens. wgpu has no
//!   mipmap generation of its own, and a blit chain on the GPU would need
//!   a render pass per level for a one-time job.
//! * The texture counts against `--ram` as node data does: it may take at
//!   most [`TEXTURE_SHARE`] of the budget, and its finest levels are
//!   dropped (the atlas halves per level) until the whole chain fits.
//!   What is counted is the chain resident on the GPU; the full-size
//!   decode is transient, once, before any node is loaded, and levels to
//!   be dropped are halved away one at a time ([`MipChain::fitted`]), so
//!   a 16k² atlas under a small budget peaks at its decode plus a quarter.
//! * One texture, the first the store has: MeshLab's `texnumber` (several
//!   textures per mesh) is not read yet, so every triangle uses texture 0.
//! * uvs follow MeshLab's (and OpenGL's) convention: v = 0 is the image's
//!   bottom row; the shader samples (u, 1 − v), repeating outside [0, 1].

use crate::error::{Error, Location, Result};
use std::path::Path;

/// The largest share of `--ram` a texture may take.
pub const TEXTURE_SHARE: f64 = 0.25;

/// One mip level: RGBA8, sRGB-encoded, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct MipLevel {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// A texture's mip chain, finest level first, down to 1×1.
#[derive(Clone, Debug, PartialEq)]
pub struct MipChain {
    pub levels: Vec<MipLevel>,
    /// Finest levels dropped to fit the budget.
    pub dropped: u32,
    /// The store's file it came from.
    pub name: String,
}

/// Each sRGB byte's linear value.
fn linear_table() -> &'static [f32; 256] {
    static T: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|b| crate::color::srgb_to_linear(b as f64 / 255.0) as f32))
}

/// The next level of `l`: sides halved (at least 1), each texel the
/// linear-light mean of the texels it covers.
fn downsample(l: &MipLevel) -> MipLevel {
    let lin = linear_table();
    let (w, h) = ((l.width / 2).max(1), (l.height / 2).max(1));
    let mut rgba = Vec::with_capacity(w as usize * h as usize * 4);
    let span = |i: u32, n: u32, src: u32| (i as u64 * src as u64 / n as u64) as usize..((i as u64 + 1) * src as u64 / n as u64) as usize;
    for y in 0..h {
        let ys = span(y, h, l.height);
        for x in 0..w {
            let xs = span(x, w, l.width);
            let mut acc = [0f32; 4];
            let mut n = 0f32;
            for sy in ys.clone() {
                for sx in xs.clone() {
                    let p = &l.rgba[(sy * l.width as usize + sx) * 4..][..4];
                    for k in 0..3 {
                        acc[k] += lin[p[k] as usize];
                    }
                    acc[3] += p[3] as f32 / 255.0;
                    n += 1.0;
                }
            }
            for (k, a) in acc.iter().enumerate() {
                let v = a / n;
                let enc = if k < 3 { crate::color::linear_to_srgb(v as f64) } else { v as f64 };
                rgba.push((enc * 255.0).round().clamp(0.0, 255.0) as u8);
            }
        }
    }
    MipLevel { width: w, height: h, rgba }
}

impl MipChain {
    /// The full chain of a `width`×`height` RGBA8 image.
    pub fn new(name: &str, width: u32, height: u32, rgba: Vec<u8>) -> MipChain {
        let mut levels = vec![MipLevel { width, height, rgba }];
        while let Some(l) = levels.last().filter(|l| l.width > 1 || l.height > 1) {
            let next = downsample(l);
            levels.push(next);
        }
        MipChain { levels, dropped: 0, name: name.to_string() }
    }

    /// [`MipChain::new`] then [`MipChain::fit`], without holding the
    /// levels that will be dropped: each finer level goes as soon as the
    /// next is made, so a texture much larger than its share costs its
    /// decode and a quarter of it, not the whole chain.
    pub fn fitted(name: &str, width: u32, height: u32, rgba: Vec<u8>, max_bytes: u64) -> Option<MipChain> {
        // Bytes of the chain from a level of these sides down to 1×1.
        let chain_bytes = |mut w: u32, mut h: u32| {
            let mut b = 0u64;
            loop {
                b += w as u64 * h as u64 * 4;
                if w == 1 && h == 1 {
                    return b;
                }
                (w, h) = ((w / 2).max(1), (h / 2).max(1));
            }
        };
        let mut level = MipLevel { width, height, rgba };
        let mut dropped = 0;
        while chain_bytes(level.width, level.height) > max_bytes {
            if level.width == 1 && level.height == 1 {
                return None;
            }
            level = downsample(&level);
            dropped += 1;
        }
        let mut chain = MipChain::new(name, level.width, level.height, level.rgba);
        chain.dropped = dropped;
        Some(chain)
    }

    /// Bytes of every level (what the GPU holds).
    pub fn bytes(&self) -> u64 {
        self.levels.iter().map(|l| l.rgba.len() as u64).sum()
    }

    /// Drops finest levels until the chain takes at most `max_bytes`;
    /// none when even the 1×1 level does not fit.
    pub fn fit(mut self, max_bytes: u64) -> Option<MipChain> {
        while self.bytes() > max_bytes {
            if self.levels.len() <= 1 {
                return None;
            }
            self.levels.remove(0);
            self.dropped += 1;
        }
        Some(self)
    }

    /// Side lengths of the finest level kept.
    pub fn size(&self) -> (u32, u32) {
        self.levels.first().map_or((0, 0), |l| (l.width, l.height))
    }
}

/// The store's first texture (its copy in the store), decoded, mipmapped
/// and fitted to [`TEXTURE_SHARE`] of `ram`; none when the store lists no
/// texture it holds. An undecodable texture is an error naming the file.
pub fn for_store(store: &Path, ram: u64) -> Result<Option<MipChain>> {
    let Some((file, path)) = crate::manifest::store_texture(store) else { return Ok(None) };
    let bad = |what: String| Error::input(Location { file: path.clone(), ..Default::default() }, what);
    let bytes = std::fs::read(&path).map_err(|e| bad(format!("cannot read the store's texture: {e} (--no-texture shows the store shaded)")))?;
    let img = ::image::load_from_memory(&bytes).map_err(|e| bad(format!("cannot decode the texture: {e} (--no-texture shows the store shaded)")))?.into_rgba8();
    let (w, h) = img.dimensions();
    let max = (ram as f64 * TEXTURE_SHARE) as u64;
    Ok(MipChain::fitted(&file, w, h, img.into_raw(), max))
}

/// Reserves the texture's bytes in `view` (and asks loads for uvs) when
/// `enabled` and the store has one; gives the chain to upload.
pub fn prepare(store: &Path, view: &mut crate::view::ViewOptions, enabled: bool) -> Result<Option<MipChain>> {
    if !enabled {
        return Ok(None);
    }
    let chain = for_store(store, view.ram)?;
    if let Some(c) = &chain {
        view.texture_bytes = c.bytes();
    }
    Ok(chain)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mips_average_in_linear_light_down_to_one_texel() {
        // Black and white columns: the mean is linear mid-grey, sRGB 188.
        let (w, h) = (6u32, 3u32);
        let rgba: Vec<u8> = (0..w * h).flat_map(|i| if i % 2 == 0 { [0, 0, 0, 255] } else { [255, 255, 255, 255] }).collect();
        let c = MipChain::new("t", w, h, rgba);
        let sizes: Vec<(u32, u32)> = c.levels.iter().map(|l| (l.width, l.height)).collect();
        assert_eq!(sizes, vec![(6, 3), (3, 1), (1, 1)]);
        assert!(c.levels[1].rgba.chunks_exact(4).all(|p| p == [188, 188, 188, 255]), "{:?}", c.levels[1].rgba);
        assert_eq!(c.levels[2].rgba, vec![188, 188, 188, 255]);
        assert_eq!(c.bytes(), (18 + 3 + 1) * 4);
    }

    #[test]
    fn a_texture_too_big_for_its_share_loses_its_finest_levels() {
        let c = MipChain::new("t", 64, 64, vec![128; 64 * 64 * 4]);
        let full = c.bytes();
        assert_eq!(full, 4 * (4096 + 1024 + 256 + 64 + 16 + 4 + 1));
        let f = c.clone().fit(full).unwrap();
        assert_eq!((f.dropped, f.size()), (0, (64, 64)));
        let f = c.clone().fit(full - 1).unwrap();
        assert_eq!((f.dropped, f.size()), (1, (32, 32)));
        assert!(f.bytes() < full);
        let f = c.clone().fit(4).unwrap();
        assert_eq!(f.size(), (1, 1));
        // Fitting while building gives the same chain.
        let rgba: Vec<u8> = (0..64 * 48 * 4).map(|i| (i * 37 % 251) as u8).collect();
        let c2 = MipChain::new("t", 64, 48, rgba.clone());
        for max in [c2.bytes(), c2.bytes() - 1, 5000, 4, 3] {
            assert_eq!(MipChain::fitted("t", 64, 48, rgba.clone(), max), c2.clone().fit(max), "{max}");
        }
        assert!(c.fit(3).is_none());
    }
}
