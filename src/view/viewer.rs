//! The viewer core shared by the window and the headless renderer.
//!
//! Takes: a store, a RAM budget and selection options. Gives, per frame:
//! the units to draw (resident on the GPU), and [`FrameStats`]. One frame
//! is: collect finished loads → upload a bounded number of bytes → select
//! the cut → issue loads in priority order (evicting LRU units outside the
//! cut). No step waits on disk.

use super::cache::{Cache, LoadCtx};
use super::camera::{dvec, Camera};
use super::select::{Hierarchy, SelectOptions, Selection, Selector, Unit};
use super::{DrawItem, DrawMesh, GpuBytes};
use crate::error::{Error, Result};
use crate::store::Store;
use std::path::Path;
use std::time::{Duration, Instant};

/// Viewer settings.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Hard limit for node data: CPU copies + GPU buffers + in-flight loads
    /// + the node index held in memory.
    pub ram: u64,
    pub select: SelectOptions,
    pub io_threads: usize,
    /// Artificial delay per read (testing slow disks).
    pub io_delay: Duration,
    /// Upload at most this many bytes per frame (spreads upload cost).
    pub upload_per_frame: u64,
    /// Pin (load at start, never evict) top levels up to this share of the budget.
    pub pin_share: f64,
    /// Bytes of the textures shown (their mip chains on the GPU), counted
    /// against `ram` like the node index; 0 when none is shown, and then
    /// uvs (and materials) are not loaded either.
    pub texture_bytes: u64,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            ram: 512 << 20,
            select: SelectOptions::default(),
            io_threads: 2,
            io_delay: Duration::ZERO,
            upload_per_frame: 64 << 20,
            pin_share: 0.125,
            texture_bytes: 0,
        }
    }
}

/// Statistics of one frame: one row of `render`'s `stats.csv` and one
/// element of `stats.json`'s `frames` (same fields, same names, in this
/// order; `max_error_px` is `null` in JSON and empty in CSV when no node
/// was refined).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FrameStats {
    pub frame: u64,
    pub select_ms: f64,
    pub upload_ms: f64,
    /// Filled by the caller after drawing.
    pub draw_ms: f64,
    pub triangles: u64,
    pub nodes: u32,
    /// Nodes drawn per level (index = level; 0 = the input's triangles).
    pub nodes_per_level: Vec<u32>,
    pub resident_bytes: u64,
    pub peak_resident_bytes: u64,
    pub budget_bytes: u64,
    /// Bytes of the textures shown, all together (included in `resident_bytes`).
    pub texture_bytes: u64,
    /// Loads in flight plus wanted loads not issued yet.
    pub pending_loads: u32,
    pub loads_done: u64,
    pub evictions: u64,
    /// Share of needed units that were ready (cumulative).
    pub hit_rate: f64,
    /// Largest projected error on screen (pixels): over the drawn patches
    /// inside the view frustum (see `Selection::max_error_px`).
    pub max_error_px: f64,
    /// Nothing wanted is missing (the cut is what the camera asks for), or
    /// nothing missing can load within the RAM budget (the cut is as fine
    /// as `--ram` allows; `max_error_px` then exceeds the target).
    pub settled: bool,
    /// Node loads that failed so far (the cut then lacks their detail).
    pub load_failures: u64,
}

impl FrameStats {
    /// Lines for the statistics overlay.
    pub fn overlay_lines(&self, fps: f64) -> Vec<String> {
        let lv: Vec<String> = self.nodes_per_level.iter().enumerate().filter(|(_, &n)| n > 0).map(|(l, n)| format!("L{l}:{n}")).collect();
        let mut lines = vec![
            format!("{fps:6.1} fps  select {:.2} ms  upload {:.2} ms  draw {:.2} ms", self.select_ms, self.upload_ms, self.draw_ms),
            format!("{} triangles in {} nodes  [{}]", group(self.triangles), self.nodes, lv.join(" ")),
            format!(
                "resident {:.1} / {:.1} MB  peak {:.1} MB{}",
                mb(self.resident_bytes),
                mb(self.budget_bytes),
                mb(self.peak_resident_bytes),
                if self.texture_bytes > 0 { format!("  (texture {:.1} MB)", mb(self.texture_bytes)) } else { String::new() }
            ),
            format!(
                "pending {}  loaded {}  evicted {}  hit rate {:.1}%  max error {:.2} px{}",
                self.pending_loads,
                self.loads_done,
                self.evictions,
                100.0 * self.hit_rate,
                self.max_error_px,
                if self.settled { "" } else { "  (loading)" }
            ),
        ];
        if self.load_failures > 0 {
            lines.push(format!("!! {} node load(s) FAILED: the view lacks their detail (messages in the log)", self.load_failures));
        }
        lines
    }
}

