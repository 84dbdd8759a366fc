// End-to-end tests of the viewer page, shoot.mjs and validate.mjs on the
// fixture tileset of fixture.mjs (no Rust exporter needed):
//
//   node --test web/test/page.test.mjs
//
// Needs `npm ci --prefix web` and, for the browser tests, Chromium (found as
// shoot.mjs finds it; those tests are skipped, saying so, without it).
import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import test from 'node:test';
import { fileURLToPath } from 'node:url';
import zlib from 'node:zlib';
import { writeFixture } from './fixture.mjs';
import { startServer } from './serve.mjs';

const here = path.dirname(fileURLToPath(import.meta.url));
const web = path.dirname(here);
const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'octolod-web-test-'));
const chromium = [process.env.CHROMIUM, '/usr/lib/chromium/chromium', '/usr/bin/chromium', '/usr/bin/chromium-browser', '/usr/bin/google-chrome'].filter(Boolean).find((p) => fs.existsSync(p));
const noBrowser = chromium ? false : 'no Chromium (apt-get install chromium, or set CHROMIUM)';

test.after(() => fs.rmSync(tmp, { recursive: true, force: true }));

function run(script, args) {
	return new Promise((resolve) => {
		const p = spawn(process.execPath, [path.join(here, script), ...args], { stdio: ['ignore', 'pipe', 'pipe'] });
		let stdout = '';
		let stderr = '';
		p.stdout.on('data', (d) => (stdout += d));
		p.stderr.on('data', (d) => (stderr += d));
		p.on('close', (code) => resolve({ code, stdout, stderr }));
	});
}

// A PNG (8-bit RGB or RGBA, not interlaced) as {width, height, rgba}.
function readPng(file) {
	const buf = fs.readFileSync(file);
	let off = 8;
	let width = 0;
	let height = 0;
	let type = 0;
	const idat = [];
	while (off < buf.length) {
		const len = buf.readUInt32BE(off);
		const kind = buf.toString('latin1', off + 4, off + 8);
		const data = buf.subarray(off + 8, off + 8 + len);
		if (kind === 'IHDR') {
			width = data.readUInt32BE(0);
			height = data.readUInt32BE(4);
			assert.equal(data[8], 8, 'bit depth');
			type = data[9];
			assert.equal(data[12], 0, 'interlace');
		} else if (kind === 'IDAT') idat.push(data);
		off += 12 + len;
	}
	const bpp = type === 6 ? 4 : type === 2 ? 3 : assert.fail(`PNG colour type ${type}`);
	const raw = zlib.inflateSync(Buffer.concat(idat));
	const stride = width * bpp;
	const out = Buffer.alloc(width * height * 4);
	let prev = Buffer.alloc(stride);
	for (let y = 0; y < height; y++) {
		const f = raw[y * (stride + 1)];
		const line = Buffer.from(raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1)));
		for (let i = 0; i < stride; i++) {
			const a = i >= bpp ? line[i - bpp] : 0;
			const b = prev[i];
			const c = i >= bpp ? prev[i - bpp] : 0;
			let p = 0;
			if (f === 1) p = a;
			else if (f === 2) p = b;
			else if (f === 3) p = (a + b) >> 1;
			else if (f === 4) {
				const q = a + b - c;
				const pa = Math.abs(q - a);
				const pb = Math.abs(q - b);
				const pc = Math.abs(q - c);
				p = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
			}
			line[i] = (line[i] + p) & 255;
		}
		for (let x = 0; x < width; x++) {
			for (let k = 0; k < 3; k++) out[(y * width + x) * 4 + k] = line[x * bpp + k];
			out[(y * width + x) * 4 + 3] = bpp === 4 ? line[x * bpp + 3] : 255;
		}
		prev = line;
	}
	return { width, height, rgba: out };
}

const BACKGROUND = [63, 69, 80]; // octolod render's clear colour, sRGB bytes

// Foreground (non-background) pixels: their bounding box and the mean
// colour of the top and bottom tenth of the silhouette.
function silhouette(img) {
	const { width, height, rgba } = img;
	let x0 = width;
	let x1 = -1;
	let y0 = height;
	let y1 = -1;
	const fg = (x, y) => {
		const i = (y * width + x) * 4;
		return rgba[i] !== BACKGROUND[0] || rgba[i + 1] !== BACKGROUND[1] || rgba[i + 2] !== BACKGROUND[2];
	};
	for (let y = 0; y < height; y++)
		for (let x = 0; x < width; x++)
			if (fg(x, y)) {
				x0 = Math.min(x0, x);
				x1 = Math.max(x1, x);
				y0 = Math.min(y0, y);
				y1 = Math.max(y1, y);
			}
	const band = (ya, yb) => {
		const s = [0, 0, 0];
		let n = 0;
		for (let y = ya; y <= yb; y++)
			for (let x = 0; x < width; x++)
				if (fg(x, y)) {
					for (let k = 0; k < 3; k++) s[k] += rgba[(y * width + x) * 4 + k];
					n++;
				}
		return s.map((v) => v / Math.max(n, 1));
	};
	const h = y1 - y0;
	return { x0, x1, y0, y1, top: band(y0, y0 + Math.floor(h / 10)), bottom: band(y1 - Math.floor(h / 10), y1), corner: [...rgba.subarray(0, 3)] };
}

