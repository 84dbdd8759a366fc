//! Build parameters and the store's manifest (`store.json`).
//!
//! Takes: `build`'s options as the CLI parsed them ([`BuildParams`], with
//! the node [`Simplifier`]) and the level builder's per-level figures
//! ([`LevelReport`]). Gives: the human-readable manifest written next to a
//! store's index and read back by `info`; nothing reads it to open a store
//! (the index, `nodes.bin`, is the truth).

use crate::error::{Error, IoContext, Location, Result};
use std::path::Path;

/// Largest `store.json` read (a real one is a few KiB: a line per level).
const MAX_MANIFEST: u64 = 16 << 20;

/// `store.json`: what was built, how, and how long it took (for people and
/// for `octolod info`; nothing reads it to open the store).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Manifest {
    /// Always `octolod-store`.
    pub format: String,
    pub version: u32,
    /// The input PLY as given to `build`.
    pub input: String,
    /// E.g. `position(f32)+normal`.
    pub attributes: String,
    pub quadric_dim: usize,
    /// Payloads carry normals computed at build time.
    pub derived_normals: bool,
    pub nodes: u64,
    /// Input triangles (level 0).
    pub triangles: u64,
    pub params: BuildParams,
    pub seconds: ManifestSeconds,
    pub disk_bytes: u64,
    pub levels: Vec<LevelReport>,
    /// The textures the input names (a PLY's `comment TextureFile`), in
    /// their order, and their copies in the store. A vertex's material id
    /// ([`crate::mesh::Vertex::material`], when the store has
    /// [`crate::mesh::AttrSet::MATERIAL`]) indexes this list.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub textures: Vec<TextureRef>,
}

/// A texture an input names: a file beside it, or an image inside it (a
/// glTF's, in a buffer), with the extension its type gives.
#[derive(Clone, Debug, PartialEq)]
pub enum TextureSource {
    File(String),
    Embedded {
        name: String,
        ext: &'static str,
        bytes: Vec<u8>,
    },
    /// A slot whose image cannot be had (a glTF's embedded image that is
    /// neither PNG nor JPEG, already reported): kept without a copy so the
    /// later slots keep their material ids.
    Missing(String),
}

/// A texture the input names and its copy next to the store's payloads.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TextureRef {
    /// The name as the input gives it (relative to the input's folder).
    pub name: String,
    /// The copy in the store (`texture-K.EXT`), or none when the file was
    /// not found beside the input.
    pub file: Option<String>,
    pub bytes: u64,
}

/// The first texture a store holds: its file name in the store and path;
/// none when the store names none it holds.
pub fn store_texture(store: &Path) -> Option<(String, std::path::PathBuf)> {
    store_textures(store).into_iter().flatten().next()
}

/// Every texture slot of a store, indexed by material id
/// ([`crate::mesh::Vertex::material`]): the copy's file name in the store
/// and its path, or none where the input named a texture the store does
/// not hold. Empty when the store names none (or has no manifest).
pub fn store_textures(store: &Path) -> Vec<Option<(String, std::path::PathBuf)>> {
    let Ok(m) = Manifest::read(store) else { return Vec::new() };
    m.textures.iter().map(|t| t.file.clone().map(|f| (f.clone(), store.join(f)))).collect()
}

impl TextureRef {
    /// The store's name for texture `k` named `name`: `texture-K.EXT`, the
    /// extension kept when it is a short alphanumeric one.
    pub fn store_name(k: usize, name: &str) -> String {
        let ext = Path::new(name)
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .filter(|e| !e.is_empty() && e.len() <= 5 && e.bytes().all(|c| c.is_ascii_alphanumeric()));
        match ext {
            Some(e) => format!("texture-{k}.{e}"),
            None => format!("texture-{k}"),
        }
    }

    /// Copies the textures `sources` (files relative to `input`'s folder,
    /// or bytes from inside it) into `store`; a missing file is recorded
    /// without a copy and reported by the caller.
    pub fn copy_all(input: &Path, sources: &[TextureSource], store: &Path) -> crate::error::Result<Vec<TextureRef>> {
        use crate::error::IoContext;
        let base = crate::io::parent_dir(input);
        let mut out = Vec::new();
        for (k, source) in sources.iter().enumerate() {
            match source {
                TextureSource::File(name) => {
                    let src = base.join(name);
                    if !src.is_file() {
                        out.push(TextureRef { name: name.clone(), file: None, bytes: 0 });
                        continue;
                    }
                    let file = Self::store_name(k, name);
                    let bytes = std::fs::copy(&src, store.join(&file)).ctx(&src, "copy texture")?;
                    out.push(TextureRef { name: name.clone(), file: Some(file), bytes });
                }
                TextureSource::Missing(name) => out.push(TextureRef { name: name.clone(), file: None, bytes: 0 }),
                TextureSource::Embedded { name, ext, bytes } => {
                    let file = format!("texture-{k}.{ext}");
                    let dest = store.join(&file);
                    std::fs::write(&dest, bytes).ctx(&dest, "write texture")?;
                    out.push(TextureRef { name: name.clone(), file: Some(file), bytes: bytes.len() as u64 });
                }
            }
        }
        Ok(out)
    }
}

