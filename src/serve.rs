//! `octolod serve`: a local HTTP server for a 3D Tiles tileset and the
//! bundled browser viewer page.
//!
//! Takes: a tileset directory (holding `tileset.json`), or a store, which
//! is first exported to 3D Tiles in a scratch directory removed when the
//! server stops. Gives: `/` → the viewer page (`index.html`), `/NAME` → the
//! page's other files (`web/dist/`, embedded at compile time by build.rs),
//! `/tiles/...` → the tileset directory. Every response allows any origin
//! (CORS `*`: pages elsewhere, e.g. CesiumJS, load the tileset) and says
//! `Cache-Control: no-cache` (revalidate: ETag and Last-Modified make that a
//! cheap 304, and a re-exported tileset on the same URL is never stale).
//! Files are served with single byte ranges (206, `Content-Range`; 416),
//! HEAD, conditional requests and content types by extension; directories
//! are never listed; nothing outside the served directory is reachable
//! (`..` raw or percent-encoded, absolute paths and symlinks leading out
//! all answer 404). Runs until SIGINT/SIGTERM, seen at [`signal::check`]
//! every 100 ms: open connections get [`DRAIN`] to finish, then
//! [`Server::run`] returns [`Error::Interrupted`].
//!
//! Why axum + tower-http's `ServeDir`: ranges, conditional requests, HEAD,
//! MIME types and percent-decoding with `..` refused are the maintained
//! code of tower-http (tokio project), and hyper's HTTP/1.1 (keep-alive,
//! pipelining) serves a browser's many parallel tile requests; `ServeDir`'s
//! pluggable backend confines paths ([`Confined`]) and serves the embedded
//! page ([`Embedded`]) through the same code. The alternative, `tiny_http`
//! (last release 2022) with our own Range/conditional code, builds faster
//! and smaller, but the difference is small next to wgpu and paid once per
//! clean build (figures in `docs/web.md`, "Serve").

use crate::error::{Error, IoContext, Result};
use crate::io::signal;
use std::future::{ready, IntoFuture, Ready};
use std::io;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, TcpListener};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tower_http::services::fs::{Backend, File as BackendFile, Metadata as BackendMetadata, TokioBackend, TokioFile};
use tower_http::services::ServeDir;

include!(concat!(env!("OUT_DIR"), "/web_dist.rs"));

/// How long open connections may take to finish once a signal stops the server.
pub const DRAIN: Duration = Duration::from_secs(2);
/// How often the server looks for a signal.
const POLL: Duration = Duration::from_millis(100);
/// The tileset's URL path prefix.
pub const TILES_PREFIX: &str = "/tiles";

/// What `octolod serve` was asked.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// 0: any free port.
    pub port: u16,
    pub bind: IpAddr,
    pub quiet: bool,
    /// Working-memory budget of a store's export.
    pub mem: u64,
}

impl Default for ServeOptions {
    fn default() -> Self {
        ServeOptions { port: 8080, bind: IpAddr::V4(Ipv4Addr::LOCALHOST), quiet: false, mem: crate::mem::DEFAULT_BUDGET }
    }
}

/// A bound server, not yet answering: [`Server::url`] is known.
pub struct Server {
    listener: TcpListener,
    addr: SocketAddr,
    /// The tileset directory (canonical).
    tiles: PathBuf,
    /// A store's export; removed when the server is dropped.
    _scratch: Option<crate::io::ScratchDir>,
}

/// Prepares the tileset of `input` (a tileset directory, or a store to
/// export) and binds the listening socket.
pub fn bind(input: &Path, o: &ServeOptions) -> Result<Server> {
    let meta = std::fs::metadata(input).ctx(input, "open")?;
    let (tiles, scratch) = if crate::io::OutputKind::Store.recognise(input) {
        let (scratch, dir) = export_store(input, o)?;
        (dir, Some(scratch))
    } else if meta.is_dir() {
        if !input.join("tileset.json").is_file() {
            return Err(Error::Usage(format!("serve: {}: neither a store nor a 3D Tiles directory (no tileset.json)", input.display())));
        }
        (input.to_path_buf(), None)
    } else {
        return Err(Error::Usage(format!("serve: {}: not a directory: serve takes a 3D Tiles directory or a store", input.display())));
    };
    let tiles = std::fs::canonicalize(&tiles).ctx(&tiles, "resolve")?;
    let want = SocketAddr::new(o.bind, o.port);
    let listener = TcpListener::bind(want).map_err(|e| Error::io(format!("{want}"), "listen on", e))?;
    let addr = listener.local_addr().map_err(|e| Error::io(format!("{want}"), "listen on", e))?;
    Ok(Server { listener, addr, tiles, _scratch: scratch })
}

