//! A many-island texture atlas laid over any mesh, as photogrammetry tools
//! make them: the surface is cut into islands (here the cells of a k×k×k
//! grid over the box, by triangle centroid), each island is projected on
//! the plane facing its mean normal and packed into its own square tile of
//! the atlas, and every vertex on an island border is split into one vertex
//! per island (a uv seam along every island border, positions identical).
//!
//! Takes: an indexed mesh and the grid's cells per axis. Gives: the mesh
//! with per-vertex uvs and split seams, and the atlas's tiles per side (a
//! uv's tile is `floor(uv × tiles)`, so a triangle whose corners lie in
//! different tiles bleeds across islands). Built in memory: test and bench
//! inputs, not billions of triangles.
//!
//! [`paint`] bakes a texture for such a mesh as a photogrammetry tool
//! would from its photos: every texel an island covers gets the colour of
//! the surface point it maps to (a smooth colour field with a fine dark
//! grid, a function of position alone), so a render of the input shows no
//! seam, and a simplified mesh whose uvs slide, tear or bleed into the
//! neighbouring island shows it. The gutters between islands are filled
//! by pull-push (each empty texel takes its nearest coarser covered
//! average) so mipmaps and bilinear filtering do not pull in a background
//! colour. Images follow MeshLab's convention: v = 0 is the bottom row.

use crate::mesh::{IndexedMesh, Vertex};
use std::collections::HashMap;

/// Margin kept free inside each tile (of its side), so corners a little
/// outside their island's cell stay in its tile.
const MARGIN: f64 = 0.15;

/// `mesh` with a `cells`³-island atlas (see the module doc); also the
/// tiles per atlas side.
pub fn atlas(mesh: &IndexedMesh, cells: u32) -> (IndexedMesh, u32) {
    let cells = cells.max(1);
    let mut bb = crate::mesh::Aabb::EMPTY;
    for v in &mesh.vertices {
        bb.add(v.pos);
    }
    let size = [0, 1, 2].map(|k| ((bb.max[k] - bb.min[k]) / cells as f64).max(f64::MIN_POSITIVE));
    let cell_of = |p: [f64; 3]| [0, 1, 2].map(|k| (((p[k] - bb.min[k]) / size[k]).floor() as i64).clamp(0, cells as i64 - 1) as u32);
    // Island per triangle: the cell of its centroid, numbered densely.
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let mut island = Vec::with_capacity(mesh.triangles.len());
    let mut normal: Vec<[f64; 3]> = Vec::new();
    let mut cell_at: Vec<[u32; 3]> = Vec::new();
    for t in &mesh.triangles {
        let p = t.map(|v| mesh.vertices[v as usize].pos);
        let c = cell_of([0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0));
        let n = ids.len() as u32;
        let id = *ids.entry(c).or_insert_with(|| {
            normal.push([0.0; 3]);
            cell_at.push(c);
            n
        });
        let e1 = crate::geom::sub(p[1], p[0]);
        let e2 = crate::geom::sub(p[2], p[0]);
        let cr = crate::geom::cross(e1, e2);
        for k in 0..3 {
            normal[id as usize][k] += cr[k];
        }
        island.push(id);
    }
    let tiles = (ids.len() as f64).sqrt().ceil().max(1.0) as u32;
    // Projection axes per island: the two not facing its mean normal.
    let axes: Vec<[usize; 2]> = normal
        .iter()
        .map(|n| {
            let d = (0..3).max_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs())).unwrap();
            [(d + 1) % 3, (d + 2) % 3]
        })
        .collect();
    let mut out = IndexedMesh::default();
    let mut split: HashMap<(u32, u32), u32> = HashMap::new();
    for (t, &id) in mesh.triangles.iter().zip(&island) {
        let nt = t.map(|v| {
            *split.entry((v, id)).or_insert_with(|| {
                let src = &mesh.vertices[v as usize];
                let (c, ax) = (cell_at[id as usize], axes[id as usize]);
                let (tx, ty) = (id % tiles, id / tiles);
                let local = ax.map(|k| (src.pos[k] - (bb.min[k] + c[k] as f64 * size[k])) / size[k]);
                let u = (tx as f64 + MARGIN + (1.0 - 2.0 * MARGIN) * local[0]) / tiles as f64;
                let w = (ty as f64 + MARGIN + (1.0 - 2.0 * MARGIN) * local[1]) / tiles as f64;
                out.vertices.push(Vertex { uv: [u as f32, w as f32], ..*src });
                out.vertices.len() as u32 - 1
            })
        });
        out.triangles.push(nt);
    }
    (out, tiles)
}

