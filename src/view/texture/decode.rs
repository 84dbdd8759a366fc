//! A texture decoded already reduced: level k of its mip chain, made while
//! the image is read, so a large atlas never lies in memory whole.
//!
//! Takes: an image file (PNG or JPEG) and, once its header is read, how
//! many finest levels to skip. Gives: that level ([`Reduced`]), the same
//! bytes as [`MipChain::new`](super::MipChain::new) on the whole image
//! would give at that level: each halving is a row-by-row stage that
//! makes its rows with the chain's own code (the linear-light box filter,
//! odd sides split unevenly), and the stages are chained, one row of a
//! level feeding the next.
//!
//! Choices:
//! * **PNG, non-interlaced**: read row by row (the `png` crate's
//!   `next_row`, with the `EXPAND` transformation `image` uses, so
//!   palettes, low bit depths and `tRNS` come out as `image` gives them;
//!   16-bit samples are narrowed as `image` narrows them, `(v + 128) /
//!   257`). Peak: the level made, plus at most three rows of each level
//!   above it and the decoder's own two rows: an 8192² RGBA atlas at half
//!   size holds 64 MiB, not 256 MiB.
//! * **Interlaced (Adam7) PNG**: its first pass spans the whole image, so
//!   no row is final before the last pass; it is decoded whole (one
//!   buffer in its own format, then reduced row by row) rather than
//!   streamed, within `image`'s default 512 MiB allocation limit, as
//!   before. Such textures are rare (interlacing is for progressive web
//!   display).
//! * **JPEG**: decoded whole, as before, by `image` (zune-jpeg), which has
//!   no row or scaled output; but into one RGB buffer reduced row by row,
//!   not an RGB image then an RGBA copy. 8192² baseline JPEG, peak RSS of
//!   the decode alone: 454 MiB the old way, 198 MiB into RGB. The
//!   `jpeg-decoder` crate decodes at 1/2..1/8 scale by IDCT scaling (99 MiB
//!   at 1/2), but averages in sRGB (not linear light, so its levels would
//!   differ from the viewer's and darken fine contrast), is in maintenance
//!   only, and would add a decoder to the build: not taken.
//! * [`Reduced::peak_bytes`] counts the buffers this module holds at once
//!   (whole-image buffer, rows, the level made); tests read it to check
//!   the bound without measuring the process.

use super::{downsample_row, halve, span, MipLevel};
use std::io::BufRead;
use std::path::Path;

/// `image`'s default allocation limit, which the whole-image decodes keep
/// (what `image::load_from_memory` allowed before).
const WHOLE_IMAGE_LIMIT: u64 = 512 << 20;

/// Why a texture did not decode.
#[derive(Debug)]
pub enum DecodeError {
    /// The file could not be opened (or its first bytes read).
    Read(std::io::Error),
    /// Its bytes are not an image this build decodes; the decoder's words.
    Decode(String),
}

/// An image decoded at a level of its mip chain.
#[derive(Clone, Debug, PartialEq)]
pub struct Reduced {
    /// The image's full size (its header's).
    pub full: (u32, u32),
    /// Finest levels skipped: `level` is level `dropped` of the chain.
    pub dropped: u32,
    pub level: MipLevel,
    /// The most bytes this decode's own buffers held at once.
    pub peak_bytes: u64,
}

/// Levels in the mip chain of a `w`×`h` image, down to 1×1.
pub fn chain_levels((w, h): (u32, u32)) -> u32 {
    let (mut wh, mut n) = ((w.max(1), h.max(1)), 1);
    while wh != (1, 1) {
        wh = halve(wh);
        n += 1;
    }
    n
}

