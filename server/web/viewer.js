// The geodesicd web viewer: one ES module, three.js from Debian's libjs-three
// (served by the gateway under three/), every query through the /v1 JSON API.
import * as THREE from './three/build/three.module.js';
import { OrbitControls } from './three/examples/jsm/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);
const ISOLINES = 20;          // isolines per field's largest finite distance
const LARGE_MESH = 200000;    // vertices above which a graph is built only on request
const PATH_RADIUS = 0.004;    // path tube radius, as a fraction of the bounding-box diagonal
const SAMPLE_MESH = 'spot';   // the bundled mesh a new user should land on
const PATH_COLOR = 0xd0306a;  // far from the beige surface and from both end markers

const canvas = $('canvas');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xffffff);
const camera = new THREE.PerspectiveCamera(40, 1, 0.001, 1000);
const controls = new OrbitControls(camera, canvas);
scene.add(new THREE.HemisphereLight(0xffffff, 0x606070, 0.7));
const sun = new THREE.DirectionalLight(0xffffff, 0.6);
camera.add(sun);
sun.position.set(1, 1, 2);
scene.add(camera);

// The field's ramp with dark stripes at even distance steps. The surface's
// texture and the legend's colour bar both sample this one function, so the
// bar shows exactly the colours and isolines on the mesh.
function rampRGB(t) {
  const phase = (t * ISOLINES) % 1;
  if (phase < 0.06 || phase > 0.94) return [32, 32, 32];
  const c = new THREE.Color().setHSL(0.66 * (1 - t), 0.85, 0.55);
  return [Math.round(c.r * 255), Math.round(c.g * 255), Math.round(c.b * 255)];
}

function paintRamp(ctx, width, height) {
  for (let x = 0; x < width; ++x) {
    const [r, g, b] = rampRGB(width === 1 ? 0 : x / (width - 1));
    ctx.fillStyle = `rgb(${r},${g},${b})`;
    ctx.fillRect(x, 0, 1, height);
  }
}

function stripeTexture() {
  const c = document.createElement('canvas');
  c.width = 1024;
  c.height = 1;
  paintRamp(c.getContext('2d'), c.width, 1);
  const texture = new THREE.CanvasTexture(c);
  texture.wrapS = THREE.ClampToEdgeWrapping;
  return texture;
}

const state = {
  // Every async answer is checked against these before it touches the page:
  // meshGen changes with the selected mesh, graphGen also with ε or pseudo
  // vertices. An answer asked under older values belongs to another view.
  meshGen: 0,
  graphGen: 0,
  watch: 0,          // generation of the graph poll loop
  abort: null,       // aborts the previous mesh's fetches on a switch
  mesh: null,        // name
  entries: new Map(),// name -> listing entry
  object: null,      // THREE.Mesh
  faces: null,       // Uint32Array, file order
  positions: null,   // Float32Array
  diagonal: 1,       // bounding-box diagonal, for sizes of overlays
  fitDistance: 1,    // camera distance that frames the whole mesh
  picks: [],         // specs of the current path's ends
  overlays: [],      // markers and path tubes
};
const baseMaterial = new THREE.MeshLambertMaterial({
  color: 0xd8d0c0, side: THREE.DoubleSide,
  // Pushed back so that paths on the surface win the depth test.
  polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
});
const fieldMaterial = new THREE.MeshLambertMaterial({
  map: stripeTexture(), side: THREE.DoubleSide,
  polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
});
const pathMaterial = new THREE.MeshLambertMaterial({ color: PATH_COLOR, emissive: 0x4a0820 });
// The part of a path behind the surface, faint, so that a path round the
// back is not simply lost.
const hiddenPathMaterial = new THREE.MeshBasicMaterial({
  color: PATH_COLOR, transparent: true, opacity: 0.3, depthTest: false, depthWrite: false,
});

function status(message) { $('status').textContent = message || ''; }

function ticket() { return { meshGen: state.meshGen, graphGen: state.graphGen, mesh: state.mesh }; }
const meshCurrent = (t) => t.meshGen === state.meshGen;
const graphCurrent = (t) => meshCurrent(t) && t.graphGen === state.graphGen;