/// The colour of surface point `q` (position relative to the box's
/// minimum, divided by its largest side): a smooth field of a few periods
/// per box, darkened on a grid of 24 lines per box side.
pub fn surface_colour(q: [f64; 3]) -> [f64; 3] {
    use std::f64::consts::TAU;
    let w = |a: f64, b: f64, c: f64| 0.5 + 0.4 * (TAU * (a * q[0] + b * q[1] + c * q[2])).sin();
    let rgb = [w(2.1, 0.7, 1.3), w(-0.9, 2.4, 0.6), w(1.1, -1.2, 2.7)];
    let line = q.iter().any(|&x| {
        let f = (x * 24.0).rem_euclid(1.0);
        !(0.07..=0.93).contains(&f)
    });
    if line {
        rgb.map(|c| c * 0.3)
    } else {
        rgb
    }
}

/// Bakes a `size`×`size` RGBA8 texture (sRGB bytes, top row first) for a
/// mesh with uvs (see the module doc): each triangle is rasterised in uv
/// space (texel centres inside it or on its edges) with the colour of the
/// surface point under each texel, then the gutters are filled.
pub fn paint(mesh: &IndexedMesh, size: u32) -> Vec<u8> {
    let n = size.max(1) as usize;
    let mut bb = crate::mesh::Aabb::EMPTY;
    for v in &mesh.vertices {
        bb.add(v.pos);
    }
    let scale = (0..3).map(|k| bb.max[k] - bb.min[k]).fold(0.0f64, f64::max).max(f64::MIN_POSITIVE);
    // Linear colour and coverage per texel.
    let mut img = vec![[0f32; 4]; n * n];
    for t in &mesh.triangles {
        let v = t.map(|i| &mesh.vertices[i as usize]);
        let px = v.map(|v| [v.uv[0] as f64 * n as f64, (1.0 - v.uv[1] as f64) * n as f64]);
        let area = (px[1][0] - px[0][0]) * (px[2][1] - px[0][1]) - (px[2][0] - px[0][0]) * (px[1][1] - px[0][1]);
        if !area.is_finite() || area.abs() < 1e-12 {
            continue;
        }
        let lo = |k: usize| (px.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min) - 0.5).floor().max(0.0) as usize;
        let hi = |k: usize| ((px.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max) - 0.5).ceil().max(0.0) as usize).min(n - 1);
        for y in lo(1)..=hi(1) {
            for x in lo(0)..=hi(0) {
                let c = [x as f64 + 0.5, y as f64 + 0.5];
                let edge = |a: [f64; 2], b: [f64; 2]| ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) / area;
                let w = [edge(px[1], px[2]), edge(px[2], px[0]), edge(px[0], px[1])];
                if w.iter().any(|&w| w < -1e-9) {
                    continue;
                }
                let p = [0, 1, 2].map(|k| (w[0] * v[0].pos[k] + w[1] * v[1].pos[k] + w[2] * v[2].pos[k] - bb.min[k]) / scale);
                let rgb = surface_colour(p).map(|c| crate::color::srgb_to_linear(c) as f32);
                img[y * n + x] = [rgb[0], rgb[1], rgb[2], 1.0];
            }
        }
    }
    fill_gutters(&mut img, n);
    img.iter().flat_map(|p| [p[0], p[1], p[2]].map(|c| (crate::color::linear_to_srgb(c as f64) * 255.0).round() as u8).into_iter().chain([255])).collect()
}

