//! Bad input through the real binary: a clear error naming the file, element,
//! record and byte offset (or header line), a non-zero exit, and nothing left
//! under the output name.

use crate::common::cli::{err, octolod, octolod_ok, out, s};
use crate::common::fixture;

fn ascii_cube(vertex_decl: usize, face_decl: usize, vertex_lines: &[&str], face_lines: &[&str]) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {vertex_decl}\nproperty float x\nproperty float y\nproperty float z\nelement face {face_decl}\nproperty list uchar int vertex_indices\nend_header\n"
    );
    for l in vertex_lines {
        s.push_str(l);
        s.push('\n');
    }
    for l in face_lines {
        s.push_str(l);
        s.push('\n');
    }
    s
}

const V: [&str; 4] = ["0 0 0", "1 0 0", "0 1 0", "0 0 1"];
const F: [&str; 4] = ["3 0 1 2", "3 0 1 3", "3 0 2 3", "3 1 2 3"];

/// Runs `octolod soup` on `bytes`; returns (exit ok, stderr) and checks no output remains on failure.
fn soup(bytes: &[u8]) -> (bool, String) {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("bad.ply");
    std::fs::write(&input, bytes).unwrap();
    let out = dir.path().join("out.soup");
    let o = octolod(&["soup", s(&input), "-o", s(&out), "--quiet"]);
    let e = err(&o);
    if !o.status.success() {
        assert!(!out.exists(), "failed run left output behind");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left.len(), 1, "failed run left files behind: {left:?}");
        assert!(e.contains(s(&input)), "error does not name the file: {e}");
    }
    (o.status.success(), e)
}

fn expect_error(bytes: &[u8], needles: &[&str]) {
    let (ok, err) = soup(bytes);
    assert!(!ok, "expected failure for input:\n{}", String::from_utf8_lossy(bytes));
    for n in needles {
        assert!(err.contains(n), "error '{}' lacks '{n}'", err.trim());
    }
}

#[test]
fn a_good_tetrahedron_converts() {
    let (ok, err) = soup(ascii_cube(4, 4, &V, &F).as_bytes());
    assert!(ok, "{err}");
}

#[test]
fn an_out_of_range_index_is_an_error_at_its_record_and_offset() {
    let bad = ascii_cube(4, 4, &V, &["3 0 1 2", "3 0 1 3", "3 0 2 99", "3 1 2 3"]);
    let offset = bad.find("3 0 2 99").unwrap();
    expect_error(bad.as_bytes(), &["element 'face' record 2", &format!("byte offset {offset}"), "vertex index 99 out of range", "4 vertices"]);
}

#[test]
fn a_negative_index_is_an_error_at_its_record() {
    let bad = ascii_cube(4, 4, &V, &["3 0 1 2", "3 0 -1 3", "3 0 2 3", "3 1 2 3"]);
    expect_error(bad.as_bytes(), &["element 'face' record 1", "negative vertex index -1"]);
}

#[test]
fn non_finite_coordinates_are_errors_at_their_record_and_offset() {
    for v in ["nan 0 0", "0 inf 0", "0 0 -inf"] {
        let bad = ascii_cube(4, 4, &["0 0 0", "1 0 0", v, "0 0 1"], &F);
        let offset = bad.find(v).unwrap();
        expect_error(bad.as_bytes(), &["element 'vertex' record 2", &format!("byte offset {offset}"), "non-finite"]);
    }
    // Binary NaN.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    let body = b.len();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, f32::NAN, 0.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.push(3);
    for i in [0i32, 1, 2] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    expect_error(&b, &["element 'vertex' record 2", &format!("byte offset {}", body + 24), "non-finite"]);
}

#[test]
fn a_truncated_body_is_an_unexpected_end_at_the_cut_record() {
    let good = std::fs::read(fixture("cube_le_attrs.ply")).unwrap();
    // Cut inside the last face record.
    expect_error(&good[..good.len() - 5], &["element 'face' record 7", "unexpected end of file", "byte offset"]);
    // Cut inside the vertices: records are 35 bytes (xyz, normal, rgb, uv), so byte 100 is in record 2.
    let header_len = good.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    expect_error(&good[..header_len + 100], &["element 'vertex' record 2", "declares 8 'vertex' records", "unexpected end of file"]);
}