async function api(method, path, body) {
  const headers = { 'Content-Type': 'application/json' };
  const token = $('token').value.trim();
  if (token) headers.Authorization = `Bearer ${token}`;
  const res = await fetch(path, {
    method, headers, body: body ? JSON.stringify(body) : undefined,
    signal: state.abort ? state.abort.signal : undefined,
  });
  const data = await res.json().catch(() => ({}));
  if (!res.ok) {
    const e = data.error || { code: `HTTP ${res.status}`, message: res.statusText };
    const err = new Error(`${e.code}: ${e.message}`);
    err.code = e.code;
    throw err;
  }
  return data;
}

// Shows an error only if it belongs to what is on screen; a fetch aborted by
// a switch is no error at all.
function report(t, check) {
  return (e) => {
    if (e.name === 'AbortError' || !check(t)) return;
    status(e.message);
  };
}

// null: no ε typed, so the server's --default-epsilon applies.
function eps() {
  const text = $('eps').value.trim();
  return text === '' ? null : Number(text);
}
// The graph every request asks for: the plain one of this ε, or the one
// with pseudo vertices (a separate graph on the server).
function graphChoice() {
  const e = eps();
  return { ...(e === null ? {} : { eps: e }), pseudo_vertices: $('pseudo').checked };
}
function graphQuery() {
  const e = eps();
  return `${e === null ? '' : `eps=${encodeURIComponent(e)}&`}pseudo_vertices=${$('pseudo').checked}`;
}
function mode() { return document.querySelector('input[name=mode]:checked').value; }
const meshPath = (name, suffix) => `v1/meshes/${encodeURIComponent(name)}/${suffix}`;

// Loading and building shown over the view: tasks by name, each with its
// text and an optional fraction done.
const busyTasks = new Map();
function busy(name, text, progress) {
  if (text === null) busyTasks.delete(name);
  else busyTasks.set(name, { text, progress });
  const el = $('busy');
  el.hidden = busyTasks.size === 0;
  el.dataset.tasks = [...busyTasks.keys()].join(' ');
  $('busy-text').textContent = [...busyTasks.values()].map((x) => x.text).join(' · ');
  const withProgress = [...busyTasks.values()].find((x) => typeof x.progress === 'number');
  const bar = $('busy-progress');
  bar.hidden = !withProgress;
  if (withProgress) bar.value = withProgress.progress;
}

// Places the camera so that the bounding sphere fits both fields of view;
// keep: the user's direction and zoom survive (on a resize).
function frame(keep) {
  if (!state.object) return;
  const { center, radius } = state.object.geometry.boundingSphere;
  const vfov = camera.fov * Math.PI / 180;
  const hfov = 2 * Math.atan(Math.tan(vfov / 2) * camera.aspect);
  const fit = (radius * 1.04) / Math.sin(Math.min(vfov, hfov) / 2);
  let direction = new THREE.Vector3(-1.4, 0.7, -2.2);  // three-quarter: most meshes face ±z
  let distance = fit;
  if (keep) {
    const offset = camera.position.clone().sub(controls.target);
    if (offset.lengthSq() > 0) direction = offset;
    distance = fit * (offset.length() / state.fitDistance);
  }
  state.fitDistance = fit;
  if (!keep) controls.target.copy(center);
  camera.position.copy(controls.target).add(direction.setLength(distance));
  controls.minDistance = radius * 0.05;
  controls.maxDistance = fit * 10;
  camera.near = radius * 0.01;
  camera.far = controls.maxDistance + 2 * radius;
  camera.updateProjectionMatrix();
  controls.update();
}

function resize() {
  const view = $('view');
  const w = view.clientWidth, h = view.clientHeight;
  if (!w || !h) return;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  frame(true);
}

function clearOverlays() {
  for (const o of state.overlays) {
    scene.remove(o);
    o.geometry.dispose();
  }
  state.overlays = [];
}

function tubeRadius() { return state.diagonal * PATH_RADIUS; }

function marker(point, color) {
  const m = new THREE.Mesh(new THREE.SphereBufferGeometry(tubeRadius() * 2.4, 16, 12),
                           new THREE.MeshLambertMaterial({ color, emissive: color, emissiveIntensity: 0.3 }));
  m.position.copy(point);
  m.renderOrder = 3;
  scene.add(m);
  state.overlays.push(m);
}

// A polyline as a curve whose parameter steps from vertex to vertex, so that
// a tube with one segment per edge has its rings exactly at the path's
// corners (an arc-length curve would cut them).
class PolylineCurve extends THREE.Curve {
  constructor(points) {
    super();
    this.points = points;
  }

