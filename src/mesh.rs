//! Vertex model shared by every stage: which attributes a mesh really has
//! ([`AttrSet`]), one decoded vertex ([`Vertex`]) and the packed little-endian
//! record layout ([`VertexLayout`]) used in temp files, soups and payloads.
//!
//! Takes: nothing (pure data model). Gives: the attribute set every later stage
//! keys on, so that position-only meshes never pay for attributes they lack.
//!
//! Positions keep the precision of the input (`f32` or `f64`), so a mesh at
//! 1e6 from the origin with 1e-3 detail written as doubles survives exactly.
//! Normals and uvs are `f32`; colors are RGBA8 (alpha is 255 when absent).

/// The set of per-vertex attributes a mesh carries, plus position precision.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct AttrSet(pub u32);

impl AttrSet {
    /// Per-vertex normal (nx, ny, nz).
    pub const NORMAL: u32 = 1;
    /// Per-vertex color (red, green, blue).
    pub const COLOR: u32 = 2;
    /// Texture coordinates (u, v).
    pub const UV: u32 = 4;
    /// Positions stored as f64 (input was double); f32 otherwise.
    pub const POS_F64: u32 = 8;
    /// Color carries a meaningful alpha channel.
    pub const ALPHA: u32 = 16;
    /// Per-vertex material: which of the input's textures its faces
    /// sample (a PLY face's `texnumber`, OBJ's `usemtl`, a glTF
    /// primitive's material). Vertices are split where materials meet, so
    /// every triangle's corners agree and a material border is a seam.
    /// Not part of the quadric: it is an identity, not a value to average.
    pub const MATERIAL: u32 = 32;
    const ALL: u32 = 63;

    pub const POSITION_ONLY: AttrSet = AttrSet(0);

    pub fn from_bits(bits: u32) -> Option<AttrSet> {
        if bits & !Self::ALL != 0 || (bits & Self::ALPHA != 0 && bits & Self::COLOR == 0) {
            None
        } else {
            Some(AttrSet(bits))
        }
    }
    pub fn has(self, flag: u32) -> bool {
        self.0 & flag != 0
    }
    pub fn with(self, flag: u32, on: bool) -> AttrSet {
        if on {
            AttrSet(self.0 | flag)
        } else {
            AttrSet(self.0 & !flag)
        }
    }
    pub fn normal(self) -> bool {
        self.has(Self::NORMAL)
    }
    pub fn color(self) -> bool {
        self.has(Self::COLOR)
    }
    pub fn alpha(self) -> bool {
        self.has(Self::ALPHA)
    }
    pub fn uv(self) -> bool {
        self.has(Self::UV)
    }
    pub fn pos_f64(self) -> bool {
        self.has(Self::POS_F64)
    }
    pub fn material(self) -> bool {
        self.has(Self::MATERIAL)
    }

    /// Dimension of the generalized quadric for this attribute set:
    /// 3 for position, +2 for uv, +3 for normal, +3 for color.
    pub fn quadric_dim(self) -> usize {
        3 + if self.uv() { 2 } else { 0 } + if self.normal() { 3 } else { 0 } + if self.color() { 3 } else { 0 }
    }

    /// Human-readable list, e.g. `position(f32)+normal+color`.
    pub fn describe(self) -> String {
        let mut s = String::from(if self.pos_f64() { "position(f64)" } else { "position(f32)" });
        if self.normal() {
            s.push_str("+normal");
        }
        if self.color() {
            s.push_str(if self.alpha() { "+color(rgba)" } else { "+color(rgb)" });
        }
        if self.uv() {
            s.push_str("+uv");
        }
        if self.material() {
            s.push_str("+material");
        }
        s
    }
}

/// One decoded vertex. Fields an [`AttrSet`] lacks hold their defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vertex {
    pub pos: [f64; 3],
    pub normal: [f32; 3],
    pub color: [u8; 4],
    pub uv: [f32; 2],
    /// Index of the material (texture) its faces use; 0 without
    /// [`AttrSet::MATERIAL`]. It indexes the input's texture list (the
    /// store manifest's `textures`); [`Vertex::NO_TEXTURE`] for faces whose
    /// material has no texture.
    pub material: u16,
}