// Where a model point lands in a W x H frame (octolod's look_at, fov_y).
function project(eye, target, up, fovDeg, w, h, p) {
	const sub = (a, b) => a.map((v, i) => v - b[i]);
	const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
	const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
	const norm = (a) => a.map((v) => v / Math.hypot(...a));
	const f = norm(sub(target, eye));
	const s = norm(cross(f, up));
	const u = cross(s, f);
	const d = sub(p, eye);
	const t = Math.tan((fovDeg * Math.PI) / 360);
	return [w / 2 + (dot(d, s) / (dot(d, f) * t)) * (h / 2), h / 2 - (dot(d, u) / (dot(d, f) * t)) * (h / 2)];
}

const yDir = path.join(tmp, 'y');
const zDir = path.join(tmp, 'z');
const OFFSET = [1000, 2000, 50];
writeFixture(yDir, { up: 'y' });
writeFixture(zDir, { up: 'z', offset: OFFSET });

// The same view of both fixtures: Rx(+90°) takes the Y-up one onto the
// Z-up one (before the offset), so the bump's tip lands on the same pixel.
const rx = ([x, y, z]) => [x, -z, y];
const plus = (a, b) => a.map((v, i) => v + b[i]);
const FAR = { eye: [2.6, 1.3, 3.4], target: [0, 0.25, 0] };
const NEAR = { eye: [0.5, 1.9, 0.9], target: [0, 1.2, 0] };
const TIP = [0, 1.5, 0];
const yPath = { fov_y_deg: 50, up: [0, 1, 0], frames: [FAR, NEAR, FAR] };
const zPath = { fov_y_deg: 50, up: [0, 0, 1], frames: [FAR, NEAR, FAR].map((p) => ({ eye: plus(rx(p.eye), OFFSET), target: plus(rx(p.target), OFFSET) })) };

test('validate.mjs passes the fixtures and reports broken ones', async () => {
	for (const dir of [yDir, zDir]) {
		const r = await run('validate.mjs', [dir, '--strict']);
		assert.equal(r.code, 0, r.stdout + r.stderr);
		const s = JSON.parse(r.stdout);
		assert.equal(s.tileset.tiles, 65);
		assert.equal(s.glb.files, 65);
		assert.equal(s.glb.errors, 0);
	}
	const broken = (name, edit) => {
		const dir = path.join(tmp, name);
		fs.cpSync(yDir, dir, { recursive: true });
		const file = path.join(dir, 'tileset.json');
		const ts = JSON.parse(fs.readFileSync(file, 'utf8'));
		edit(ts, dir);
		fs.writeFileSync(file, JSON.stringify(ts));
		return dir;
	};
	const cases = [
		[broken('no-rotation', (ts) => (ts.root.transform = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1])), /takes up \[0,1,0\] to \[0,1,0\], not \+Z/],
		[broken('z-up-content', (ts) => (ts.asset.gltfUpAxis = 'Z')), /outside the tile's box/],
		[broken('missing', (ts, dir) => fs.rmSync(path.join(dir, ts.root.children[0].content.uri))), /does not exist/],
		[broken('schema', (ts) => delete ts.root.geometricError), /schema: \/root must have required property 'geometricError'/],
		[broken('escape', (ts) => (ts.root.content.uri = '../y/t/0-0-0-0.glb')), /points outside the directory/],
	];
	for (const [dir, re] of cases) {
		const r = await run('validate.mjs', [dir]);
		assert.equal(r.code, 1, `${dir}: ${r.stdout}`);
		assert.match(JSON.parse(r.stdout).errorMessages.join('\n'), re);
	}
});

