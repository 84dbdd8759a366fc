#!/usr/bin/env node
// Drives the viewer page in real headless Chromium and takes one settled
// screenshot per camera pose:
//
//   node web/test/shoot.mjs --url URL --cameras CAMERAS.json --out DIR
//       [--chromium PATH] [--width 640 --height 480]
//       [--error-target 16] [--timeout-ms 120000] [--ready-timeout-ms 60000]
//       [--page]
//
// --page: each frame is a screenshot of the whole page (the overlay and
// its controls included), for documentation; by default the canvas alone.
//
// --chromium defaults to $CHROMIUM, else the first that exists of
// /usr/lib/chromium/chromium (the binary behind Debian's /usr/bin/chromium
// wrapper script, which adds flags of its own), /usr/bin/chromium,
// /usr/bin/chromium-browser, /usr/bin/google-chrome.
// URL is the page (e.g. `octolod serve`'s http://127.0.0.1:PORT/, or with
// ?tileset=...). CAMERAS.json is octolod's camera path format, model
// coordinates: {"fov_y_deg": 50, "up": [0,1,0], "frames": [{"eye": [..],
// "target": [..]}, ...]}; like `octolod render` it also takes "keyframes"
// with "frames_between" (default 10), "hold", and "space": "bbox" (0..1 over
// the model's bounds); without "up" the model's up axis is used.
//
// Chromium runs headless with `--headless=new --no-sandbox
// --use-angle=swiftshader --enable-unsafe-swiftshader` (WebGL2 on the CPU;
// no sandbox because CI runs as root), a WIDTHxHEIGHT window and viewport at
// device scale factor 1, through puppeteer-core (the system's chromium; no
// browser is downloaded). For each pose: window.octolod.setCamera(pose and
// size), wait until window.octolod.settled() (fails after --timeout-ms),
// then window.octolod.capture() (the canvas alone, drawn in that state) is
// written as DIR/frame-00000.png, ... .
//
// DIR/browser.json: the command line, Chromium's version and arguments, per
// frame the page's statistics (tiles loaded and drawn, triangles, bytes
// fetched in all and for that frame, settle time, the tile depths drawn and
// how many tiles at each, the largest screen-space error on screen), and
// every console message, page error, failed request and HTTP error.
//
// Exit status: 0 when every frame settled and was written; 1 on any console
// error, page error, failed request (a request the page itself aborts,
// net::ERR_ABORTED, is listed but allowed: 3DTilesRendererJS cancels tiles
// it no longer needs), HTTP status >= 400, timeout or load error; 2 on bad
// usage. browser.json is written in every case.
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import puppeteer from 'puppeteer-core';

export const CHROMIUM_FLAGS = ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'];

const USAGE =
	'usage: node web/test/shoot.mjs --url URL --cameras CAMERAS.json --out DIR [--chromium PATH] [--width 640 --height 480] [--error-target 16] [--timeout-ms 120000] [--ready-timeout-ms 60000]';

function parseArgs(argv) {
	const o = { width: 640, height: 480, errorTarget: 16, timeoutMs: 120000, readyTimeoutMs: 60000, chromium: null, page: false };
	const names = {
		'--url': 'url',
		'--cameras': 'cameras',
		'--out': 'out',
		'--chromium': 'chromium',
		'--width': 'width',
		'--height': 'height',
		'--error-target': 'errorTarget',
		'--timeout-ms': 'timeoutMs',
		'--ready-timeout-ms': 'readyTimeoutMs',
	};
	const numeric = new Set(['width', 'height', 'errorTarget', 'timeoutMs', 'readyTimeoutMs']);
	for (let i = 0; i < argv.length; i++) {
		if (argv[i] === '--page') {
			o.page = true;
			continue;
		}
		const k = names[argv[i]];
		if (!k || i + 1 >= argv.length) throw new Error(`unknown or incomplete argument ${argv[i]}`);
		const v = argv[++i];
		o[k] = numeric.has(k) ? Number(v) : v;
		if (numeric.has(k) && !(o[k] > 0 && Number.isFinite(o[k]))) throw new Error(`${argv[i - 1]} must be a positive number, not ${v}`);
	}
	for (const k of ['url', 'cameras', 'out']) if (!o[k]) throw new Error(`--${k} is required`);
	if (!Number.isInteger(o.width) || !Number.isInteger(o.height)) throw new Error('--width and --height must be integers');
	if (!o.chromium) {
		// Debian's /usr/bin/chromium is a shell script that adds flags of its
		// own (GPU rasterization, extensions): start the binary behind it.
		const candidates = [process.env.CHROMIUM, '/usr/lib/chromium/chromium', '/usr/bin/chromium', '/usr/bin/chromium-browser', '/usr/bin/google-chrome'].filter(Boolean);
		o.chromium = candidates.find((p) => fs.existsSync(p)) || '/usr/bin/chromium';
	}
	return o;
}