/// Exports the store at `path` to 3D Tiles in a fresh scratch directory
/// (under the system temp directory); gives the scratch directory (which
/// removes itself when dropped) and the tileset directory inside it.
fn export_store(path: &Path, o: &ServeOptions) -> Result<(crate::io::ScratchDir, PathBuf)> {
    let store = crate::store::Store::open(path)?;
    let scratch = crate::io::scratch_in(&std::env::temp_dir())?;
    let out = scratch.path().join("tiles");
    let topts = crate::tiles::TilesOptions { quiet: o.quiet, mem: o.mem, ..Default::default() };
    crate::tiles::export(&store, &out, &topts)?;
    Ok((scratch, out))
}

impl Server {
    /// The address listened on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The viewer page's URL (loopback when bound to every address).
    pub fn url(&self) -> String {
        let ip = match self.addr.ip() {
            IpAddr::V4(a) if a.is_unspecified() => IpAddr::V4(Ipv4Addr::LOCALHOST),
            IpAddr::V6(a) if a.is_unspecified() => IpAddr::V6(Ipv6Addr::LOCALHOST),
            ip => ip,
        };
        format!("http://{}/", SocketAddr::new(ip, self.addr.port()))
    }

    /// The tileset's URL.
    pub fn tileset_url(&self) -> String {
        format!("{}{}/tileset.json", self.url(), &TILES_PREFIX[1..])
    }

    /// The tileset directory served under `/tiles/`.
    pub fn tiles_dir(&self) -> &Path {
        &self.tiles
    }

    /// Answers requests until a signal asks the process to stop; then gives
    /// [`Error::Interrupted`] (after at most [`DRAIN`] for open connections).
    pub fn run(self) -> Result<()> {
        let rt = tokio::runtime::Builder::new_current_thread().enable_io().enable_time().build().map_err(|e| Error::io("tokio runtime", "start", e))?;
        let addr = self.addr;
        let listen_err = |e| Error::io(format!("{addr}"), "listen on", e);
        self.listener.set_nonblocking(true).map_err(listen_err)?;
        let app = router(self.tiles.clone());
        let std_listener = self.listener;
        let r = rt.block_on(async move {
            let listener = tokio::net::TcpListener::from_std(std_listener).map_err(listen_err)?;
            let server = tokio::spawn(axum::serve(listener, app).with_graceful_shutdown(until_signal()).into_future());
            until_signal().await;
            // Stop accepting, let open connections finish for a moment.
            let _ = tokio::time::timeout(DRAIN, server).await;
            Ok::<(), Error>(())
        });
        rt.shutdown_timeout(Duration::from_millis(500));
        r?;
        signal::check()
    }
}

/// Resolves once a signal asked the process to stop.
async fn until_signal() {
    while signal::check().is_ok() {
        tokio::time::sleep(POLL).await;
    }
}

/// The routes: `/tiles/...` from `tiles`, everything else from the page.
fn router(tiles: PathBuf) -> axum::Router {
    use axum::http::{header, HeaderValue};
    use tower_http::cors::CorsLayer;
    use tower_http::set_header::SetResponseHeaderLayer;
    let tiles = ServeDir::with_backend(&tiles, Confined { root: tiles.clone() }).append_index_html_on_directories(false).redirect_to_trailing_slash(false);
    let page = ServeDir::with_backend("", Embedded).append_index_html_on_directories(true).redirect_to_trailing_slash(false);
    axum::Router::new()
        .nest_service(TILES_PREFIX, tiles)
        .fallback_service(page)
        .layer(SetResponseHeaderLayer::overriding(header::CACHE_CONTROL, HeaderValue::from_static("no-cache")))
        .layer(CorsLayer::permissive())
}

/// Opens `url` in the default browser (`xdg-open`), best effort: a failure
/// is a warning on stderr (unless `quiet`), never an error.
pub fn open_browser(url: &str, quiet: bool) {
    use std::process::{Command, Stdio};
    match Command::new("xdg-open").arg(url).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null()).spawn() {
        Ok(mut child) => {
            // Reap it when it ends.
            std::thread::spawn(move || child.wait());
        }
        Err(e) if !quiet => eprintln!("octolod: warning: could not open a browser (xdg-open: {e}); open {url}"),
        Err(_) => {}
    }
}

/// Not found: what every refused path answers.
fn not_found() -> io::Error {
    io::Error::from(io::ErrorKind::NotFound)
}

/// The local file system below `root` (canonical): a path whose real
/// location (symlinks resolved) is outside `root` is not found, and so is
/// anything but a regular file or a directory (a FIFO would block a reader).
#[derive(Clone, Debug)]
pub struct Confined {
    root: PathBuf,
}

impl Confined {
    /// The real path of `p` when it lies inside the root.
    async fn resolve(root: &Path, p: &Path) -> io::Result<(PathBuf, std::fs::Metadata)> {
        let real = tokio::fs::canonicalize(p).await?;
        if !real.starts_with(root) {
            return Err(not_found());
        }
        let m = tokio::fs::metadata(&real).await?;
        if !m.is_file() && !m.is_dir() {
            return Err(not_found());
        }
        Ok((real, m))
    }
}

impl Backend for Confined {
    type File = TokioFile;
    type Metadata = std::fs::Metadata;
    type OpenFuture = Pin<Box<dyn std::future::Future<Output = io::Result<TokioFile>> + Send>>;
    type MetadataFuture = Pin<Box<dyn std::future::Future<Output = io::Result<std::fs::Metadata>> + Send>>;

