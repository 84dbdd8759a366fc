//! `octolod-gen`: writes deterministic procedural test meshes as PLY, from
//! one triangle to billions, fast (parallel encoding, streamed, bounded memory).
//!
//! Takes: a shape, a target triangle count, a seed, the attributes and PLY
//! flavour to write. Gives: the PLY (atomically) and one summary line on stdout.

use anyhow::{anyhow, bail};
use clap::{Parser, ValueEnum};
use octolod::gen::{GenOptions, Generator, OtherFormat, Shape};
use octolod::mesh::AttrSet;
use octolod::ply::write::{PlyWriteOptions, UvNames};
use octolod::ply::{Encoding, Scalar};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Format {
    /// PLY, binary little-endian.
    BinaryLe,
    /// PLY, binary big-endian.
    BinaryBe,
    /// PLY, ascii.
    Ascii,
    /// Wavefront OBJ (`v`, `vt`, `vn`, faces by the same index).
    Obj,
    /// Binary STL (positions only).
    StlBinary,
    /// Ascii STL (positions only).
    StlAscii,
}

#[derive(Parser)]
#[command(name = "octolod-gen", version, about = "Generate deterministic procedural test meshes as PLY (or OBJ, STL)")]
struct Args {
    /// Which mesh.
    #[arg(long, value_enum, default_value = "sphere")]
    shape: ShapeArg,
    /// Target triangle count (approximate; accepts 2e7, 20M, 1G).
    #[arg(long, default_value = "1000000", value_parser = parse_count)]
    tris: u64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[arg(long, value_enum, default_value = "binary-le")]
    format: Format,
    /// Double-precision positions.
    #[arg(long)]
    double: bool,
    /// Per-vertex unit normals.
    #[arg(long)]
    normals: bool,
    /// Per-vertex colors (red, green, blue).
    #[arg(long)]
    colors: bool,
    /// Alpha channel too (implies --colors).
    #[arg(long)]
    alpha: bool,
    /// Texture coordinates.
    #[arg(long)]
    uvs: bool,
    /// Names of the texture-coordinate properties.
    #[arg(long, value_enum, default_value = "uv")]
    uv_names: UvNamesArg,
    /// Colors as float (0 to 1) instead of uchar.
    #[arg(long)]
    float_colors: bool,
    /// Add a `float quality` vertex property between x and y (reader test).
    #[arg(long)]
    quality: bool,
    /// Face index type.
    #[arg(long, value_enum, default_value = "int")]
    index_type: IndexType,
    /// Header comment (repeatable).
    #[arg(long)]
    comment: Vec<String>,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
    /// Replace an existing PLY that octolod wrote (never any other file).
    #[arg(long)]
    force: bool,
    /// A texture atlas of about CELLS³ islands (the cells of a grid over the
    /// box), split along every island border as photogrammetry writes them
    /// (implies --uvs; PLY only; built in memory, up to 5e7 triangles).
    #[arg(long, value_name = "CELLS")]
    atlas: Option<u32>,
    /// With --atlas: also bake a SIZE×SIZE texture of the surface (a
    /// colour field and a fine grid, a function of position: seams are
    /// invisible on the input) as OUTPUT's name with `.png`, named by a
    /// `comment TextureFile` line (MeshLab's convention).
    #[arg(long, value_name = "SIZE", requires = "atlas", value_parser = clap::value_parser!(u32).range(1..=16384))]
    texture: Option<u32>,
    /// With --texture: spread the atlas's islands over K textures (island
    /// i samples texture i mod K, MeshLab's face `texnumber`): K images
    /// (OUTPUT's name with `_0.png` … , each tinted its own colour: red,
    /// green, blue, yellow, magenta, cyan, …) and K `comment TextureFile`
    /// lines.
    #[arg(long, value_name = "K", requires = "texture", value_parser = clap::value_parser!(u32).range(2..=1024))]
    textures: Option<u32>,
    /// Output file (PLY, or OBJ/STL with --format).
    #[arg(short, long)]
    output: PathBuf,
}

