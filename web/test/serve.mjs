#!/usr/bin/env node
// A static server for developing and testing the viewer without `octolod
// serve`: the page's files at /, a tileset directory at /tiles/.
//
//   node web/test/serve.mjs --tiles DIR [--dist web/dist] [--port 0] [--host 127.0.0.1] [--delay-ms 0]
//
// --delay-ms holds every tile response that long (a slow network, for
// testing that the page waits for its loads before it says it settled).
// Prints one JSON line {"url": "http://127.0.0.1:PORT/"} once listening, and
// serves until killed. GET and HEAD only; no directory listings; paths that
// leave the served folders are 404.
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const TYPES = {
	'.html': 'text/html; charset=utf-8',
	'.js': 'text/javascript; charset=utf-8',
	'.json': 'application/json',
	'.glb': 'model/gltf-binary',
	'.gltf': 'model/gltf+json',
	'.bin': 'application/octet-stream',
	'.png': 'image/png',
};

export function startServer({ dist, tiles, port = 0, host = '127.0.0.1', delayMs = 0 }) {
	const roots = [
		['/tiles/', path.resolve(tiles)],
		['/', path.resolve(dist)],
	];
	const server = http.createServer((req, res) => {
		if (req.method !== 'GET' && req.method !== 'HEAD') {
			res.writeHead(405, { Allow: 'GET, HEAD' }).end();
			return;
		}
		let pathname;
		try {
			pathname = decodeURIComponent(new URL(req.url, 'http://x').pathname);
		} catch {
			res.writeHead(400).end();
			return;
		}
		if (pathname === '/') pathname = '/index.html';
		const [prefix, root] = roots.find(([p]) => pathname.startsWith(p));
		const file = path.resolve(root, '.' + pathname.slice(prefix.length - 1));
		if (path.relative(root, file).startsWith('..') || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
			res.writeHead(404, { 'Content-Type': 'text/plain' }).end('not found\n');
			return;
		}
		const size = fs.statSync(file).size;
		const send = () => {
			res.writeHead(200, {
				'Content-Type': TYPES[path.extname(file).toLowerCase()] || 'application/octet-stream',
				'Content-Length': size,
				'Cache-Control': 'no-cache',
			});
			if (req.method === 'HEAD') res.end();
			else fs.createReadStream(file).pipe(res);
		};
		if (delayMs > 0 && prefix === '/tiles/') setTimeout(send, delayMs);
		else send();
	});
	return new Promise((resolve, reject) => {
		server.once('error', reject);
		server.listen(port, host, () => {
			const a = server.address();
			resolve({ server, url: `http://${host}:${a.port}/` });
		});
	});
}

if (process.argv[1] && path.resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
	const args = process.argv.slice(2);
	const opt = (name, dflt) => {
		const i = args.indexOf(name);
		return i >= 0 ? args[i + 1] : dflt;
	};
	const web = path.dirname(path.dirname(fileURLToPath(import.meta.url)));
	const tiles = opt('--tiles', null);
	if (!tiles) {
		console.error('usage: node web/test/serve.mjs --tiles DIR [--dist web/dist] [--port 0] [--host 127.0.0.1] [--delay-ms 0]');
		process.exit(2);
	}
	const { url } = await startServer({ dist: opt('--dist', path.join(web, 'dist')), tiles, port: Number(opt('--port', 0)), host: opt('--host', '127.0.0.1'), delayMs: Number(opt('--delay-ms', 0)) });
	console.log(JSON.stringify({ url }));
}
