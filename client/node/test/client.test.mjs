// The client against a real daemon on 127.0.0.1 (GEODESIC_BIN_DIR names the
// build's bin/): every query kind equal to the offline CLI's bit for bit,
// uploads, graphs requested, watched and cancelled, tokens, deadlines,
// per-call limits learnt, and retries that wait out the server's hint.
import "./fresh.mjs";  // before dist/ is used
import assert from "node:assert/strict";
import {
  copyFileSync, existsSync, mkdirSync, mkdtempSync, readdirSync, rmSync, writeFileSync,
} from "node:fs";
import { tmpdir } from "node:os";
import { basename, dirname, join, resolve } from "node:path";
import { after, before, test } from "node:test";
import { fileURLToPath } from "node:url";
import {
  Client, DeadlineExceededError, EdgePoints, FacePoints, GraphState, NotFoundError,
  OutOfRangeError, ResourceExhaustedError, status, UnauthenticatedError, UnavailableError,
} from "../dist/index.js";
import { assertSameBits } from "./compare.mjs";
import { startDaemon } from "./daemon.mjs";
import { geodesicd, readF64, readNpy, readNpz } from "./offline.mjs";

const BIN = process.env.GEODESIC_BIN_DIR ?? "";
const SRC = resolve(dirname(fileURLToPath(import.meta.url)), "..", "..", "..");
const SPOT = join(SRC, "data", "spot.obj");
const SPOT_VERTICES = 2930;
const TOKEN = "the-node-client";
const EPS = 0.01;
// A graph of spot whose build (one thread) takes far longer than this file
// runs: queries on it wait, then are answered UNAVAILABLE. Cancelled after.
const SLOW_EPS = 1e-6;

let work;
let daemon;
let c;

before(async () => {
  assert.ok(existsSync(join(BIN, "geodesicd")),
    `GEODESIC_BIN_DIR (${BIN}) must name the build's bin/ holding geodesicd`);
  work = mkdtempSync(join(tmpdir(), "geodesic-node-"));
  daemon = await startDaemon(BIN, work, [
    "--graph-dir", join(work, "graphs"), "--mesh-root", join(SRC, "data"), "--log-level",
    "warning", "--min-epsilon", String(SLOW_EPS), "--build-threads", "1", "--max-pairs", "2000",
  ], { tokens: [TOKEN] });
  c = new Client({ address: `127.0.0.1:${daemon.port}`, token: TOKEN, epsilon: EPS, timeout: 60 });
});

after(async () => {
  c?.close();
  await daemon?.stop();
  if (work) rmSync(work, { recursive: true, force: true });
});

function graphFile() {
  const name = readdirSync(join(work, "graphs"))
    .find((f) => f.includes(`eps${EPS}-`) && !f.includes("-pseudo") && f.endsWith(".dgg"));
  assert.ok(name, `no graph file of eps ${EPS} in ${readdirSync(join(work, "graphs"))}`);
  return join(work, "graphs", name);
}

function offline(args) {
  return geodesicd(BIN, [args[0], "--mesh", SPOT, "--graph", graphFile(), ...args.slice(1)]);
}

test("requestGraph waits, reporting each state, the last one READY", async () => {
  const seen = [];
  const g = await c.requestGraph("spot", { progress: (s) => seen.push(s) });
  assert.equal(g.state, GraphState.READY);
  assert.ok(seen.length >= 1, "progress was never called");
  assert.equal(seen.at(-1).state, GraphState.READY);
  for (const s of seen) assert.ok(s.progress >= 0 && s.progress <= 1, `progress ${s.progress}`);
  // 64-bit fields arrive as numbers, exact: not Long objects, not strings.
  assert.equal(g.nodes, SPOT_VERTICES);
  for (const key of ["bytes", "edges", "lastUsedUnixMs"]) {
    assert.equal(typeof g[key], "number", key);
    assert.ok(Number.isSafeInteger(g[key]) && g[key] > 0, `${key} ${g[key]}`);
  }
  const mesh = await c.mesh("spot");
  assert.equal(mesh.diagnostics.vertices, SPOT_VERTICES);
  assert.equal(mesh.diagnostics.genus, 0);  // a zero, present (defaults: true)
});

