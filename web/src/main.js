/**
 * octolod's browser viewer for the 3D Tiles that `octolod tiles` exports
 * (served by `octolod serve` at `/`, the tileset at `/tiles/tileset.json`).
 *
 * URL parameters:
 *   tileset=URL    the tileset to open (default /tiles/tileset.json)
 *   error=PX       the initial error target in pixels (default 16)
 *   overlay=0      no statistics overlay
 *   bg=RRGGBB      another background (sRGB hex)
 *   materials=gltf keep the GLBs' own materials (default: octolod's shading)
 *   colors=srgb    vertex colours (COLOR_0) hold sRGB-encoded values, as
 *                  octolod's own colour bytes are: decode them per fragment
 *                  (as octolod's shader does); colors=linear: glTF's rule.
 *                  Default: asset.extras.octolod.color_encoding ("srgb" or
 *                  "linear") when the tileset says, else linear.
 *
 * Frames. The tileset is Z-up (3D Tiles): its root `transform` rotates the
 * model's up axis (`asset.extras.octolod.up`, model coordinates) to +Z,
 * and 3DTilesRendererJS turns each GLB's glTF Y-up content to Z-up. The
 * tiles group is rotated -90° about X (Z-up to three.js' Y-up) and moved so
 * the centre of the model's bounds (`asset.extras.octolod.bounds`, else the
 * root box) sits at the origin (keeps float32 vertices near zero). So with
 * T the root transform and G the group's matrix, a model point p is drawn
 * at G·T·p, and the model's up axis is screen-up. Without the octolod
 * extras, up is T⁻¹·Z.
 *
 * Opening: the model's bounds are framed like `octolod view` frames them
 * (looking slightly down along a diagonal, the bounding sphere filling the
 * narrower field of view); near and far planes follow octolod's fit_clip
 * (far past the farthest corner of the bounds, near at the nearest point).
 * Orbit, pan and zoom: three.js' OrbitControls (left drag orbits about the
 * up axis, right drag or shift-drag pans, the wheel zooms).
 *
 * Pixels. The background is linear RGB (0.05, 0.06, 0.08), which is sRGB
 * #3F4550, bytes (63, 69, 80): exactly `octolod render`'s background, so the
 * background fraction of a frame means the same in both. No anti-aliasing,
 * no tone mapping, sRGB output. Shading replaces the GLBs' materials with
 * octolod's (`octolod view` and `render`, src/view/headless.rs draw_params):
 * Lambert, linear ambient 0.25 plus 0.75 of a directional light that moves
 * with the camera, from over the viewer's right shoulder (towards the light:
 * 0.35 right + 0.5 up - 0.8 forward, normalized); vertex colours (glTF COLOR_0:
 * linear, or sRGB-encoded with colors=srgb) times the base colour;
 * single-sided unless the GLB's material is doubleSided (glTF's default
 * culls back faces, where octolod's own renderer is always two-sided).
 * A base colour texture is kept (times the vertex colours). Textures that
 * octolod names (`texture-0-SIDE`: each level's copy, one file for every
 * tile of the level) are shared: the first tile's texture and material
 * serve every later tile naming the same image, so the GPU holds each
 * copy once, not once per tile.
 * Cameras whose view direction is parallel to their up vector get the up
 * vector octolod's camera picks then (glam's any_orthonormal_vector), so
 * such views are oriented as in `octolod render`.
 *
 * Overlay: tiles loaded and drawn, triangles drawn (renderer.info), bytes
 * fetched (every response body is counted by a fetch plugin), frames drawn
 * per second (the page draws only when something changed), the error target
 * and the largest screen-space error on screen, loading state, and a
 * "max error px" control bound to `tiles.errorTarget`.
 *
 * Scripting API for tests, `window.octolod`:
 *   ready: Promise      resolves ({up, bounds, transform, url, worldUp,
 *                       colors}) when the root tileset is loaded and a first
 *                       frame drawn (worldUp: the model's up in three.js
 *                       coordinates, [0, 1, 0]; colors: "linear" or "srgb");
 *                       rejects when the root tileset cannot be loaded.
 *   setCamera({eye, target, up, fovYDeg, width, height})
 *                       a camera in MODEL coordinates (the page applies G·T);
 *                       width/height (optional) fix the canvas to that many
 *                       pixels at device pixel ratio 1.
 *   settled(): boolean  true when, for the current camera and error target,
 *                       the root is loaded, no tile is queued, downloading or
 *                       parsing, no download/parse/child-preprocessing queue
 *                       is running, the cache refused nothing, the last
 *                       SETTLE_FRAMES (3) tile updates changed no tile's
 *                       visibility and loaded or disposed no model, and the
 *                       frame on the canvas was drawn after the last change.
 *   stats(): object     see `stats()` below.
 *   setErrorTarget(px)  sets tiles.errorTarget (and the overlay control).
 *   capture(): string   draws the current state and returns the canvas as a
 *                       PNG data URL (only the 3D view, no overlay).
 *
 * The page logs no console errors in normal use: a tile or tileset that
 * fails to load is an error (3DTilesRendererJS logs it), warnings are not
 * (3DTilesRendererJS warns that 1.1 tilesets have "limited support").
 */