/// Decodes the image at `path` at the level of its chain that `choose`
/// gives for its full size (at most the 1×1 level). PNG is streamed, an
/// interlaced PNG and a JPEG are decoded whole (see the module doc).
pub fn decode_reduced(path: &Path, choose: impl FnOnce((u32, u32)) -> u32) -> Result<Reduced, DecodeError> {
    let file = std::fs::File::open(path).map_err(DecodeError::Read)?;
    let mut r = std::io::BufReader::new(file);
    if r.fill_buf().map_err(DecodeError::Read)?.starts_with(b"\x89PNG\r\n\x1a\n") {
        let mut d = png::Decoder::new_with_limits(r, png::Limits { bytes: WHOLE_IMAGE_LIMIT as usize });
        d.set_transformations(png::Transformations::EXPAND);
        let reader = d.read_info().map_err(|e| DecodeError::Decode(e.to_string()))?;
        if !reader.info().interlaced {
            return stream_png(reader, choose);
        }
    }
    whole(path, choose)
}

fn stream_png<R: BufRead + std::io::Seek>(mut reader: png::Reader<R>, choose: impl FnOnce((u32, u32)) -> u32) -> Result<Reduced, DecodeError> {
    let bad = |e: &dyn std::fmt::Display| DecodeError::Decode(e.to_string());
    let full = (reader.info().width, reader.info().height);
    let layout = match reader.output_color_type() {
        (png::ColorType::Indexed, _) => return Err(bad(&"a palette left unexpanded")),
        (c, png::BitDepth::Eight) => Layout { channels: c.samples(), wide: None },
        (c, png::BitDepth::Sixteen) => Layout { channels: c.samples(), wide: Some(u16::from_be_bytes) },
        (_, d) => return Err(bad(&format!("{d:?} samples left unexpanded"))),
    };
    let mut red = Reducer::new(full, choose(full));
    let mut rgba = Vec::with_capacity(full.0 as usize * 4);
    while let Some(row) = reader.next_row().map_err(|e| bad(&e))? {
        layout.expand(row.data(), &mut rgba);
        red.push(&rgba, rgba.capacity());
    }
    red.finish()
}

/// The whole-image path: `image` decodes into one buffer of the image's
/// own format, reduced row by row.
fn whole(path: &Path, choose: impl FnOnce((u32, u32)) -> u32) -> Result<Reduced, DecodeError> {
    use ::image::{ColorType, ImageDecoder};
    let bad = |e: &dyn std::fmt::Display| DecodeError::Decode(e.to_string());
    let file = std::fs::File::open(path).map_err(DecodeError::Read)?;
    // The format from the bytes alone, as `image::load_from_memory` had it.
    let reader = ::image::ImageReader::new(std::io::BufReader::new(file)).with_guessed_format().map_err(DecodeError::Read)?;
    let dec = reader.into_decoder().map_err(|e| bad(&e))?;
    let full = dec.dimensions();
    let mut limits = ::image::Limits::default();
    limits.max_alloc = Some(WHOLE_IMAGE_LIMIT);
    limits.reserve(dec.total_bytes()).map_err(|e| bad(&e))?;
    let (channels, wide): (usize, Option<Wide>) = match dec.color_type() {
        ColorType::L8 => (1, None),
        ColorType::La8 => (2, None),
        ColorType::Rgb8 => (3, None),
        ColorType::Rgba8 => (4, None),
        ColorType::L16 => (1, Some(u16::from_ne_bytes)),
        ColorType::La16 => (2, Some(u16::from_ne_bytes)),
        ColorType::Rgb16 => (3, Some(u16::from_ne_bytes)),
        ColorType::Rgba16 => (4, Some(u16::from_ne_bytes)),
        c => return Err(bad(&format!("{c:?} texels"))),
    };
    let layout = Layout { channels, wide };
    let mut buf = vec![0u8; dec.total_bytes() as usize];
    dec.read_image(&mut buf).map_err(|e| bad(&e))?;
    let mut red = Reducer::new(full, choose(full));
    let mut rgba = Vec::with_capacity(full.0 as usize * 4);
    let stride = full.0 as usize * layout.texel_bytes();
    for row in buf.chunks_exact(stride.max(1)).take(full.1 as usize) {
        layout.expand(row, &mut rgba);
        red.push(&rgba, buf.capacity() + rgba.capacity());
    }
    red.finish()
}

