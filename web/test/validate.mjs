#!/usr/bin/env node
// Validates a 3D Tiles directory as `octolod tiles` writes it:
//
//   node web/test/validate.mjs DIR [--schema-dir SCHEMA] [--strict] [--max-issues N]
//
// * DIR/tileset.json against the 3D Tiles 1.1 JSON schema with ajv (draft
//   2020-12). CesiumGS's 3d-tiles-validator is not on the npm registry and
//   the official schema files are in no npm package, so the schema used by
//   default is BUILTIN_SCHEMA below: the core of tileset.schema.json,
//   tile.schema.json, content.schema.json, boundingVolume.schema.json and
//   asset.schema.json (required properties, types, array lengths, ranges,
//   enums, content xor contents). `--schema-dir` (or the environment
//   variable OCTOLOD_3DTILES_SCHEMA) points at a copy of the official schema
//   folder (the specification/schema folder of the 3d-tiles repository)
//   and validates against that instead.
// * What a schema cannot say, as the 3d-tiles-validator checks it: every
//   content URI resolves to a file inside DIR (relative, no "..", no URL);
//   the root has `refine`; transforms are affine; boxes are not degenerate;
//   each tile's content (a GLB's POSITION bounds through its node
//   transforms and glTF's Y-up to Z-up rotation) lies inside the tile's
//   bounding volume (error); a child's geometricError is at most its
//   parent's and a child's box inside its parent's (warnings, as in the
//   3d-tiles-validator). External tilesets (content *.json) are followed.
// * octolod's promises when asset.extras.octolod is present (errors):
//   asset.version "1.1", `up` a unit 3-vector, `bounds` {min, max} with
//   min <= max, the root's transform a rotation taking `up` to +Z, the root
//   refine "REPLACE". Without it: one warning, "not an octolod export".
// * Every *.glb under DIR (referenced or not) with Khronos' glTF-Validator
//   (images it names by URI read beside it); a GLB no tile references is a
//   warning.
//
// Prints one JSON summary on stdout; exit 0 when there is no error (with
// --strict: no error and no warning), 1 otherwise, 2 on bad usage.
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import Ajv2020 from 'ajv/dist/2020.js';
import gltfValidator from 'gltf-validator';

const num = { type: 'number' };
const nums = (n) => ({ type: 'array', items: num, minItems: n, maxItems: n });
const rootProperty = {
	extensions: { type: 'object', additionalProperties: { type: 'object' } },
	extras: {},
};

export const BUILTIN_SCHEMA = {
	$schema: 'https://json-schema.org/draft/2020-12/schema',
	$id: 'https://octolod.invalid/3dtiles-1.1-core/tileset.schema.json',
	title: '3D Tiles 1.1 tileset (core, as in the official tileset/tile/content/boundingVolume/asset schemas)',
	type: 'object',
	required: ['asset', 'geometricError', 'root'],
	properties: {
		...rootProperty,
		asset: { $ref: '#/$defs/asset' },
		properties: { type: 'object', additionalProperties: { type: 'object' } },
		schema: { type: 'object' },
		schemaUri: { type: 'string' },
		statistics: { type: 'object' },
		groups: { type: 'array', items: { type: 'object' }, minItems: 1 },
		metadata: { type: 'object' },
		geometricError: { type: 'number', minimum: 0 },
		root: { $ref: '#/$defs/tile' },
		extensionsUsed: { type: 'array', items: { type: 'string' }, uniqueItems: true, minItems: 1 },
		extensionsRequired: { type: 'array', items: { type: 'string' }, uniqueItems: true, minItems: 1 },
	},
	not: { required: ['schema', 'schemaUri'] },
	$defs: {
		asset: {
			type: 'object',
			required: ['version'],
			properties: { ...rootProperty, version: { type: 'string' }, tilesetVersion: { type: 'string' } },
		},
		boundingVolume: {
			type: 'object',
			minProperties: 1,
			properties: {
				...rootProperty,
				box: nums(12),
				region: {
					...nums(6),
					prefixItems: [
						{ type: 'number', minimum: -Math.PI, maximum: Math.PI },
						{ type: 'number', minimum: -Math.PI / 2, maximum: Math.PI / 2 },
						{ type: 'number', minimum: -Math.PI, maximum: Math.PI },
						{ type: 'number', minimum: -Math.PI / 2, maximum: Math.PI / 2 },
						num,
						num,
					],
				},
				sphere: { ...nums(4), prefixItems: [num, num, num, { type: 'number', minimum: 0 }] },
			},
			anyOf: [{ required: ['box'] }, { required: ['region'] }, { required: ['sphere'] }, { required: ['extensions'] }],
		},
		content: {
			type: 'object',
			required: ['uri'],
			properties: {
				...rootProperty,
				boundingVolume: { $ref: '#/$defs/boundingVolume' },
				uri: { type: 'string' },
				metadata: { type: 'object' },
				group: { type: 'integer', minimum: 0 },
			},
		},
		tile: {
			type: 'object',
			required: ['boundingVolume', 'geometricError'],
			properties: {
				...rootProperty,
				boundingVolume: { $ref: '#/$defs/boundingVolume' },
				viewerRequestVolume: { $ref: '#/$defs/boundingVolume' },
				geometricError: { type: 'number', minimum: 0 },
				refine: { type: 'string' },
				transform: nums(16),
				content: { $ref: '#/$defs/content' },
				contents: { type: 'array', items: { $ref: '#/$defs/content' }, minItems: 1 },
				metadata: { type: 'object' },
				implicitTiling: { type: 'object' },
				children: { type: 'array', items: { $ref: '#/$defs/tile' }, minItems: 1 },
			},
			not: { required: ['content', 'contents'] },
		},
	},
};

