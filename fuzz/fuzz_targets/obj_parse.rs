//! Fuzz target: OBJ first pass and body reader (`octolod::input::obj`).
//!
//! The reader takes a path, so each input is written to a per-process temp
//! file (overwritten every iteration), read by `read_info`, then by
//! `read_body` under a 64 MiB budget, then under the smallest (a file whose
//! faces reference `vt` or `vn` then takes the out-of-core corner path),
//! which must give the same triangles.
//! Any `Err` is an accepted outcome; a panic, abort, OOM or timeout is a bug.
#![no_main]

use libfuzzer_sys::fuzz_target;
use octolod::input::obj::{read_body, read_info};
use octolod::ply::read::CollectSink;
use octolod::progress::Progress;
use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

fn scratch_path() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| std::env::temp_dir().join(format!("octolod-fuzz-obj-{}.obj", std::process::id())))
}

fuzz_target!(|data: &[u8]| {
    let path = scratch_path();
    {
        let mut f = std::fs::File::create(path).expect("create scratch file");
        f.write_all(data).expect("write scratch file");
    }
    let progress = Progress::hidden();
    let Ok(info) = read_info(path, &progress) else { return };
    assert_eq!(info.bytes, data.len() as u64);
    assert!(info.corners >= 3 * info.faces);
    let mut sink = CollectSink::default();
    // The first pass validated everything: the body must read.
    let scratch = std::env::temp_dir();
    let stats = match read_body(path, &info, 64 << 20, &scratch, &mut sink, &progress) {
        Ok(s) => s,
        Err(octolod::Error::Usage(_)) => return, // more than 2^32 - 1 table lines
        Err(e) => panic!("read_info accepted what read_body refused: {e}"),
    };
    let mut small = CollectSink::default();
    match read_body(path, &info, 0, &scratch, &mut small, &progress) {
        Ok(s) => {
            assert_eq!((s.triangles, s.faces, s.degenerate), (stats.triangles, stats.faces, stats.degenerate));
            let corners = |c: &CollectSink| -> Vec<[u64; 3]> {
                c.triangles.iter().flatten().map(|&i| c.vertices[i as usize].pos.map(f64::to_bits)).collect()
            };
            assert_eq!(corners(&small), corners(&sink));
        }
        Err(octolod::Error::Usage(_)) => {} // too many slabs for the smallest budget
        Err(e) => panic!("read_body failed out of core: {e}"),
    }
    assert_eq!(sink.vertices.len() as u64, stats.vertices);
    assert_eq!(sink.triangles.len() as u64, stats.triangles);
    assert_eq!(stats.faces, info.faces);
    assert_eq!(stats.triangles + stats.degenerate, info.corners - 2 * info.faces);
    if info.corner_vertices() {
        assert!(stats.vertices <= info.vertices);
    } else {
        assert_eq!(stats.vertices, info.positions);
    }
    for t in &sink.triangles {
        for &i in t {
            assert!(i < stats.vertices, "triangle index {i} >= vertex count {}", stats.vertices);
        }
    }
    for v in &sink.vertices {
        assert!(v.pos.iter().all(|c| c.is_finite()));
    }
});
