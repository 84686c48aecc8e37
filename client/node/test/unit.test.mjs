// The package's parts without a daemon: the traps of decoding (64-bit
// fields, zero values, unaligned packed rows), points, errors and retry
// delays.
import "./fresh.mjs";  // before dist/ is used
import assert from "node:assert/strict";
import { Metadata } from "@grpc/grpc-js";
import { test } from "node:test";
import {
  FacePoints, formatPoint, GeodesicError, parsePoint, ResourceExhaustedError, retryDelayMs,
  retryPolicy, status, UnavailableError,
} from "../dist/index.js";
import { fromGrpcError } from "../dist/errors.js";
import { toBigInt, toNumber, toUint64 } from "../dist/longs.js";
import { isOnePosition, toWirePoints } from "../dist/points.js";
import { ArraySink, npyHeader, unpack } from "../dist/sinks.js";
import { graphFromWire } from "../dist/types.js";
import { methods } from "../dist/wire.js";

const api = methods();

function roundTrip(name, message) {
  const m = api[name];
  return m.responseDeserialize(m.responseSerialize(message));
}

test("64-bit fields become exact numbers, never strings or Longs", () => {
  const chunk = roundTrip("DistanceField", { offset: 4096, total: 10000, values: [1, 2] });
  assert.equal(toNumber(chunk.offset, "offset") + 1, 4097);  // not "40961"
  assert.equal(toNumber("9007199254740991", "x"), Number.MAX_SAFE_INTEGER);
  assert.throws(() => toNumber("9007199254740993", "Graph.edges"), /Graph.edges/);
  assert.equal(toNumber({ toString: () => "12" }, "long"), 12);  // a Long object
  assert.equal(toBigInt("18446744073709551615", "seed"), 2n ** 64n - 1n);
  assert.equal(toUint64(2n ** 63n, "seed"), "9223372036854775808");
  assert.throws(() => toUint64(-1, "seed"), RangeError);
  const g = graphFromWire(roundTrip("GetGraph", {
    mesh: "m", epsilon: 0.01, state: 4, bytes: "5000000000", edges: 3, nodes: 2,
    last_used_unix_ms: "1764662400000",
    certificate: { seed: "18446744073709551615", max_error_bound: 0.01 },
  }));
  assert.equal(g.bytes, 5e9);
  assert.equal(g.lastUsedUnixMs, 1764662400000);
  assert.equal(g.certificate.seed, 2n ** 64n - 1n);
});

test("zero values are decoded, not dropped", () => {
  const chunk = roundTrip("DistanceField", { offset: 0, total: 2, values: [0, 1] });
  assert.equal(toNumber(chunk.offset, "offset"), 0);
  const rows = roundTrip("MatrixRows", { first_row: 0, rows: 1, cols: 1, dtype: 0 });
  assert.equal(rows.first_row, 0);
  assert.equal(rows.dtype, 0);
  const pair = roundTrip("Distance", { results: [{ distance: 0, reachable: true }] });
  assert.equal(pair.results[0].distance, 0);
});

test("packed rows at an odd byte offset are copied out, not viewed", () => {
  const values = Float64Array.of(0.5, Infinity, 3);
  const message = roundTrip("Matrix", { rows: 1, cols: 3, dtype: 1,
    packed: Buffer.from(values.buffer) });
  const odd = Buffer.concat([Buffer.alloc(1), message.packed]).subarray(1);
  assert.notEqual(odd.byteOffset % 8, 0);
  assert.throws(() => new Float64Array(odd.buffer, odd.byteOffset, 3), RangeError);
  assert.deepEqual(unpack(odd, "float64", 3), values);
  const sink = new ArraySink(2, 3, "float64", new Float64Array(6));
  return sink.writePacked(1, 0, 1, 3, odd).then(() => {
    assert.deepEqual(Array.from(sink.data), [0, 0, 0, 0.5, Infinity, 3]);
  });
});

test("an .npy header is 64-byte aligned and names the dtype and shape", () => {
  const header = npyHeader(3, 2930, "float32");
  assert.equal(header.length % 64, 0);
  assert.equal(header.readUInt16LE(8), header.length - 10);
  assert.match(header.toString("latin1"), /'descr': '<f4'.*'shape': \(3, 2930\)/);
  assert.equal(header.at(-1), 0x0a);
});