// ---------------------------------------------------------------- schema

function walkFiles(dir, pred, out = []) {
	for (const e of fs.readdirSync(dir, { withFileTypes: true })) {
		const p = path.join(dir, e.name);
		if (e.isDirectory()) walkFiles(p, pred, out);
		else if (e.isFile() && pred(e.name)) out.push(p);
	}
	return out.sort();
}

function makeSchemaValidator(schemaDir) {
	const ajv = new Ajv2020({ allErrors: true, strict: false, validateFormats: false });
	if (!schemaDir) {
		return { name: 'builtin 3D Tiles 1.1 core schema (web/test/validate.mjs)', validate: ajv.compile(BUILTIN_SCHEMA) };
	}
	// The official files name themselves by base name ($id) but refer to
	// one another by relative path: key each by its path under the folder.
	const base = 'https://octolod.invalid/3dtiles-schema/';
	const files = walkFiles(schemaDir, (n) => n.endsWith('.schema.json'));
	let top = null;
	for (const f of files) {
		const rel = path.relative(schemaDir, f).split(path.sep).join('/');
		const s = JSON.parse(fs.readFileSync(f, 'utf8'));
		s.$id = base + rel;
		ajv.addSchema(s);
		if (rel === 'tileset.schema.json') top = s.$id;
	}
	if (!top) throw new Error(`${schemaDir}: no tileset.schema.json`);
	return { name: `official schema from ${schemaDir}`, validate: ajv.getSchema(top) };
}

// ---------------------------------------------------------------- maths

// 4x4 column-major matrices as arrays of 16.
const IDENTITY = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
function mul(a, b) {
	const r = new Array(16).fill(0);
	for (let c = 0; c < 4; c++) for (let rr = 0; rr < 4; rr++) for (let k = 0; k < 4; k++) r[c * 4 + rr] += a[k * 4 + rr] * b[c * 4 + k];
	return r;
}
const apply = (m, [x, y, z]) => [0, 1, 2].map((i) => m[i] * x + m[4 + i] * y + m[8 + i] * z + m[12 + i]);
const applyDir = (m, [x, y, z]) => [0, 1, 2].map((i) => m[i] * x + m[4 + i] * y + m[8 + i] * z);
const sub = (a, b) => a.map((v, i) => v - b[i]);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const len = (a) => Math.hypot(a[0], a[1], a[2]);
function trs(node) {
	if (node.matrix) return node.matrix;
	const [tx, ty, tz] = node.translation || [0, 0, 0];
	const [x, y, z, w] = node.rotation || [0, 0, 0, 1];
	const [sx, sy, sz] = node.scale || [1, 1, 1];
	return [
		(1 - 2 * (y * y + z * z)) * sx, 2 * (x * y + z * w) * sx, 2 * (x * z - y * w) * sx, 0,
		2 * (x * y - z * w) * sy, (1 - 2 * (x * x + z * z)) * sy, 2 * (y * z + x * w) * sy, 0,
		2 * (x * z + y * w) * sz, 2 * (y * z - x * w) * sz, (1 - 2 * (x * x + y * y)) * sz, 0,
		tx, ty, tz, 1,
	];
}
// glTF's Y-up to 3D Tiles' Z-up: Rx(+90°).
const Y_UP_TO_Z_UP = [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1];

