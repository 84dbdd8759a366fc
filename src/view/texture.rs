//! The store's textures for the viewer: decoded, mipmapped, fitted to the
//! RAM budget together.
//!
//! Takes: a store whose manifest lists textures (copies of the input's
//! images, one slot per material id, see [`crate::manifest::store_textures`])
//! and the viewer's `--ram`. Gives: a [`TextureSet`], each slot's mip chain
//! as RGBA8 sRGB levels ([`MipChain`]) or none, ready for
//! [`crate::view::gpu::Renderer::set_textures`].
//!
//! Choices:
//! * Which slots: a store whose faces choose among textures
//!   ([`crate::mesh::AttrSet::MATERIAL`]) loads every slot, indexed by
//!   material id; any other store draws every face with texture 0, so only
//!   slot 0 is loaded. A slot whose image the store lacks stays empty: its
//!   faces are drawn shaded, as are faces of [`crate::mesh::Vertex::NO_TEXTURE`].
//! * Mipmaps are made here, on the CPU, by a box filter in linear light
//!   (sRGB bytes decoded, averaged, encoded; odd sides split unevenly), so
//!   a far, minified atlas neither shimmers nor darkens. wgpu has no
//!   mipmap generation of its own, and a blit chain on the GPU would need
//!   a render pass per level for a one-time job.
//! * The textures count against `--ram` as node data does: together they
//!   may take at most [`TEXTURE_SHARE`] of the budget. When they do not
//!   fit, finest levels are dropped from the texture whose finest kept
//!   level is the largest, one level at a time ([`plan_drops`]): a small
//!   texture keeps its detail while a large one halves, which keeps the
//!   textures' resolutions as even as their sizes allow (an equal number
//!   of levels each would halve a 64² label as often as an 8k² atlas), and
//!   each step frees the most bytes. The plan is made from the images'
//!   headers before any is decoded.
//! * What is counted is the chains resident on the GPU. Each image is
//!   decoded straight at the finest level kept ([`decode`]), one at a
//!   time, before any node is loaded: a PNG row by row, so it costs that
//!   level and a few rows of the full size (a 16k² atlas kept at 4k²:
//!   64 MiB, not the 1 GiB full-size decode); an interlaced PNG or a JPEG
//!   is decoded whole into one buffer of its own format (an 8192² JPEG:
//!   192 MiB of RGB) and reduced from there, transiently.
//! * uvs follow MeshLab's (and OpenGL's) convention: v = 0 is the image's
//!   bottom row; the shader samples (u, 1 − v), repeating outside [0, 1].

use crate::error::{Error, Location, Result};
use std::path::PathBuf;

pub mod decode;

/// The largest share of `--ram` the textures may take, all together.
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

/// The source texels output index `i` of `n` covers among `src` (the
/// spans of a side split into `n` near-equal runs; odd sides split
/// unevenly).
fn span(i: u32, n: u32, src: u32) -> std::ops::Range<usize> {
    (i as u64 * src as u64 / n as u64) as usize..((i as u64 + 1) * src as u64 / n as u64) as usize
}