impl Vertex {
    /// Material id of faces without a texture (an OBJ material without
    /// `map_Kd`, a glTF material without a base colour texture).
    pub const NO_TEXTURE: u16 = u16::MAX;
}

impl Default for Vertex {
    fn default() -> Self {
        Vertex { pos: [0.0; 3], normal: [0.0; 3], color: [0, 0, 0, 255], uv: [0.0; 2], material: 0 }
    }
}

/// Packed little-endian layout of a vertex for an attribute set:
/// position (12 or 24 bytes), then normal (12), color (4), uv (8) and
/// material (u16, 2) when present.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VertexLayout {
    pub attrs: AttrSet,
    pub size: usize,
    normal_at: usize,
    color_at: usize,
    uv_at: usize,
    material_at: usize,
}

impl VertexLayout {
    pub fn new(attrs: AttrSet) -> VertexLayout {
        let mut off = if attrs.pos_f64() { 24 } else { 12 };
        let normal_at = off;
        if attrs.normal() {
            off += 12;
        }
        let color_at = off;
        if attrs.color() {
            off += 4;
        }
        let uv_at = off;
        if attrs.uv() {
            off += 8;
        }
        let material_at = off;
        if attrs.material() {
            off += 2;
        }
        VertexLayout { attrs, size: off, normal_at, color_at, uv_at, material_at }
    }

    /// Byte offset of the uv in an encoded vertex, when the layout has one.
    pub fn uv_offset(&self) -> Option<usize> {
        self.attrs.uv().then_some(self.uv_at)
    }

    /// Sets the uv of an encoded vertex (a layout with uvs).
    #[inline]
    pub fn set_uv(&self, rec: &mut [u8], uv: [f32; 2]) {
        let o = self.uv_at;
        rec[o..o + 4].copy_from_slice(&uv[0].to_le_bytes());
        rec[o + 4..o + 8].copy_from_slice(&uv[1].to_le_bytes());
    }

    /// Writes `v` into `out[..self.size]`. Positions are rounded to f32 when
    /// the layout is single precision.
    #[inline]
    pub fn encode(&self, v: &Vertex, out: &mut [u8]) {
        let out = &mut out[..self.size];
        if self.attrs.pos_f64() {
            for k in 0..3 {
                out[8 * k..8 * k + 8].copy_from_slice(&v.pos[k].to_le_bytes());
            }
        } else {
            for k in 0..3 {
                out[4 * k..4 * k + 4].copy_from_slice(&(v.pos[k] as f32).to_le_bytes());
            }
        }
        if self.attrs.normal() {
            let o = self.normal_at;
            for k in 0..3 {
                out[o + 4 * k..o + 4 * k + 4].copy_from_slice(&v.normal[k].to_le_bytes());
            }
        }
        if self.attrs.color() {
            out[self.color_at..self.color_at + 4].copy_from_slice(&v.color);
        }
        if self.attrs.uv() {
            let o = self.uv_at;
            for k in 0..2 {
                out[o + 4 * k..o + 4 * k + 4].copy_from_slice(&v.uv[k].to_le_bytes());
            }
        }
        if self.attrs.material() {
            out[self.material_at..self.material_at + 2].copy_from_slice(&v.material.to_le_bytes());
        }
    }

    /// Reads a vertex from `bytes[..self.size]`.
    #[inline]
    pub fn decode(&self, bytes: &[u8]) -> Vertex {
        let b = &bytes[..self.size];
        let mut v = Vertex { pos: self.position(b), ..Default::default() };
        if self.attrs.normal() {
            let o = self.normal_at;
            for k in 0..3 {
                v.normal[k] = f32::from_le_bytes(b[o + 4 * k..o + 4 * k + 4].try_into().unwrap());
            }
        }
        if self.attrs.color() {
            v.color.copy_from_slice(&b[self.color_at..self.color_at + 4]);
        }
        if self.attrs.uv() {
            let o = self.uv_at;
            for k in 0..2 {
                v.uv[k] = f32::from_le_bytes(b[o + 4 * k..o + 4 * k + 4].try_into().unwrap());
            }
        }
        if self.attrs.material() {
            v.material = u16::from_le_bytes([b[self.material_at], b[self.material_at + 1]]);
        }
        v
    }

