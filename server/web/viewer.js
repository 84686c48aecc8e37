// The geodesicd web viewer: one ES module, three.js from Debian's libjs-three
// (served by the gateway under three/), every query through the /v1 JSON API.
import * as THREE from './three/build/three.module.js';
import { OrbitControls } from './three/examples/jsm/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);
const ISOLINES = 20;  // isolines per field's largest finite distance

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

// The field's colours and isolines: a 1-D texture indexed by distance / max,
// a colour ramp with dark stripes at even distance steps.
function stripeTexture() {
  const width = 1024;
  const c = document.createElement('canvas');
  c.width = width;
  c.height = 1;
  const g = c.getContext('2d');
  for (let x = 0; x < width; ++x) {
    const t = x / (width - 1);
    const color = new THREE.Color().setHSL(0.66 * (1 - t), 0.85, 0.55);
    const phase = (t * ISOLINES) % 1;
    const dark = phase < 0.06 || phase > 0.94;
    g.fillStyle = dark ? '#202020' : `#${color.getHexString()}`;
    g.fillRect(x, 0, 1, 1);
  }
  const texture = new THREE.CanvasTexture(c);
  texture.wrapS = THREE.ClampToEdgeWrapping;
  return texture;
}

const state = {
  mesh: null,       // name
  object: null,     // THREE.Mesh
  faces: null,      // Uint32Array, file order
  positions: null,  // Float32Array
  picks: [],        // specs of the current path's ends
  overlays: [],     // markers and path lines
  watch: 0,         // generation of the graph poll loop
};
const baseMaterial = new THREE.MeshLambertMaterial({
  color: 0xd8d0c0, side: THREE.DoubleSide,
  // Pushed back so that path lines on the surface win the depth test.
  polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
});
const fieldMaterial = new THREE.MeshLambertMaterial({
  map: stripeTexture(), side: THREE.DoubleSide,
  polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
});

function status(message) { $('status').textContent = message || ''; }

async function api(method, path, body) {
  const headers = { 'Content-Type': 'application/json' };
  const token = $('token').value.trim();
  if (token) headers.Authorization = `Bearer ${token}`;
  const res = await fetch(path, { method, headers, body: body ? JSON.stringify(body) : undefined });
  const data = await res.json().catch(() => ({}));
  if (!res.ok) {
    const e = data.error || { code: `HTTP ${res.status}`, message: res.statusText };
    const err = new Error(`${e.code}: ${e.message}`);
    err.code = e.code;
    throw err;
  }
  return data;
}

function eps() { return Number($('eps').value); }
// The graph every request asks for: the plain one of this ε, or the one
// with pseudo vertices (a separate graph on the server).
function graphChoice() { return { eps: eps(), pseudo_vertices: $('pseudo').checked }; }
function graphQuery() {
  return `eps=${encodeURIComponent(eps())}&pseudo_vertices=${$('pseudo').checked}`;
}
function mode() { return document.querySelector('input[name=mode]:checked').value; }
const meshPath = (suffix) => `v1/meshes/${encodeURIComponent(state.mesh)}/${suffix}`;

function resize() {
  const view = $('view');
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}

function clearOverlays() {
  for (const o of state.overlays) {
    scene.remove(o);
    o.geometry.dispose();
  }
  state.overlays = [];
}

function marker(point, color) {
  const radius = state.object.geometry.boundingSphere.radius * 0.012;
  const m = new THREE.Mesh(new THREE.SphereBufferGeometry(radius, 12, 8),
                           new THREE.MeshBasicMaterial({ color }));
  m.position.copy(point);
  scene.add(m);
  state.overlays.push(m);
}

async function loadMeshes() {
  const { meshes } = await api('GET', 'v1/meshes');
  const select = $('mesh');
  select.innerHTML = '';
  for (const m of meshes) {
    const option = document.createElement('option');
    option.value = m.name;
    option.textContent = `${m.name} (${m.vertices} vertices)`;
    select.appendChild(option);
  }
  if (meshes.length) await selectMesh(meshes[0].name);
  else status('no mesh is registered');
}