  getPoint(t, target = new THREE.Vector3()) {
    const n = this.points.length - 1;
    const u = Math.min(Math.max(t, 0), 1) * n;
    const i = Math.min(Math.floor(u), n - 1);
    return target.copy(this.points[i]).lerp(this.points[i + 1], u - i);
  }

  getPointAt(t, target) { return this.getPoint(t, target); }

  // At a corner, the bisector of the two edges: the ring there is then the
  // miter between them rather than a kink.
  getTangentAt(t, target = new THREE.Vector3()) {
    const p = this.points, n = p.length - 1;
    const u = Math.min(Math.max(t, 0), 1) * n;
    const k = Math.round(u);
    const edge = (i) => p[i + 1].clone().sub(p[i]).normalize();
    if (Math.abs(u - k) > 1e-6) return target.copy(edge(Math.min(Math.floor(u), n - 1)));
    if (k === 0) return target.copy(edge(0));
    if (k === n) return target.copy(edge(n - 1));
    target.copy(edge(k - 1)).add(edge(k));
    return target.lengthSq() > 1e-12 ? target.normalize() : target.copy(edge(k));
  }
}

function drawPath(xyz) {
  const eps2 = (state.diagonal * 1e-9) ** 2;
  const points = [];
  for (const c of xyz) {
    const p = new THREE.Vector3(...c);
    // Repeated points have no direction for the tube's frames.
    if (!points.length || p.distanceToSquared(points[points.length - 1]) > eps2) points.push(p);
  }
  if (points.length < 2) return;
  const geometry = new THREE.TubeBufferGeometry(new PolylineCurve(points), points.length - 1,
                                                tubeRadius(), 10, false);
  const hidden = new THREE.Mesh(geometry, hiddenPathMaterial);
  hidden.renderOrder = 1;
  const tube = new THREE.Mesh(geometry, pathMaterial);
  tube.renderOrder = 2;
  scene.add(hidden, tube);
  state.overlays.push(hidden, tube);
}

// The length of the polyline the server sent, in 3-D: a check on the path
// as drawn, which may differ from the pair's distance in the last digits.
function polylineLength(xyz) {
  let sum = 0;
  for (let i = 1; i < xyz.length; ++i) {
    sum += Math.hypot(xyz[i][0] - xyz[i - 1][0], xyz[i][1] - xyz[i - 1][1], xyz[i][2] - xyz[i - 1][2]);
  }
  return sum;
}

async function loadMeshes() {
  const { meshes } = await api('GET', 'v1/meshes');
  const select = $('mesh');
  select.innerHTML = '';
  state.entries.clear();
  for (const m of meshes) {
    state.entries.set(m.name, m);
    const option = document.createElement('option');
    option.value = m.name;
    option.textContent = `${m.name} (${m.vertices.toLocaleString('en')} vertices)`;
    select.appendChild(option);
  }
  if (!meshes.length) {
    status('no mesh is registered');
    return;
  }
  const names = meshes.map((m) => m.name);
  const name = [state.mesh, SAMPLE_MESH].find((n) => names.includes(n)) || names[0];
  select.value = name;
  await selectMesh(name);
}

// Nothing of the previous mesh may stay on screen under the new name.
function clearPanel(name) {
  status('');
  $('mesh-title').textContent = name;
  $('mesh-title').dataset.mesh = name;
  $('mesh-info').textContent = 'loading…';
  showGraph(null);
  setDistance(null);
  setPathLength(null);
  $('picked').textContent = '';
  hideLegend();
}

async function selectMesh(name) {
  if (state.abort) state.abort.abort();
  state.abort = new AbortController();
  state.mesh = name;
  ++state.meshGen;
  ++state.graphGen;
  ++state.watch;
  state.picks = [];
  clearOverlays();
  if (state.object) {
    scene.remove(state.object);
    state.object.geometry.dispose();
    state.object = null;
  }
  canvas.dataset.mesh = '';
  busyTasks.clear();
  clearPanel(name);
  const t = ticket();
  const entry = state.entries.get(name);
  // A large mesh's graph can take minutes and gigabytes: only watched, built on request.
  const graph = watchGraph(!entry || entry.vertices <= LARGE_MESH);
  busy('geometry', `Loading ${name}…`);
  try {
    const geo = await api('GET', meshPath(name, 'geometry'));
    if (!meshCurrent(t)) return;
    busy('geometry', `Preparing ${name}…`);
    showGeometry(name, geo);
  } catch (e) {
    report(t, meshCurrent)(e);
  } finally {
    if (meshCurrent(t)) busy('geometry', null);
  }
  await graph;
}