/// Pull-push: texels with coverage 0 take the covered average of the
/// nearest coarser level that has one (an `n`×`n` image of linear colour
/// and coverage in `[3]`, coverage 1 where painted).
pub fn fill_gutters(img: &mut [[f32; 4]], n: usize) {
    // Pull: averages of covered texels, level by level (odd sides clamp).
    let mut levels: Vec<(usize, Vec<[f32; 4]>)> = Vec::new();
    let (mut side, mut cur) = (n, img.to_vec());
    while side > 1 {
        let half = side.div_ceil(2);
        let mut next = vec![[0f32; 4]; half * half];
        for y in 0..half {
            for x in 0..half {
                let mut acc = [0f32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (sx, sy) = ((2 * x + dx).min(side - 1), (2 * y + dy).min(side - 1));
                    let p = cur[sy * side + sx];
                    if p[3] > 0.0 {
                        for k in 0..3 {
                            acc[k] += p[k] * p[3];
                        }
                        acc[3] += p[3];
                    }
                }
                if acc[3] > 0.0 {
                    next[y * half + x] = [acc[0] / acc[3], acc[1] / acc[3], acc[2] / acc[3], 1.0];
                }
            }
        }
        levels.push((side, std::mem::replace(&mut cur, next)));
        side = half;
    }
    levels.push((side, cur));
    // Push: from the coarsest down, empty texels take their parent.
    for l in (0..levels.len() - 1).rev() {
        let (upper, lower) = levels.split_at_mut(l + 1);
        let (side, fine) = &mut upper[l];
        let (half, coarse) = &lower[0];
        for y in 0..*side {
            for x in 0..*side {
                if fine[y * *side + x][3] == 0.0 {
                    fine[y * *side + x] = coarse[(y / 2).min(half - 1) * half + (x / 2).min(half - 1)];
                }
            }
        }
    }
    img.copy_from_slice(&levels[0].1);
}

/// The text chunk every texture octolod-gen writes carries (`Software`).
pub const TEXTURE_MARK: &str = "octolod-gen";

/// Whether `path` is a PNG octolod-gen wrote (its `Software` text chunk).
pub fn is_generated_texture(path: &std::path::Path) -> bool {
    let mut head = vec![0u8; 4096];
    let Ok(n) = std::fs::File::open(path).and_then(|mut f| std::io::Read::read(&mut f, &mut head)) else { return false };
    let needle = format!("tEXtSoftware\0{TEXTURE_MARK}");
    head[..n].windows(needle.len()).any(|w| w == needle.as_bytes())
}

/// Writes an RGBA8 `size`×`size` texture as PNG at `path` (through a
/// temporary file renamed into place), marked as octolod-gen's. An
/// existing file is replaced only when octolod-gen wrote it and `force`.
pub fn write_texture(path: &std::path::Path, size: u32, rgba: &[u8], force: bool) -> crate::error::Result<()> {
    use crate::error::{Error, IoContext};
    if std::fs::symlink_metadata(path).is_ok() {
        if !is_generated_texture(path) {
            return Err(Error::Usage(format!("{} exists and is not a texture octolod-gen wrote; refusing to replace it", path.display())));
        }
        if !force {
            return Err(Error::Usage(format!("{} exists (--force replaces a texture octolod-gen wrote)", path.display())));
        }
    }
    let dir = crate::io::parent_dir(path);
    let tmp = tempfile::Builder::new().prefix(".octolod-gen-texture").tempfile_in(&dir).ctx(&dir, "create temporary file")?;
    {
        let mut w = std::io::BufWriter::new(tmp.as_file());
        let mut enc = png::Encoder::new(&mut w, size, size);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let bad = |e: png::EncodingError| Error::Usage(format!("{}: cannot encode PNG: {e}", path.display()));
        enc.add_text_chunk("Software".into(), TEXTURE_MARK.into()).map_err(bad)?;
        let mut pw = enc.write_header().map_err(bad)?;
        pw.write_image_data(rgba).map_err(bad)?;
        pw.finish().map_err(bad)?;
        std::io::Write::flush(&mut w).ctx(path, "write PNG")?;
    }
    // A temporary file is private; the texture is an ordinary file.
    tmp.as_file().set_permissions(<std::fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o644)).ctx(path, "set permissions")?;
    tmp.persist(path).map_err(|e| Error::io(path, "rename texture into place", e.error))?;
    Ok(())
}

/// Base colours of the textures [`tint`] marks (red, green, blue, yellow,
/// magenta, cyan, then repeating): a render tells which texture a pixel
/// came from by its dominant hue.
pub const PALETTE: [[u8; 3]; 6] = [[230, 40, 40], [40, 200, 40], [50, 70, 235], [225, 215, 40], [215, 50, 215], [40, 210, 220]];