// A box volume (12 numbers) in a frame `m`: centre and the three half axes.
function boxIn(m, b) {
	return { c: apply(m, b.slice(0, 3)), axes: [b.slice(3, 6), b.slice(6, 9), b.slice(9, 12)].map((a) => applyDir(m, a)) };
}
const boxCorners = ({ c, axes }) => {
	const out = [];
	for (const s0 of [-1, 1]) for (const s1 of [-1, 1]) for (const s2 of [-1, 1]) out.push([0, 1, 2].map((k) => c[k] + s0 * axes[0][k] + s1 * axes[1][k] + s2 * axes[2][k]));
	return out;
};
// How far outside the box `p` lies, in the box's units (0 inside; 0.01 =
// 1 % of a half axis beyond a face). Half axes are taken as orthogonal, as
// octolod writes them.
function outside(box, p, absTol) {
	const d = sub(p, box.c);
	let worst = 0;
	for (const a of box.axes) {
		const l = len(a);
		if (l === 0) continue;
		const t = Math.abs(dot(d, a) / l) - l - absTol;
		if (t > 0) worst = Math.max(worst, t / l);
	}
	return worst;
}

// ---------------------------------------------------------------- GLB

function readGlbJson(buf) {
	if (buf.length < 20 || buf.readUInt32LE(0) !== 0x46546c67) return null;
	const len0 = buf.readUInt32LE(12);
	if (buf.readUInt32LE(16) !== 0x4e4f534a || 20 + len0 > buf.length) return null;
	try {
		return JSON.parse(buf.subarray(20, 20 + len0).toString('utf8'));
	} catch {
		return null;
	}
}

const NORMALIZED_MAX = { 5120: 127, 5121: 255, 5122: 32767, 5123: 65535 };

// The corners of every primitive's POSITION bounds in the GLB's scene
// coordinates (node transforms applied), or null when unknown.
function glbCorners(json) {
	if (!json || !Array.isArray(json.nodes)) return null;
	const scene = (json.scenes || [])[json.scene ?? 0];
	const roots = scene ? scene.nodes || [] : json.nodes.map((_, i) => i);
	const out = [];
	const visit = (i, parent, depth) => {
		const node = json.nodes[i];
		if (!node || depth > 64) return;
		const m = mul(parent, trs(node));
		const mesh = node.mesh !== undefined ? (json.meshes || [])[node.mesh] : null;
		for (const prim of mesh ? mesh.primitives || [] : []) {
			const acc = (json.accessors || [])[prim.attributes?.POSITION];
			if (!acc || !acc.min || !acc.max) continue;
			// Normalized integers (KHR_mesh_quantization) read as v / max.
			const scale = acc.normalized ? NORMALIZED_MAX[acc.componentType] || 1 : 1;
			const [lo, hi] = [acc.min, acc.max].map((v) => v.map((c) => (scale === 1 ? c : Math.max(c / scale, -1))));
			for (const x of [lo[0], hi[0]]) for (const y of [lo[1], hi[1]]) for (const z of [lo[2], hi[2]]) out.push(apply(m, [x, y, z]));
		}
		for (const c of node.children || []) visit(c, m, depth + 1);
	};
	for (const r of roots) visit(r, IDENTITY, 0);
	return out;
}

// ---------------------------------------------------------------- tileset