async function selectMesh(name) {
  state.mesh = name;
  state.picks = [];
  clearOverlays();
  setDistance(null);
  const geo = await api('GET', meshPath('geometry'));
  state.positions = new Float32Array(geo.positions);
  state.faces = new Uint32Array(geo.faces);
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(state.positions, 3));
  g.setAttribute('uv', new THREE.BufferAttribute(new Float32Array(2 * state.positions.length / 3), 2));
  // Index order is file order: a hit's faceIndex is the file's face id.
  g.setIndex(new THREE.BufferAttribute(state.faces, 1));
  g.computeVertexNormals();
  g.computeBoundingSphere();
  if (state.object) {
    scene.remove(state.object);
    state.object.geometry.dispose();
  }
  state.object = new THREE.Mesh(g, baseMaterial);
  scene.add(state.object);
  const { center, radius } = g.boundingSphere;
  controls.target.copy(center);
  // A three-quarter view: most meshes face +z or -z, and show their shape obliquely.
  camera.position.copy(center).add(new THREE.Vector3(-1.4, 0.7, -2.2).setLength(radius * 2.8));
  camera.near = radius / 100;
  camera.far = radius * 100;
  camera.updateProjectionMatrix();
  controls.update();
  $('mesh-info').textContent = `${geo.positions.length / 3} vertices, ${geo.faces.length / 3} faces`;
  $('legend').style.display = 'none';
  await requestGraph();
}

// Requests the graph (a no-op when it exists) and shows its build progress.
async function requestGraph() {
  const generation = ++state.watch;
  try {
    let g = await api('POST', meshPath('graph'), graphChoice());
    while (generation === state.watch) {
      showGraph(g);
      if (!['QUEUED', 'BUILDING', 'LOADING'].includes(g.state)) break;
      await new Promise((r) => setTimeout(r, 300));
      g = await api('GET', `${meshPath('graph')}?${graphQuery()}`);
    }
  } catch (e) {
    status(e.message);
  }
}

function showGraph(g) {
  const el = $('graph-state');
  el.dataset.state = g.state;
  el.dataset.pseudo = String(Boolean(g.pseudo_vertices));
  const detail = g.state === 'READY' ? `${g.edges} edges` : g.phase || '';
  el.textContent = `${g.state.toLowerCase()}${detail ? ` (${detail})` : ''}${g.error ? `: ${g.error}` : ''}`;
  $('progress').value = g.state === 'READY' ? 1 : g.progress;
}

function setDistance(value, from = '', to = '', pseudo = false) {
  const el = $('distance');
  el.dataset.value = value === null ? '' : String(value);
  el.dataset.from = from;
  el.dataset.to = to;
  el.dataset.pseudo = String(pseudo);
  el.textContent = value === null ? '–' : value.toPrecision(8);
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
    clearOverlays();
  }
  state.picks.push(p.spec);
  marker(p.point, state.picks.length === 1 ? 0x1a7f37 : 0xc0392b);
  $('picked').textContent = state.picks.join('\n');
  if (state.picks.length < 2) return;
  const [from, to] = state.picks;
  try {
    const r = await api('POST', meshPath('distance'),
                        { pairs: [[from, to]], ...graphChoice(), path: true });
    const d = r.distances[0];
    if (d === null) {
      setDistance(null);
      status('unreachable: the points lie on different components');
      return;
    }
    setDistance(d, from, to, r.pseudo_vertices);
    const pts = r.paths[0].map((xyz) => new THREE.Vector3(...xyz));
    const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints(pts),
                                new THREE.LineBasicMaterial({ color: 0xc0392b, linewidth: 2 }));
    scene.add(line);
    state.overlays.push(line);
  } catch (e) {
    status(e.message);
  }
}

async function showField(p) {
  state.picks = [];
  clearOverlays();
  marker(p.point, 0x000000);
  try {
    const { distances } = await api('POST', meshPath('field'),
                                    { sources: [p.spec], ...graphChoice() });
    let max = 0;
    for (const d of distances) if (d !== null && d > max) max = d;
    const uv = state.object.geometry.getAttribute('uv');
    distances.forEach((d, i) => uv.setXY(i, d === null ? 1 : d / (max || 1), 0.5));
    uv.needsUpdate = true;
    state.object.material = fieldMaterial;
    setDistance(null);
    $('picked').textContent = `source ${p.spec}`;
    const legend = $('legend');
    legend.style.display = 'block';
    legend.textContent = `max ${max.toPrecision(4)}, isolines every ${(max / ISOLINES).toPrecision(3)}`;
    legend.dataset.max = String(max);
  } catch (e) {
    status(e.message);
  }
}

// A click is a pick only if the pointer did not move: drags orbit.
let down = null;
canvas.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
canvas.addEventListener('pointerup', (e) => {
  if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4) onPick(e);
  down = null;
});
$('mesh').addEventListener('change', (e) => selectMesh(e.target.value).catch((x) => status(x.message)));
$('build').addEventListener('click', () => requestGraph());
$('eps').addEventListener('change', () => state.mesh && requestGraph());
$('pseudo').addEventListener('change', () => state.mesh && requestGraph());
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
      $('legend').style.display = 'none';
    }
    state.picks = [];
    clearOverlays();
  });
}
window.addEventListener('resize', resize);
resize();
renderer.setAnimationLoop(() => {
  controls.update();
  renderer.render(scene, camera);
});
loadMeshes().catch((e) => status(e.message));