test("field equals the offline field, nearest sources too", async () => {
  const out = join(work, "field.f64");
  const labels = join(work, "labels.npy");
  offline(["field", "--source", "v:3", "--source", "f:0:0.2,0.3,0.5", "--out", out,
    "--labels-out", labels]);
  const [values, nearest] = await c.field("spot", ["v:3", "f:0:0.2,0.3,0.5"],
    { nearestSource: true });
  assertSameBits(values, readF64(out), "field");
  const want = readNpy(labels).data;
  assertSameBits(Uint32Array.from(nearest), Uint32Array.from(want, Number), "nearest source");
  assert.equal(values[3], 0);
  // The same sources given as typed points.
  const typed = await c.field("spot", [3, "f:0:0.2,0.3,0.5"]);
  assertSameBits(typed, values, "field of [3, spec]");
  const face = await c.field("spot", new FacePoints([0], [0.2, 0.3, 0.5]));
  const faceOffline = join(work, "face.f64");
  offline(["field", "--source", "f:0:0.2,0.3,0.5", "--out", faceOffline]);
  assertSameBits(face, readF64(faceOffline), "field of FacePoints");
  // One position, snapped by the server as the CLI snaps it.
  const snapped = await c.field("spot", [0.1, 0.2, 0.3]);
  const snappedOffline = join(work, "xyz.f64");
  offline(["field", "--source", "xyz:0.1,0.2,0.3", "--out", snappedOffline]);
  assertSameBits(snapped, readF64(snappedOffline), "field of a position");
});

test("distances equal the offline pairs, a zero distance included", async () => {
  const pairs = [["v:0", "v:100"], ["f:12:0.2,0.3,0.5", "xyz:0.1,0.2,0.3"],
    ["e:5:0.25", "v:2000"], ["v:7", "v:7"]];
  writeFileSync(join(work, "pairs.txt"), pairs.map((p) => p.join(" ")).join("\n") + "\n");
  const want = JSON.parse(offline(["distance", "--pairs", join(work, "pairs.txt"), "--json"]))
    .map((r) => r.distance);
  // Ids, specs and a position (snapped by the server) mixed.
  const got = await c.distances("spot", [0, "f:12:0.2,0.3,0.5", "e:5:0.25", 7],
    ["v:100", [0.1, 0.2, 0.3], 2000, 7]);
  assertSameBits(got, Float64Array.from(want), "distances");
  assert.equal(got[3], 0);
  const edge = await c.distances("spot", new EdgePoints([5], [0.25]), Uint32Array.of(2000));
  assert.equal(edge[0], want[2]);
  assert.equal(await c.distance("spot", "v:0", 100), want[0]);
});

test("exact pairs equal the offline exact pairs", async () => {
  const pairs = [["v:0", "v:1500"], ["f:12:0.2,0.3,0.5", "e:5:0.25"]];
  writeFileSync(join(work, "exact.txt"), pairs.map((p) => p.join(" ")).join("\n") + "\n");
  const want = JSON.parse(offline(["distance", "--exact", "--pairs", join(work, "exact.txt"),
    "--json"])).map((r) => r.distance);
  assert.ok(want.length === 2 && want.every((d) => Number.isFinite(d) && d > 0), String(want));
  const got = await c.distances("spot", pairs.map((p) => p[0]), pairs.map((p) => p[1]),
    { exact: true });
  assertSameBits(got, Float64Array.from(want), "exact distances");
  // Not the graph's: an exact distance is at most the graph's.
  const graph = await c.distances("spot", pairs.map((p) => p[0]), pairs.map((p) => p[1]));
  got.forEach((d, i) => assert.ok(d <= graph[i], `pair ${i}: exact ${d} > graph ${graph[i]}`));
});

test("path equals the offline path", async () => {
  const want = JSON.parse(offline(["distance", "--from", "f:0:0.2,0.3,0.5", "--to", "v:1500",
    "--path", "--json"]));
  const path = await c.path("spot", "f:0:0.2,0.3,0.5", 1500);
  assertSameBits(path.xyz, Float64Array.from(want.path.flatMap((p) => p.xyz)), "path xyz");
  assert.equal(path.points.length, want.path.length);
  path.points.forEach((p, i) => {
    const numbers = (s) => s.split(/[:,]/).slice(1).map(Number);
    assert.deepEqual(numbers(p), numbers(want.path[i].point), `path point ${i}`);
  });
  assert.equal(path.length, want.path_length ?? want.distance);
});