fn mb(b: u64) -> f64 {
    b as f64 / (1u64 << 20) as f64
}

fn group(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The out-of-core viewer state.
pub struct Viewer<M> {
    pub store: Store,
    pub hierarchy: Hierarchy,
    pub cache: Cache<M>,
    pub selector: Selector,
    pub opts: ViewOptions,
    /// Vertices are uploaded relative to this point (the input's bbox centre).
    pub origin: [f64; 3],
    /// Bytes of the in-memory index (and the texture, when one is shown)
    /// counted against the budget.
    pub index_bytes: u64,
    frame: u64,
    last: Selection,
}

impl<M: GpuBytes> Viewer<M> {
    /// Opens a store, starts the I/O threads and loads the pinned top
    /// levels (the only synchronous reads, before the first frame).
    pub fn open(dir: &Path, opts: ViewOptions) -> Result<Viewer<M>> {
        Viewer::with_store(Store::open(dir)?, opts)
    }

    /// [`Viewer::open`] of a store already opened (to size its textures
    /// first: [`super::texture::prepare`]).
    pub fn with_store(store: Store, opts: ViewOptions) -> Result<Viewer<M>> {
        let dir = store.dir.clone();
        if store.level_triangles(0) == 0 {
            return Err(Error::Usage(format!("{}: the store holds no triangles", dir.display())));
        }
        let mut hierarchy = Hierarchy::new(&store);
        let mut ctx = load_ctx(&store);
        if opts.texture_bytes > 0 && ctx.attrs.uv() {
            hierarchy.vertex_bytes += 8;
        } else {
            // Materials choose textures: without one shown, neither matters.
            ctx.attrs = ctx.attrs.with(crate::mesh::AttrSet::UV, false).with(crate::mesh::AttrSet::MATERIAL, false);
        }
        let origin = store.header.bbox.center();
        // The texture is held for the whole session, as the index is.
        let index_bytes = (store.nodes.len() * std::mem::size_of::<crate::store::NodeRec>()) as u64 + hierarchy.bytes() + opts.texture_bytes;
        if opts.ram <= index_bytes {
            return Err(Error::Usage(format!(
                "--ram {} does not even hold the node index and texture ({}): raise it",
                crate::progress::bytes(opts.ram),
                crate::progress::bytes(index_bytes)
            )));
        }
        let budget = opts.ram - index_bytes;
        let mut cache = Cache::new(&dir, ctx, budget, opts.io_threads, opts.io_delay);
        // Pin whole top levels of the hierarchy while they fit the share.
        let mut pinned: Vec<Unit> = hierarchy.roots.clone();
        let mut tier = pinned.clone();
        let share = (budget as f64 * opts.pin_share) as u64;
        let mut bytes: u64 = pinned.iter().map(|&u| hierarchy.draw_bytes(u)).sum();
        loop {
            let mut next: Vec<Unit> = tier.iter().flat_map(|&u| hierarchy.children(u).to_vec()).collect();
            next.sort_unstable();
            next.dedup();
            let nb: u64 = next.iter().map(|&u| hierarchy.draw_bytes(u)).sum();
            if next.is_empty() || bytes + nb > share {
                break;
            }
            bytes += nb;
            pinned.extend(&next);
            tier = next;
        }
        cache.pin(&hierarchy, &dir, ctx, &pinned)?;
        Ok(Viewer { store, hierarchy, cache, selector: Selector::new(opts.select.clone()), opts, origin, index_bytes, frame: 0, last: Selection::default() })
    }

    pub fn origin(&self) -> glam::DVec3 {
        dvec(self.origin)
    }

    /// Node loads that failed so far, and the first messages.
    pub fn load_failures(&self) -> (u64, &[String]) {
        (self.cache.counters.load_failures, &self.cache.errors)
    }

    /// Tight bounds of the whole model.
    pub fn bounds(&self) -> crate::mesh::Aabb {
        self.hierarchy.bounds
    }

    /// Runs one frame's CPU work; the draw list is then [`Viewer::draw_list`].
    pub fn frame(&mut self, cam: &Camera, viewport: (u32, u32), upload: &mut dyn FnMut(&DrawMesh) -> M) -> FrameStats {
        self.frame += 1;
        let t0 = Instant::now();
        self.cache.poll();
        self.cache.upload(self.opts.upload_per_frame, upload);
        let t1 = Instant::now();
        let cache = &self.cache;
        let sel = self.selector.select(&self.hierarchy, cam, viewport, &|u| cache.is_ready(u));
        self.cache.touch(&sel.visited, self.frame);
        self.cache.touch(&sel.held, self.frame);
        let needed = sel.visited.len() as u64;
        let missing = sel.wanted.len() as u64;
        self.cache.counters.hits += needed;
        self.cache.counters.misses += missing;
        let left = self.cache.request(&self.hierarchy, &sel.wanted, self.frame, true);
        // Prefetch only into free memory.
        self.cache.request(&self.hierarchy, &sel.prefetch, self.frame, false);
        let t2 = Instant::now();
        let mut per_level = vec![0u32; self.store.header.levels.max(1) as usize + 1];
        for &u in &sel.cut {
            let l = self.hierarchy.info(u).level as usize;
            if l >= per_level.len() {
                per_level.resize(l + 1, 0);
            }
            per_level[l] += 1;
        }
        let c = self.cache.counters;
        let stats = FrameStats {
            frame: self.frame,
            select_ms: (t2 - t1).as_secs_f64() * 1e3,
            upload_ms: (t1 - t0).as_secs_f64() * 1e3,
            draw_ms: 0.0,
            triangles: sel.triangles,
            nodes: sel.cut.len() as u32,
            nodes_per_level: per_level,
            resident_bytes: self.cache.resident() + self.index_bytes,
            peak_resident_bytes: self.cache.peak() + self.index_bytes,
            budget_bytes: self.opts.ram,
            texture_bytes: self.opts.texture_bytes,
            pending_loads: (self.cache.in_flight() + left) as u32,
            loads_done: c.loads_done,
            evictions: c.evictions,
            hit_rate: if c.hits + c.misses == 0 { 1.0 } else { c.hits as f64 / (c.hits + c.misses) as f64 },
            max_error_px: sel.max_error_px,
            // Nothing left to load, or nothing more that can be: no load in
            // flight and no wanted node fits the budget (the cut is as fine
            // as --ram allows; `render` then warns, as it does for the
            // triangle budget).
            settled: (sel.wanted.is_empty() || (left == sel.wanted.len() && self.cache.in_flight() == 0)) && self.cache.awaiting_upload() == 0,
            load_failures: c.load_failures,
        };
        self.last = sel;
        stats
    }

    /// What the last frame draws (all resident on the GPU): each node of
    /// the cut with the triangle ranges of its patches whose child is not
    /// selected.
    pub fn draw_list(&self) -> Vec<DrawItem<'_, M>> {
        self.last
            .cut
            .iter()
            .filter_map(|&u| {
                let mesh = self.cache.gpu(u)?;
                let mut ranges: Vec<std::ops::Range<u32>> = Vec::new();
                for p in self.cache.patches(u) {
                    if p.count == 0 || !self.last.draws(p.child) {
                        continue;
                    }
                    match ranges.last_mut() {
                        Some(r) if r.end == p.first => r.end = p.first + p.count,
                        _ => ranges.push(p.first..p.first + p.count),
                    }
                }
                (!ranges.is_empty()).then_some(DrawItem { mesh, ranges })
            })
            .collect()
    }

    /// The last frame's selection.
    pub fn selection(&self) -> &Selection {
        &self.last
    }

    /// Nodes of the last frame's cut.
    pub fn cut(&self) -> &[Unit] {
        &self.last.cut
    }

    /// Blocks until in-flight loads finish (tests, reference renders).
    pub fn wait_for_loads(&mut self) {
        self.cache.drain();
    }
}