import {
	AmbientLight,
	Color,
	DirectionalLight,
	DoubleSide,
	FrontSide,
	LinearSRGBColorSpace,
	Matrix4,
	MeshLambertMaterial,
	PerspectiveCamera,
	Scene,
	SRGBColorSpace,
	Vector2,
	Vector3,
	WebGLRenderer,
} from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { MeshoptDecoder } from 'three/examples/jsm/libs/meshopt_decoder.module.js';
import { TilesRenderer } from '3d-tiles-renderer/three';
import { GLTFExtensionsPlugin } from '3d-tiles-renderer/three/plugins';

const SETTLE_FRAMES = 3;
const AMBIENT = 0.25;
const CLEAR_LINEAR = [0.05, 0.06, 0.08];

const params = new URLSearchParams(window.location.search);
const tilesetUrl = params.get('tileset') || '/tiles/tileset.json';
const initialError = Number(params.get('error')) > 0 ? Number(params.get('error')) : 16;
const showOverlay = params.get('overlay') !== '0';
const keepMaterials = params.get('materials') === 'gltf';
const colorsParam = params.get('colors');
let srgbColors = colorsParam === 'srgb'; // settled once the root tileset is read

// ------------------------------------------------------------------ scene

const canvas = document.getElementById('view');
const renderer = new WebGLRenderer({ canvas, antialias: false, alpha: false, powerPreference: 'high-performance' });
renderer.outputColorSpace = SRGBColorSpace;
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setSize(window.innerWidth, window.innerHeight, false);
const bg = params.get('bg');
if (bg && /^[0-9a-fA-F]{6}$/.test(bg)) renderer.setClearColor(new Color().setStyle('#' + bg, SRGBColorSpace), 1);
else renderer.setClearColor(new Color().setRGB(...CLEAR_LINEAR, LinearSRGBColorSpace), 1);

const scene = new Scene();
const camera = new PerspectiveCamera(50, window.innerWidth / Math.max(1, window.innerHeight), 0.01, 100);
// Physically based light units: Lambert's diffuse is colour·E/π, so an
// intensity of k·π gives the fraction k.
scene.add(new AmbientLight(0xffffff, AMBIENT * Math.PI));
// octolod's light, in camera space (x right, y up, -z forward): it shines
// from (0.35, 0.5, 0.8) towards the eye.
const light = new DirectionalLight(0xffffff, (1 - AMBIENT) * Math.PI);
light.position.set(0.35, 0.5, 0.8);
camera.add(light);
camera.add(light.target);
scene.add(camera);

const tiles = new TilesRenderer(tilesetUrl);
tiles.errorTarget = initialError;
tiles.registerPlugin(new GLTFExtensionsPlugin({ meshoptDecoder: MeshoptDecoder }));