test("matrix equals the offline matrix: float64, float32 its rounding, tiles, files", async () => {
  offline(["matrix", "--sources", "v:0", "v:1", "v:2", "--targets", "all", "--dtype", "float64",
    "--out", join(work, "m64.npy")]);
  offline(["matrix", "--sources", "v:0", "v:1", "v:2", "--targets", "all", "--dtype", "float32",
    "--out", join(work, "m32.npy")]);
  const m64 = readNpy(join(work, "m64.npy"));
  const m32 = readNpy(join(work, "m32.npy"));
  assert.deepEqual(m64.shape, [3, SPOT_VERTICES]);

  const whole64 = await c.matrix("spot", [0, 1, 2], null, { dtype: "float64" });
  assert.deepEqual([whole64.rows, whole64.cols, whole64.dtype], [3, SPOT_VERTICES, "float64"]);
  assertSameBits(whole64.data, m64.data, "matrix float64 (rows streamed)");
  const whole32 = await c.matrix("spot", [0, 1, 2], null);  // whole mesh: float32 by default
  assertSameBits(whole32.data, m32.data, "matrix float32");
  assertSameBits(whole32.data, Float32Array.from(m64.data), "float32 = float64 rounded");

  // Listed targets: over the daemon's --max-pairs 2000, refused with its
  // limit-max-pairs trailer, learnt, and tiled.
  const all = Uint32Array.from({ length: SPOT_VERTICES }, (_, i) => i);
  const listed = await c.matrix("spot", Uint32Array.of(0, 1, 2), all);
  assert.equal(listed.dtype, "float64");
  assertSameBits(listed.data, m64.data, "matrix of listed targets (Matrix, tiled)");
  assert.equal(c.maxPairs, 2000, "the server's --max-pairs, learnt from its trailer");
  const tiny = new Client({ address: c.address, token: TOKEN, epsilon: EPS, maxSources: 2,
    maxPairs: 700 });
  try {
    const tiled = await tiny.matrix("spot", [0, 1, 2], all, { dtype: "float32" });
    assertSameBits(tiled.data, m32.data, "matrix in 2 x 700 tiles");
  } finally {
    tiny.close();
  }

  const file = await c.matrix("spot", [0, 1, 2], null, { out: join(work, "client.npy") });
  assert.equal(file.path, join(work, "client.npy"));
  const back = readNpy(join(work, "client.npy"));
  assert.deepEqual(back.shape, [3, SPOT_VERTICES]);
  assertSameBits(back.data, m32.data, "matrix streamed to an .npy");
  const into = new Float64Array(3 * SPOT_VERTICES);
  const filled = await c.matrix("spot", [0, 1, 2], null, { out: into });
  assert.equal(filled.data, into);
  assertSameBits(into, m64.data, "matrix into the caller's Float64Array");
});

test("neighbourhoodMatrix equals the offline sparse matrix", async () => {
  for (const dtype of ["float32", "float64"]) {
    const out = join(work, `n-${dtype}.npz`);
    offline(["matrix", "--sources", "v:0", "v:1", "v:2", "--targets", "all", "--radius", "0.3",
      "--dtype", dtype, "--out", out]);
    const want = readNpz(out);
    const tiny = new Client({ address: c.address, token: TOKEN, epsilon: EPS, maxPairs: 1000 });
    try {
      for (const [how, client, targets] of [["whole", c, null],
        ["tiled", tiny, Uint32Array.from({ length: SPOT_VERTICES }, (_, i) => i)]]) {
        const got = await client.neighbourhoodMatrix("spot", 0.3,
          { sources: [0, 1, 2], targets, dtype });
        const what = `neighbourhood ${dtype} ${how}`;
        assert.deepEqual([got.rows, got.cols], [3, SPOT_VERTICES], what);
        assertSameBits(got.indptr, Float64Array.from(want.indptr.data, Number), `${what} indptr`);
        assertSameBits(got.indices, Uint32Array.from(want.indices.data, Number),
          `${what} indices`);
        assertSameBits(got.data, want.data.data, `${what} values`);
      }
    } finally {
      tiny.close();
    }
  }
});