/// How the viewer turns a store's payloads into GPU form.
pub fn load_ctx(store: &Store) -> LoadCtx {
    LoadCtx { layout: store.payload_layout, attrs: store.payload_layout.attrs, origin: store.header.bbox.center() }
}

/// Brute force: every level-0 (input) triangle loaded and uploaded at once,
/// ignoring the budget (the baseline and the full-resolution reference).
/// Gives the meshes with their triangle counts.
pub fn load_all_originals<M>(store: &Store, upload: &mut dyn FnMut(&DrawMesh) -> M) -> Result<(Vec<(M, u32)>, u64)> {
    let ctx = load_ctx(store);
    let mut out = Vec::new();
    let mut tris = 0u64;
    for i in store.level_nodes(0) {
        let d = super::draw_node(&store.read_node(i)?, ctx.attrs, ctx.origin);
        tris += d.triangles() as u64;
        out.push((upload(&d), d.triangles() as u32));
    }
    Ok((out, tris))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_overlay_shows_the_textures_share_of_the_budget() {
        let s = FrameStats { resident_bytes: 5 << 20, budget_bytes: 64 << 20, texture_bytes: 3 << 20, ..FrameStats::default() };
        assert!(s.overlay_lines(60.0)[2].ends_with("(texture 3.0 MB)"), "{:?}", s.overlay_lines(60.0));
        let s = FrameStats { texture_bytes: 0, ..s };
        assert!(!s.overlay_lines(60.0)[2].contains("texture"));
    }
}