/// A row's texels as the decoder gives them: 1 (grey), 2 (grey, alpha),
/// 3 (RGB) or 4 (RGBA) samples, of 8 bits or of 16 (`wide`: their byte
/// order).
#[derive(Clone, Copy)]
struct Layout {
    channels: usize,
    wide: Option<Wide>,
}

/// A 16-bit sample from its two bytes (in the decoder's byte order).
type Wide = fn([u8; 2]) -> u16;

impl Layout {
    fn texel_bytes(self) -> usize {
        self.channels * if self.wide.is_some() { 2 } else { 1 }
    }

    /// `src`'s texels as RGBA8 into `out` (cleared), as `image`'s
    /// `into_rgba8` converts them: grey to its three channels, opaque
    /// without alpha, 16 bits to 8 by `(v + 128) / 257`.
    fn expand(self, src: &[u8], out: &mut Vec<u8>) {
        out.clear();
        for px in src.chunks_exact(self.texel_bytes()) {
            let s = |i: usize| match self.wide {
                None => px[i],
                Some(f) => ((f([px[2 * i], px[2 * i + 1]]) as u32 + 128) / 257) as u8,
            };
            let p = match self.channels {
                1 => [s(0), s(0), s(0), 255],
                2 => [s(0), s(0), s(0), s(1)],
                3 => [s(0), s(1), s(2), 255],
                _ => [s(0), s(1), s(2), s(3)],
            };
            out.extend_from_slice(&p);
        }
    }
}

/// One halving fed row by row: it keeps the source rows of the output row
/// being made (at most three) and gives that row once its last source row
/// arrives.
struct Halver {
    src: (u32, u32),
    dst: (u32, u32),
    rows: Vec<Vec<u8>>,
    held: usize,
    seen: u32,
    y: u32,
}

impl Halver {
    fn new(src: (u32, u32)) -> Halver {
        Halver { src, dst: halve(src), rows: Vec::new(), held: 0, seen: 0, y: 0 }
    }

    /// Takes the next source row; true when it completed an output row,
    /// then in `out`.
    fn push(&mut self, row: &[u8], out: &mut Vec<u8>) -> bool {
        if self.held == self.rows.len() {
            self.rows.push(Vec::with_capacity(row.len()));
        }
        let r = &mut self.rows[self.held];
        r.clear();
        r.extend_from_slice(row);
        self.held += 1;
        self.seen += 1;
        if self.y >= self.dst.1 || (self.seen as usize) < span(self.y, self.dst.1, self.src.1).end {
            return false;
        }
        let rows: Vec<&[u8]> = self.rows[..self.held].iter().map(Vec::as_slice).collect();
        out.clear();
        downsample_row(&rows, self.src.0, self.dst.0, out);
        self.held = 0;
        self.y += 1;
        true
    }

    fn bytes(&self) -> usize {
        self.rows.iter().map(Vec::capacity).sum()
    }
}

/// `dropped` halvings chained: full-size RGBA8 rows in, the level's rows
/// out.
struct Reducer {
    full: (u32, u32),
    dropped: u32,
    size: (u32, u32),
    stages: Vec<Halver>,
    /// Each stage's last output row.
    bufs: Vec<Vec<u8>>,
    out: Vec<u8>,
    rows_in: u32,
    peak: usize,
}

impl Reducer {
    /// For an image of `full` size, skipping `k` levels (at most to 1×1).
    fn new(full: (u32, u32), k: u32) -> Reducer {
        let dropped = k.min(chain_levels(full) - 1);
        let mut stages = Vec::new();
        let mut size = full;
        for _ in 0..dropped {
            stages.push(Halver::new(size));
            size = halve(size);
        }
        let bufs = vec![Vec::new(); stages.len()];
        let out = Vec::with_capacity(size.0 as usize * size.1 as usize * 4);
        Reducer { full, dropped, size, stages, bufs, out, rows_in: 0, peak: 0 }
    }