test("a MeshSolver answers as its client does", async () => {
  const spot = c.meshSolver("spot");
  assert.equal(spot.mesh(), spot.mesh(), "the mesh is fetched once");
  assert.equal((await spot.mesh()).diagnostics.vertices, SPOT_VERTICES);
  assert.equal((await spot.graph()).epsilon, EPS);
  assertSameBits(await spot.distances([0, 1], [100, 200]),
    await c.distances("spot", [0, 1], [100, 200]), "solver distances");
  assertSameBits(await spot.field([3]), await c.field("spot", [3]), "solver field");
  assertSameBits((await spot.matrix([0], null)).data, (await c.matrix("spot", [0], null)).data,
    "solver matrix");
});

test("uploadMesh from typed arrays and from a file registers the same mesh", async () => {
  const spot = await c.mesh("spot");
  const geometry = await c.geometry("spot");
  assert.equal(geometry.vertices.length, 3 * SPOT_VERTICES);
  const fromArrays = await c.uploadMesh("spot-arrays",
    { vertices: geometry.vertices, faces: geometry.faces }, { chunkBytes: 10000 });
  assert.equal(fromArrays.fingerprint, spot.fingerprint);
  assert.equal(fromArrays.source, "upload");
  const back = await c.geometry("spot-arrays");
  assertSameBits(back.vertices, geometry.vertices, "uploaded vertices");
  assertSameBits(back.faces, geometry.faces, "uploaded faces");
  const fromFile = await c.uploadMesh("spot-file", SPOT, { chunkBytes: 65536 });
  assert.equal(fromFile.fingerprint, spot.fingerprint);
  assert.equal(fromFile.diagnostics.vertices, SPOT_VERTICES);
  await assert.rejects(c.uploadMesh("nothing", join(work, "missing.obj")), /ENOENT/);
});

test("errors are typed classes carrying the gRPC code", async () => {
  const anonymous = new Client({ address: c.address, epsilon: EPS });
  try {
    const t = Date.now();
    await assert.rejects(anonymous.mesh("spot"), (e) => e instanceof UnauthenticatedError &&
      e.code === status.UNAUTHENTICATED && /Bearer/.test(e.details));
    assert.ok(Date.now() - t < 5000, "an UNAUTHENTICATED call is not retried");
  } finally {
    anonymous.close();
  }
  await assert.rejects(c.mesh("no-such-mesh"), (e) => e instanceof NotFoundError &&
    e.code === status.NOT_FOUND && e.codeName === "NOT_FOUND");
  await assert.rejects(c.distance("spot", 0, 10 ** 6), OutOfRangeError);
  await assert.rejects(c.distance("spot", "v:x", 1), RangeError);
});

test("a call past its deadline is DeadlineExceededError, not retried", async () => {
  const hasty = new Client({ address: c.address, token: TOKEN, epsilon: EPS, timeout: 0.001 });
  try {
    await assert.rejects(hasty.matrix("spot", null, null), (e) =>
      e instanceof DeadlineExceededError && e.code === status.DEADLINE_EXCEEDED);
  } finally {
    hasty.close();
  }
});

test("a query on a graph still building is retried after the server's retry-after-ms", async () => {
  const eps = 0.002;
  await c.requestGraph("spot", { epsilon: eps, wait: false });
  const retries = [];
  const patient = new Client({ address: c.address, token: TOKEN, timeout: 0.3,
    retry: { onRetry: (e, delayMs) => retries.push({ e, delayMs, at: Date.now() }) } });
  try {
    const t = Date.now();
    const d = await patient.distance("spot", 0, 1500, { epsilon: eps });
    assert.ok(Number.isFinite(d) && d > 0, `distance ${d}`);
    assert.ok(retries.length >= 1, "the first attempt was answered: the build was too fast");
    for (const { e, delayMs } of retries) {
      assert.ok(e instanceof UnavailableError, `${e}`);
      assert.ok(e.retryAfterMs >= 1000, `retry-after-ms ${e.retryAfterMs}`);
      assert.ok(delayMs >= e.retryAfterMs, `waited ${delayMs} ms, asked ${e.retryAfterMs}`);
      assert.ok(typeof e.graphState === "string" && e.graphProgress >= 0, `${e.graphState}`);
    }
    assert.ok(Date.now() - t >= retries[0].delayMs, "the wait happened");
  } finally {
    patient.close();
  }
});