// Every response body the tiles renderer fetches, counted.
const net = { requests: 0, bytes: 0, failed: 0, inFlight: 0 };
tiles.registerPlugin({
	name: 'OCTOLOD_FETCH_COUNTER',
	fetchData(url, options) {
		net.requests++;
		net.inFlight++;
		return fetch(url, options)
			.then(async (res) => {
				const body = await res.arrayBuffer();
				net.bytes += body.byteLength;
				if (!res.ok) net.failed++;
				return new Response(body, { status: res.status, statusText: res.statusText, headers: res.headers });
			})
			.finally(() => {
				net.inFlight--;
			});
	},
});

// octolod's per-level texture copies are shared by the tiles of a level and
// kept for the session (see octolodMaterial): no tile's cache entry owns
// one. The tiles renderer charges every tile with the whole image it names,
// so a few tiles of a 4096² atlas would fill its cache; that charge is
// taken back here.
tiles.registerPlugin({
	name: 'OCTOLOD_SHARED_TEXTURE_BYTES',
	calculateBytesUsed(tile, model) {
		if (!model) return 0;
		const seen = new Set();
		let bytes = 0;
		model.traverse((c) => {
			for (const m of Array.isArray(c.material) ? c.material : c.material ? [c.material] : []) {
				for (const key in m) {
					const t = m[key];
					if (t && t.isTexture && t.image && sharedName.test(t.name) && !seen.has(t)) {
						seen.add(t);
						bytes += t.image.width * t.image.height * 4 * (t.generateMipmaps ? 4 / 3 : 1);
					}
				}
			}
		});
		return -bytes;
	},
});

tiles.setCamera(camera);
scene.add(tiles.group);

const controls = new OrbitControls(camera, canvas);
controls.enableDamping = false;
controls.screenSpacePanning = true;

// ------------------------------------------------------------------ frames

const modelToWorld = new Matrix4(); // G·T
const worldToModel = new Matrix4();
let model = null; // { up, bounds: {min, max}, transform, url }

function v3(a) {
	return new Vector3(a[0], a[1], a[2]);
}

// Model bounds (octolod extras, else the root bounding volume's AABB).
function modelBounds(tileset) {
	const o = tileset.asset && tileset.asset.extras && tileset.asset.extras.octolod;
	if (o && o.bounds && Array.isArray(o.bounds.min) && Array.isArray(o.bounds.max)) return { min: o.bounds.min.slice(), max: o.bounds.max.slice() };
	const bv = tileset.root.boundingVolume || {};
	if (bv.box) {
		const b = bv.box;
		const min = [0, 1, 2].map((k) => b[k] - Math.abs(b[3 + k]) - Math.abs(b[6 + k]) - Math.abs(b[9 + k]));
		const max = [0, 1, 2].map((k) => b[k] + Math.abs(b[3 + k]) + Math.abs(b[6 + k]) + Math.abs(b[9 + k]));
		return { min, max };
	}
	if (bv.sphere) {
		const s = bv.sphere;
		return { min: [s[0] - s[3], s[1] - s[3], s[2] - s[3]], max: [s[0] + s[3], s[1] + s[3], s[2] + s[3]] };
	}
	return { min: [-1, -1, -1], max: [1, 1, 1] };
}

