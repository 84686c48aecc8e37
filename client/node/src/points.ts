// Surface points: from ids, typed arrays and spec strings to the wire's
// SurfacePoint (or a Vec3 position, which the server snaps), and back to
// spec strings. Everything is checked here, before any call.
import type { SurfacePointMsg, Vec3Msg } from "./wire";

/** N points inside faces: face ids (N) and barycentric coordinates (3 N, b0 b1 b2 of each
 * point, flattened). The coordinates weight each face's vertices in the order the mesh file
 * lists them; they must be non-negative and sum to 1 (within 1e-6). */
export class FacePoints {
  constructor(readonly faces: ArrayLike<number>, readonly barycentrics: ArrayLike<number>) {}
}

/** N points on edges: edge ids (N) and t (N), the point (1 - t) first + t second vertex. */
export class EdgePoints {
  constructor(readonly edges: ArrayLike<number>, readonly t: ArrayLike<number>) {}
}

/** One point: a vertex id, a spec string ("v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2",
 * "xyz:X,Y,Z"), or a position [x, y, z] that the server snaps to the surface. */
export type Point = number | string | readonly [number, number, number] | Float64Array;

/** A set of points:
 * - Uint32Array, Int32Array or an array of integers: vertex ids;
 * - Float64Array or Float32Array: positions, x y z of each point flattened (as geometry()
 *   returns vertices), snapped to the surface by the server;
 * - FacePoints, EdgePoints;
 * - an array of Points (ids, spec strings and [x, y, z] positions may mix). */
export type Points = Uint32Array | Int32Array | Uint16Array | Uint8Array | Float64Array |
  Float32Array | FacePoints | EdgePoints | readonly Point[];

/** A point as the wire carries it: a SurfacePoint, or a position still to snap. */
export type WirePoint = SurfacePointMsg | Vec3Msg;

export function isPosition(p: WirePoint): p is Vec3Msg {
  return "x" in p;
}

const MAX_ID = 2 ** 32 - 1;

function id(value: number, what: string): number {
  if (!Number.isInteger(value) || value < 0 || value > MAX_ID) {
    throw new RangeError(`${what}: ${value} is not an id in [0, 2^32)`);
  }
  return value;
}

function finite(value: number, what: string): number {
  if (!Number.isFinite(value)) throw new RangeError(`${what}: ${value} is not a finite number`);
  return value;
}

function parseNumber(text: string, what: string): number {
  const t = text.trim().replace(/^([-+]?)inf(inity)?$/i, "$1Infinity");
  const value = Number(t);
  // Number("") is 0: not a coordinate anyone wrote.
  if (t === "" || Number.isNaN(value)) {
    throw new RangeError(`bad surface point ${JSON.stringify(what)}: ` +
      `${JSON.stringify(text)} is not a number`);
  }
  return value;
}

function parseId(text: string, what: string): number {
  if (!/^\d+$/.test(text)) {
    throw new RangeError(`bad surface point ${JSON.stringify(what)}: ` +
      `${JSON.stringify(text)} is not an id`);
  }
  return id(Number(text), what);
}

/** Parses "v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2" or "xyz:X,Y,Z" (the CLI's spec strings). */
export function parsePoint(text: string): WirePoint {
  const colon = text.indexOf(":");
  const kind = colon < 0 ? text : text.slice(0, colon);
  const rest = colon < 0 ? "" : text.slice(colon + 1);
  if (kind === "v") return { vertex: parseId(rest, text) };
  if (kind === "e") {
    const [edge, t, extra] = rest.split(":");
    if (edge === undefined || t === undefined || extra !== undefined) {
      throw new RangeError(`bad surface point ${JSON.stringify(text)}: expected e:EDGE:T`);
    }
    return { edge: { edge: parseId(edge, text), t: parseNumber(t, text) } };
  }
  if (kind === "f") {
    const sep = rest.indexOf(":");
    const b = sep < 0 ? [] : rest.slice(sep + 1).split(",");
    if (sep < 0 || b.length !== 3) {
      throw new RangeError(`bad surface point ${JSON.stringify(text)}: ` +
        "a face point needs three barycentric coordinates");
    }
    const [b0, b1, b2] = b.map((x) => parseNumber(x, text)) as [number, number, number];
    return { face: { face: parseId(rest.slice(0, sep), text), b0, b1, b2 } };
  }
  if (kind === "xyz") {
    const x = rest.split(",");
    if (x.length !== 3) {
      throw new RangeError(`bad surface point ${JSON.stringify(text)}: ` +
        "a position needs three coordinates");
    }
    const [px, py, pz] = x.map((v) => parseNumber(v, text)) as [number, number, number];
    return { x: px, y: py, z: pz };
  }
  throw new RangeError(`bad surface point ${JSON.stringify(text)}: expected v:, e:, f: or xyz:`);
}