/// How each node (or the whole mesh) is reduced: recorded in the
/// manifest (`params.simplifier`), chosen by `build` and `simplify`.
/// [`Simplifier::Auto`] (`build`'s default) is resolved against the
/// input's attributes before any node is reduced
/// ([`Simplifier::resolve`]); a manifest or plan never records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Simplifier {
    /// Generalized-quadric adaptive vertex clustering (fast).
    Cluster,
    /// Quadric edge collapse with attributes (accurate).
    Collapse,
    /// The more accurate of the two for the input's attributes, as the
    /// bench measured them ([`Simplifier::resolve`]).
    Auto,
}

impl Simplifier {
    /// The name `--simplifier` takes.
    pub fn name(self) -> &'static str {
        match self {
            Simplifier::Cluster => "cluster",
            Simplifier::Collapse => "collapse",
            Simplifier::Auto => "auto",
        }
    }

    /// The simplifier to use for a mesh with `attrs`: itself, unless
    /// [`Simplifier::Auto`]. Auto takes `collapse` for textured inputs
    /// (uvs): on the bench's atlas scan and terrain, whose seams bound
    /// islands of a few triangles at coarse levels, clustering's coarse
    /// levels reached 1.9× meshoptimizer's RMS where collapse stayed below
    /// it ([benchmarks](../docs/benchmarks.md#textured-atlases-1-m-triangles-seams-simplifying)).
    /// Else `cluster`: as accurate or more on smooth inputs with normals
    /// and colours, and faster.
    pub fn resolve(self, attrs: crate::mesh::AttrSet) -> Simplifier {
        match self {
            Simplifier::Auto if attrs.uv() => Simplifier::Collapse,
            Simplifier::Auto => Simplifier::Cluster,
            s => s,
        }
    }
}

impl std::str::FromStr for Simplifier {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "cluster" => Ok(Simplifier::Cluster),
            "collapse" => Ok(Simplifier::Collapse),
            "auto" => Ok(Simplifier::Auto),
            _ => Err(format!("unknown simplifier {s:?} (auto, cluster or collapse)")),
        }
    }
}

/// How a store is built: `build`'s options (the CLI fills them, the level
/// builder reads them), recorded as the manifest's `params`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BuildParams {
    /// `--mem`, bytes.
    pub mem: u64,
    /// Split a level-0 octree cell while it holds more triangles than this.
    pub leaf_tris: u64,
    /// Never split deeper than this.
    pub max_depth: u8,
    /// Each level holds about 1/ratio of the triangles below it.
    pub level_ratio: f64,
    /// The root holds at most this many triangles.
    pub root_tris: u64,
    /// Build levels up to this one only (its nodes are then the roots).
    pub levels: Option<u8>,
    /// The node simplifier (`cluster` for stores built before it was a choice).
    #[serde(default = "cluster")]
    pub simplifier: Simplifier,
    /// Where the levels' normals come from (`carry` for stores built before
    /// it was a choice).
    #[serde(default = "carry")]
    pub normals: Normals,
}

impl Default for BuildParams {
    fn default() -> Self {
        BuildParams {
            mem: crate::mem::DEFAULT_BUDGET,
            leaf_tris: 16384,
            max_depth: 16,
            level_ratio: 2.0,
            root_tris: 4096,
            levels: None,
            simplifier: Simplifier::Cluster,
            normals: Normals::Auto,
        }
    }
}

fn cluster() -> Simplifier {
    Simplifier::Cluster
}

fn carry() -> Normals {
    Normals::Carry
}