function setupFrames(tileset, url) {
	const T = new Matrix4();
	if (Array.isArray(tileset.root.transform) && tileset.root.transform.length === 16) T.fromArray(tileset.root.transform);
	const o = tileset.asset && tileset.asset.extras && tileset.asset.extras.octolod;
	let up;
	if (o && Array.isArray(o.up) && o.up.length === 3) up = v3(o.up).normalize();
	else up = new Vector3(0, 0, 1).transformDirection(T.clone().invert());
	if (colorsParam !== 'srgb' && colorsParam !== 'linear') srgbColors = Boolean(o && o.color_encoding === 'srgb');
	const bounds = modelBounds(tileset);
	const center = v3(bounds.min).add(v3(bounds.max)).multiplyScalar(0.5);
	// G = translate(-(R·T·c)) · R, R = Rx(-90°).
	const R = new Matrix4().makeRotationX(-Math.PI / 2);
	const c = center.clone().applyMatrix4(T).applyMatrix4(R);
	tiles.group.rotation.set(-Math.PI / 2, 0, 0);
	tiles.group.position.copy(c).negate();
	tiles.group.updateMatrixWorld(true);
	modelToWorld.multiplyMatrices(tiles.group.matrixWorld, T);
	worldToModel.copy(modelToWorld).invert();
	// The up axis on screen: +Y of three.js, which OrbitControls orbits about.
	const worldUp = up.clone().transformDirection(modelToWorld);
	model = { up: up.toArray(), bounds, transform: T.toArray(), url, worldUp: worldUp.toArray().map((v) => Math.round(v * 1e9) / 1e9), colors: srgbColors ? 'srgb' : 'linear' };
}

// octolod's Camera::fit_clip: far past the farthest corner of the bounds,
// near at the nearest point (at least far·2e-5).
function fitClip() {
	if (!model) return;
	const eye = camera.position.clone().applyMatrix4(worldToModel);
	const { min, max } = model.bounds;
	let dNear = 0;
	let dFar = 0;
	for (let k = 0; k < 3; k++) {
		const p = eye.getComponent(k);
		const out = p < min[k] ? min[k] - p : p > max[k] ? p - max[k] : 0;
		dNear += out * out;
		const far = Math.max(Math.abs(p - min[k]), Math.abs(p - max[k]));
		dFar += far * far;
	}
	const far = Math.sqrt(dFar) * 1.01 + 1e-9;
	const near = Math.max(Math.sqrt(dNear) * 0.9, far * 2e-5);
	if (camera.near !== near || camera.far !== Math.max(far, near * 2)) {
		camera.near = near;
		camera.far = Math.max(far, near * 2);
		camera.updateProjectionMatrix();
	}
}

// ------------------------------------------------------------------ state

let dirty = true; // the canvas does not show the current state
let changeSerial = 0; // tile visibility, model loads and disposals
let viewSerial = 0; // camera, size, error target
let lastChange = -1;
let lastView = -1;
let quietFrames = 0;
let updates = 0;
let draws = 0;
let lastDraw = { triangles: 0, calls: 0 };
let fixedSize = false;
const drawTimes = [];
const loadErrors = [];

function viewChanged() {
	viewSerial++;
	dirty = true;
}

controls.addEventListener('change', viewChanged);
tiles.addEventListener('tile-visibility-change', () => {
	changeSerial++;
	dirty = true;
});
tiles.addEventListener('dispose-model', ({ scene: s }) => {
	changeSerial++;
	dirty = true;
	s.traverse((o) => {
		if (o.isMesh && o.material && o.material.userData.octolodPerTile) o.material.dispose();
	});
});

// Vertex colours that hold sRGB-encoded values: interpolated as they are and
// decoded per fragment, as octolod's shader does.
function decodeSrgbColors(material) {
	material.onBeforeCompile = (shader) => {
		shader.fragmentShader = shader.fragmentShader
			.replace(
				'#include <color_pars_fragment>',
				`#include <color_pars_fragment>
vec3 octolodSrgbToLinear( vec3 c ) {
	return mix( pow( ( c + 0.055 ) / 1.055, vec3( 2.4 ) ), c / 12.92, vec3( lessThanEqual( c, vec3( 0.04045 ) ) ) );
}`,
			)
			.replace(
				'#include <color_fragment>',
				`#if defined( USE_COLOR ) || defined( USE_COLOR_ALPHA )
	diffuseColor *= vec4( octolodSrgbToLinear( vColor.rgb ), vColor.a );
#endif`,
			);
	};
	material.customProgramCacheKey = () => 'octolod-srgb-vertex-colors';
	return material;
}

