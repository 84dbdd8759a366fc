#!/usr/bin/env node
// Writes a small 3D Tiles 1.1 tileset shaped like octolod's export, for
// testing the viewer page and the browser driver without the Rust exporter:
//
//   node web/test/fixture.mjs OUT_DIR [--up y|z] [--offset X,Y,Z]
//
// The model: a unit sphere with a cone-shaped bump on the model's up axis,
// coloured by height (red at the top, blue at the bottom), so a screenshot
// shows at a glance whether the page opened it upright. Three levels with
// REPLACE refinement: the root (one GLB), 8 octant tiles, 64 tiles of a
// 4x4x4 grid; geometricError 0.08, 0.02, 0 (model units, radius 1).
// tileset.json carries what octolod's exporter writes: asset.version "1.1",
// asset.extras.octolod {up, bounds}, a root transform that rotates the
// model's up axis to +Z, boxes in model coordinates, GLBs under t/ whose
// coordinates follow glTF's Y-up convention (a client rotates them Y-up to
// Z-up before the tile transforms). Deterministic: the same arguments write
// the same bytes.
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

export const LEVELS = [
	{ seg: 24, cells: 1, geometricError: 0.08 },
	{ seg: 64, cells: 2, geometricError: 0.02 },
	{ seg: 160, cells: 4, geometricError: 0 },
];

// Model-space up axis -> (the rotation to +Z as a column-major 4x4, the map
// from model coordinates to glTF content coordinates).
function frames(up) {
	if (up === 'y') {
		// Rx(+90°): (x, y, z) -> (x, -z, y) takes +Y to +Z.
		return {
			transform: [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1],
			// Content is in the root frame (model coordinates) expressed Y-up:
			// the client applies Rx(+90°) (Y-up to Z-up), so store Rx(-90°) p.
			toContent: ([x, y, z]) => [x, z, -y],
			upVec: [0, 1, 0],
		};
	}
	if (up === 'z') {
		return {
			transform: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
			toContent: ([x, y, z]) => [x, z, -y],
			upVec: [0, 0, 1],
		};
	}
	throw new Error(`--up must be y or z, not ${up}`);
}

// A UV sphere of `seg` x seg/2 quads with a bump along `upVec`, with vertex
// normals (averaged face normals) and colours, in model coordinates.
function sphere(seg, upVec, offset) {
	const rows = seg / 2;
	const pos = [];
	const col = [];
	// Local frame: e3 = up, e1, e2 perpendicular.
	const e3 = upVec;
	const e1 = e3[0] === 0 && e3[1] === 1 ? [0, 0, 1] : [1, 0, 0];
	const e2 = [e3[1] * e1[2] - e3[2] * e1[1], e3[2] * e1[0] - e3[0] * e1[2], e3[0] * e1[1] - e3[1] * e1[0]];
	for (let i = 0; i <= rows; i++) {
		const th = (Math.PI * i) / rows; // 0 at the top
		for (let j = 0; j <= seg; j++) {
			const ph = (2 * Math.PI * (j % seg)) / seg;
			const h = Math.cos(th);
			const s = Math.sin(th);
			const bump = 1 + 0.5 * Math.max(0, (h - 0.8) / 0.2) ** 1.5;
			const l = [s * Math.cos(ph) * bump, s * Math.sin(ph) * bump, h * bump];
			pos.push([0, 1, 2].map((k) => offset[k] + l[0] * e1[k] + l[1] * e2[k] + l[2] * e3[k]));
			const t = (h + 1) / 2; // 1 at the top
			col.push([0.05 + 0.9 * t, 0.25, 0.05 + 0.9 * (1 - t)]);
		}
	}
	const tris = [];
	const v = (i, j) => i * (seg + 1) + j;
	for (let i = 0; i < rows; i++) {
		for (let j = 0; j < seg; j++) {
			// Counter-clockwise seen from outside.
			if (i > 0) tris.push([v(i, j), v(i + 1, j), v(i, j + 1)]);
			if (i < rows - 1) tris.push([v(i, j + 1), v(i + 1, j), v(i + 1, j + 1)]);
		}
	}
	// Poles and the seam duplicate positions: weld normals by position.
	const key = (p) => p.map((c) => c.toFixed(9)).join(',');
	const acc = new Map();
	for (const [a, b, c] of tris) {
		const [pa, pb, pc] = [pos[a], pos[b], pos[c]];
		const u = [0, 1, 2].map((k) => pb[k] - pa[k]);
		const w = [0, 1, 2].map((k) => pc[k] - pa[k]);
		const n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
		for (const p of [pa, pb, pc]) {
			const k = key(p);
			const s = acc.get(k) || [0, 0, 0];
			acc.set(k, [s[0] + n[0], s[1] + n[1], s[2] + n[2]]);
		}
	}
	const nrm = pos.map((p) => {
		const n = acc.get(key(p)) || [0, 0, 1];
		const l = Math.hypot(...n) || 1;
		return n.map((c) => c / l);
	});
	return { pos, nrm, col, tris };
}