/// One row of the next level: `rows` are the source rows (RGBA8, `src_w`
/// texels each) its texels cover, top first; the row's `w` texels, each
/// the linear-light mean of the texels it covers, are appended to `out`.
/// [`downsample`] and the streaming decoder ([`decode`]) both make their
/// rows here, so their levels are the same bytes.
fn downsample_row(rows: &[&[u8]], src_w: u32, w: u32, out: &mut Vec<u8>) {
    let lin = linear_table();
    for x in 0..w {
        let xs = span(x, w, src_w);
        let mut acc = [0f32; 4];
        let mut n = 0f32;
        for row in rows {
            for sx in xs.clone() {
                let p = &row[sx * 4..][..4];
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
            out.push((enc * 255.0).round().clamp(0.0, 255.0) as u8);
        }
    }
}

/// The next level of `l`: sides halved (at least 1), each texel the
/// linear-light mean of the texels it covers.
fn downsample(l: &MipLevel) -> MipLevel {
    let (w, h) = halve((l.width, l.height));
    let mut rgba = Vec::with_capacity(w as usize * h as usize * 4);
    let stride = l.width as usize * 4;
    for y in 0..h {
        let rows: Vec<&[u8]> = span(y, h, l.height).map(|sy| &l.rgba[sy * stride..][..stride]).collect();
        downsample_row(&rows, l.width, w, &mut rgba);
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
    /// levels that will be dropped (see [`MipChain::dropping`]).
    pub fn fitted(name: &str, width: u32, height: u32, rgba: Vec<u8>, max_bytes: u64) -> Option<MipChain> {
        let levels = plan_drops(&[(width, height)], max_bytes)?[0];
        Some(MipChain::dropping(name, width, height, rgba, levels))
    }

    /// The chain of a `width`×`height` image less its `levels` finest
    /// levels (at most down to 1×1), without holding them: each finer
    /// level goes as soon as the next is made, so a texture much larger
    /// than its share costs its decode and a quarter of it, not the whole
    /// chain.
    pub fn dropping(name: &str, width: u32, height: u32, rgba: Vec<u8>, levels: u32) -> MipChain {
        let mut level = MipLevel { width, height, rgba };
        let mut dropped = 0;
        while dropped < levels && (level.width > 1 || level.height > 1) {
            level = downsample(&level);
            dropped += 1;
        }
        let mut chain = MipChain::new(name, level.width, level.height, level.rgba);
        chain.dropped = dropped;
        chain
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

/// Sides of the next mip level.
pub fn halve((w, h): (u32, u32)) -> (u32, u32) {
    ((w / 2).max(1), (h / 2).max(1))
}

/// Bytes (RGBA8) of the mip chain from a level of sides `wh` down to 1×1.
pub fn chain_bytes(mut wh: (u32, u32)) -> u64 {
    let mut b = 0u64;
    loop {
        b += wh.0 as u64 * wh.1 as u64 * 4;
        if wh == (1, 1) {
            return b;
        }
        wh = halve(wh);
    }
}

/// How many finest levels to drop from each texture (full sizes `sizes`)
/// so that their chains take at most `max_bytes` together: one level at a
/// time from the texture whose finest kept level is the largest (the
/// lowest slot among equals). None when even every texture at 1×1 does
/// not fit.
pub fn plan_drops(sizes: &[(u32, u32)], max_bytes: u64) -> Option<Vec<u32>> {
    let mut sides: Vec<(u32, u32)> = sizes.iter().map(|&(w, h)| (w.max(1), h.max(1))).collect();
    let mut drops = vec![0u32; sides.len()];
    let mut total: u64 = sides.iter().map(|&s| chain_bytes(s)).sum();
    let finest = |(w, h): (u32, u32)| w as u64 * h as u64 * 4;
    while total > max_bytes {
        let i = (0..sides.len()).filter(|&i| sides[i] != (1, 1)).max_by_key(|&i| (finest(sides[i]), std::cmp::Reverse(i)))?;
        // A chain less its finest level is the chain of the next level.
        total -= finest(sides[i]);
        sides[i] = halve(sides[i]);
        drops[i] += 1;
    }
    Some(drops)
}

/// The textures a viewer shows, by material id.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TextureSet {
    /// Slot k: texture k's chain, or none (the store lacks its image).
    pub slots: Vec<Option<MipChain>>,
}

impl TextureSet {
    /// Bytes of every chain (what the GPU holds).
    pub fn bytes(&self) -> u64 {
        self.slots.iter().flatten().map(MipChain::bytes).sum()
    }

    /// No slot holds a texture: nothing is drawn textured.
    pub fn is_empty(&self) -> bool {
        self.slots.iter().all(Option::is_none)
    }
}

/// Loads the images `slots` (each the store's file name and its path, or
/// none) as mip chains that together take at most `max_bytes`
/// ([`plan_drops`]); an empty set when even their 1×1 levels do not fit.
/// An image that cannot be read or decoded is an error naming its file.
pub fn load(slots: &[Option<(String, PathBuf)>], max_bytes: u64) -> Result<TextureSet> {
    let bad = |path: &PathBuf, what: String| Error::input(Location { file: path.clone(), ..Default::default() }, what);
    let cannot_read =
        |path: &PathBuf, e: &dyn std::fmt::Display| bad(path, format!("cannot read the store's texture: {e} (--no-texture shows the store shaded)"));
    let cannot_decode = |path: &PathBuf, e: &dyn std::fmt::Display| bad(path, format!("cannot decode the texture: {e} (--no-texture shows the store shaded)"));
    // Sizes from the headers: the plan is made before anything is decoded.
    let mut sizes = Vec::new();
    for (_, path) in slots.iter().flatten() {
        let reader = ::image::ImageReader::open(path).and_then(|r| r.with_guessed_format()).map_err(|e| cannot_read(path, &e))?;
        let (w, h) = reader.into_dimensions().map_err(|e| cannot_decode(path, &e))?;
        if w == 0 || h == 0 {
            return Err(cannot_decode(path, &format!("an image of {w}×{h} texels")));
        }
        sizes.push((w, h));
    }
    let Some(drops) = plan_drops(&sizes, max_bytes) else { return Ok(TextureSet { slots: vec![None; slots.len()] }) };
    let mut plan = sizes.into_iter().zip(drops);
    let mut out = Vec::with_capacity(slots.len());
    for slot in slots {
        let Some((file, path)) = slot else {
            out.push(None);
            continue;
        };
        let (size, levels) = plan.next().expect("a plan per image");
        // Decoded straight at the planned level: the full size never lies
        // in memory whole (a PNG; see `decode`).
        let r = decode::decode_reduced(path, |_| levels).map_err(|e| match e {
            decode::DecodeError::Read(e) => cannot_read(path, &e),
            decode::DecodeError::Decode(e) => cannot_decode(path, &e),
        })?;
        if r.full != size {
            return Err(cannot_decode(path, &format!("it decodes to {:?} texels, its header says {size:?}", r.full)));
        }
        let mut chain = MipChain::new(file, r.level.width, r.level.height, r.level.rgba);
        chain.dropped = r.dropped;
        out.push(Some(chain));
    }
    Ok(TextureSet { slots: out })
}

/// The store's textures (every slot when its faces choose among them,
/// else texture 0), decoded, mipmapped and fitted to [`TEXTURE_SHARE`] of
/// `ram` together (see the module doc).
pub fn for_store(store: &crate::store::Store, ram: u64) -> Result<TextureSet> {
    let mut slots = crate::manifest::store_textures(&store.dir);
    if !store.payload_layout.attrs.material() {
        slots.truncate(1);
    }
    load(&slots, (ram as f64 * TEXTURE_SHARE) as u64)
}

/// Reserves the textures' bytes in `view` (and so asks loads for uvs)
/// when `enabled` and the store has any; gives the set to upload (empty
/// when disabled or there is none).
pub fn prepare(store: &crate::store::Store, view: &mut crate::view::ViewOptions, enabled: bool) -> Result<TextureSet> {
    if !enabled {
        return Ok(TextureSet::default());
    }
    let set = for_store(store, view.ram)?;
    view.texture_bytes = set.bytes();
    Ok(set)
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

    /// Several textures share one budget: finest levels go from the
    /// texture whose finest kept level is the largest (the lowest slot
    /// among equals), and the chains then fit.
    #[test]
    fn textures_share_the_budget_largest_first() {
        let sizes = [(256, 256), (64, 64), (32, 16)];
        assert_eq!(sizes.map(chain_bytes), [4 * 87381, 4 * 5461, 4 * 683]);
        let total = |drops: &[u32]| -> u64 {
            sizes
                .iter()
                .zip(drops)
                .map(|(&s, &k)| {
                    let mut s = s;
                    for _ in 0..k {
                        s = halve(s);
                    }
                    chain_bytes(s)
                })
                .sum()
        };
        for (max, want) in [
            (374_100, vec![0, 0, 0]),
            // 256² goes, then 128² (still larger than 64²).
            (374_099, vec![1, 0, 0]),
            (100_000, vec![2, 0, 0]),
            // 64² against 64²: the lower slot first.
            (40_000, vec![3, 0, 0]),
            // The 64² texture halves before the 32² one does again.
            (20_000, vec![3, 1, 0]),
            (12, vec![8, 6, 5]),
        ] {
            let drops = plan_drops(&sizes, max).unwrap();
            assert_eq!(drops, want, "{max}");
            assert!(total(&drops) <= max, "{max}: {}", total(&drops));
        }
        assert_eq!(plan_drops(&sizes, 11), None);
        assert_eq!(plan_drops(&[], 0), Some(vec![]));
    }

    /// Each slot's image is decoded with the planned levels dropped; a
    /// slot the store lacks stays empty; the set fits its share; a
    /// damaged image fails naming its file.
    #[test]
    fn every_slot_is_loaded_mipmapped_within_the_share() {
        let dir = tempfile::tempdir().unwrap();
        let png = |name: &str, n: u32, rgba: [u8; 4]| {
            let p = dir.path().join(name);
            ::image::RgbaImage::from_pixel(n, n, ::image::Rgba(rgba)).save(&p).unwrap();
            Some((name.to_string(), p))
        };
        let slots = vec![png("texture-0.png", 64, [255, 0, 0, 255]), None, png("texture-2.png", 16, [0, 0, 255, 255])];
        // Each slot's finest size, levels dropped and levels kept.
        type Shape = Option<((u32, u32), u32, usize)>;
        let shapes = |set: &TextureSet| -> Vec<Shape> { set.slots.iter().map(|c| c.as_ref().map(|c| (c.size(), c.dropped, c.levels.len()))).collect() };
        let full = chain_bytes((64, 64)) + chain_bytes((16, 16));
        let set = load(&slots, full).unwrap();
        assert_eq!(set.bytes(), full);
        let sizes = shapes(&set);
        assert_eq!(sizes, vec![Some(((64, 64), 0, 7)), None, Some(((16, 16), 0, 5))]);
        // One byte less: the 64² level goes, the 16² texture keeps all.
        let set = load(&slots, full - 1).unwrap();
        assert_eq!(set.bytes(), full - 64 * 64 * 4);
        let sizes = shapes(&set);
        assert_eq!(sizes, vec![Some(((32, 32), 1, 6)), None, Some(((16, 16), 0, 5))]);
        let red = set.slots[0].as_ref().unwrap();
        assert_eq!(red.name, "texture-0.png");
        assert!(red.levels.iter().all(|l| l.rgba.chunks_exact(4).all(|p| p == [255, 0, 0, 255])));
        assert!(set.slots[2].as_ref().unwrap().levels[0].rgba.chunks_exact(4).all(|p| p == [0, 0, 255, 255]));
        // Not even 1×1 each: nothing is shown.
        let set = load(&slots, 7).unwrap();
        assert!(set.is_empty() && set.slots.len() == 3 && set.bytes() == 0);
        assert!(load(&[None], 100).unwrap().is_empty());
        // A damaged image names itself.
        std::fs::write(dir.path().join("texture-2.png"), b"not a png").unwrap();
        let e = load(&slots, full).unwrap_err().to_string();
        assert!(e.contains("texture-2.png") && e.contains("--no-texture"), "{e}");
    }
}