// octolod's shading: shared Lambert materials, one per variant.
const materialCache = new Map();
// Textures by octolod's image name, kept for the session (a few per level).
const sharedMaps = new Map();
const sharedName = /^texture-\d+-\d+$/;
function sharedMap(map) {
	if (!map || !sharedName.test(map.name)) return map;
	const known = sharedMaps.get(map.name);
	if (!known) {
		sharedMaps.set(map.name, map);
		return map;
	}
	if (known !== map) map.dispose();
	return known;
}
function octolodMaterial(src, geometry) {
	const vertexColors = Boolean(geometry.attributes.color);
	const side = src && src.side === DoubleSide ? DoubleSide : FrontSide;
	const color = src && src.color ? src.color.getHex(LinearSRGBColorSpace) : 0xffffff;
	const map = sharedMap(src && src.map ? src.map : null);
	const opts = { vertexColors, side, color: new Color().setHex(color, LinearSRGBColorSpace), map };
	const make = () => {
		const m = new MeshLambertMaterial(opts);
		return vertexColors && srgbColors ? decodeSrgbColors(m) : m;
	};
	if (map && !sharedName.test(map.name)) {
		const m = make();
		m.userData.octolodPerTile = true;
		return m;
	}
	const key = `${vertexColors}|${side}|${color}|${srgbColors}|${map ? map.name : ''}`;
	if (!materialCache.has(key)) materialCache.set(key, make());
	return materialCache.get(key);
}

tiles.addEventListener('load-model', ({ scene: s, tile }) => {
	changeSerial++;
	dirty = true;
	if (keepMaterials) return;
	s.traverse((o) => {
		if (!o.isMesh) return;
		o.material = Array.isArray(o.material) ? o.material.map((m) => octolodMaterial(m, o.geometry)) : octolodMaterial(o.material, o.geometry);
	});
	// A shared texture outlives the tile that brought it: the renderer
	// must not close its image when that tile goes.
	const own = tile && tile.engineData && tile.engineData.textures;
	if (own && sharedMaps.size) {
		const shared = new Set(sharedMaps.values());
		tile.engineData.textures = own.filter((t) => !shared.has(t));
	}
});

let resolveReady;
let rejectReady;
const ready = new Promise((res, rej) => {
	resolveReady = res;
	rejectReady = rej;
});
ready.catch(() => {}); // a failed root load is reported by the renderer's own console error
let readyResolved = false;
let pendingCamera = null;

tiles.addEventListener('load-root-tileset', ({ tileset, url }) => {
	setupFrames(tileset, url);
	if (pendingCamera) {
		applyCamera(pendingCamera);
		pendingCamera = null;
	} else {
		frameAll();
	}
});
tiles.addEventListener('load-error', ({ tile, error, url }) => {
	loadErrors.push({ url: String(url), root: !tile, message: String(error && error.message ? error.message : error) });
	if (!tile) rejectReady(new Error(`cannot load ${url}: ${error && error.message ? error.message : error}`));
});

// ------------------------------------------------------------------ camera

function setCanvasSize(width, height, pixelRatio) {
	renderer.setPixelRatio(pixelRatio);
	renderer.setSize(width, height, true);
	camera.aspect = width / height;
	camera.updateProjectionMatrix();
	viewChanged();
}

// glam's DVec3::any_orthonormal_vector (Frisvad / Pixar), for a unit `n`.
function anyOrthonormal(n) {
	const sign = n.z > 0 || Object.is(n.z, 0) ? 1 : -1;
	const a = -1 / (sign + n.z);
	const b = n.x * n.y * a;
	return new Vector3(b, sign + n.y * n.y * a, -n.y);
}

// The up vector octolod's camera uses for this pose (Camera::view): the
// given one, or when the view direction is parallel to it, cam_up().
function octolodUp(eye, target, up) {
	const f = v3(target).sub(v3(eye)).normalize();
	const u = v3(up).normalize();
	if (f.clone().cross(u).lengthSq() >= 1e-12) return u;
	return anyOrthonormal(f).cross(f).normalize();
}

