//! Fuzz target: opening and reading a damaged store (`octolod::store`), as
//! `info`, `extract` and the viewer's first frame do.
//!
//! A small store (a 3,000-triangle sphere in 256-triangle nodes, several
//! levels) is built once per process; each input is a list of edits to its
//! files (index `nodes.bin`, manifest `store.json`, `level-L.pack`):
//! `[op, file, offset u32 LE, len, bytes...]` with op 0 overwrite, 1 XOR,
//! 2 truncate, 3 insert (see `tests/it/common/store_mutation.rs`, shared with
//! the fixed-seed run in `tests/it/reliability.rs`). The damaged copy is
//! written to a per-process directory, opened, read level by level and at
//! two error cuts, and given one selection step. Any `Err` is an accepted
//! outcome; a panic, abort, OOM, timeout or garbage accepted is a bug.
#![no_main]

#[path = "../../tests/it/common/store_mutation.rs"]
mod store_mutation;

use libfuzzer_sys::fuzz_target;
use octolod::gen::{GenOptions, Generator, Shape};
use octolod::mesh::AttrSet;
use octolod::pipeline::{build_store, BuildOptions};
use octolod::manifest::BuildParams;
use octolod::ply::write::{write_ply, PlyWriteOptions};
use std::path::PathBuf;
use std::sync::OnceLock;

struct Base {
    files: Vec<(String, Vec<u8>)>,
    work: PathBuf,
}

fn base() -> &'static Base {
    static B: OnceLock<Base> = OnceLock::new();
    B.get_or_init(|| {
        let root = std::env::temp_dir().join(format!("octolod-fuzz-store-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).expect("scratch directory");
        let g = Generator::new(&GenOptions { shape: Shape::Sphere, tris: 3000, seed: 5, attrs: AttrSet::POSITION_ONLY });
        let (v, f) = g.mesh();
        let ply = root.join("in.ply");
        write_ply(&ply, &PlyWriteOptions::default(), &v, &f).expect("write the input");
        let built = root.join("base.octolod");
        let params = BuildParams { mem: 16 << 20, leaf_tris: 256, max_depth: 12, root_tris: 256, ..Default::default() };
        let opts = BuildOptions { params, ..Default::default() };
        build_store(&ply, &built, &opts).expect("build the base store");
        Base { files: store_mutation::snapshot(&built), work: root.join("damaged.octolod") }
    })
}

fuzz_target!(|data: &[u8]| {
    let b = base();
    let mut files = b.files.clone();
    store_mutation::mutate(&mut files, data);
    store_mutation::write(&b.work, &files);
    store_mutation::exercise(&b.work);
});
