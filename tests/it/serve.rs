//! `octolod serve` (issue 31 item 3): the real binary on `--port 0`, a fake
//! tileset of known bytes, and a plain HTTP/1.1 client over `TcpStream`:
//! content types and lengths, HEAD, byte ranges (206, 416), 404s, no
//! directory listing, no way out of the served directory, the viewer page
//! at `/`, CORS and caching headers, conditional requests; then SIGINT and
//! SIGTERM stop it with 130 and 143.

use crate::common::cli::{bin, wait_or_fail};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Duration;

/// A running `octolod serve`.
struct Srv {
    child: Child,
    /// `127.0.0.1:PORT`
    host: String,
    stdout: BufReader<ChildStdout>,
}

impl Drop for Srv {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `octolod serve DIR --port 0` and reads its URL line.
fn start(dir: &Path) -> Srv {
    let mut child = Command::new(bin())
        .args(["serve", dir.to_str().unwrap(), "--port", "0"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut r = BufReader::new(stdout);
        let mut line = String::new();
        let n = r.read_line(&mut line);
        let _ = tx.send((n.map_err(|e| e.to_string()), line, r));
    });
    let (n, line, stdout) = rx.recv_timeout(Duration::from_secs(60)).expect("no URL line within 60 s");
    if n.unwrap() == 0 {
        let o = child.wait_with_output().unwrap();
        panic!("serve ended without a URL line: {:?}: {}", o.status, String::from_utf8_lossy(&o.stderr));
    }
    // serving http://127.0.0.1:PORT/ (tileset: http://127.0.0.1:PORT/tiles/tileset.json)
    let line = line.trim_end_matches('\n');
    let rest = line.strip_prefix("serving http://127.0.0.1:").unwrap_or_else(|| panic!("unexpected line {line:?}"));
    let port: u16 = rest.split('/').next().unwrap().parse().unwrap_or_else(|_| panic!("no port in {line:?}"));
    assert_ne!(port, 0);
    assert_eq!(line, format!("serving http://127.0.0.1:{port}/ (tileset: http://127.0.0.1:{port}/tiles/tileset.json)"));
    Srv { child, host: format!("127.0.0.1:{port}"), stdout }
}

/// A parsed response.
#[derive(Debug)]
struct Resp {
    status: u16,
    /// (lower-case name, value)
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Resp {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_str())
    }
    fn len(&self) -> Option<usize> {
        self.header("content-length").map(|v| v.parse().unwrap())
    }
}

