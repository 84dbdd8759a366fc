#!/usr/bin/env node
// Bundles the viewer: web/src/main.js -> web/dist/viewer.js (esbuild, one
// minified IIFE, no source map) and web/index.html -> web/dist/index.html.
// The output depends only on the sources and the locked packages, so CI can
// rebuild and `git diff --exit-code web/dist`. `octolod serve` embeds
// web/dist/ at compile time, so the bundle is committed.
//
//   node web/build.mjs [--check]   (--check: fail if dist/ would change)
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import * as esbuild from 'esbuild';

const web = path.dirname(fileURLToPath(import.meta.url));
const dist = path.join(web, 'dist');
const check = process.argv.includes('--check');

const result = await esbuild.build({
	absWorkingDir: web,
	entryPoints: ['src/main.js'],
	bundle: true,
	format: 'iife',
	platform: 'browser',
	target: ['chrome109', 'firefox115', 'safari16'],
	minify: true,
	legalComments: 'eof',
	sourcemap: false,
	charset: 'utf8',
	logLevel: 'warning',
	write: false,
	outfile: 'dist/viewer.js',
	define: { 'process.env.NODE_ENV': '"production"' },
});

const outputs = new Map();
for (const f of result.outputFiles) outputs.set(path.join(dist, path.basename(f.path)), Buffer.from(f.contents));
outputs.set(path.join(dist, 'index.html'), fs.readFileSync(path.join(web, 'index.html')));

let changed = [];
for (const [file, bytes] of outputs) {
	const old = fs.existsSync(file) ? fs.readFileSync(file) : null;
	if (!old || !old.equals(bytes)) changed.push(path.relative(web, file));
}
const stale = fs.existsSync(dist) ? fs.readdirSync(dist).map((n) => path.join(dist, n)).filter((f) => !outputs.has(f)) : [];
changed = changed.concat(stale.map((f) => path.relative(web, f) + ' (stale)'));
if (check) {
	if (changed.length) {
		console.error(`build: web/dist is out of date: ${changed.join(', ')} (run node web/build.mjs)`);
		process.exit(1);
	}
	console.log('build: web/dist is up to date');
} else {
	fs.mkdirSync(dist, { recursive: true });
	for (const f of stale) fs.rmSync(f, { recursive: true });
	for (const [file, bytes] of outputs) fs.writeFileSync(file, bytes);
	for (const [file, bytes] of outputs) console.log(`build: ${path.relative(web, file)} ${bytes.length} bytes`);
}
