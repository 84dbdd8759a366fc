//! Inputs the fuzzer found (fixtures/fuzz/): each once made the reader
//! allocate what a declared list length or element count asked for, overflow
//! a size, or loop over records of nothing. Each must now end with a
//! located error (or, for an element with no properties, succeed).

use crate::common::{finishes, fixture};
use octolod::ply::read::read_all;

/// Reads fixtures/fuzz/NAME; gives its vertex count. A read that loops
/// fails the test ("still running after 60 s") instead of hanging it.
fn run(name: &str) -> octolod::Result<u64> {
    let p = fixture(&format!("fuzz/{name}"));
    finishes(60, &format!("reading {name}"), move || read_all(&p).map(|(_, m, _)| m.vertices.len() as u64))
}

#[test]
fn huge_declared_lists_are_truncation_errors_not_allocations() {
    for name in ["A_face_list_oom.ply", "A2_face_list_oom_nonsimple.ply", "B_vertex_list_oom.ply", "fuzzer_found_oom_face_list.ply"] {
        let e = run(name).expect_err(name);
        let msg = e.to_string();
        assert!(msg.contains(name), "{msg}");
        assert!(msg.contains("record") && msg.contains("byte offset"), "{name}: {msg}");
    }
}

#[test]
fn element_count_overflow_is_a_truncation_error() {
    let e = run("D_skip_overflow.ply").unwrap_err().to_string();
    assert!(e.contains("element 'pad'") && e.contains("unexpected end of file"), "{e}");
}

#[test]
fn element_without_properties_reads_no_bytes() {
    assert_eq!(run("E_ascii_empty_elem_hang.ply").unwrap(), 3);
}