function contentPath(dir, base, uri) {
	if (/^[a-z][a-z0-9+.-]*:/i.test(uri) || uri.startsWith('/')) return { error: 'is not a relative URI' };
	let decoded;
	try {
		decoded = decodeURIComponent(uri.split(/[?#]/)[0]);
	} catch {
		return { error: 'is not a valid URI' };
	}
	const p = path.resolve(base, decoded);
	const rel = path.relative(dir, p);
	if (rel.startsWith('..') || path.isAbsolute(rel)) return { error: 'points outside the directory' };
	return { path: p, rel: rel.split(path.sep).join('/') };
}

export async function validateDir(dir, { schemaDir = null, maxIssues = 20 } = {}) {
	dir = path.resolve(dir);
	const errors = [];
	const warnings = [];
	const err = (where, msg) => errors.push(`${where}: ${msg}`);
	const warn = (where, msg) => warnings.push(`${where}: ${msg}`);
	const schema = makeSchemaValidator(schemaDir);
	const referenced = new Set();
	const glbInfo = new Map(); // rel path -> parsed JSON (for bounds)
	const perDepth = new Map(); // depth -> { tiles, contents }
	let tiles = 0;
	let contents = 0;
	let octolod = null;
	let traversed = true; // false when a tileset failed its schema: references unknown
	const readJson = (file, where) => {
		try {
			return JSON.parse(fs.readFileSync(file, 'utf8'));
		} catch (e) {
			err(where, e.code === 'ENOENT' ? 'missing' : `not JSON: ${e.message}`);
			return null;
		}
	};

	const visitTileset = (file, rel, parentFrame, depth0, isRoot, seen) => {
		const ts = readJson(file, rel);
		if (!ts) {
			traversed = false;
			return;
		}
		if (!schema.validate(ts)) {
			for (const e of schema.validate.errors.slice(0, maxIssues)) err(rel, `schema: ${e.instancePath || '/'} ${e.message}${e.params && Object.keys(e.params).length ? ' ' + JSON.stringify(e.params) : ''}`);
			if (schema.validate.errors.length > maxIssues) err(rel, `schema: ${schema.validate.errors.length - maxIssues} more schema errors`);
			traversed = false;
			return;
		}
		const version = ts.asset.version;
		if (version !== '1.0' && version !== '1.1') err(rel, `asset.version ${JSON.stringify(version)} is neither "1.0" nor "1.1"`);
		if (isRoot) {
			if (!ts.root.refine) err(`${rel} root`, 'the root tile has no refine');
			if (ts.geometricError < ts.root.geometricError) warn(rel, `the tileset's geometricError ${ts.geometricError} is below the root tile's ${ts.root.geometricError}`);
			octolod = ts.asset.extras && ts.asset.extras.octolod;
			if (octolod === undefined) warn(rel, 'asset.extras.octolod is missing: not an octolod export (its checks skipped)');
			else checkOctolod(ts, rel, octolod, err, warn);
		}
		const base = path.dirname(file);
		const visitTile = (tile, where, parent, parentFrameM, parentBox, depth) => {
			tiles++;
			const d = perDepth.get(depth) || { tiles: 0, contents: 0 };
			d.tiles++;
			perDepth.set(depth, d);
			let frame = parentFrameM;
			if (tile.transform) {
				const t = tile.transform;
				if (Math.abs(t[3]) > 1e-12 || Math.abs(t[7]) > 1e-12 || Math.abs(t[11]) > 1e-12 || Math.abs(t[15] - 1) > 1e-12) err(where, 'transform is not affine (its last row is not 0 0 0 1)');
				if (!t.every(Number.isFinite)) err(where, 'transform has a non-finite number');
				frame = mul(parentFrameM, t);
			}
			const bv = tile.boundingVolume;
			let box = null;
			if (bv.box) {
				if (!bv.box.every(Number.isFinite)) err(where, 'boundingVolume.box has a non-finite number');
				box = boxIn(frame, bv.box);
				const axesLen = box.axes.map(len);
				if (axesLen.every((l) => l === 0)) err(where, 'boundingVolume.box is a point (all half axes zero)');
			} else if (bv.sphere && bv.sphere[3] < 0) {
				err(where, 'boundingVolume.sphere has a negative radius');
			}
			if (parent) {
				if (tile.geometricError > parent.geometricError) warn(where, `geometricError ${tile.geometricError} is above its parent's ${parent.geometricError}`);
			}
			if (box && parentBox) {
				const scale = Math.max(...parentBox.c.map(Math.abs), 1);
				const worst = Math.max(...boxCorners(box).map((p) => outside(parentBox, p, scale * 1e-6)));
				if (worst > 1e-3) warn(where, `its box reaches ${(worst * 100).toFixed(2)} % of a half axis outside its parent's box`);
			}
			const list = tile.contents || (tile.content ? [tile.content] : []);
			list.forEach((content, ci) => {
				const cw = list.length > 1 ? `${where} contents[${ci}]` : `${where} content`;
				const r = contentPath(dir, base, content.uri);
				if (r.error) {
					err(cw, `uri ${JSON.stringify(content.uri)} ${r.error}`);
					return;
				}
				contents++;
				d.contents++;
				if (!fs.existsSync(r.path)) {
					err(cw, `uri ${JSON.stringify(content.uri)}: ${r.rel} does not exist`);
					return;
				}
				referenced.add(r.rel);
				if (/\.json$/i.test(r.rel)) {
					if (seen.has(r.path)) {
						err(cw, `external tileset ${r.rel} refers back to itself`);
						return;
					}
					visitTileset(r.path, r.rel, frame, depth + 1, false, new Set([...seen, r.path]));
					return;
				}
				if (!/\.glb$/i.test(r.rel)) {
					warn(cw, `${r.rel} is not a .glb (not checked)`);
					return;
				}
				const json = readGlbJson(fs.readFileSync(r.path));
				glbInfo.set(r.rel, json);
				if (!json) {
					err(cw, `${r.rel} is not a GLB (bad header or JSON chunk)`);
					return;
				}
				if (!box) return;
				const corners = glbCorners(json);
				if (!corners || corners.length === 0) return;
				const upAxis = (ts.asset.gltfUpAxis || 'Y').toUpperCase();
				const toTile = upAxis === 'Z' ? IDENTITY : Y_UP_TO_Z_UP;
				const scale = Math.max(...box.c.map(Math.abs), 1);
				const worst = Math.max(...corners.map((p) => outside(box, apply(frame, apply(toTile, p)), scale * 1e-6)));
				if (worst > 1e-3) err(cw, `${r.rel}'s geometry reaches ${(worst * 100).toFixed(2)} % of a half axis outside the tile's box (its POSITION bounds through its node transforms, ${upAxis === 'Z' ? 'glTF taken as Z-up (asset.gltfUpAxis)' : "glTF's Y-up rotated to Z-up"}, then the tile transforms)`);
			});
			(tile.children || []).forEach((c, i) => visitTile(c, `${where}.children[${i}]`, tile, frame, box, depth + 1));
		};
		visitTile(ts.root, `${rel} root`, null, parentFrame, null, depth0);
	};

	const top = path.join(dir, 'tileset.json');
	visitTileset(top, 'tileset.json', IDENTITY, 0, true, new Set([top]));

	// Every GLB under DIR through glTF-Validator.
	const glbs = fs.existsSync(dir) ? walkFiles(dir, (n) => /\.glb$/i.test(n)) : [];
	const glb = { files: glbs.length, errors: 0, warnings: 0, infos: 0, hints: 0, triangles: 0, vertices: 0, unreferenced: 0, validator: gltfValidator.version(), issues: [] };
	for (const f of glbs) {
		const rel = path.relative(dir, f).split(path.sep).join('/');
		if (traversed && !referenced.has(rel)) {
			glb.unreferenced++;
			warn(rel, 'no tile refers to this GLB');
		}
		let report;
		try {
			report = await gltfValidator.validateBytes(new Uint8Array(fs.readFileSync(f)), {
				uri: rel,
				format: 'glb',
				maxIssues: maxIssues,
				writeTimestamp: false,
				// Images named by URI (a level's texture copy) beside the GLB.
				externalResourceFunction: (uri) => new Promise((ok, fail) => {
					try {
						ok(new Uint8Array(fs.readFileSync(path.resolve(path.dirname(f), decodeURIComponent(uri)))));
					} catch (e) {
						fail(String(e));
					}
				}),
			});
		} catch (e) {
			glb.errors++;
			err(rel, `glTF-Validator failed: ${e && e.message ? e.message : e}`);
			continue;
		}
		const is = report.issues;
		glb.errors += is.numErrors;
		glb.warnings += is.numWarnings;
		glb.infos += is.numInfos;
		glb.hints += is.numHints;
		glb.triangles += report.info?.totalTriangleCount || 0;
		glb.vertices += report.info?.totalVertexCount || 0;
		for (const m of is.messages) {
			if (m.severity > 1) continue; // 0 error, 1 warning, 2 info, 3 hint
			const line = `${rel}: glTF ${m.severity === 0 ? 'error' : 'warning'} ${m.code} at ${m.pointer || m.offset || '/'}: ${m.message}`;
			if (glb.issues.length < maxIssues) glb.issues.push(line);
			if (m.severity === 0) errors.push(line);
			else warnings.push(line);
		}
	}
	const depths = [...perDepth.keys()].sort((a, b) => a - b).map((k) => ({ depth: k, ...perDepth.get(k) }));
	return {
		dir,
		ok: errors.length === 0,
		errors: errors.length,
		warnings: warnings.length,
		tileset: { schema: schema.name, tiles, contents, depths, octolod: octolod || null },
		glb,
		errorMessages: errors.slice(0, 200),
		warningMessages: warnings.slice(0, 200),
	};
}

function checkOctolod(ts, rel, o, err, warn) {
	const w = `${rel} asset.extras.octolod`;
	if (ts.asset.version !== '1.1') err(rel, `asset.version is ${JSON.stringify(ts.asset.version)}, octolod writes "1.1"`);
	const vec3 = (v) => Array.isArray(v) && v.length === 3 && v.every(Number.isFinite);
	if (!o || typeof o !== 'object') {
		err(w, 'is not an object');
		return;
	}
	let up = null;
	if (!vec3(o.up)) err(w, '.up is not 3 finite numbers');
	else if (Math.abs(len(o.up) - 1) > 1e-6) err(w, `.up ${JSON.stringify(o.up)} is not a unit vector`);
	else up = o.up;
	const b = o.bounds;
	if (!b || !vec3(b.min) || !vec3(b.max)) err(w, '.bounds is not {min: [x,y,z], max: [x,y,z]}');
	else if (b.min.some((v, i) => v > b.max[i])) err(w, '.bounds has min above max');
	if (ts.root.refine !== 'REPLACE') err(`${rel} root`, `refine is ${JSON.stringify(ts.root.refine)}, octolod writes "REPLACE"`);
	const t = ts.root.transform;
	if (!t) {
		if (up && len(sub(up, [0, 0, 1])) > 1e-6) err(`${rel} root`, `has no transform but up is ${JSON.stringify(up)}, not +Z`);
		return;
	}
	const cols = [t.slice(0, 3), t.slice(4, 7), t.slice(8, 11)];
	const ortho = cols.every((c, i) => cols.every((d, j) => Math.abs(dot(c, d) - (i === j ? 1 : 0)) < 1e-6));
	const det = dot(cols[0], [cols[1][1] * cols[2][2] - cols[1][2] * cols[2][1], cols[1][2] * cols[2][0] - cols[1][0] * cols[2][2], cols[1][0] * cols[2][1] - cols[1][1] * cols[2][0]]);
	if (!ortho || det < 0) err(`${rel} root`, 'transform is not a rotation (its 3x3 part is not orthonormal with determinant +1)');
	if (up && len(sub(applyDir(t, up), [0, 0, 1])) > 1e-6) err(`${rel} root`, `transform takes up ${JSON.stringify(up)} to ${JSON.stringify(applyDir(t, up).map((v) => +v.toFixed(6)))}, not +Z`);
	const bv = ts.root.boundingVolume.box;
	if (bv && b && vec3(b.min) && vec3(b.max)) {
		const box = boxIn(IDENTITY, bv);
		const scale = Math.max(...box.c.map(Math.abs), 1);
		const corners = [];
		for (const x of [b.min[0], b.max[0]]) for (const y of [b.min[1], b.max[1]]) for (const z of [b.min[2], b.max[2]]) corners.push([x, y, z]);
		const worst = Math.max(...corners.map((p) => outside(box, p, scale * 1e-6)));
		if (worst > 1e-3) warn(w, `.bounds reach ${(worst * 100).toFixed(2)} % of a half axis outside the root box (both in model coordinates)`);
	}
}

async function main(argv) {
	const args = argv.slice(2);
	let dir = null;
	let schemaDir = process.env.OCTOLOD_3DTILES_SCHEMA || null;
	let strict = false;
	let maxIssues = 20;
	for (let i = 0; i < args.length; i++) {
		const a = args[i];
		if (a === '--schema-dir') schemaDir = args[++i];
		else if (a === '--strict') strict = true;
		else if (a === '--max-issues') maxIssues = Number(args[++i]);
		else if (a === '-h' || a === '--help') {
			console.log('usage: node web/test/validate.mjs DIR [--schema-dir SCHEMA] [--strict] [--max-issues N]');
			return 0;
		} else if (!a.startsWith('--') && dir === null) dir = a;
		else {
			console.error(`validate: unknown argument ${a}`);
			return 2;
		}
	}
	if (!dir || !(maxIssues >= 1)) {
		console.error('usage: node web/test/validate.mjs DIR [--schema-dir SCHEMA] [--strict] [--max-issues N]');
		return 2;
	}
	const summary = await validateDir(dir, { schemaDir, maxIssues });
	summary.strict = strict;
	if (strict && summary.warnings > 0) summary.ok = false;
	console.log(JSON.stringify(summary, null, 1));
	return summary.ok ? 0 : 1;
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
	main(process.argv).then(
		(code) => process.exit(code),
		(e) => {
			console.error(`validate: ${e && e.stack ? e.stack : e}`);
			process.exit(1);
		},
	);
}