    /// Position only, without decoding attributes.
    #[inline]
    pub fn position(&self, bytes: &[u8]) -> [f64; 3] {
        let mut p = [0.0; 3];
        if self.attrs.pos_f64() {
            for k in 0..3 {
                p[k] = f64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().unwrap());
            }
        } else {
            for k in 0..3 {
                p[k] = f32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().unwrap()) as f64;
            }
        }
        p
    }
}

/// Axis-aligned bounding box in f64 (the default is empty).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };

    #[inline]
    #[allow(clippy::needless_range_loop, reason = "axis loop over three arrays in lockstep")]
    pub fn add(&mut self, p: [f64; 3]) {
        for k in 0..3 {
            self.min[k] = self.min[k].min(p[k]);
            self.max[k] = self.max[k].max(p[k]);
        }
    }
    /// Grows to include `o` (an empty `o` changes nothing).
    pub fn merge(&mut self, o: &Aabb) {
        if !o.is_empty() {
            self.add(o.min);
            self.add(o.max);
        }
    }
    pub fn is_empty(&self) -> bool {
        self.min[0] > self.max[0]
    }
    pub fn diagonal(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let d: f64 = (0..3).map(|k| (self.max[k] - self.min[k]).powi(2)).sum();
        d.sqrt()
    }
    pub fn center(&self) -> [f64; 3] {
        [0, 1, 2].map(|k| 0.5 * (self.min[k] + self.max[k]))
    }
}

impl Default for Aabb {
    fn default() -> Self {
        Aabb::EMPTY
    }
}

/// An indexed mesh whose vertices carry the model's attributes: a store
/// payload, a node being simplified, a level's chunk, `simplify`'s parts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndexedMesh {
    pub vertices: Vec<Vertex>,
    pub triangles: Vec<[u32; 3]>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_round_trips_every_attribute_set() {
        for bits in 0..64u32 {
            let Some(a) = AttrSet::from_bits(bits) else { continue };
            let l = VertexLayout::new(a);
            let v = Vertex {
                pos: [1.0e6 + 1.0e-3, -2.5, 3.25],
                normal: [0.0, 0.6, 0.8],
                color: [1, 2, 3, if a.alpha() { 4 } else { 255 }],
                uv: [0.25, 0.75],
                material: 517,
            };
            let mut buf = vec![0u8; l.size];
            l.encode(&v, &mut buf);
            let w = l.decode(&buf);
            if a.pos_f64() {
                assert_eq!(w.pos, v.pos);
            } else {
                assert_eq!(w.pos[1], -2.5);
                assert_eq!(w.pos[0], (v.pos[0] as f32) as f64);
            }
            assert_eq!(w.normal, if a.normal() { v.normal } else { [0.0; 3] });
            assert_eq!(w.uv, if a.uv() { v.uv } else { [0.0; 2] });
            if a.color() {
                assert_eq!(w.color, v.color);
            }
            assert_eq!(w.material, if a.material() { 517 } else { 0 });
            assert_eq!(
                l.size,
                12 * (1 + a.pos_f64() as usize) + 12 * a.normal() as usize + 4 * a.color() as usize + 8 * a.uv() as usize + 2 * a.material() as usize
            );
        }
    }

    #[test]
    fn quadric_dimension_follows_attributes() {
        assert_eq!(AttrSet::POSITION_ONLY.quadric_dim(), 3);
        assert_eq!(AttrSet(AttrSet::UV).quadric_dim(), 5);
        assert_eq!(AttrSet(AttrSet::NORMAL).quadric_dim(), 6);
        assert_eq!(AttrSet(AttrSet::COLOR).quadric_dim(), 6);
        assert_eq!(AttrSet(AttrSet::COLOR | AttrSet::NORMAL | AttrSet::UV).quadric_dim(), 11);
        assert!(AttrSet::from_bits(AttrSet::ALPHA).is_none());
    }
}