function pad4(buf, byte) {
	const extra = (4 - (buf.length % 4)) % 4;
	return extra ? Buffer.concat([buf, Buffer.alloc(extra, byte)]) : buf;
}

// One GLB with one mesh: POSITION, NORMAL, COLOR_0 (float, linear), uint32
// indices, a plain non-metallic material.
function glb(pos, nrm, col, idx) {
	const n = pos.length;
	const f = (arr) => Buffer.from(new Float32Array(arr.flat()).buffer);
	const bPos = f(pos);
	const bNrm = f(nrm.map((v) => {
		const l = Math.hypot(...v);
		return v.map((c) => Math.fround(c / l));
	}));
	const bCol = f(col);
	const bIdx = Buffer.from(new Uint32Array(idx.flat()).buffer);
	const bin = Buffer.concat([bPos, bNrm, bCol, bIdx]);
	const min = [0, 1, 2].map((k) => Math.min(...pos.map((p) => Math.fround(p[k]))));
	const max = [0, 1, 2].map((k) => Math.max(...pos.map((p) => Math.fround(p[k]))));
	const json = {
		asset: { version: '2.0', generator: 'octolod web/test/fixture.mjs' },
		scene: 0,
		scenes: [{ nodes: [0] }],
		nodes: [{ mesh: 0 }],
		meshes: [{ primitives: [{ attributes: { POSITION: 0, NORMAL: 1, COLOR_0: 2 }, indices: 3, material: 0 }] }],
		materials: [{ pbrMetallicRoughness: { baseColorFactor: [1, 1, 1, 1], metallicFactor: 0, roughnessFactor: 1 } }],
		buffers: [{ byteLength: bin.length }],
		bufferViews: [
			{ buffer: 0, byteOffset: 0, byteLength: bPos.length, target: 34962 },
			{ buffer: 0, byteOffset: bPos.length, byteLength: bNrm.length, target: 34962 },
			{ buffer: 0, byteOffset: bPos.length + bNrm.length, byteLength: bCol.length, target: 34962 },
			{ buffer: 0, byteOffset: bPos.length + bNrm.length + bCol.length, byteLength: bIdx.length, target: 34963 },
		],
		accessors: [
			{ bufferView: 0, componentType: 5126, count: n, type: 'VEC3', min, max },
			{ bufferView: 1, componentType: 5126, count: n, type: 'VEC3' },
			{ bufferView: 2, componentType: 5126, count: n, type: 'VEC3' },
			{ bufferView: 3, componentType: 5125, count: idx.length * 3, type: 'SCALAR' },
		],
	};
	const jsonBuf = pad4(Buffer.from(JSON.stringify(json)), 0x20);
	const binBuf = pad4(bin, 0);
	const header = Buffer.alloc(12);
	header.writeUInt32LE(0x46546c67, 0);
	header.writeUInt32LE(2, 4);
	header.writeUInt32LE(12 + 8 + jsonBuf.length + 8 + binBuf.length, 8);
	const chunk = (buf, type) => {
		const h = Buffer.alloc(8);
		h.writeUInt32LE(buf.length, 0);
		h.writeUInt32LE(type, 4);
		return Buffer.concat([h, buf]);
	};
	return Buffer.concat([header, chunk(jsonBuf, 0x4e4f534a), chunk(binBuf, 0x004e4942)]);
}

function boxOf(points) {
	const min = [0, 1, 2].map((k) => Math.min(...points.map((p) => p[k])));
	const max = [0, 1, 2].map((k) => Math.max(...points.map((p) => p[k])));
	return { min, max };
}

function boxVolume({ min, max }) {
	const c = [0, 1, 2].map((k) => (min[k] + max[k]) / 2);
	const h = [0, 1, 2].map((k) => Math.max((max[k] - min[k]) / 2, 1e-6));
	return [c[0], c[1], c[2], h[0], 0, 0, 0, h[1], 0, 0, 0, h[2]];
}