    /// Takes the next full-size row; `outside` is what the caller's own
    /// buffers hold meanwhile (counted in the peak).
    fn push(&mut self, row: &[u8], outside: usize) {
        self.rows_in += 1;
        if self.rows_in <= self.full.1 {
            feed(&mut self.stages, &mut self.bufs, &mut self.out, row);
        }
        let held = outside + self.out.capacity() + self.stages.iter().map(Halver::bytes).sum::<usize>() + self.bufs.iter().map(Vec::capacity).sum::<usize>();
        self.peak = self.peak.max(held);
    }

    fn finish(self) -> Result<Reduced, DecodeError> {
        let (w, h) = self.size;
        if self.rows_in != self.full.1 || self.out.len() != w as usize * h as usize * 4 {
            return Err(DecodeError::Decode(format!("{} rows decoded of {}", self.rows_in, self.full.1)));
        }
        let level = MipLevel { width: w, height: h, rgba: self.out };
        Ok(Reduced { full: self.full, dropped: self.dropped, level, peak_bytes: self.peak as u64 })
    }
}

/// Passes `row` down the stages; a row out of the last is the level's.
fn feed(stages: &mut [Halver], bufs: &mut [Vec<u8>], out: &mut Vec<u8>, row: &[u8]) {
    match (stages.split_first_mut(), bufs.split_first_mut()) {
        (Some((stage, stages)), Some((buf, bufs))) => {
            if stage.push(row, buf) {
                feed(stages, bufs, out, buf);
            }
        }
        _ => out.extend_from_slice(row),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::view::texture::MipChain;
    use png::{BitDepth, ColorType};

    /// Deterministic bytes that vary texel to texel (so every box filter
    /// rounding shows).
    fn noise(n: usize, seed: u32) -> Vec<u8> {
        let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(12_345);
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                (x >> 8) as u8
            })
            .collect()
    }

    /// A PNG of `data` (rows packed as the format has them), with a palette
    /// and `tRNS` when given.
    fn png_file(dir: &Path, name: &str, (w, h): (u32, u32), ct: ColorType, depth: BitDepth, data: &[u8], plte: Option<(&[u8], &[u8])>) -> std::path::PathBuf {
        let p = dir.join(name);
        let mut e = png::Encoder::new(std::io::BufWriter::new(std::fs::File::create(&p).unwrap()), w, h);
        e.set_color(ct);
        e.set_depth(depth);
        if let Some((palette, trns)) = plte {
            e.set_palette(palette.to_vec());
            e.set_trns(trns.to_vec());
        }
        let mut wr = e.write_header().unwrap();
        wr.write_image_data(data).unwrap();
        wr.finish().unwrap();
        p
    }

    /// The chain `image` gives for the whole file, as the code before did.
    fn reference(p: &Path) -> MipChain {
        let img = ::image::load_from_memory(&std::fs::read(p).unwrap()).unwrap().into_rgba8();
        let (w, h) = img.dimensions();
        MipChain::new("t", w, h, img.into_raw())
    }

    /// Level k decoded reduced is the chain's level k, for every k (and
    /// past the 1×1 level, which it stops at).
    fn matches_chain(p: &Path) {
        let chain = reference(p);
        let l0 = &chain.levels[0];
        for k in 0..chain.levels.len() as u32 + 2 {
            let r = decode_reduced(p, |_| k).unwrap();
            let want = k.min(chain.levels.len() as u32 - 1);
            assert_eq!((r.full, r.dropped), ((l0.width, l0.height), want), "{p:?} k={k}");
            assert!(r.level == chain.levels[want as usize], "{p:?} k={k}: differs from the chain's level {want}");
        }
    }

    #[test]
    fn every_png_format_streams_to_the_chains_levels() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let sizes = [(37, 21), (21, 37), (64, 48), (1, 7), (3, 1), (1, 1), (16, 16)];
        for (i, &(w, h)) in sizes.iter().enumerate() {
            let n = (w * h) as usize;
            let s = i as u32;
            for (name, ct, depth, bytes) in [
                ("rgba8", ColorType::Rgba, BitDepth::Eight, noise(n * 4, s)),
                ("rgb8", ColorType::Rgb, BitDepth::Eight, noise(n * 3, s)),
                ("grey8", ColorType::Grayscale, BitDepth::Eight, noise(n, s)),
                ("greya8", ColorType::GrayscaleAlpha, BitDepth::Eight, noise(n * 2, s)),
                ("rgb16", ColorType::Rgb, BitDepth::Sixteen, noise(n * 6, s)),
                ("rgba16", ColorType::Rgba, BitDepth::Sixteen, noise(n * 8, s)),
                ("grey16", ColorType::Grayscale, BitDepth::Sixteen, noise(n * 2, s)),
            ] {
                matches_chain(&png_file(d, &format!("{name}-{w}x{h}.png"), (w, h), ct, depth, &bytes, None));
            }
            // A palette of 200 colours, some translucent.
            let palette = noise(200 * 3, 99);
            let trns = noise(150, 98);
            let idx: Vec<u8> = noise(n, s).iter().map(|b| b % 200).collect();
            matches_chain(&png_file(d, &format!("pal8-{w}x{h}.png"), (w, h), ColorType::Indexed, BitDepth::Eight, &idx, Some((&palette, &trns))));
            // Packed samples: 4-bit palette, 1-bit grey (rows padded to bytes).
            let row4 = (w as usize).div_ceil(2);
            let p4: Vec<u8> = noise(row4 * h as usize, s + 7);
            matches_chain(&png_file(d, &format!("pal4-{w}x{h}.png"), (w, h), ColorType::Indexed, BitDepth::Four, &p4, Some((&palette[..48], &trns[..5]))));
            let g1 = noise((w as usize).div_ceil(8) * h as usize, s + 3);
            matches_chain(&png_file(d, &format!("grey1-{w}x{h}.png"), (w, h), ColorType::Grayscale, BitDepth::One, &g1, None));
        }
    }

    /// The PNG CRC (ISO 3309).
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
        }
        !c
    }

    /// An Adam7-interlaced RGBA8 PNG of `rgba` (the `png` encoder writes
    /// none): each pass's rows unfiltered, in stored deflate blocks.
    fn interlaced_png(p: &Path, (w, h): (u32, u32), rgba: &[u8]) {
        let mut raw = Vec::new();
        for (x0, y0, dx, dy) in [(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2)] {
            if x0 >= w || y0 >= h {
                continue;
            }
            for y in (y0..h).step_by(dy) {
                raw.push(0);
                for x in (x0..w).step_by(dx) {
                    raw.extend_from_slice(&rgba[((y * w + x) * 4) as usize..][..4]);
                }
            }
        }
        let mut z = vec![0x78, 0x01];
        let blocks: Vec<&[u8]> = raw.chunks(65_535).collect();
        for (i, b) in blocks.iter().enumerate() {
            z.push((i + 1 == blocks.len()) as u8);
            z.extend_from_slice(&(b.len() as u16).to_le_bytes());
            z.extend_from_slice(&(!(b.len() as u16)).to_le_bytes());
            z.extend_from_slice(b);
        }
        let (mut a, mut b) = (1u32, 0u32);
        for &x in &raw {
            a = (a + x as u32) % 65_521;
            b = (b + a) % 65_521;
        }
        z.extend_from_slice(&((b << 16) | a).to_be_bytes());
        let mut f = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut chunk = |kind: &[u8], data: &[u8]| {
            f.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let start = f.len();
            f.extend_from_slice(kind);
            f.extend_from_slice(data);
            let crc = crc32(&f[start..]);
            f.extend_from_slice(&crc.to_be_bytes());
        };
        let mut ihdr = [w.to_be_bytes(), h.to_be_bytes()].concat();
        ihdr.extend_from_slice(&[8, 6, 0, 0, 1]);
        chunk(b"IHDR", &ihdr);
        chunk(b"IDAT", &z);
        chunk(b"IEND", &[]);
        std::fs::write(p, f).unwrap();
    }

    /// An interlaced PNG is decoded whole, then reduced: the same levels,
    /// and its peak counts the whole image.
    #[test]
    fn an_interlaced_png_falls_back_to_the_whole_image() {
        let dir = tempfile::tempdir().unwrap();
        for (w, h) in [(37, 21), (5, 3), (1, 1), (64, 64)] {
            let p = dir.path().join(format!("adam7-{w}x{h}.png"));
            let rgba = noise((w * h * 4) as usize, w);
            interlaced_png(&p, (w, h), &rgba);
            let chain = reference(&p);
            assert_eq!(chain.levels[0].rgba, rgba, "the hand-made file decodes as written");
            matches_chain(&p);
            assert!(decode_reduced(&p, |_| 1).unwrap().peak_bytes >= (w * h * 4) as u64);
        }
    }

    #[test]
    fn a_jpeg_is_reduced_as_its_chain() {
        use ::image::ImageEncoder;
        let dir = tempfile::tempdir().unwrap();
        for (w, h, ct, n) in
            [(40, 24, ::image::ExtendedColorType::Rgb8, 3), (37, 21, ::image::ExtendedColorType::Rgb8, 3), (19, 9, ::image::ExtendedColorType::L8, 1)]
        {
            let p = dir.path().join(format!("t-{w}x{h}-{n}.jpg"));
            let f = std::fs::File::create(&p).unwrap();
            ::image::codecs::jpeg::JpegEncoder::new_with_quality(f, 90).write_image(&noise(w * h * n, 5), w as u32, h as u32, ct).unwrap();
            matches_chain(&p);
        }
    }

    /// The streaming path holds the level made and a few rows, not the
    /// image: counted on the decoder's own buffers, so the bound is exact.
    #[test]
    fn a_streamed_png_holds_its_level_and_a_few_rows() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (256u32, 192u32);
        let p = png_file(dir.path(), "big.png", (w, h), ColorType::Rgba, BitDepth::Eight, &noise((w * h * 4) as usize, 1), None);
        let full = (w * h * 4) as u64;
        let row = (w * 4) as u64;
        for k in 1..4u32 {
            let r = decode_reduced(&p, |_| k).unwrap();
            let out = r.level.rgba.len() as u64;
            assert_eq!(out, full >> (2 * k));
            // The level, the converted row, and per stage at most three
            // source rows and one output row.
            let rows: u64 = (0..k).map(|i| 3 * (row >> i) + (row >> (i + 1))).sum();
            assert!(r.peak_bytes >= out && r.peak_bytes <= out + row + rows, "k={k}: {} bytes held", r.peak_bytes);
            assert!(r.peak_bytes < full / 3, "k={k}: {} bytes held", r.peak_bytes);
        }
        let r = decode_reduced(&p, |_| 0).unwrap();
        assert_eq!(r.peak_bytes, full + row);
    }

    #[test]
    fn unreadable_and_damaged_files_say_which() {
        let dir = tempfile::tempdir().unwrap();
        let missing = decode_reduced(&dir.path().join("none.png"), |_| 0);
        assert!(matches!(missing, Err(DecodeError::Read(_))), "{missing:?}");
        std::fs::write(dir.path().join("junk.png"), b"not a png").unwrap();
        let junk = decode_reduced(&dir.path().join("junk.png"), |_| 0);
        assert!(matches!(junk, Err(DecodeError::Decode(_))), "{junk:?}");
        // A PNG cut short fails, whatever level is asked for.
        let p = png_file(dir.path(), "cut.png", (64, 64), ColorType::Rgb, BitDepth::Eight, &noise(64 * 64 * 3, 2), None);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        for k in [0, 2] {
            let cut = decode_reduced(&p, |_| k);
            assert!(matches!(cut, Err(DecodeError::Decode(_))), "{cut:?}");
        }
    }
}