function applyCamera({ eye, target, up, fovYDeg }) {
	const e = v3(eye).applyMatrix4(modelToWorld);
	const t = v3(target).applyMatrix4(modelToWorld);
	const u = octolodUp(eye, target, up || model.up).transformDirection(modelToWorld);
	camera.up.copy(u);
	camera.position.copy(e);
	if (fovYDeg) camera.fov = fovYDeg;
	camera.lookAt(t);
	camera.updateMatrixWorld(true);
	controls.target.copy(t);
	fitClip();
	camera.updateProjectionMatrix();
	viewChanged();
}

// octolod's Camera::frame_all: the default slightly downward diagonal for
// this up axis, backed off until the bounding sphere fits the narrower
// field of view.
function frameAll() {
	const up = v3(model.up);
	const side = Math.abs(up.x) < 0.9 ? new Vector3(1, 0, 0) : new Vector3(0, 1, 0);
	const a = side.clone().cross(up).normalize();
	const dir = side.clone().add(a.multiplyScalar(0.6)).negate().addScaledVector(up, -0.45).normalize();
	const { min, max } = model.bounds;
	const center = v3(min).add(v3(max)).multiplyScalar(0.5);
	const r = Math.max(0.5 * v3(max).sub(v3(min)).length(), 1e-9);
	const fovY = (camera.fov * Math.PI) / 180;
	const fovX = 2 * Math.atan(Math.tan(fovY / 2) * camera.aspect);
	const dist = (r / Math.sin(0.5 * Math.min(fovY, fovX))) * 1.05;
	applyCamera({ eye: center.clone().addScaledVector(dir, -dist).toArray(), target: center.toArray(), up: model.up, fovYDeg: camera.fov });
}

window.addEventListener('resize', () => {
	if (fixedSize) return;
	setCanvasSize(window.innerWidth, window.innerHeight, window.devicePixelRatio || 1);
});

// ------------------------------------------------------------------ loop

function busy() {
	const s = tiles.stats;
	return (
		!tiles.rootTileset ||
		s.queued + s.downloading + s.parsing > 0 ||
		s.refused > 0 ||
		tiles.downloadQueue.running ||
		tiles.parseQueue.running ||
		tiles.processNodeQueue.running ||
		tiles.isLoading === true ||
		net.inFlight > 0
	);
}

function draw() {
	renderer.render(scene, camera);
	lastDraw = { triangles: renderer.info.render.triangles, calls: renderer.info.render.calls };
	draws++;
	dirty = false;
	const now = performance.now();
	drawTimes.push(now);
	while (drawTimes.length && drawTimes[0] < now - 1000) drawTimes.shift();
}

function frame() {
	requestAnimationFrame(frame);
	if (model) fitClip();
	camera.updateMatrixWorld();
	const drawingBuffer = renderer.getDrawingBufferSize(new Vector2());
	tiles.setResolution(camera, drawingBuffer.x, drawingBuffer.y);
	tiles.update();
	updates++;
	if (busy() || changeSerial !== lastChange || viewSerial !== lastView) quietFrames = 0;
	else quietFrames++;
	lastChange = changeSerial;
	lastView = viewSerial;
	if (dirty && model) draw();
	if (model && !readyResolved && draws > 0) {
		readyResolved = true;
		resolveReady({ ...model });
	}
	overlayTick();
}

function isSettled() {
	return Boolean(model) && quietFrames >= SETTLE_FRAMES && !dirty && !busy();
}

function visibleInfo() {
	const depths = {};
	let maxErrorPx = 0;
	for (const t of tiles.visibleTiles) {
		const d = t.internal.depth;
		depths[d] = (depths[d] || 0) + 1;
		if (Number.isFinite(t.traversal.error)) maxErrorPx = Math.max(maxErrorPx, t.traversal.error);
	}
	return { depths, maxErrorPx };
}