/// [`Shape`] on the command line (the library has no clap): names and
/// help texts come from the library.
#[derive(Clone, Copy, Debug)]
struct ShapeArg(Shape);

impl ValueEnum for ShapeArg {
    fn value_variants<'a>() -> &'a [Self] {
        static ALL: std::sync::LazyLock<Vec<ShapeArg>> = std::sync::LazyLock::new(|| Shape::ALL.iter().map(|&s| ShapeArg(s)).collect());
        &ALL
    }
    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.0.name()).help(self.0.about()))
    }
}

/// The command-line side of [`UvNames`] (the library has no clap).
#[allow(clippy::upper_case_acronyms)]
#[derive(Clone, Copy, Debug, ValueEnum)]
enum UvNamesArg {
    /// `u`, `v`
    UV,
    /// `s`, `t`
    ST,
    /// `texture_u`, `texture_v`
    TextureUV,
}

impl From<UvNamesArg> for UvNames {
    fn from(a: UvNamesArg) -> UvNames {
        match a {
            UvNamesArg::UV => UvNames::UV,
            UvNamesArg::ST => UvNames::ST,
            UvNamesArg::TextureUV => UvNames::TextureUV,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum IndexType {
    Int,
    Uint,
}

/// `1000`, `2e7`, `20M`, `1.5G`, `10k`.
fn parse_count(s: &str) -> Result<u64, String> {
    let t = s.trim().replace('_', "");
    let (num, mul) = match t.chars().last() {
        Some('k' | 'K') => (&t[..t.len() - 1], 1e3),
        Some('m' | 'M') => (&t[..t.len() - 1], 1e6),
        Some('g' | 'G') => (&t[..t.len() - 1], 1e9),
        _ => (&t[..], 1.0),
    };
    if let Ok(n) = num.parse::<u64>() {
        if mul == 1.0 {
            return Ok(n);
        }
    }
    match num.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 && x * mul <= u64::MAX as f64 => Ok((x * mul).round() as u64),
        _ => Err(format!("'{s}' is not a count (e.g. 1000000, 2e7, 20M)")),
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    let shape = args.shape.0;
    if args.tris == 0 {
        bail!("--tris must be at least 1");
    }
    if args.tris > octolod::gen::MAX_TRIS {
        bail!("--tris {} is above the maximum {}", args.tris, octolod::gen::MAX_TRIS);
    }
    let mut attrs = AttrSet::POSITION_ONLY;
    attrs = attrs.with(AttrSet::POS_F64, args.double);
    attrs = attrs.with(AttrSet::NORMAL, args.normals);
    attrs = attrs.with(AttrSet::COLOR, args.colors || args.alpha);
    attrs = attrs.with(AttrSet::ALPHA, args.alpha);
    attrs = attrs.with(AttrSet::UV, args.uvs || args.atlas.is_some());
    let opts = GenOptions { shape, tris: args.tris, seed: args.seed, attrs };
    let (mut nv, nf) = {
        let g = Generator::new(&opts);
        (g.vertex_count(), g.face_count())
    };
    let mut index_type = match args.index_type {
        IndexType::Int => Scalar::I32,
        IndexType::Uint => Scalar::U32,
    };
    if index_type == Scalar::I32 && nv > i32::MAX as u64 {
        // `int` cannot hold these indices.
        index_type = Scalar::U32;
    }
    let wopts = PlyWriteOptions {
        encoding: match args.format {
            Format::BinaryLe => Encoding::BinaryLe,
            Format::BinaryBe => Encoding::BinaryBe,
            Format::Ascii | Format::Obj | Format::StlBinary | Format::StlAscii => Encoding::Ascii,
        },
        attrs,
        float_colors: args.float_colors,
        uv_names: args.uv_names.into(),
        index_type,
        comments: std::iter::once(format!("octolod-gen shape {} tris {} seed {}", shape.name(), args.tris, args.seed))
            .chain(args.comment.iter().cloned())
            .collect(),
        extra_vertex_quality: args.quality,
    };
    let start = Instant::now();
    // octolod errors already name the file and include their cause.
    let other = match args.format {
        Format::Obj => Some(OtherFormat::Obj),
        Format::StlBinary => Some(OtherFormat::StlBinary),
        Format::StlAscii => Some(OtherFormat::StlAscii),
        _ => None,
    };
    let bytes = match (other, args.atlas) {
        (Some(_), Some(_)) => bail!("--atlas writes PLY only"),
        (None, Some(cells)) => {
            if args.tris > 50_000_000 {
                bail!("--atlas builds the mesh in memory: at most 5e7 triangles");
            }
            if args.output.exists() && !args.force {
                bail!("{} exists (--force replaces a PLY octolod wrote)", args.output.display());
            }
            let (vertices, triangles) = Generator::new(&opts).mesh();
            let (mut m, tiles) = octolod::gen::atlas::atlas(&octolod::mesh::IndexedMesh { vertices, triangles }, cells);
            if let Some(k) = args.textures {
                octolod::gen::atlas::spread_textures(&mut m, tiles, k);
            }
            // Seam vertices split, one per island.
            nv = m.vertices.len() as u64;
            let mut comments = vec![format!("octolod-gen shape {} tris {} seed {} atlas {cells} ({tiles}x{tiles} tiles)", shape.name(), args.tris, args.seed)];
            let stem = args.output.file_stem().unwrap_or_default().to_string_lossy().into_owned();
            match (args.texture, args.textures) {
                (Some(size), Some(k)) => {
                    for t in 0..k {
                        let name = format!("{stem}_{t}.png");
                        let path = octolod::io::parent_dir(&args.output).join(&name);
                        let img = octolod::gen::atlas::paint_material(&m, size, t as u16);
                        octolod::gen::atlas::write_texture(&path, size, &img, args.force).map_err(|e| anyhow!("{e}"))?;
                        comments.push(format!("TextureFile {name}"));
                    }
                }
                (Some(size), None) => {
                    let name = format!("{stem}.png");
                    let path = octolod::io::parent_dir(&args.output).join(&name);
                    octolod::gen::atlas::write_texture(&path, size, &octolod::gen::atlas::paint(&m, size), args.force).map_err(|e| anyhow!("{e}"))?;
                    comments.push(format!("TextureFile {name}"));
                }
                _ => {}
            }
            // Faces carry their texture as `texnumber`.
            let attrs = wopts.attrs.with(AttrSet::MATERIAL, args.textures.is_some());
            let wopts = PlyWriteOptions { comments, attrs, ..wopts };
            octolod::ply::write::write_ply(&args.output, &wopts, &m.vertices, &m.triangles)
                .map(|_| std::fs::metadata(&args.output).map(|m| m.len()).unwrap_or(0))
        }
        (Some(f), None) => {
            if args.force {
                bail!("--force replaces only PLYs octolod wrote; remove {} yourself", args.output.display());
            }
            octolod::gen::write_other(&opts, f, &args.output, args.quiet)
        }
        (None, None) => octolod::gen::write(&opts, &wopts, &args.output, args.quiet, args.force),
    }
    .map_err(|e| anyhow!("{e}"))?;
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{}: {} vertices, {} triangles, {} bytes in {:.2} s ({:.1} MB/s) -> {}",
        shape.name(),
        nv,
        nf,
        bytes,
        secs,
        bytes as f64 / 1e6 / secs.max(1e-9),
        args.output.display()
    );
    Ok(())
}

fn main() {
    let args = match Args::try_parse() {
        Ok(a) => a,
        Err(e) => {
            let code = if e.use_stderr() { 1 } else { 0 };
            let _ = e.print();
            std::process::exit(code);
        }
    };
    octolod::io::signal::install();
    if let Err(e) = run(args) {
        // Interrupted (the writer stopped at a safe point): 128 + the signal.
        if let Some(sig) = octolod::io::signal::interrupted() {
            std::process::exit(128 + sig);
        }
        eprintln!("octolod-gen: error: {e:#}");
        std::process::exit(1);
    }
}
