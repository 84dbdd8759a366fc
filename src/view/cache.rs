//! The viewer's node cache under a hard byte budget, and its I/O threads.
//!
//! Takes: load requests in priority order from the selection, and the GPU
//! upload function. Gives: nodes resident on the GPU, with every byte the
//! viewer holds for node data counted against `--ram`: a load reserves its
//! read buffer, its decoded form and its GPU-ready form *before* it is
//! issued; the reservation shrinks to the GPU-ready mesh when the load
//! completes, and to the GPU buffers' size once uploaded (the CPU copy is
//! then dropped). Nothing is loaded unless it fits after evicting
//! least-recently-used units that are neither pinned (the top levels,
//! loaded at start) nor used by the current frame's traversal.
//!
//! Loads run on background threads: one positioned read of the node's
//! page-aligned byte range in its pack file, the checksum check, then
//! decoding and conversion to GPU form. The render thread only polls a channel, so a frame never
//! waits on disk; `io_delay` slows every read (tests and demos of slow
//! disks).

use super::select::{Hierarchy, Unit};
use super::{draw_node, DrawMesh, GpuBytes};
use crate::error::{Error, IoContext, Location, Result};
use crate::mesh::{AttrSet, VertexLayout};
use crate::store::{decode_payload, Patch};
use std::collections::HashMap;
use std::path::Path;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A load job: node, pack file (level, part), byte range, checksum, patch shift.
struct Job {
    unit: Unit,
    pack: (u8, u32),
    offset: u64,
    bytes: u32,
    crc: u32,
    shift: u32,
}

impl Job {
    fn of(h: &Hierarchy, u: Unit) -> Job {
        let i = h.info(u);
        Job { unit: u, pack: (i.level, i.part), offset: i.offset, bytes: i.bytes, crc: i.crc, shift: i.patch_shift }
    }
}

/// What the I/O threads need to turn bytes into a GPU-ready mesh.
#[derive(Clone, Copy)]
pub struct LoadCtx {
    /// Layout of payload vertices.
    pub layout: VertexLayout,
    /// Attributes of payload vertices (normals present when stored).
    pub attrs: AttrSet,
    pub origin: [f64; 3],
}

type Done = (Unit, std::result::Result<DrawMesh, String>);