test("points: spec strings round-trip, typed arrays are ids or positions", () => {
  for (const spec of ["v:12", "e:5:0.25", "f:7:0.2,0.3,0.5"]) {
    assert.equal(formatPoint(parsePoint(spec)), spec);
  }
  assert.deepEqual(parsePoint("xyz:0.1,-2,3e-3"), { x: 0.1, y: -2, z: 0.003 });
  for (const bad of ["v:", "v:-1", "v:1.5", "f:1:0.5,0.5", "q:1", "e:1", "v:4294967296"]) {
    assert.throws(() => parsePoint(bad), RangeError, bad);
  }
  assert.deepEqual(toWirePoints(Uint32Array.of(1, 2)), [{ vertex: 1 }, { vertex: 2 }]);
  assert.deepEqual(toWirePoints(Float64Array.of(1, 2, 3)), [{ x: 1, y: 2, z: 3 }]);
  assert.deepEqual(toWirePoints([4, "v:5", [1, 2, 3]]),
    [{ vertex: 4 }, { vertex: 5 }, { x: 1, y: 2, z: 3 }]);
  assert.deepEqual(toWirePoints(new FacePoints([7], [0.2, 0.3, 0.5])),
    [{ face: { face: 7, b0: 0.2, b1: 0.3, b2: 0.5 } }]);
  assert.throws(() => toWirePoints([1.5]), RangeError);
  assert.throws(() => toWirePoints(new FacePoints([7], [0.2, 0.3])), RangeError);
  assert.throws(() => toWirePoints(Float64Array.of(1, 2)), RangeError);
  assert.ok(isOnePosition([0.1, 0.2, 0.3]));
  assert.ok(!isOnePosition([1, 2, 3]), "three integers are three vertex ids");
});

function grpcError(code, details, trailers) {
  const metadata = new Metadata();
  for (const [key, value] of Object.entries(trailers)) metadata.set(key, value);
  return Object.assign(new Error(details), { code, details, metadata });
}

test("errors are the class of their code, with the trailers' hints", () => {
  const unavailable = fromGrpcError(grpcError(status.UNAVAILABLE, "still building", {
    "retry-after-ms": "1500", "graph-state": "building", "graph-progress": "0.2500",
  }), "Distance");
  assert.ok(unavailable instanceof UnavailableError && unavailable instanceof GeodesicError);
  assert.equal(unavailable.code, status.UNAVAILABLE);
  assert.equal(unavailable.codeName, "UNAVAILABLE");
  assert.equal(unavailable.retryAfterMs, 1500);
  assert.equal(unavailable.graphState, "building");
  assert.equal(unavailable.graphProgress, 0.25);
  assert.match(unavailable.message, /UNAVAILABLE: still building \(Distance\)/);
  const limit = fromGrpcError(grpcError(status.RESOURCE_EXHAUSTED, "too many pairs",
    { "limit-max-pairs": "10000" }), "Distance");
  assert.ok(limit instanceof ResourceExhaustedError);
  assert.deepEqual(limit.limits, { "max-pairs": 10000 });
  assert.equal(limit.overloaded, false);
  const overload = fromGrpcError(grpcError(status.RESOURCE_EXHAUSTED, "server overloaded",
    { "retry-after-ms": "15" }), "Distance");
  assert.equal(overload.overloaded, true);
  const bug = new TypeError("not a gRPC error");
  assert.equal(fromGrpcError(bug, "Distance"), bug);
});

test("retry delays: jittered backoff, never below the server's hint", () => {
  const policy = retryPolicy();
  const half = () => 0.5;
  const unavailable = new UnavailableError(status.UNAVAILABLE, "x", "m", {});
  assert.equal(retryDelayMs(policy, unavailable, 1, half), 75);   // 100 ms, jittered
  assert.equal(retryDelayMs(policy, unavailable, 3, half), 300);  // 400 ms, jittered
  assert.equal(retryDelayMs(policy, unavailable, 7, half), 1500); // capped at 2 s
  assert.equal(retryDelayMs(policy, unavailable, 8, half), null); // 8 attempts made
  const hinted = new UnavailableError(status.UNAVAILABLE, "x", "m", { "retry-after-ms": "1200" });
  assert.equal(retryDelayMs(policy, hinted, 1, half), 1200);
  const overload = new ResourceExhaustedError(status.RESOURCE_EXHAUSTED, "x", "m",
    { "retry-after-ms": "900" });
  assert.equal(retryDelayMs(policy, overload, 1, half), 900);
  assert.equal(retryDelayMs(retryPolicy({ overload: false }), overload, 1, half), null);
  const limit = new ResourceExhaustedError(status.RESOURCE_EXHAUSTED, "x", "m",
    { "limit-max-pairs": "10" });
  assert.equal(retryDelayMs(policy, limit, 1, half), null);
  const notFound = new GeodesicError(status.NOT_FOUND, "x");
  assert.equal(retryDelayMs(policy, notFound, 1, half), null);
  assert.throws(() => retryPolicy({ maxAttempts: 0 }), RangeError);
});

test("the public declarations use no `any`", async () => {
  const { readdirSync, readFileSync } = await import("node:fs");
  const dist = new URL("../dist/", import.meta.url);
  for (const file of readdirSync(dist).filter((f) => f.endsWith(".d.ts"))) {
    // Comments say "any" in prose; only code counts.
    const code = readFileSync(new URL(file, dist), "utf8")
      .replace(/\/\*[\s\S]*?\*\//g, "").replace(/\/\/.*$/gm, "");
    assert.doesNotMatch(code, /\bany\b/, file);
  }
});