function showGeometry(name, geo) {
  state.positions = new Float32Array(geo.positions);
  state.faces = new Uint32Array(geo.faces);
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(state.positions, 3));
  g.setAttribute('uv', new THREE.BufferAttribute(new Float32Array(2 * state.positions.length / 3), 2));
  // Index order is file order: a hit's faceIndex is the file's face id.
  g.setIndex(new THREE.BufferAttribute(state.faces, 1));
  g.computeVertexNormals();
  g.computeBoundingSphere();
  g.computeBoundingBox();
  state.diagonal = g.boundingBox.getSize(new THREE.Vector3()).length() || 1;
  state.object = new THREE.Mesh(g, baseMaterial);
  scene.add(state.object);
  canvas.dataset.mesh = name;
  frame(false);
  $('mesh-info').textContent = `${(geo.positions.length / 3).toLocaleString('en')} vertices, `
    + `${(geo.faces.length / 3).toLocaleString('en')} faces, diagonal ${state.diagonal.toPrecision(4)}`;
}

// Requests (post) or only looks up the graph of the current choice, and
// follows it until it is built.
async function watchGraph(post) {
  const t = ticket();
  const w = ++state.watch;
  const name = t.mesh;
  const live = () => w === state.watch && graphCurrent(t);
  busy('graph', post ? `Requesting the graph of ${name}…` : `Looking up the graph of ${name}…`);
  try {
    let g = post ? await api('POST', meshPath(name, 'graph'), graphChoice())
      : await api('GET', `${meshPath(name, 'graph')}?${graphQuery()}`);
    while (live()) {
      showGraph(g);
      if (!['QUEUED', 'BUILDING', 'LOADING'].includes(g.state)) break;
      const pct = Math.round(100 * (g.progress || 0));
      busy('graph', `${g.state === 'LOADING' ? 'Loading' : g.state === 'QUEUED' ? 'Queued:' : 'Building'} `
        + `the graph of ${name} (ε ${g.eps}${g.pseudo_vertices ? ', pseudo vertices' : ''})`
        + `${g.phase ? `: ${g.phase}` : ''} ${pct} %`, g.progress || 0);
      await new Promise((r) => setTimeout(r, 300));
      if (!live()) break;
      g = await api('GET', `${meshPath(name, 'graph')}?${graphQuery()}`);
    }
  } catch (e) {
    if (!live()) return;
    if (!post && e.code === 'NOT_FOUND') {
      const entry = state.entries.get(name);
      showGraph({ state: 'ABSENT', mesh: name });
      $('graph-state').textContent = `not built: ${entry ? `${entry.vertices.toLocaleString('en')} vertices, ` : ''}`
        + 'press “Build graph” to build it (this may take long)';
    } else {
      report(t, graphCurrent)(e);
    }
  } finally {
    if (w === state.watch && graphCurrent(t)) busy('graph', null);
  }
}

function showEps(value) {
  const el = $('eps-default');
  if (eps() === null && typeof value === 'number') {
    el.dataset.eps = String(value);
    el.textContent = `empty: the server's default, ε = ${value}`;
  }
}

function showGraph(g) {
  const el = $('graph-state');
  if (!g) {
    el.dataset.state = '';
    el.dataset.mesh = '';
    el.dataset.eps = '';
    el.dataset.pseudo = '';
    el.textContent = '–';
    $('progress').value = 0;
    return;
  }
  el.dataset.state = g.state;
  el.dataset.mesh = g.mesh || state.mesh;
  el.dataset.eps = g.eps === undefined ? '' : String(g.eps);
  el.dataset.pseudo = String(Boolean(g.pseudo_vertices));
  const detail = g.state === 'READY' ? `${g.edges.toLocaleString('en')} edges`
    : g.state === 'ABSENT' ? '' : `${g.phase ? `${g.phase}, ` : ''}${Math.round(100 * (g.progress || 0))} %`;
  el.textContent = `${g.state.toLowerCase()}${g.eps ? ` at ε ${g.eps}` : ''}`
    + `${detail ? ` (${detail})` : ''}${g.error ? `: ${g.error}` : ''}`;
  $('progress').value = g.state === 'READY' ? 1 : g.progress || 0;
  showEps(g.eps);
}