    fn open(&self, path: PathBuf) -> Self::OpenFuture {
        let root = self.root.clone();
        Box::pin(async move {
            let (real, m) = Confined::resolve(&root, &path).await?;
            if !m.is_file() {
                return Err(not_found());
            }
            TokioBackend.open(real).await
        })
    }

    fn metadata(&self, path: PathBuf) -> Self::MetadataFuture {
        let root = self.root.clone();
        Box::pin(async move { Confined::resolve(&root, &path).await.map(|(_, m)| m) })
    }
}

/// The viewer page's files, embedded at compile time ([`WEB_FILES`]).
#[derive(Clone, Copy, Debug)]
pub struct Embedded;

/// An embedded file or directory.
#[derive(Clone, Copy, Debug)]
pub struct EmbeddedMeta {
    len: u64,
    dir: bool,
}

impl BackendMetadata for EmbeddedMeta {
    fn is_dir(&self) -> bool {
        self.dir
    }
    fn modified(&self) -> io::Result<SystemTime> {
        match WEB_MTIME {
            0 => Err(io::Error::other("no modification time")),
            s => Ok(UNIX_EPOCH + Duration::from_secs(s)),
        }
    }
    fn len(&self) -> u64 {
        self.len
    }
}

/// An open embedded file.
pub struct EmbeddedFile(io::Cursor<&'static [u8]>);

impl tokio::io::AsyncRead for EmbeddedFile {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut tokio::io::ReadBuf<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.0).poll_read(cx, buf)
    }
}

impl tokio::io::AsyncSeek for EmbeddedFile {
    fn start_seek(mut self: Pin<&mut Self>, pos: io::SeekFrom) -> io::Result<()> {
        Pin::new(&mut self.0).start_seek(pos)
    }
    fn poll_complete(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<u64>> {
        Pin::new(&mut self.0).poll_complete(cx)
    }
}

impl BackendFile for EmbeddedFile {
    type Metadata = EmbeddedMeta;
    type MetadataFuture<'a> = Ready<io::Result<EmbeddedMeta>>;
    fn metadata(&self) -> Self::MetadataFuture<'_> {
        ready(Ok(EmbeddedMeta { len: self.0.get_ref().len() as u64, dir: false }))
    }
}

impl Embedded {
    /// The embedded file named `path` (relative, `/`-separated).
    pub fn file(path: &str) -> Option<&'static [u8]> {
        WEB_FILES.binary_search_by(|(n, _)| (*n).cmp(path)).ok().map(|i| WEB_FILES[i].1)
    }

    /// The table's name for `path` (ServeDir's paths start with `./`).
    fn key(path: &Path) -> Option<String> {
        let mut k = String::new();
        for c in path.components() {
            match c {
                std::path::Component::CurDir => {}
                std::path::Component::Normal(n) => {
                    if !k.is_empty() {
                        k.push('/');
                    }
                    k.push_str(n.to_str()?);
                }
                _ => return None,
            }
        }
        Some(k)
    }

    fn lookup(path: &Path) -> io::Result<EmbeddedMeta> {
        let k = Embedded::key(path).ok_or_else(not_found)?;
        let p = k.as_str();
        if let Some(b) = Embedded::file(p) {
            return Ok(EmbeddedMeta { len: b.len() as u64, dir: false });
        }
        let is_dir = p.is_empty() || WEB_FILES.iter().any(|(n, _)| n.strip_prefix(p).is_some_and(|r| r.starts_with('/')));
        if is_dir {
            Ok(EmbeddedMeta { len: 0, dir: true })
        } else {
            Err(not_found())
        }
    }
}

impl Backend for Embedded {
    type File = EmbeddedFile;
    type Metadata = EmbeddedMeta;
    type OpenFuture = Ready<io::Result<EmbeddedFile>>;
    type MetadataFuture = Ready<io::Result<EmbeddedMeta>>;

    fn open(&self, path: PathBuf) -> Self::OpenFuture {
        ready(Embedded::key(&path).and_then(|k| Embedded::file(&k)).map(|b| EmbeddedFile(io::Cursor::new(b))).ok_or_else(not_found))
    }

    fn metadata(&self, path: PathBuf) -> Self::MetadataFuture {
        ready(Embedded::lookup(&path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_table_is_sorted_and_has_an_index() {
        assert!(WEB_FILES.windows(2).all(|w| w[0].0 < w[1].0));
        assert!(Embedded::file("index.html").is_some_and(|b| !b.is_empty()));
        assert!(Embedded::lookup(Path::new("")).unwrap().dir);
        assert!(Embedded::lookup(Path::new(".")).unwrap().dir);
        assert!(!Embedded::lookup(Path::new("./index.html")).unwrap().dir);
        assert!(Embedded::lookup(Path::new("../index.html")).is_err());
        assert!(Embedded::lookup(Path::new("no-such-file.js")).is_err());
    }
}