/// Spreads an atlas's islands over `k` textures (MeshLab's `texnumber`):
/// island `i` (its tile, `tx + ty × tiles`) samples texture `i mod k`, so
/// neighbouring islands mostly differ. Every vertex belongs to one island
/// (the atlas splits them along island borders), so each takes its
/// island's material and every triangle's corners agree. Gives the
/// triangles per texture.
pub fn spread_textures(mesh: &mut IndexedMesh, tiles: u32, k: u32) -> Vec<u64> {
    let k = k.max(1);
    let mut per = vec![0u64; k as usize];
    for v in &mut mesh.vertices {
        let (tx, ty) = tile(v.uv, tiles);
        let island = (ty.clamp(0, tiles as i64 - 1) * tiles as i64 + tx.clamp(0, tiles as i64 - 1)) as u32;
        v.material = (island % k) as u16;
    }
    for t in &mesh.triangles {
        per[mesh.vertices[t[0] as usize].material as usize] += 1;
    }
    per
}

/// The texture of material `m` for a mesh spread over textures
/// ([`spread_textures`]): its islands painted ([`paint`]), then every
/// texel mixed 60 % toward `PALETTE[m % 6]` (and a second, darker grid
/// for m ≥ 6), so each texture is told apart at a glance and in a render.
pub fn paint_material(mesh: &IndexedMesh, size: u32, m: u16) -> Vec<u8> {
    let own = IndexedMesh {
        vertices: mesh.vertices.clone(),
        triangles: mesh.triangles.iter().copied().filter(|t| mesh.vertices[t[0] as usize].material == m).collect(),
    };
    let mut img = paint(&own, size);
    tint(&mut img, size, m);
    img
}

/// Mixes an RGBA8 image 60 % toward texture `m`'s palette colour (see
/// [`paint_material`]).
pub fn tint(rgba: &mut [u8], size: u32, m: u16) {
    let base = PALETTE[m as usize % PALETTE.len()];
    let dark = m as usize >= PALETTE.len();
    for (i, px) in rgba.chunks_exact_mut(4).enumerate() {
        let stripe = dark && ((i % size as usize) / 8 + (i / size as usize) / 8) % 2 == 0;
        for c in 0..3 {
            let x = 0.4 * px[c] as f64 + 0.6 * base[c] as f64;
            px[c] = (if stripe { x * 0.6 } else { x }).round() as u8;
        }
    }
}