function setDistance(value, from = '', to = '', answer = {}) {
  const el = $('distance');
  el.dataset.value = value === null ? '' : String(value);
  el.dataset.from = from;
  el.dataset.to = to;
  el.dataset.mesh = value === null ? '' : state.mesh;
  el.dataset.pseudo = String(Boolean(answer.pseudo_vertices));
  el.dataset.eps = answer.eps === undefined ? '' : String(answer.eps);
  el.textContent = value === null ? '–' : value.toPrecision(8);
}

function setPathLength(length, points = 0) {
  const el = $('path-length');
  el.dataset.value = length === null ? '' : String(length);
  el.dataset.points = String(points);
  el.dataset.radius = length === null ? '' : String(tubeRadius());
  el.dataset.diagonal = String(state.diagonal);
  el.textContent = length === null ? '' : `path length ${length.toPrecision(8)} (polyline of ${points} points)`;
}

function hideLegend() {
  $('legend').hidden = true;
  $('legend').dataset.max = '';
}

// Round ticks (1, 2 or 5 times a power of ten) from 0, ending at max itself.
function tickValues(max) {
  if (!(max > 0)) return [0];
  const rough = max / 4;
  const power = 10 ** Math.floor(Math.log10(rough));
  const step = [1, 2, 5, 10].map((m) => m * power).find((s) => s >= rough);
  const out = [];
  // A round tick within a fifth of the bar of max would collide with max's label.
  for (let i = 0; i * step < 0.8 * max; ++i) out.push(Number((i * step).toPrecision(12)));
  out.push(max);
  return out;
}

function showLegend(max) {
  const legend = $('legend');
  legend.hidden = false;
  legend.dataset.max = String(max);
  const bar = $('colorbar');
  const ratio = window.devicePixelRatio || 1;
  bar.width = Math.round(bar.clientWidth * ratio);
  bar.height = Math.round(bar.clientHeight * ratio);
  paintRamp(bar.getContext('2d'), bar.width, bar.height);
  bar.setAttribute('aria-label', `colour scale from 0 (blue) to ${max.toPrecision(4)} (red)`);
  const ticks = $('ticks');
  ticks.innerHTML = '';
  const values = tickValues(max);
  values.forEach((v, i) => {
    const span = document.createElement('span');
    span.dataset.value = String(v);
    span.textContent = i === values.length - 1 ? v.toPrecision(4) : String(v);
    span.style.left = `${(100 * v) / (max || 1)}%`;
    if (i === 0) span.className = 'first';
    if (i === values.length - 1 && i > 0) span.className = 'last';
    ticks.appendChild(span);
  });
  $('isolines').textContent = `isolines every ${(max / ISOLINES).toPrecision(3)} (mesh units)`;
  $('isolines').dataset.spacing = String(max / ISOLINES);
}

// The hit as a face point: barycentrics weight the face's corners in the
// file's order, as the API's f:FACE:B0,B1,B2 form does.
function pick(event) {
  const rect = canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
                                -((event.clientY - rect.top) / rect.height) * 2 + 1);
  const ray = new THREE.Raycaster();
  ray.setFromCamera(ndc, camera);
  const hit = ray.intersectObject(state.object)[0];
  if (!hit) return null;
  const f = hit.faceIndex;
  const corner = (k) => new THREE.Vector3().fromArray(state.positions, 3 * state.faces[3 * f + k]);
  const b = new THREE.Triangle(corner(0), corner(1), corner(2))
    .getBarycoord(hit.point, new THREE.Vector3()).toArray().map((x) => Math.max(0, x));
  const sum = b[0] + b[1] + b[2];
  const bary = b.map((x) => x / sum);
  const point = corner(0).multiplyScalar(bary[0])
    .add(corner(1).multiplyScalar(bary[1])).add(corner(2).multiplyScalar(bary[2]));
  return { spec: `f:${f}:${bary.map((x) => x.toPrecision(17)).join(',')}`, point };
}