/// Background readers.
pub struct IoPool {
    jobs: Option<Sender<Job>>,
    done: Receiver<Done>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl IoPool {
    pub fn new(dir: &Path, ctx: LoadCtx, threads: usize, delay: Duration) -> IoPool {
        let (jtx, jrx) = channel::<Job>();
        let (dtx, drx) = channel::<Done>();
        let jrx = Arc::new(Mutex::new(jrx));
        let threads = (0..threads.max(1))
            .map(|_| {
                let (jrx, dtx, dir) = (jrx.clone(), dtx.clone(), dir.to_path_buf());
                std::thread::spawn(move || {
                    let mut files: HashMap<(u8, u32), std::fs::File> = HashMap::new();
                    loop {
                        let job = match jrx.lock().map(|r| r.recv()) {
                            Ok(Ok(j)) => j,
                            _ => return,
                        };
                        if !delay.is_zero() {
                            std::thread::sleep(delay);
                        }
                        let r = load(&dir, &mut files, ctx, &job).map_err(|e| e.to_string());
                        if dtx.send((job.unit, r)).is_err() {
                            return;
                        }
                    }
                })
            })
            .collect();
        IoPool { jobs: Some(jtx), done: drx, threads }
    }
}

impl Drop for IoPool {
    fn drop(&mut self) {
        self.jobs = None;
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Reads, checks and decodes one node (used by the I/O threads and for pinned nodes).
fn load(dir: &Path, files: &mut HashMap<(u8, u32), std::fs::File>, ctx: LoadCtx, job: &Job) -> Result<DrawMesh> {
    use std::os::unix::fs::FileExt;
    let path = crate::store::pack_file_part(dir, job.pack.0, job.pack.1);
    let f = match files.entry(job.pack) {
        std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
        std::collections::hash_map::Entry::Vacant(e) => e.insert(std::fs::File::open(&path).ctx(&path, "open pack file")?),
    };
    let mut b = vec![0u8; job.bytes as usize];
    f.read_exact_at(&mut b, job.offset).ctx(&path, "read pack file")?;
    if crc32c::crc32c(&b) != job.crc {
        return Err(Error::input(
            Location { file: path.clone(), offset: Some(job.offset), ..Default::default() },
            format!("node {}: payload checksum mismatch (the store is damaged or was rewritten)", job.unit),
        ));
    }
    let mut m = decode_payload(&ctx.layout, &b, &path, job.offset)?;
    drop(b);
    crate::store::shift_patches(&mut m.patches, job.shift);
    Ok(draw_node(&m, ctx.attrs, ctx.origin))
}

enum State<M> {
    Loading,
    Cpu(DrawMesh),
    Gpu(M),
    Failed,
}

struct Entry<M> {
    state: State<M>,
    /// The node's patches (kept once the mesh is on the GPU).
    patches: Vec<Patch>,
    /// Bytes charged against the budget now.
    charged: u64,
    last_used: u64,
    pinned: bool,
}

/// Counters for statistics.
#[derive(Clone, Copy, Debug, Default)]
pub struct CacheCounters {
    pub loads_issued: u64,
    pub loads_done: u64,
    pub load_failures: u64,
    pub evictions: u64,
    pub uploaded_bytes: u64,
    pub read_bytes: u64,
    /// Units the selection needed that were ready / not ready (hit rate).
    pub hits: u64,
    pub misses: u64,
}

/// The budgeted cache of nodes.
pub struct Cache<M> {
    entries: HashMap<Unit, Entry<M>>,
    budget: u64,
    charged: u64,
    peak: u64,
    io: IoPool,
    in_flight: usize,
    max_in_flight: usize,
    vertex_size: u64,
    pub counters: CacheCounters,
    pub errors: Vec<String>,
}

/// Bytes a load holds at its peak: read buffer, decoded vertices and
/// triangles, and the GPU-ready mesh.
fn load_reservation(h: &Hierarchy, u: Unit, vertex_size: u64) -> u64 {
    let s = h.info(u);
    s.bytes as u64 + s.verts as u64 * vertex_size + s.tris as u64 * 12 + h.draw_bytes(u)
}

impl<M: GpuBytes> Cache<M> {
    pub fn new(dir: &Path, ctx: LoadCtx, budget: u64, io_threads: usize, io_delay: Duration) -> Cache<M> {
        Cache {
            entries: HashMap::new(),
            budget,
            charged: 0,
            peak: 0,
            io: IoPool::new(dir, ctx, io_threads, io_delay),
            in_flight: 0,
            max_in_flight: 8 * io_threads.max(1) + 8,
            vertex_size: std::mem::size_of::<crate::mesh::Vertex>() as u64,
            counters: CacheCounters::default(),
            errors: Vec::new(),
        }
    }

    pub fn budget(&self) -> u64 {
        self.budget
    }
    /// Bytes held now (CPU copies, GPU buffers and in-flight reservations).
    pub fn resident(&self) -> u64 {
        self.charged
    }
    /// Most bytes ever held.
    pub fn peak(&self) -> u64 {
        self.peak
    }
    pub fn in_flight(&self) -> usize {
        self.in_flight
    }
    pub fn len(&self) -> usize {
        self.entries.len()
    }
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
    /// Units waiting in CPU memory for upload.
    pub fn awaiting_upload(&self) -> usize {
        self.entries.values().filter(|e| matches!(e.state, State::Cpu(_))).count()
    }

    fn charge(&mut self, add: u64, sub: u64) {
        self.charged = self.charged + add - sub;
        self.peak = self.peak.max(self.charged);
    }

    /// Loads `units` synchronously and pins them (start-up only, before
    /// the first frame). Fails when they do not fit the budget.
    pub fn pin(&mut self, h: &Hierarchy, dir: &Path, ctx: LoadCtx, units: &[Unit]) -> Result<()> {
        let need: u64 = units.iter().map(|&u| h.draw_bytes(u)).sum();
        if need > self.budget {
            return Err(crate::Error::Usage(format!(
                "the RAM budget leaves {} for node data but the coarsest level alone needs {}: raise --ram",
                crate::progress::bytes(self.budget),
                crate::progress::bytes(need)
            )));
        }
        let mut files = HashMap::new();
        for &u in units {
            let job = Job::of(h, u);
            let m = load(dir, &mut files, ctx, &job)?;
            self.counters.read_bytes += job.bytes as u64;
            self.counters.loads_done += 1;
            let b = m.bytes();
            self.charge(b, 0);
            let patches = m.patches.clone();
            self.entries.insert(u, Entry { state: State::Cpu(m), patches, charged: b, last_used: 0, pinned: true });
        }
        Ok(())
    }

    /// Collects finished loads (never blocks).
    pub fn poll(&mut self) {
        while let Ok(d) = self.io.done.try_recv() {
            self.finish(d);
        }
    }

    fn finish(&mut self, (u, r): Done) {
        self.in_flight -= 1;
        let Some(e) = self.entries.get_mut(&u) else { return };
        let old = e.charged;
        match r {
            Ok(m) => {
                let b = m.bytes();
                e.patches = m.patches.clone();
                e.state = State::Cpu(m);
                e.charged = b;
                self.counters.loads_done += 1;
                self.charge(b, old);
            }
            Err(msg) => {
                e.state = State::Failed;
                e.charged = 0;
                self.counters.load_failures += 1;
                if self.errors.len() < 16 {
                    self.errors.push(msg);
                }
                self.charge(0, old);
            }
        }
    }

    /// Uploads loaded units to the GPU, pinned first, up to `max_bytes`
    /// (at least one unit). Returns bytes uploaded.
    pub fn upload(&mut self, max_bytes: u64, upload: &mut dyn FnMut(&DrawMesh) -> M) -> u64 {
        let mut todo: Vec<(bool, u64, Unit)> =
            self.entries.iter().filter(|(_, e)| matches!(e.state, State::Cpu(_))).map(|(&u, e)| (!e.pinned, u64::MAX - e.last_used, u)).collect();
        todo.sort_unstable();
        let mut done = 0u64;
        for (not_pinned, _, u) in todo {
            if not_pinned && done > 0 && done >= max_bytes {
                break;
            }
            let e = self.entries.get_mut(&u).unwrap();
            let State::Cpu(m) = &e.state else { unreachable!() };
            let g = upload(m);
            let gb = g.gpu_bytes();
            done += m.bytes();
            let old = e.charged;
            e.state = State::Gpu(g);
            e.charged = gb;
            self.counters.uploaded_bytes += gb;
            self.charge(gb, old);
        }
        done
    }

    pub fn is_ready(&self, u: Unit) -> bool {
        matches!(self.entries.get(&u).map(|e| &e.state), Some(State::Gpu(_)))
    }

    pub fn gpu(&self, u: Unit) -> Option<&M> {
        match self.entries.get(&u).map(|e| &e.state) {
            Some(State::Gpu(g)) => Some(g),
            _ => None,
        }
    }

    /// The patches of a resident node.
    pub fn patches(&self, u: Unit) -> &[Patch] {
        self.entries.get(&u).map_or(&[], |e| &e.patches)
    }

    /// Marks units as used by frame `frame` (they will not be evicted now).
    pub fn touch(&mut self, units: &[Unit], frame: u64) {
        for u in units {
            if let Some(e) = self.entries.get_mut(u) {
                e.last_used = frame;
            }
        }
    }

    /// Issues loads for `wanted` in order while the in-flight limit and the
    /// budget allow, evicting least-recently-used units not used in `frame`
    /// when `may_evict`. Returns how many wanted units remain unissued.
    pub fn request(&mut self, h: &Hierarchy, wanted: &[(Unit, f64)], frame: u64, may_evict: bool) -> usize {
        let mut left = 0;
        let mut victims: Option<Vec<(u64, Unit)>> = None;
        // Wanted units already here must not be evicted for each other.
        for (u, _) in wanted {
            if let Some(e) = self.entries.get_mut(u) {
                e.last_used = e.last_used.max(frame);
            }
        }
        for &(u, _) in wanted {
            if self.entries.contains_key(&u) {
                continue;
            }
            if self.in_flight >= self.max_in_flight {
                left += 1;
                continue;
            }
            let need = load_reservation(h, u, self.vertex_size);
            if self.charged + need > self.budget {
                if !may_evict {
                    left += 1;
                    continue;
                }
                let v = victims.get_or_insert_with(|| {
                    let mut v: Vec<(u64, Unit)> = self
                        .entries
                        .iter()
                        .filter(|(_, e)| !e.pinned && e.last_used < frame && !matches!(e.state, State::Loading))
                        .map(|(&u, e)| (e.last_used, u))
                        .collect();
                    v.sort_unstable_by(|a, b| b.cmp(a)); // pop() gives the oldest
                    v
                });
                // Evict only when that makes room: evictions that leave the
                // load unissued free memory the prefetch refills, and the
                // next frame evicts it again, without end.
                let evictable: u64 = v.iter().map(|(_, u)| self.entries.get(u).map_or(0, |e| e.charged)).sum();
                if self.charged.saturating_sub(evictable) + need > self.budget {
                    left += 1;
                    continue;
                }
                while self.charged + need > self.budget {
                    let Some((_, victim)) = v.pop() else { break };
                    if let Some(e) = self.entries.remove(&victim) {
                        self.charge(0, e.charged);
                        self.counters.evictions += 1;
                    }
                }
                if self.charged + need > self.budget {
                    left += 1;
                    continue;
                }
            }
            let job = Job::of(h, u);
            let read = job.bytes as u64;
            if self.io.jobs.as_ref().map(|j| j.send(job).is_ok()) != Some(true) {
                left += 1;
                continue;
            }
            self.counters.loads_issued += 1;
            self.counters.read_bytes += read;
            self.in_flight += 1;
            self.charge(need, 0);
            self.entries.insert(u, Entry { state: State::Loading, patches: Vec::new(), charged: need, last_used: frame, pinned: false });
        }
        left
    }

    /// Waits (blocking) until no load is in flight. For tests and the
    /// reference renderer only; the frame loop never calls it.
    pub fn drain(&mut self) {
        while self.in_flight > 0 {
            match self.io.done.recv() {
                Ok(d) => self.finish(d),
                Err(_) => break,
            }
        }
    }
}