/// The atlas tile a uv lies in.
pub fn tile(uv: [f32; 2], tiles: u32) -> (i64, i64) {
    ((uv[0] as f64 * tiles as f64).floor() as i64, (uv[1] as f64 * tiles as f64).floor() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen::{GenOptions, Generator, Shape};
    use crate::mesh::AttrSet;

    #[test]
    fn islands_spread_over_textures_each_tinted_its_own_colour() {
        let (vertices, triangles) = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 4000, attrs: AttrSet(AttrSet::UV), ..Default::default() }).mesh();
        let (mut a, tiles) = atlas(&IndexedMesh { vertices, triangles }, 4);
        let per = spread_textures(&mut a, tiles, 3);
        assert_eq!(per.iter().sum::<u64>(), a.triangles.len() as u64);
        assert!(per.iter().all(|&n| n > a.triangles.len() as u64 / 10), "{per:?}");
        // Every triangle lies on one island, so its corners agree.
        assert!(a.triangles.iter().all(|t| t.iter().all(|&i| a.vertices[i as usize].material == a.vertices[t[0] as usize].material)));
        // Each image's dominant channel is its palette colour's.
        for m in 0..3u16 {
            let img = paint_material(&a, 32, m);
            let sum = [0, 1, 2].map(|c| img.chunks_exact(4).map(|p| p[c] as u64).sum::<u64>());
            let top = (0..3).max_by_key(|&c| sum[c]).unwrap();
            assert_eq!(top, m as usize, "texture {m}: channel sums {sum:?}");
        }
    }

    #[test]
    fn islands_are_split_along_their_borders_and_tiled() {
        let (vertices, triangles) = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 4000, attrs: AttrSet(AttrSet::UV), ..Default::default() }).mesh();
        let m = IndexedMesh { vertices, triangles };
        let (a, tiles) = atlas(&m, 4);
        assert_eq!(a.triangles.len(), m.triangles.len());
        assert!(a.vertices.len() > m.vertices.len() + 100, "{} vertices from {}", a.vertices.len(), m.vertices.len());
        assert!(tiles >= 4, "{tiles} tiles per side");
        // Same positions, every triangle inside one tile.
        for (t, s) in a.triangles.iter().zip(&m.triangles) {
            for k in 0..3 {
                assert_eq!(a.vertices[t[k] as usize].pos, m.vertices[s[k] as usize].pos);
            }
            let c = t.map(|v| tile(a.vertices[v as usize].uv, tiles));
            assert!(c[0] == c[1] && c[1] == c[2], "a triangle across tiles {c:?}");
        }
    }

    #[test]
    fn painted_texels_show_the_surface_under_them_and_gutters_are_filled() {
        let (vertices, triangles) = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 4000, attrs: AttrSet(AttrSet::UV), ..Default::default() }).mesh();
        let (a, _) = atlas(&IndexedMesh { vertices, triangles }, 3);
        // About 180 texels per box side: the field changes by < 0.05 a texel.
        let n = 512u32;
        let img = paint(&a, n);
        assert_eq!(img.len(), (n * n * 4) as usize);
        assert!(img.chunks_exact(4).all(|p| p[3] == 255));
        // At a triangle's centroid, the texel holds the centroid's colour.
        let mut bb = crate::mesh::Aabb::EMPTY;
        for v in &a.vertices {
            bb.add(v.pos);
        }
        let scale = (0..3).map(|k| bb.max[k] - bb.min[k]).fold(0.0f64, f64::max);
        let (mut checked, mut close) = (0, 0);
        for t in a.triangles.iter().step_by(17) {
            let v = t.map(|i| &a.vertices[i as usize]);
            let uv = [0, 1].map(|k| (v[0].uv[k] + v[1].uv[k] + v[2].uv[k]) as f64 / 3.0);
            let (x, y) = ((uv[0] * n as f64) as usize, ((1.0 - uv[1]) * n as f64) as usize);
            let q = [0, 1, 2].map(|k| ((v[0].pos[k] + v[1].pos[k] + v[2].pos[k]) / 3.0 - bb.min[k]) / scale);
            let want = surface_colour(q);
            let got = &img[(y * n as usize + x) * 4..][..3];
            // A texel spans a little surface: the field changes slowly
            // except near grid lines, which are skipped. Where an island's
            // planar projection folds (near its silhouette), another
            // triangle may own the texel: most, not all, match.
            let near_line = q.iter().any(|&x| {
                let f = (x * 24.0).rem_euclid(1.0);
                !(0.12..=0.88).contains(&f)
            });
            if near_line {
                continue;
            }
            checked += 1;
            close += (0..3).all(|k| (got[k] as f64 / 255.0 - want[k]).abs() < 0.1) as u32;
        }
        assert!(checked > 40, "{checked}");
        assert!(close as f64 >= 0.9 * checked as f64, "{close} of {checked} texels show their surface's colour");
        // Gutter filling: an image with one painted texel is that colour everywhere.
        let mut one = vec![[0f32; 4]; 9 * 9];
        one[40] = [0.25, 0.5, 0.75, 1.0];
        fill_gutters(&mut one, 9);
        assert!(one.iter().all(|p| *p == [0.25, 0.5, 0.75, 1.0]));
    }

    #[test]
    fn textures_are_marked_and_only_ours_are_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.png");
        write_texture(&p, 4, &[7u8; 64], false).unwrap();
        assert!(is_generated_texture(&p));
        assert!(write_texture(&p, 4, &[9u8; 64], false).is_err());
        write_texture(&p, 4, &[9u8; 64], true).unwrap();
        let user = dir.path().join("u.png");
        std::fs::write(&user, b"mine").unwrap();
        let e = write_texture(&user, 4, &[9u8; 64], true).unwrap_err().to_string();
        assert!(e.contains("not a texture octolod-gen wrote"), "{e}");
        assert_eq!(std::fs::read(&user).unwrap(), b"mine");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 2, "{names:?}");
    }
}