/// Sends `method target` with `extra` header lines and `Connection: close`;
/// reads the whole response.
fn req(host: &str, method: &str, target: &str, extra: &[&str]) -> Resp {
    let mut s = TcpStream::connect(host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let mut r = format!("{method} {target} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n");
    for h in extra {
        r.push_str(h);
        r.push_str("\r\n");
    }
    r.push_str("\r\n");
    s.write_all(r.as_bytes()).unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let end =
        raw.windows(4).position(|w| w == b"\r\n\r\n").unwrap_or_else(|| panic!("{method} {target}: no header end in {:?}", String::from_utf8_lossy(&raw)));
    let head = String::from_utf8(raw[..end].to_vec()).unwrap();
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap();
    let status = status_line.split(' ').nth(1).unwrap().parse().unwrap();
    let headers = lines
        .map(|l| {
            let (n, v) = l.split_once(':').unwrap();
            (n.trim().to_ascii_lowercase(), v.trim().to_string())
        })
        .collect();
    Resp { status, headers, body: raw[end + 4..].to_vec() }
}

fn get(host: &str, target: &str) -> Resp {
    req(host, "GET", target, &[])
}

/// Known bytes: `n` bytes of a pattern seeded by `seed`.
fn bytes(n: usize, seed: u8) -> Vec<u8> {
    (0..n).map(|i| (i as u32 * 7 + seed as u32) as u8 ^ (i >> 8) as u8).collect()
}

const SECRET: &str = "TOP-SECRET-OUTSIDE-THE-TILESET";

/// `root/tiles`: a tileset of known bytes; `root/secret.txt` outside it,
/// reached by symlinks from inside.
fn fake_tileset(root: &Path) -> std::path::PathBuf {
    let t = root.join("tiles");
    std::fs::create_dir_all(t.join("sub")).unwrap();
    std::fs::write(t.join("tileset.json"), br#"{"asset":{"version":"1.1"},"geometricError":1,"root":{"content":{"uri":"a.glb"}}}"#).unwrap();
    std::fs::write(t.join("a.glb"), bytes(1000, 1)).unwrap();
    std::fs::write(t.join("sub/b.glb"), bytes(300, 2)).unwrap();
    std::fs::write(t.join("m.gltf"), br#"{"asset":{"version":"2.0"}}"#).unwrap();
    std::fs::write(t.join("d.bin"), bytes(64, 3)).unwrap();
    std::fs::write(t.join("x.js"), b"export const x = 1;\n").unwrap();
    std::fs::write(t.join("x.wasm"), b"\0asm\x01\0\0\0").unwrap();
    std::fs::write(t.join("i.png"), b"\x89PNG\r\n\x1a\n").unwrap();
    std::fs::write(t.join("p.html"), b"<!doctype html><p>hi</p>").unwrap();
    std::fs::write(t.join("empty.glb"), b"").unwrap();
    std::fs::write(root.join("secret.txt"), SECRET).unwrap();
    std::os::unix::fs::symlink("../secret.txt", t.join("link.glb")).unwrap();
    std::os::unix::fs::symlink(root, t.join("outdir")).unwrap();
    std::os::unix::fs::symlink("sub/b.glb", t.join("inside.glb")).unwrap();
    t
}

#[test]
fn files_are_served_with_type_length_head_cors_and_revalidation() {
    let d = tempfile::tempdir().unwrap();
    let t = fake_tileset(d.path());
    let s = start(&t);
    let h = s.host.as_str();
    for (path, ty) in [
        ("tileset.json", "application/json"),
        ("a.glb", "model/gltf-binary"),
        ("sub/b.glb", "model/gltf-binary"),
        ("m.gltf", "model/gltf+json"),
        ("d.bin", "application/octet-stream"),
        ("x.js", "text/javascript"),
        ("x.wasm", "application/wasm"),
        ("i.png", "image/png"),
        ("p.html", "text/html"),
        ("empty.glb", "model/gltf-binary"),
        ("inside.glb", "model/gltf-binary"),
    ] {
        let want = std::fs::read(t.join(path)).unwrap();
        let r = get(h, &format!("/tiles/{path}"));
        assert_eq!(r.status, 200, "{path}: {r:?}");
        assert_eq!(r.body, want, "{path}");
        assert_eq!(r.len(), Some(want.len()), "{path}");
        let ct = r.header("content-type").unwrap();
        assert!(ct == ty || ct.starts_with(&format!("{ty};")), "{path}: content type {ct}, {ty} expected");
        assert_eq!(r.header("accept-ranges"), Some("bytes"), "{path}");
        assert_eq!(r.header("access-control-allow-origin"), Some("*"), "{path}");
        assert_eq!(r.header("cache-control"), Some("no-cache"), "{path}");

        let hd = req(h, "HEAD", &format!("/tiles/{path}"), &[]);
        assert_eq!(hd.status, 200, "HEAD {path}");
        assert!(hd.body.is_empty(), "HEAD {path} sent a body");
        assert_eq!(hd.len(), Some(want.len()), "HEAD {path}");
        assert_eq!(hd.header("content-type"), Some(ct), "HEAD {path}");
    }

    // Revalidation: the ETag (and Last-Modified) answer 304 without a body.
    let r = get(h, "/tiles/a.glb");
    let etag = r.header("etag").expect("an ETag").to_string();
    let c = req(h, "GET", "/tiles/a.glb", &[&format!("If-None-Match: {etag}")]);
    assert_eq!(c.status, 304, "{c:?}");
    assert!(c.body.is_empty());
    let lm = r.header("last-modified").expect("a Last-Modified").to_string();
    let c = req(h, "GET", "/tiles/a.glb", &[&format!("If-Modified-Since: {lm}")]);
    assert_eq!(c.status, 304, "{c:?}");

    // CORS preflight from another origin (a Range header is not always safelisted).
    let p = req(h, "OPTIONS", "/tiles/a.glb", &["Origin: http://example.test", "Access-Control-Request-Method: GET", "Access-Control-Request-Headers: range"]);
    assert!(p.status == 200 || p.status == 204, "{p:?}");
    assert_eq!(p.header("access-control-allow-origin"), Some("*"));
    let g = req(h, "GET", "/tiles/tileset.json", &["Origin: http://example.test"]);
    assert_eq!(g.header("access-control-allow-origin"), Some("*"));

    // Only GET and HEAD.
    assert_eq!(req(h, "POST", "/tiles/a.glb", &["Content-Length: 0"]).status, 405);
}

#[test]
fn byte_ranges_are_served_206_and_unsatisfiable_ones_416() {
    let d = tempfile::tempdir().unwrap();
    let t = fake_tileset(d.path());
    let s = start(&t);
    let h = s.host.as_str();
    let data = bytes(1000, 1);
    for (range, from, to) in [("bytes=10-19", 10, 19), ("bytes=10-", 10, 999), ("bytes=-5", 995, 999), ("bytes=0-0", 0, 0), ("bytes=990-5000", 990, 999)] {
        let r = req(h, "GET", "/tiles/a.glb", &[&format!("Range: {range}")]);
        assert_eq!(r.status, 206, "{range}: {r:?}");
        assert_eq!(r.body, &data[from..=to], "{range}");
        assert_eq!(r.header("content-range"), Some(format!("bytes {from}-{to}/1000").as_str()), "{range}");
        assert_eq!(r.len(), Some(to - from + 1), "{range}");
        assert_eq!(r.header("content-type"), Some("model/gltf-binary"), "{range}");
        assert_eq!(r.header("access-control-allow-origin"), Some("*"), "{range}");
        let hd = req(h, "HEAD", "/tiles/a.glb", &[&format!("Range: {range}")]);
        assert_eq!(hd.status, 206, "HEAD {range}");
        assert!(hd.body.is_empty());
        assert_eq!(hd.header("content-range"), r.header("content-range"));
    }
    for range in ["bytes=1000-", "bytes=2000-3000"] {
        let r = req(h, "GET", "/tiles/a.glb", &[&format!("Range: {range}")]);
        assert_eq!(r.status, 416, "{range}: {r:?}");
        assert_eq!(r.header("content-range"), Some("bytes */1000"), "{range}");
        assert!(!r.body.windows(16).any(|w| w == &data[..16]), "{range}: the 416 carried the file");
    }
    // Malformed ranges: ignored (200, the whole file) or refused (416), never an error.
    for range in ["bytes=50-10", "bytes=abc", "lines=1-2"] {
        let r = req(h, "GET", "/tiles/a.glb", &[&format!("Range: {range}")]);
        assert!(r.status == 416 || (r.status == 200 && r.body == data), "{range}: {r:?}");
    }
}

#[test]
fn missing_files_directories_and_escapes_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let t = fake_tileset(d.path());
    let s = start(&t);
    let h = s.host.as_str();
    for path in ["/tiles/nope.glb", "/tiles/sub/nope.glb", "/nope.js", "/tiles/a.glb/", "/tiles/tileset.json/x"] {
        let r = get(h, path);
        assert_eq!(r.status, 404, "{path}: {r:?}");
    }
    // No directory listing, with or without the slash.
    for path in ["/tiles", "/tiles/", "/tiles/sub", "/tiles/sub/", "/tiles/outdir/"] {
        let r = get(h, path);
        assert_eq!(r.status, 404, "{path}: {r:?}");
        assert!(!String::from_utf8_lossy(&r.body).contains("a.glb"), "{path} listed the directory");
    }
    let port = h.rsplit(':').next().unwrap();
    let absolute_form = format!("http://127.0.0.1:{port}/tiles/../secret.txt");
    for path in [
        "/tiles/../secret.txt",
        "/tiles/sub/../../secret.txt",
        "/tiles/%2e%2e/secret.txt",
        "/tiles/%2E%2E/secret.txt",
        "/tiles/..%2fsecret.txt",
        "/tiles/%2e%2e%2fsecret.txt",
        "/tiles/sub/%2e%2e/%2e%2e/secret.txt",
        "/tiles/.%2e/secret.txt",
        "/../secret.txt",
        "/%2e%2e/secret.txt",
        "/tiles/link.glb",
        "/tiles/outdir/secret.txt",
        &format!("/tiles/{}", d.path().join("secret.txt").display()),
        &format!("/tiles/%2F{}", d.path().join("secret.txt").display().to_string().trim_start_matches('/').replace('/', "%2F")),
        &format!("/tiles//{}", d.path().join("secret.txt").display()),
        "/tiles//etc/passwd",
        "/tiles/%2fetc%2fpasswd",
        "//etc/passwd",
        "/%2fetc%2fpasswd",
        &absolute_form,
    ] {
        for method in ["GET", "HEAD"] {
            let r = req(h, method, path, &[]);
            assert!(matches!(r.status, 400 | 403 | 404), "{method} {path}: {r:?}");
            let body = String::from_utf8_lossy(&r.body);
            assert!(!body.contains(SECRET) && !body.contains("root:"), "{method} {path} leaked a file");
            assert_ne!(r.len(), Some(SECRET.len()), "{method} {path}: the length of the secret");
        }
    }
    // A symlink out and back in again reaches a file inside: served.
    assert_eq!(get(h, "/tiles/outdir/tiles/a.glb").status, 200);
    // The refusals did not stop the server.
    assert_eq!(get(h, "/tiles/a.glb").status, 200);
}

#[test]
fn the_viewer_page_is_at_the_root() {
    let d = tempfile::tempdir().unwrap();
    let t = fake_tileset(d.path());
    let s = start(&t);
    let h = s.host.as_str();
    let r = get(h, "/");
    assert_eq!(r.status, 200, "{r:?}");
    assert!(r.header("content-type").unwrap().starts_with("text/html"), "{r:?}");
    assert_eq!(r.len(), Some(r.body.len()));
    assert!(String::from_utf8_lossy(&r.body).to_ascii_lowercase().contains("<html"), "not a page");
    assert_eq!(r.header("access-control-allow-origin"), Some("*"));
    assert_eq!(get(h, "/index.html").body, r.body);
    let hd = req(h, "HEAD", "/", &[]);
    assert_eq!((hd.status, hd.len()), (200, Some(r.body.len())));
    assert!(hd.body.is_empty());
    // The bundle's script, when the page loads one from the root.
    let page = String::from_utf8_lossy(&r.body).into_owned();
    if page.contains("viewer.js") {
        let js = get(h, "/viewer.js");
        assert_eq!(js.status, 200);
        assert_eq!(js.header("content-type"), Some("text/javascript"));
    }
}

#[test]
fn sigint_and_sigterm_stop_it_with_128_plus_the_signal() {
    let d = tempfile::tempdir().unwrap();
    let t = fake_tileset(d.path());
    for (sig, code) in [(libc::SIGINT, 130), (libc::SIGTERM, 143)] {
        let mut s = start(&t);
        // An idle keep-alive connection must not hold the server open.
        let mut idle = TcpStream::connect(&s.host).unwrap();
        idle.write_all(format!("GET /tiles/tileset.json HTTP/1.1\r\nHost: {}\r\n\r\n", s.host).as_bytes()).unwrap();
        std::thread::sleep(Duration::from_millis(200));
        assert_eq!(get(&s.host, "/tiles/a.glb").status, 200);
        // SAFETY: kill on our own child's pid.
        assert_eq!(unsafe { libc::kill(s.child.id() as i32, sig) }, 0);
        // It stops with the idle connection still open.
        let st = wait_or_fail(&mut s.child, 20, &format!("serve, signal {sig} and an idle connection open,"));
        assert_eq!(st.code(), Some(code), "signal {sig}");
        drop(idle);
        // Exactly one line on stdout, nothing on stderr.
        let mut rest = String::new();
        s.stdout.read_to_string(&mut rest).unwrap();
        assert_eq!(rest, "", "more than one line on stdout");
        let mut err = String::new();
        s.child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
        assert_eq!(err, "", "stderr");
        assert!(TcpStream::connect(&s.host).is_err(), "still listening after exit");
    }
}

#[test]
fn bad_inputs_and_a_busy_port_fail_with_status_1() {
    let d = tempfile::tempdir().unwrap();
    let plain = d.path().join("plain");
    std::fs::create_dir(&plain).unwrap();
    let file = d.path().join("f.json");
    std::fs::write(&file, "{}").unwrap();
    let t = fake_tileset(d.path());
    let missing = d.path().join("missing");
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = busy.local_addr().unwrap().port().to_string();
    let cases: [(Vec<&str>, &str); 4] = [
        (vec![plain.to_str().unwrap()], "tileset.json"),
        (vec![file.to_str().unwrap()], "not a directory"),
        (vec![missing.to_str().unwrap()], "missing"),
        (vec![t.to_str().unwrap(), "--port", &port], "listen"),
    ];
    for (args, msg) in cases {
        let o = Command::new(bin()).arg("serve").args(&args).stdin(Stdio::null()).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(msg), "{args:?}: {err}");
        assert!(o.stdout.is_empty(), "{args:?}");
    }
}