test('the page opens upright, projects exactly, settles the same under latency, and fails loudly', { skip: noBrowser }, async (t) => {
	const fast = await startServer({ dist: path.join(web, 'dist'), tiles: yDir });
	const slow = await startServer({ dist: path.join(web, 'dist'), tiles: yDir, delayMs: 150 });
	const zup = await startServer({ dist: path.join(web, 'dist'), tiles: zDir });
	t.after(() => [fast, slow, zup].forEach((s) => s.server.close()));
	const cams = (name, p) => {
		const f = path.join(tmp, name);
		fs.writeFileSync(f, JSON.stringify(p));
		return f;
	};
	const shoot = async (url, camFile, out, extra = []) => {
		const r = await run('shoot.mjs', ['--url', url, '--cameras', camFile, '--out', path.join(tmp, out), '--chromium', chromium, '--timeout-ms', '60000', ...extra]);
		const report = JSON.parse(fs.readFileSync(path.join(tmp, out, 'browser.json'), 'utf8'));
		return { ...r, report, frame: (i) => path.join(tmp, out, `frame-${String(i).padStart(5, '0')}.png`) };
	};

	const a = await shoot(fast.url, cams('y.json', yPath), 'y-fast', ['--error-target', '4']);
	assert.equal(a.code, 0, a.stderr);
	assert.deepEqual(a.report.failures, []);
	assert.deepEqual(a.report.model.worldUp, [0, 1, 0], 'the model is not upright for orbiting');
	assert.equal(a.report.frames.length, 3);
	for (const f of a.report.frames) {
		assert.equal(f.settled, true);
		assert.ok(f.settleMs >= 0 && f.triangles > 0 && f.tilesVisible > 0 && f.bytesFetched > 0);
		assert.ok(f.maxErrorPx <= 4 + 1e-9, `frame ${f.index}: ${f.maxErrorPx} px on screen over the 4 px target`);
	}
	// Far: the 8 octant tiles (depth 1) meet 4 px; near: the 64-cell level.
	assert.deepEqual(a.report.frames[0].depths, [1]);
	assert.deepEqual(a.report.frames[1].depths, [2]);
	assert.ok(a.report.frames[1].bytesFetchedFrame > 0);
	assert.ok(!a.report.console.some((m) => m.type === 'error'));

	const img = readPng(a.frame(0));
	assert.equal(img.width, 640);
	assert.equal(img.height, 480);
	const s = silhouette(img);
	assert.deepEqual(s.corner, BACKGROUND);
	const [tx, ty] = project(FAR.eye, FAR.target, [0, 1, 0], 50, 640, 480, TIP);
	assert.ok(Math.abs(s.y0 - ty) <= 1.01, `the tip is drawn at row ${s.y0}, projected at ${ty.toFixed(2)}`);
	assert.ok(s.x0 < tx && tx < s.x1);
	assert.ok(s.top[0] > s.top[2] + 40, `top of the silhouette is not red: ${s.top}`);
	assert.ok(s.bottom[2] > s.bottom[0] + 40, `bottom of the silhouette is not blue: ${s.bottom}`);
	// The same pose twice in one run: the same bytes.
	assert.ok(fs.readFileSync(a.frame(0)).equals(fs.readFileSync(a.frame(2))));

	// colors=srgb decodes COLOR_0 as sRGB: the same silhouette, darker.
	assert.equal(a.report.model.colors, 'linear');
	const e = await shoot(`${fast.url}?colors=srgb`, cams('y1.json', { ...yPath, frames: [FAR] }), 'y-srgb', ['--error-target', '4']);
	assert.equal(e.code, 0, e.stderr);
	assert.equal(e.report.model.colors, 'srgb');
	const se = silhouette(readPng(e.frame(0)));
	assert.deepEqual([se.x0, se.x1, se.y0, se.y1], [s.x0, s.x1, s.y0, s.y1]);
	assert.ok(se.top[0] < s.top[0] - 5 && se.bottom[2] < s.bottom[2] - 5, `sRGB-decoded colours are not darker: ${se.top} ${se.bottom}`);

	// 150 ms per tile response: settled() waits for the loads, and the
	// frames are byte-identical to those of the fast server.
	const b = await shoot(slow.url, cams('y.json', yPath), 'y-slow', ['--error-target', '4']);
	assert.equal(b.code, 0, b.stderr);
	for (let i = 0; i < 3; i++) assert.ok(fs.readFileSync(a.frame(i)).equals(fs.readFileSync(b.frame(i))), `frame ${i} differs under latency`);
	assert.ok(b.report.frames[1].settleMs >= 150, 'the near frame needed a new level: at least one slow response');

	// Z-up model far from the origin, identity root transform: the same
	// picture up to tessellation, tip on the same row.
	const c = await shoot(zup.url, cams('z.json', zPath), 'z', ['--error-target', '4']);
	assert.equal(c.code, 0, c.stderr);
	assert.deepEqual(c.report.model.worldUp, [0, 1, 0]);
	const sz = silhouette(readPng(c.frame(0)));
	assert.ok(Math.abs(sz.y0 - ty) <= 1.01, `z-up: the tip is drawn at row ${sz.y0}, projected at ${ty.toFixed(2)}`);
	assert.ok(sz.top[0] > sz.top[2] + 40 && sz.bottom[2] > sz.bottom[0] + 40);

	// A missing tile: HTTP 404 and the renderer's console error fail the run.
	const gone = path.join(tmp, 'gone');
	fs.cpSync(yDir, gone, { recursive: true });
	fs.rmSync(path.join(gone, 't', '1-0-0-0.glb'));
	const broken = await startServer({ dist: path.join(web, 'dist'), tiles: gone });
	t.after(() => broken.server.close());
	const d = await shoot(broken.url, cams('y.json', yPath), 'gone', ['--error-target', '4']);
	assert.equal(d.code, 1);
	assert.ok(d.report.failures.some((f) => /HTTP 404/.test(f)));
	assert.ok(d.report.failures.some((f) => /console error/.test(f)));
});
