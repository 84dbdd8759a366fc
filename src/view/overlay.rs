//! Statistics overlay: text lines rasterised on the CPU with the 8x8 bitmap
//! font of `font8x8`, drawn 2x scaled in white over a translucent dark panel.
//!
//! Takes: lines of text. Gives: an [`OverlayImage`] (straight-alpha RGBA8,
//! sRGB) that [`crate::view::gpu::Renderer`] uploads as a texture when it
//! changes and blends over the frame, pixel for pixel, at the top-left corner.

use font8x8::UnicodeFonts;

/// A straight-alpha RGBA8 (sRGB) image, row-major, top row first.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OverlayImage {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// Scale of the 8x8 glyphs.
pub const SCALE: u32 = 2;
/// Padding around the text, in pixels.
pub const PAD: u32 = 6;
/// Vertical gap between lines, in pixels.
pub const LINE_GAP: u32 = 2;
/// Panel color (dark, translucent).
pub const BACKGROUND: [u8; 4] = [10, 12, 16, 170];
/// Text color.
pub const FOREGROUND: [u8; 4] = [255, 255, 255, 255];

const GLYPH: u32 = 8 * SCALE;

fn glyph(c: char) -> [u8; 8] {
    font8x8::BASIC_FONTS
        .get(c)
        .or_else(|| font8x8::LATIN_FONTS.get(c))
        .or_else(|| font8x8::BOX_FONTS.get(c))
        .or_else(|| font8x8::GREEK_FONTS.get(c))
        .or_else(|| font8x8::BASIC_FONTS.get('?'))
        .unwrap_or([0; 8])
}

/// Renders `lines` (a tab counts as one space; characters the font lacks
/// draw as `?`) into an image just large enough for the longest line. An empty list
/// gives a panel with only padding.
pub fn overlay_text(lines: &[String]) -> OverlayImage {
    let cols = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32;
    let rows = lines.len() as u32;
    let width = cols * GLYPH + 2 * PAD;
    let height = rows * GLYPH + rows.saturating_sub(1) * LINE_GAP + 2 * PAD;
    let mut rgba = BACKGROUND.repeat((width * height) as usize);
    for (row, line) in lines.iter().enumerate() {
        let y0 = PAD + row as u32 * (GLYPH + LINE_GAP);
        for (col, c) in line.chars().enumerate() {
            let c = if c == '\t' { ' ' } else { c };
            if c == ' ' {
                continue;
            }
            let bits = glyph(c);
            let x0 = PAD + col as u32 * GLYPH;
            for (gy, byte) in bits.iter().enumerate() {
                for gx in 0..8u32 {
                    // Bit 0 is the leftmost pixel.
                    if byte >> gx & 1 == 0 {
                        continue;
                    }
                    for sy in 0..SCALE {
                        for sx in 0..SCALE {
                            let x = x0 + gx * SCALE + sx;
                            let y = y0 + gy as u32 * SCALE + sy;
                            let i = ((y * width + x) * 4) as usize;
                            rgba[i..i + 4].copy_from_slice(&FOREGROUND);
                        }
                    }
                }
            }
        }
    }
    OverlayImage { width, height, rgba }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_follows_the_longest_line() {
        let img = overlay_text(&["ab".to_string(), "abcd".to_string()]);
        assert_eq!(img.width, 4 * 16 + 2 * PAD);
        assert_eq!(img.height, 2 * 16 + LINE_GAP + 2 * PAD);
        assert_eq!(img.rgba.len(), (img.width * img.height * 4) as usize);
    }

    #[test]
    fn text_pixels_are_foreground_and_padding_is_background() {
        let img = overlay_text(&["H".to_string()]);
        let px = |x: u32, y: u32| {
            let i = ((y * img.width + x) * 4) as usize;
            [img.rgba[i], img.rgba[i + 1], img.rgba[i + 2], img.rgba[i + 3]]
        };
        assert_eq!(px(0, 0), BACKGROUND);
        let fg = img.rgba.chunks(4).filter(|p| *p == FOREGROUND).count();
        // 'H' in font8x8 has 22 set bits, each a 2x2 block.
        let bits: u32 = glyph('H').iter().map(|b| b.count_ones()).sum();
        assert_eq!(fg as u32, bits * SCALE * SCALE);
        assert!(fg > 0);
        // The left stroke of 'H' starts in the first glyph column or two.
        let on_left = (0..16).any(|y| px(PAD, PAD + y) == FOREGROUND || px(PAD + 2, PAD + y) == FOREGROUND);
        assert!(on_left);
    }

    #[test]
    fn empty_and_unknown() {
        let img = overlay_text(&[]);
        assert_eq!((img.width, img.height), (2 * PAD, 2 * PAD));
        let img = overlay_text(&["\u{1F600}".to_string()]);
        assert!(img.rgba.chunks(4).any(|p| p == FOREGROUND), "unknown glyphs draw as '?'");
    }
}