async function onPick(event) {
  if (!state.object) return;
  const p = pick(event);
  if (!p) {
    status('missed the surface');
    return;
  }
  status('');
  if (mode() === 'field') return showField(p);
  if (state.picks.length === 2) {
    state.picks = [];
    busy('query', null);
    clearOverlays();
    setDistance(null);
    setPathLength(null);
  }
  state.picks.push(p.spec);
  marker(p.point, state.picks.length === 1 ? 0x1a7f37 : 0x1f5fbf);
  $('picked').textContent = state.picks.map((s, i) => `${i ? 'to' : 'from'} ${s}`).join('\n');
  if (state.picks.length < 2) return;
  const [from, to] = state.picks;
  const t = ticket();
  const mine = () => graphCurrent(t) && state.picks[0] === from && state.picks[1] === to;
  busy('query', 'Computing the path…');
  try {
    const r = await api('POST', meshPath(t.mesh, 'distance'),
                        { pairs: [[from, to]], ...graphChoice(), path: true });
    // A newer pair, another mesh or another graph: this answer is not theirs.
    if (!mine()) return;
    const d = r.distances[0];
    if (d === null) {
      setDistance(null);
      status('unreachable: the points lie on different components');
      return;
    }
    setDistance(d, from, to, r);
    const path = r.paths[0];
    setPathLength(polylineLength(path), path.length);
    drawPath(path);
  } catch (e) {
    report(t, graphCurrent)(e);
  } finally {
    if (mine()) busy('query', null);
  }
}

async function showField(p) {
  state.picks = [];
  clearOverlays();
  setDistance(null);
  setPathLength(null);
  marker(p.point, 0x000000);
  const t = ticket();
  $('picked').textContent = `source ${p.spec}`;
  const mine = () => graphCurrent(t) && $('picked').textContent === `source ${p.spec}`;
  busy('field', 'Computing the distance field…');
  try {
    const { distances } = await api('POST', meshPath(t.mesh, 'field'),
                                    { sources: [p.spec], ...graphChoice() });
    if (!mine()) return;
    let max = 0;
    for (const d of distances) if (d !== null && d > max) max = d;
    const uv = state.object.geometry.getAttribute('uv');
    distances.forEach((d, i) => uv.setXY(i, d === null ? 1 : d / (max || 1), 0.5));
    uv.needsUpdate = true;
    state.object.material = fieldMaterial;
    showLegend(max);
  } catch (e) {
    report(t, graphCurrent)(e);
  } finally {
    if (mine()) busy('field', null);
  }
}

// ε or pseudo vertices changed: answers shown so far belong to the old graph.
function graphChoiceChanged() {
  if (!state.mesh) return;
  const e = eps();
  // A number input reads "" for text it cannot parse: that is no request
  // for the server's default.
  if ($('eps').validity.badInput || (e !== null && !(e >= 1e-6 && e <= 0.5))) {
    status('ε must lie in [0.000001, 0.5]; leave it empty for the server default');
    return;
  }
  status('');
  ++state.graphGen;
  state.picks = [];
  clearOverlays();
  setDistance(null);
  setPathLength(null);
  $('picked').textContent = '';
  hideLegend();
  if (state.object) state.object.material = baseMaterial;
  busy('field', null);
  busy('query', null);
  const entry = state.entries.get(state.mesh);
  watchGraph(!entry || entry.vertices <= LARGE_MESH);
}

// A click is a pick only if the pointer did not move: drags orbit.
let down = null;
canvas.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
canvas.addEventListener('pointerup', (e) => {
  if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4) onPick(e);
  down = null;
});
canvas.addEventListener('keydown', (e) => {
  if (e.key === 'f' || e.key === 'F') frame(false);
});
$('mesh').addEventListener('change', (e) => selectMesh(e.target.value));
$('build').addEventListener('click', () => state.mesh && watchGraph(true));
$('eps').addEventListener('change', graphChoiceChanged);
$('pseudo').addEventListener('change', graphChoiceChanged);
// A token typed after a 401 retries the listing; kept for this tab only.
$('token').value = sessionStorage.getItem('geodesicd-token') || '';
$('token').addEventListener('change', () => {
  sessionStorage.setItem('geodesicd-token', $('token').value.trim());
  status('');
  loadMeshes().catch((e) => status(e.message));
});
for (const r of document.querySelectorAll('input[name=mode]')) {
  r.addEventListener('change', () => {
    if (mode() === 'path' && state.object) {
      state.object.material = baseMaterial;
      hideLegend();
    }
    state.picks = [];
    clearOverlays();
    setDistance(null);
    setPathLength(null);
    $('picked').textContent = '';
    busy('field', null);
    busy('query', null);
  });
}
new ResizeObserver(resize).observe($('view'));
resize();
renderer.setAnimationLoop(() => {
  controls.update();
  renderer.render(scene, camera);
});
loadMeshes().catch((e) => status(e.message));