export function writeFixture(out, { up = 'y', offset = [0, 0, 0] } = {}) {
	const { transform, toContent, upVec } = frames(up);
	fs.mkdirSync(path.join(out, 't'), { recursive: true });
	// The cells are a grid over the level-0 bounds (the same at every level).
	const all = sphere(LEVELS[0].seg, upVec, offset);
	const bounds = boxOf(LEVELS.map((l) => sphere(l.seg, upVec, offset).pos).flat());
	const cellOf = (p, cells) =>
		[0, 1, 2].map((k) => {
			const t = (p[k] - bounds.min[k]) / (bounds.max[k] - bounds.min[k]);
			return Math.min(cells - 1, Math.max(0, Math.floor(t * cells)));
		});
	const tiles = new Map(); // "L-i-j-k" -> tile
	let files = 0;
	let triangles = 0;
	LEVELS.forEach((level, L) => {
		const m = L === 0 ? all : sphere(level.seg, upVec, offset);
		const groups = new Map();
		for (const t of m.tris) {
			const c = [0, 1, 2].map((k) => (m.pos[t[0]][k] + m.pos[t[1]][k] + m.pos[t[2]][k]) / 3);
			const cell = cellOf(c, level.cells);
			const id = `${L}-${cell.join('-')}`;
			if (!groups.has(id)) groups.set(id, { cell, tris: [] });
			groups.get(id).tris.push(t);
		}
		for (const id of [...groups.keys()].sort()) {
			const { cell, tris } = groups.get(id);
			const remap = new Map();
			const P = [];
			const N = [];
			const C = [];
			const idx = tris.map((t) =>
				t.map((v) => {
					if (!remap.has(v)) {
						remap.set(v, P.length);
						P.push(m.pos[v]);
						N.push(m.nrm[v]);
						C.push(m.col[v]);
					}
					return remap.get(v);
				}),
			);
			const uri = `t/${id}.glb`;
			fs.writeFileSync(path.join(out, uri), glb(P.map(toContent), N.map(toContent), C, idx));
			files++;
			triangles += idx.length;
			tiles.set(id, {
				boundingVolume: { box: boxVolume(boxOf(P)) },
				geometricError: level.geometricError,
				content: { uri },
				children: [],
				_cell: cell,
				_level: L,
			});
		}
	});
	// Parent links: a level-L tile's parent is the level L-1 tile whose cell
	// contains it; a parent's box grows to hold its children's.
	for (const t of tiles.values()) {
		if (t._level === 0) continue;
		const ratio = LEVELS[t._level].cells / LEVELS[t._level - 1].cells;
		const pc = t._cell.map((c) => Math.floor(c / ratio));
		const parent = tiles.get(`${t._level - 1}-${pc.join('-')}`);
		if (!parent) throw new Error('fixture: orphan tile');
		parent.children.push(t);
	}
	const grow = (t) => {
		for (const c of t.children) grow(c);
		const pts = [t, ...t.children].flatMap((x) => {
			const b = x.boundingVolume.box;
			return [
				[b[0] - b[3], b[1] - b[7], b[2] - b[11]],
				[b[0] + b[3], b[1] + b[7], b[2] + b[11]],
			];
		});
		t.boundingVolume.box = boxVolume(boxOf(pts));
	};
	const root = tiles.get('0-0-0-0');
	grow(root);
	const clean = (t) => {
		const o = { boundingVolume: t.boundingVolume, geometricError: t.geometricError, content: t.content };
		if (t.children.length) o.children = t.children.map(clean);
		return o;
	};
	const tileset = {
		asset: { version: '1.1', generator: 'octolod web/test/fixture.mjs', extras: { octolod: { up: upVec, bounds } } },
		geometricError: 0.5,
		root: { ...clean(root), transform, refine: 'REPLACE' },
	};
	fs.writeFileSync(path.join(out, 'tileset.json'), JSON.stringify(tileset, null, 1) + '\n');
	return { files, triangles, bounds, up: upVec };
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
	const args = process.argv.slice(2);
	const out = args.find((a, i) => !a.startsWith('--') && !(i > 0 && args[i - 1].startsWith('--')));
	const opt = (name, dflt) => {
		const i = args.indexOf(name);
		return i >= 0 ? args[i + 1] : dflt;
	};
	if (!out) {
		console.error('usage: node web/test/fixture.mjs OUT_DIR [--up y|z] [--offset X,Y,Z]');
		process.exit(2);
	}
	const r = writeFixture(out, { up: opt('--up', 'y'), offset: opt('--offset', '0,0,0').split(',').map(Number) });
	console.log(JSON.stringify({ out, ...r }));
}