/// How the levels above level 0 get an input's normals (`--normals`; an
/// input without normals gets them from its geometry at every level,
/// whatever this says). Level 0 always keeps the input's.
///
/// [`Normals::Auto`] is resolved before level 0 is simplified, by one
/// test (`lod::level::CreaseProbe`: a hash-chosen share of the
/// input's positions) in the pass that reads the input's vertices: the
/// soup stage's in a whole build, the plan's in a sharded one, so both
/// decide alike (the level builder carries normals `auto` reaches it
/// with). A manifest or plan records what was used.
/// Measured in `docs/build-costs.md`, "Normals averaged".
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Normals {
    /// In the quadric with the other attributes (three more dimensions),
    /// solved with each representative: the two sides of a crease keep
    /// their own normals.
    Carry,
    /// Out of the quadric (clustering only: edge collapse carries them); a
    /// representative's normal is the area-weighted mean of the normals of
    /// the vertices it stands for. Builds about 1.3× faster than `carry`
    /// at normals about as near the input's; a crease's sides blur.
    Average,
    /// `average` unless the input's normals have creases (a position whose
    /// vertices' normals differ by more than 10°) or the simplifier is edge
    /// collapse.
    Auto,
}

impl Normals {
    /// `auto` resolved for `simplifier` (resolved) from the input's crease
    /// test (`smooth`: no crease seen; `None`: not tested, stays `auto`):
    /// only clustering averages.
    pub fn resolved(self, simplifier: Simplifier, smooth: Option<bool>) -> Normals {
        match (self, smooth) {
            (Normals::Auto, Some(true)) if simplifier == Simplifier::Cluster => Normals::Average,
            (Normals::Auto, Some(_)) => Normals::Carry,
            (n, _) => n,
        }
    }

    /// The name `--normals` takes.
    pub fn name(self) -> &'static str {
        match self {
            Normals::Carry => "carry",
            Normals::Average => "average",
            Normals::Auto => "auto",
        }
    }
}

impl std::str::FromStr for Normals {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "carry" => Ok(Normals::Carry),
            "average" => Ok(Normals::Average),
            "auto" => Ok(Normals::Auto),
            _ => Err(format!("unknown normals mode {s:?} (auto, average or carry)")),
        }
    }
}

/// Wall-clock seconds per stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestSeconds {
    pub soup: f64,
    pub partition: f64,
    pub levels: f64,
    pub total: f64,
}

/// One built level's figures: the build report's line and the manifest's
/// (the counts behind the two shares are not written to the manifest).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LevelReport {
    pub level: u8,
    pub nodes: u64,
    pub triangles: u64,
    /// Distinct vertex positions of the level.
    pub positions: u64,
    pub bytes: u64,
    /// Node errors (object space).
    pub error_min: f64,
    pub error_max: f64,
    /// Share of the level's positions locked when it was simplified
    /// (shared with another node of the level, or seams).
    pub locked_fraction: f64,
    /// Share of the previous level's locked positions still locked here.
    pub prev_locked_still_fraction: f64,
    /// The level's error threshold (0 for the top level).
    pub tau: f64,
    pub seconds: f64,
    /// Positions locked (the count behind `locked_fraction`).
    #[serde(skip)]
    pub locked: u64,
    /// Positions locked one level below, and how many of them are still
    /// locked here.
    #[serde(skip)]
    pub prev_locked: u64,
    #[serde(skip)]
    pub prev_locked_still: u64,
    /// Representatives clamped to their cell.
    #[serde(skip)]
    pub clamped: u64,
}

impl LevelReport {
    /// Sets the locked counts and the shares made of them.
    pub fn set_locked(&mut self, locked: u64, prev_locked: u64, prev_locked_still: u64) {
        (self.locked, self.prev_locked, self.prev_locked_still) = (locked, prev_locked, prev_locked_still);
        self.locked_fraction = locked as f64 / self.positions.max(1) as f64;
        self.prev_locked_still_fraction = if prev_locked == 0 { 0.0 } else { prev_locked_still as f64 / prev_locked as f64 };
    }
}

impl Manifest {
    pub fn write(&self, dir: &Path) -> Result<()> {
        let path = dir.join("store.json");
        let text = serde_json::to_string_pretty(self).map_err(|e| Error::Usage(format!("{}: {e}", path.display())))?;
        std::fs::write(&path, text + "\n").ctx(&path, "write")
    }

    pub fn read(dir: &Path) -> Result<Manifest> {
        let path = dir.join("store.json");
        let text = crate::io::read_bounded(&path, MAX_MANIFEST, "a manifest")?;
        serde_json::from_slice(&text).map_err(|e| Error::input(Location { file: path.clone(), ..Default::default() }, format!("bad manifest: {e}")))
    }
}