// octolod's camera path file (src/view/camera.rs, CameraPath::parse) ->
// poses {eye, target} in model coordinates, fov and up.
export function expandCameraPath(file, bounds, modelUp) {
	const f = typeof file === 'string' ? JSON.parse(file) : file;
	const fov = f.fov_y_deg ?? 50;
	if (!(fov >= 1 && fov <= 170)) throw new Error(`fov_y_deg ${fov} is outside 1..170`);
	const space = f.space ?? 'world';
	if (space !== 'world' && space !== 'bbox') throw new Error(`space must be "world" or "bbox", not ${JSON.stringify(space)}`);
	const vec = (p, what) => {
		if (!Array.isArray(p) || p.length !== 3 || !p.every(Number.isFinite)) throw new Error(`${what} is not 3 finite numbers`);
		if (space === 'world') return p.slice();
		const ext = [0, 1, 2].map((k) => bounds.max[k] - bounds.min[k]);
		const m = Math.max(...ext) * 1e-3;
		return [0, 1, 2].map((k) => bounds.min[k] + p[k] * Math.max(ext[k], m));
	};
	const pose = (p, i) => {
		const eye = vec(p.eye, `frame ${i}: eye`);
		const target = vec(p.target, `frame ${i}: target`);
		if (eye.every((v, k) => v === target[k])) throw new Error(`frame ${i}: eye equals target`);
		return { eye, target };
	};
	let poses;
	if (Array.isArray(f.frames)) poses = f.frames.map(pose);
	else if (Array.isArray(f.keyframes)) {
		const keys = f.keyframes.map(pose);
		const between = Math.max(1, Math.floor(f.frames_between ?? 10));
		poses = [];
		for (let i = 0; i + 1 < keys.length; i++) {
			for (let s = 0; s < between; s++) {
				const t = s / between;
				const lerp = (a, b) => a.map((v, k) => v + (b[k] - v) * t);
				poses.push({ eye: lerp(keys[i].eye, keys[i + 1].eye), target: lerp(keys[i].target, keys[i + 1].target) });
			}
		}
		if (keys.length) poses.push(keys[keys.length - 1]);
	} else throw new Error('needs "frames" or "keyframes"');
	if (!poses.length) throw new Error('the path has no frames');
	const hold = Math.max(0, Math.floor(f.hold ?? 0));
	for (let i = 0; i < hold; i++) poses.push(poses[poses.length - 1]);
	let up = modelUp;
	if (Array.isArray(f.up)) {
		const l = Math.hypot(...f.up);
		if (l > 0 && Number.isFinite(l)) up = f.up.map((v) => v / l);
	}
	return { fovYDeg: fov, up, poses };
}

const pad = (i) => String(i).padStart(5, '0');