#[test]
fn declared_counts_the_body_disagrees_with_are_errors() {
    // More faces declared than present: truncated at the missing record.
    expect_error(ascii_cube(4, 5, &V, &F).as_bytes(), &["element 'face' record 4", "unexpected end of file"]);
    // Fewer declared than present: trailing data.
    expect_error(ascii_cube(4, 3, &V, &F).as_bytes(), &["after the last element", "counts are too small"]);
    // Binary with trailing bytes.
    let mut good = std::fs::read(fixture("cube_le_attrs.ply")).unwrap();
    let len = good.len();
    good.extend_from_slice(&[0u8; 13]);
    expect_error(&good, &["13 unexpected bytes", &format!("byte offset {len}")]);
}

#[test]
fn unsupported_header_lines_are_errors_naming_the_line() {
    let bad = ascii_cube(4, 4, &V, &F).replacen("element face", "frobnicate 3\nelement face", 1);
    expect_error(bad.as_bytes(), &["header line 7", "unsupported or malformed header line"]);
    let bad = ascii_cube(4, 4, &V, &F).replacen("property float z", "property quaternion z", 1);
    expect_error(bad.as_bytes(), &["header line 6"]);
    expect_error(b"solid cube\nfacet normal 0 0 1\n", &["not a PLY file"]);
    expect_error(b"ply\nformat ascii 1.0\nelement vertex 1\n", &["missing 'end_header'"]);
    let no_z = ascii_cube(4, 4, &V, &F).replacen("property float z\n", "", 1);
    expect_error(no_z.as_bytes(), &["element 'vertex'", "no 'z' property"]);
}

#[test]
fn no_faces_short_faces_and_only_degenerate_faces_are_errors() {
    expect_error(ascii_cube(4, 0, &V, &[]).as_bytes(), &["element 'face'", "declares no faces"]);
    let two = ascii_cube(4, 4, &V, &["3 0 1 2", "2 0 1", "3 0 2 3", "3 1 2 3"]);
    expect_error(two.as_bytes(), &["element 'face' record 1", "face with 2 vertex index(es)"]);
    let all_degenerate = ascii_cube(4, 2, &V, &["3 0 0 1", "4 2 2 2 2"]);
    expect_error(all_degenerate.as_bytes(), &["all 2 faces are degenerate"]);
}

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let some = ascii_cube(4, 5, &V, &["3 0 1 2", "3 1 1 2", "3 0 2 3", "3 1 2 3", "3 0 1 3"]);
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("d.ply");
    std::fs::write(&input, some).unwrap();
    let soup = dir.path().join("d.soup");
    let text = out(&octolod_ok(&["soup", s(&input), "-o", s(&soup), "--json"]));
    assert!(text.contains("\"triangles\":4") && text.contains("\"degenerate\":1"), "{text}");
    assert_eq!(std::fs::metadata(&soup).unwrap().len(), 128 + 4 * 36);
}

#[test]
fn bad_budget_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("t.ply");
    std::fs::write(&input, ascii_cube(4, 4, &V, &F)).unwrap();
    for mem in ["12X", "1K"] {
        let o = octolod(&["soup", s(&input), "-o", s(&dir.path().join("o.soup")), "--mem", mem]);
        assert!(!o.status.success());
        assert!(err(&o).contains("octolod: error:"), "--mem {mem}: {}", err(&o));
    }
}

#[test]
fn missing_input_names_the_path() {
    // The output in a directory of its own: a /tmp/x.soup left by anything
    // else would be refused first.
    let dir = tempfile::tempdir().unwrap();
    let o = octolod(&["soup", "/nonexistent/x.ply", "-o", s(&dir.path().join("x.soup"))]);
    assert!(!o.status.success());
    assert!(err(&o).contains("/nonexistent/x.ply: open"), "{}", err(&o));
}