/** The spec string of a surface point; numbers in their shortest exact form, so that the
 * string parses back to the same point. */
export function formatPoint(p: SurfacePointMsg): string {
  const which = p.point ?? (p.face ? "face" : p.edge ? "edge" : "vertex");
  if (which === "edge" && p.edge) return `e:${p.edge.edge}:${p.edge.t}`;
  if (which === "face" && p.face) {
    const f = p.face;
    return `f:${f.face}:${f.b0},${f.b1},${f.b2}`;
  }
  return `v:${p.vertex ?? 0}`;
}

function position(xyz: ArrayLike<number>, what: string): Vec3Msg {
  return {
    x: finite(Number(xyz[0]), what), y: finite(Number(xyz[1]), what),
    z: finite(Number(xyz[2]), what),
  };
}

/** One point to the wire. */
export function toWirePoint(point: Point, what = "point"): WirePoint {
  if (typeof point === "number") return { vertex: id(point, what) };
  if (typeof point === "string") return parsePoint(point);
  if ((Array.isArray(point) || point instanceof Float64Array) && point.length === 3) {
    return position(point, what);
  }
  throw new TypeError(`${what}: ${String(point)} is not a vertex id, a spec string or a ` +
    "position [x, y, z]");
}

/** One position given where a set of points may be: three numbers, not all integers (three
 * integers are three vertex ids), as the Python client tells a position from ids. */
export function isOnePosition(value: unknown): value is readonly [number, number, number] {
  return Array.isArray(value) && value.length === 3 &&
    value.every((x) => typeof x === "number") && !value.every(Number.isInteger);
}

/** A set of points to the wire. */
export function toWirePoints(points: Points): WirePoint[] {
  if (points instanceof FacePoints) {
    const n = points.faces.length;
    if (points.barycentrics.length !== 3 * n) {
      throw new RangeError(`FacePoints: ${n} faces need ${3 * n} barycentrics, ` +
        `got ${points.barycentrics.length}`);
    }
    const b = points.barycentrics;
    const coordinate = (k: number): number => finite(Number(b[k]), `barycentrics[${k}]`);
    return Array.from({ length: n }, (_, i) => ({
      face: {
        face: id(Number(points.faces[i]), `face ids[${i}]`), b0: coordinate(3 * i),
        b1: coordinate(3 * i + 1), b2: coordinate(3 * i + 2),
      },
    }));
  }
  if (points instanceof EdgePoints) {
    if (points.t.length !== points.edges.length) {
      throw new RangeError(`EdgePoints: ${points.edges.length} edges but ${points.t.length} t`);
    }
    return Array.from({ length: points.edges.length }, (_, i) => ({
      edge: {
        edge: id(Number(points.edges[i]), `edge ids[${i}]`),
        t: finite(Number(points.t[i]), `t[${i}]`),
      },
    }));
  }
  if (points instanceof Float64Array || points instanceof Float32Array) {
    if (points.length % 3 !== 0) {
      throw new RangeError(`positions: ${points.length} values are not x, y, z triples`);
    }
    return Array.from({ length: points.length / 3 }, (_, i) =>
      position(points.subarray(3 * i, 3 * i + 3), `positions[${i}]`));
  }
  if (ArrayBuffer.isView(points)) {
    return Array.from(points, (v, i) => ({ vertex: id(v, `vertex ids[${i}]`) }));
  }
  if (typeof points === "string" || typeof points === "number" || !Array.isArray(points)) {
    throw new TypeError(`expected a set of points, got ${JSON.stringify(points)}: ` +
      "wrap a single point in an array");
  }
  return points.map((p, i) => toWirePoint(p, `point ${i}`));
}

/** Target vertex ids, checked. */
export function toVertexIds(ids: ArrayLike<number>, what = "targets"): number[] {
  return Array.from(ids, (v, i) => id(v, `${what}[${i}]`));
}