async function main() {
	let opts;
	try {
		opts = parseArgs(process.argv.slice(2));
	} catch (e) {
		console.error(`shoot: ${e.message}\n${USAGE}`);
		return 2;
	}
	let pathFile;
	try {
		pathFile = JSON.parse(fs.readFileSync(opts.cameras, 'utf8'));
		expandCameraPath(pathFile, { min: [0, 0, 0], max: [1, 1, 1] }, [0, 0, 1]); // syntax check before launching
	} catch (e) {
		console.error(`shoot: ${opts.cameras}: ${e.message}`);
		return 2;
	}
	fs.mkdirSync(opts.out, { recursive: true });

	const report = {
		command: process.argv.slice(1),
		url: opts.url,
		cameras: path.resolve(opts.cameras),
		width: opts.width,
		height: opts.height,
		errorTarget: opts.errorTarget,
		chromium: { path: opts.chromium, version: null, args: null },
		ok: false,
		failures: [],
		frames: [],
		console: [],
		pageErrors: [],
		failedRequests: [],
		abortedRequests: [],
		httpErrors: [],
		timing: {},
	};
	const fail = (msg) => {
		report.failures.push(msg);
		console.error(`shoot: ${msg}`);
	};
	const writeReport = () => fs.writeFileSync(path.join(opts.out, 'browser.json'), JSON.stringify(report, null, 1) + '\n');

	const t0 = Date.now();
	let browser = null;
	try {
		browser = await puppeteer.launch({
			executablePath: opts.chromium,
			headless: true, // puppeteer passes --headless=new (and --hide-scrollbars --mute-audio)
			args: [...CHROMIUM_FLAGS, `--window-size=${opts.width},${opts.height}`, '--force-device-scale-factor=1'],
			defaultViewport: { width: opts.width, height: opts.height, deviceScaleFactor: 1 },
			timeout: 60000,
			protocolTimeout: Math.max(180000, opts.timeoutMs * 2),
		});
		report.chromium.version = await browser.version();
		report.chromium.args = browser.process() ? browser.process().spawnargs.slice(1) : null;
		report.timing.launchMs = Date.now() - t0;

		const page = await browser.newPage();
		await page.setViewport({ width: opts.width, height: opts.height, deviceScaleFactor: 1 });
		page.on('console', (m) => {
			const loc = m.location();
			const entry = { type: m.type(), text: m.text(), url: loc && loc.url ? `${loc.url}:${loc.lineNumber ?? ''}` : undefined, atMs: Date.now() - t0 };
			report.console.push(entry);
			if (entry.type === 'error' || entry.type === 'assert') fail(`console ${entry.type}: ${entry.text}${entry.url ? ` (${entry.url})` : ''}`);
		});
		page.on('pageerror', (e) => {
			report.pageErrors.push(String(e && e.stack ? e.stack : e));
			fail(`page error: ${e && e.message ? e.message : e}`);
		});
		page.on('requestfailed', (r) => {
			const f = r.failure();
			const entry = { url: r.url(), method: r.method(), error: f ? f.errorText : 'unknown' };
			if (entry.error === 'net::ERR_ABORTED') report.abortedRequests.push(entry);
			else {
				report.failedRequests.push(entry);
				fail(`request failed: ${entry.method} ${entry.url}: ${entry.error}`);
			}
		});
		page.on('response', (r) => {
			if (r.status() >= 400) {
				report.httpErrors.push({ url: r.url(), status: r.status() });
				fail(`HTTP ${r.status()} for ${r.url()}`);
			}
		});

		const tLoad = Date.now();
		await page.goto(opts.url, { waitUntil: 'load', timeout: opts.readyTimeoutMs });
		await page.waitForFunction(() => Boolean(window.octolod), { timeout: opts.readyTimeoutMs });
		const info = await page.evaluate(
			(ms) =>
				Promise.race([
					window.octolod.ready.then((v) => ({ ok: true, v }), (e) => ({ ok: false, error: String(e && e.message ? e.message : e) })),
					new Promise((res) => setTimeout(() => res({ ok: false, error: `window.octolod.ready did not resolve within ${ms} ms` }), ms)),
				]),
			opts.readyTimeoutMs,
		);
		report.timing.readyMs = Date.now() - tLoad;
		if (!info.ok) throw new Error(info.error);
		report.model = info.v;
		const webgl = await page.evaluate(() => {
			const gl = document.getElementById('view').getContext('webgl2');
			const dbg = gl && gl.getExtension('WEBGL_debug_renderer_info');
			return gl ? { version: gl.getParameter(gl.VERSION), renderer: dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER) } : null;
		});
		report.webgl = webgl;

		const cams = expandCameraPath(pathFile, info.v.bounds, info.v.up);
		report.fovYDeg = cams.fovYDeg;
		report.up = cams.up;
		await page.evaluate((px) => window.octolod.setErrorTarget(px), opts.errorTarget);

		let prevBytes = null;
		for (let i = 0; i < cams.poses.length; i++) {
			if (report.failures.length) break;
			const pose = cams.poses[i];
			const ts = Date.now();
			const before = await page.evaluate(
				(c) => {
					window.octolod.setCamera(c);
					return window.octolod.stats();
				},
				{ ...pose, up: cams.up, fovYDeg: cams.fovYDeg, width: opts.width, height: opts.height },
			);
			if (prevBytes === null) prevBytes = before.bytesFetched;
			try {
				await page.waitForFunction(() => window.octolod.settled() || window.octolod.stats().loadErrors.length > 0, { polling: 'raf', timeout: opts.timeoutMs });
			} catch (e) {
				const s = await page.evaluate(() => window.octolod.stats()).catch(() => null);
				fail(`frame ${i}: not settled after ${opts.timeoutMs} ms (${s ? `${s.queued} queued, ${s.downloading} downloading, ${s.parsing} parsing, ${s.refused} refused, ${s.tilesVisible} drawn` : 'no stats'})`);
				report.frames.push({ index: i, ...pose, settled: false, stats: s });
				break;
			}
			const settleMs = Date.now() - ts;
			const s = await page.evaluate(() => window.octolod.stats());
			if (s.loadErrors.length) {
				fail(`frame ${i}: load errors: ${s.loadErrors.map((e) => `${e.url}: ${e.message}`).join('; ')}`);
				break;
			}
			const tc = Date.now();
			let png;
			if (opts.page) {
				// The overlay refreshes every 250 ms: let it show the settled state.
				await new Promise((r) => setTimeout(r, 400));
				png = Buffer.from(await page.screenshot({ type: 'png', captureBeyondViewport: false }));
			} else {
				const dataUrl = await page.evaluate(() => window.octolod.capture());
				png = Buffer.from(dataUrl.slice(dataUrl.indexOf(',') + 1), 'base64');
			}
			const file = `frame-${pad(i)}.png`;
			fs.writeFileSync(path.join(opts.out, file), png);
			const captureMs = Date.now() - tc;
			report.frames.push({
				index: i,
				file,
				eye: pose.eye,
				target: pose.target,
				settled: true,
				settleMs,
				captureMs,
				tilesLoaded: s.tilesLoaded,
				tilesVisible: s.tilesVisible,
				triangles: s.triangles,
				drawCalls: s.drawCalls,
				bytesFetched: s.bytesFetched,
				bytesFetchedFrame: s.bytesFetched - prevBytes,
				requests: s.requests,
				depths: Object.keys(s.depths).map(Number).sort((a, b) => a - b),
				tilesPerDepth: s.depths,
				maxErrorPx: s.maxErrorPx,
				errorTarget: s.errorTarget,
				sharedTextures: s.sharedTextures,
				width: s.width,
				height: s.height,
			});
			prevBytes = s.bytesFetched;
			if (s.width !== opts.width || s.height !== opts.height) fail(`frame ${i}: the canvas is ${s.width}x${s.height}, not ${opts.width}x${opts.height}`);
		}
		// Late console errors (after the last frame) still count.
		await new Promise((r) => setTimeout(r, 50));
	} catch (e) {
		fail(e && e.message ? e.message : String(e));
	} finally {
		report.timing.totalMs = Date.now() - t0;
		const shot = report.frames.filter((f) => f.settled).length;
		report.ok = report.failures.length === 0 && shot > 0;
		if (browser) await browser.close().catch(() => {});
		writeReport();
		console.log(
			JSON.stringify({
				ok: report.ok,
				frames: shot,
				out: opts.out,
				meanSettleMs: shot ? Math.round(report.frames.filter((f) => f.settled).reduce((a, f) => a + f.settleMs, 0) / shot) : null,
				failures: report.failures.length,
			}),
		);
	}
	return report.ok ? 0 : 1;
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
	main().then(
		(code) => process.exit(code),
		(e) => {
			console.error(`shoot: ${e && e.stack ? e.stack : e}`);
			process.exit(1);
		},
	);
}