function stats() {
	const s = tiles.stats;
	const { depths, maxErrorPx } = visibleInfo();
	const size = renderer.getDrawingBufferSize(new Vector2());
	return {
		settled: isSettled(),
		tilesLoaded: s.loaded,
		tilesVisible: tiles.visibleTiles.size,
		tilesInCache: s.inCache,
		queued: s.queued,
		downloading: s.downloading,
		parsing: s.parsing,
		failed: s.failed,
		refused: s.refused,
		triangles: lastDraw.triangles,
		drawCalls: lastDraw.calls,
		requests: net.requests,
		bytesFetched: net.bytes,
		failedResponses: net.failed,
		fps: drawTimes.filter((t) => t > performance.now() - 1000).length,
		draws,
		updates,
		errorTarget: tiles.errorTarget,
		maxErrorPx,
		depths, // tile depth -> tiles drawn at that depth
		width: size.x,
		height: size.y,
		loadErrors: loadErrors.slice(),
		sharedTextures: [...sharedMaps.keys()].sort(),
		cacheBytes: tiles.lruCache.cachedBytes,
		cacheMaxBytes: tiles.lruCache.maxBytesSize,
	};
}

function setErrorTarget(px) {
	const v = Number(px);
	if (!(v > 0) || !Number.isFinite(v)) throw new Error(`error target must be a positive number, not ${px}`);
	tiles.errorTarget = v;
	syncErrorControls();
	viewChanged();
}

window.octolod = {
	ready,
	setCamera(c) {
		if (!c || !Array.isArray(c.eye) || !Array.isArray(c.target)) throw new Error('setCamera needs {eye: [x,y,z], target: [x,y,z]}');
		if (c.width && c.height) {
			fixedSize = true;
			setCanvasSize(Math.round(c.width), Math.round(c.height), 1);
		}
		if (model) applyCamera(c);
		else pendingCamera = c;
	},
	settled: isSettled,
	stats,
	setErrorTarget,
	capture() {
		draw();
		return canvas.toDataURL('image/png');
	},
};

// ------------------------------------------------------------------ overlay

const overlay = document.getElementById('overlay');
const statsEl = document.getElementById('stats');
const errNumber = document.getElementById('error-px');
const errRange = document.getElementById('error-range');
if (!showOverlay) overlay.style.display = 'none';

function syncErrorControls() {
	if (document.activeElement !== errNumber) errNumber.value = String(+tiles.errorTarget.toFixed(3));
	errRange.value = String(Math.log2(tiles.errorTarget));
}
errNumber.addEventListener('change', () => {
	const v = Number(errNumber.value);
	if (v > 0) setErrorTarget(v);
	else syncErrorControls();
});
errRange.addEventListener('input', () => setErrorTarget(+(2 ** Number(errRange.value)).toPrecision(3)));
syncErrorControls();

function mb(b) {
	return b >= 1 << 20 ? `${(b / (1 << 20)).toFixed(1)} MiB` : `${(b / 1024).toFixed(1)} KiB`;
}

let lastOverlay = 0;
function overlayTick() {
	if (!showOverlay) return;
	const now = performance.now();
	if (now - lastOverlay < 250) return;
	lastOverlay = now;
	const s = stats();
	const depthList = Object.keys(s.depths)
		.map(Number)
		.sort((a, b) => a - b)
		.map((d) => `${d}:${s.depths[d]}`)
		.join(' ');
	const state = loadErrors.length ? `${loadErrors.length} load error(s)` : s.settled ? 'settled' : `loading (${s.queued} queued, ${s.downloading} downloading, ${s.parsing} parsing)`;
	statsEl.textContent = [
		`tiles     ${s.tilesVisible} drawn, ${s.tilesLoaded} loaded`,
		`depths    ${depthList || '-'}`,
		`triangles ${s.triangles.toLocaleString('en-US')} (${s.drawCalls} draw calls)`,
		`fetched   ${mb(s.bytesFetched)} in ${s.requests} requests`,
		`fps       ${s.fps} (draws only on change)`,
		`error     target ${+s.errorTarget.toFixed(3)} px, on screen ${s.maxErrorPx.toFixed(2)} px`,
		`state     ${state}`,
	].join('\n');
	statsEl.classList.toggle('bad', loadErrors.length > 0);
}

requestAnimationFrame(frame);