test("20 queries with a 300 ms deadline on a building graph: UNAVAILABLE with its hint", async () => {
  const g = await c.requestGraph("spot", { epsilon: SLOW_EPS, wait: false });
  assert.ok([GraphState.QUEUED, GraphState.BUILDING].includes(g.state), GraphState[g.state]);
  const hasty = new Client({ address: c.address, token: TOKEN, timeout: 0.3,
    retry: { maxAttempts: 1 } });
  const seen = [];
  try {
    for (let k = 0; k < 20; k++) {
      const t = Date.now();
      try {
        await hasty.distance("spot", k, 500 + k, { epsilon: SLOW_EPS });
        seen.push({ code: "OK" });
      } catch (e) {
        seen.push({ code: e.codeName, hint: e.retryAfterMs, state: e.graphState,
          progress: e.graphProgress, ms: Date.now() - t, unavailable: e instanceof UnavailableError });
      }
    }
  } finally {
    hasty.close();
  }
  const withHint = seen.filter((s) => s.unavailable && s.hint > 0 && s.state &&
    s.progress >= 0 && s.progress <= 1);
  console.log(`# 300 ms deadline on a building graph: ${withHint.length} of 20 UNAVAILABLE ` +
    `with retry-after-ms, graph-state and graph-progress; codes ` +
    `${JSON.stringify(seen.map((s) => s.code))}, ms ${JSON.stringify(seen.map((s) => s.ms))}`);
  assert.ok(withHint.length >= 19, JSON.stringify(seen));

  // Cancelled, the graph's watch ends CANCELLED (within 30 s).
  await c.cancelGraph("spot", { epsilon: SLOW_EPS });
  const states = [];
  const watched = (async () => {
    for await (const s of c.watchGraph("spot", { epsilon: SLOW_EPS })) states.push(s.state);
  })();
  const timer = new Promise((_, reject) => setTimeout(() => reject(new Error(
    `still watching after 30 s: ${states.map((s) => GraphState[s])}`)), 30000).unref());
  await Promise.race([watched, timer]);
  assert.equal(states.at(-1), GraphState.CANCELLED, states.map((s) => GraphState[s]).join());
  assert.equal((await c.graph("spot", { epsilon: SLOW_EPS })).state, GraphState.CANCELLED);
});

test("an overloaded server's RESOURCE_EXHAUSTED is retried after its retry-after-ms", async () => {
  // One query admitted at a time: one waiting on a build holds the slot
  // (2.5 s); another queues for a second, then is refused as an overload,
  // with a hint. The graph the polite client uses is mapped from its file.
  mkdirSync(join(work, "busy"));
  copyFileSync(graphFile(), join(work, "busy", basename(graphFile())));
  const busy = await startDaemon(BIN, work, ["--graph-dir", join(work, "busy"),
    "--max-inflight", "1", "--min-epsilon",
    String(SLOW_EPS), "--build-threads", "1", "--log-level", "error"]);
  const holder = new Client({ address: `127.0.0.1:${busy.port}`, timeout: 2.5,
    retry: { maxAttempts: 1 } });
  const retries = [];
  const polite = new Client({ address: `127.0.0.1:${busy.port}`, epsilon: EPS,
    retry: { initialBackoff: 0.001, maxBackoff: 0.001, maxAttempts: 200,
      onRetry: (e, delayMs) => retries.push({ e, delayMs }) } });
  try {
    await polite.requestGraph("spot");
    await holder.requestGraph("spot", { epsilon: SLOW_EPS, wait: false });
    const held = holder.distance("spot", 0, 1, { epsilon: SLOW_EPS }).catch((e) => e);
    await new Promise((r) => setTimeout(r, 200));  // the holder is admitted first
    const d = await polite.distance("spot", 0, 1500);
    assert.ok(Number.isFinite(d) && d > 0, `distance ${d}`);
    assert.ok(retries.length >= 1, "the polite query was never refused");
    for (const { e, delayMs } of retries) {
      assert.ok(e instanceof ResourceExhaustedError && e.overloaded, `${e}`);
      assert.ok(e.retryAfterMs > 0 && delayMs >= e.retryAfterMs,
        `waited ${delayMs} ms, asked ${e.retryAfterMs}`);
    }
    const refusal = await held;
    assert.ok(refusal instanceof UnavailableError, `${refusal}`);
    await holder.cancelGraph("spot", { epsilon: SLOW_EPS });
  } finally {
    holder.close();
    polite.close();
    await busy.stop();
  }
});
