// Point sets cut into calls within the server's limits: positions snapped
// maxPairs at a time, fields maxSources sources at a time (combined by their
// minimum), distances maxPairs pairs at a time (fewer with paths), each
// batch shrunk when the server refuses it.
import { GeodesicError } from "./errors";
import { toNumber } from "./longs";
import { Limits, MAX_PAIRS, MAX_SOURCES } from "./limits";
import { formatPoint, isPosition, WirePoint } from "./points";
import type { Transport } from "./transport";
import type { Path } from "./types";
import type {
  DistanceFieldRequest, GraphSelectorMsg, PairResultMsg, SurfacePointMsg, Vec3Msg,
} from "./wire";

/** SurfacePoints for wire points, positions snapped by the server in batches. */
export async function resolve(transport: Transport, limits: Limits, mesh: string,
  points: WirePoint[]): Promise<SurfacePointMsg[]> {
  const out = points.slice();
  const at = points.flatMap((p, i) => (isPosition(p) ? [i] : []));
  for (let start = 0; start < at.length;) {
    const chunk = at.slice(start, start + limits.maxPairs);
    let snapped;
    try {
      snapped = await transport.unary("Snap", {
        mesh, positions: chunk.map((i) => points[i] as Vec3Msg),
      }, mesh);
    } catch (e) {
      if (e instanceof GeodesicError && limits.learn(e, MAX_PAIRS, chunk.length)) continue;
      throw e;
    }
    chunk.forEach((i, k) => { out[i] = snapped.points[k]!; });
    start += chunk.length;
  }
  return out as SurfacePointMsg[];
}

export interface FieldOptions {
  targets: number[];
  maxDistance: number;
  method: string;
  nearestSource: boolean;
}

interface FieldPart { values: Float64Array; labels: Uint32Array | null }

// One DistanceField stream, read into arrays. Offsets and totals are uint64
// (strings on the wire: longs.ts); a chunk at offset 0 restarts the field.
async function readField(transport: Transport, request: DistanceFieldRequest): Promise<FieldPart> {
  let values = new Float64Array(0);
  let labels: Uint32Array | null = null;
  for await (const chunk of transport.stream("DistanceField", request, request.graph.mesh)) {
    const offset = toNumber(chunk.offset, "DistanceFieldChunk.offset");
    const total = toNumber(chunk.total, "DistanceFieldChunk.total");
    if (offset === 0 && values.length !== total) {
      values = new Float64Array(total);
      labels = request.nearest_source ? new Uint32Array(total) : null;
    }
    if (offset + chunk.values.length > values.length) {
      throw new Error(`DistanceField: a chunk at ${offset} of ${chunk.values.length} values ` +
        `passes the field's ${values.length}`);
    }
    values.set(chunk.values, offset);
    if (labels) labels.set(chunk.nearest_source, offset);
  }
  return { values, labels };
}

/** The field of `points`, computed maxSources sources at a time and combined by their
 * minimum (labels: the index in `points` of each value's nearest source). */
export async function field(transport: Transport, limits: Limits, graph: GraphSelectorMsg,
  points: SurfacePointMsg[], options: FieldOptions): Promise<FieldPart> {
  let result: FieldPart | null = null;
  for (let start = 0; start < points.length;) {
    const batch = points.slice(start, start + limits.maxSources);
    const request: DistanceFieldRequest = {
      graph, sources: batch, targets: options.targets, max_distance: options.maxDistance,
      method: options.method, nearest_source: options.nearestSource,
    };
    let part: FieldPart;
    try {
      part = await transport.call(() => readField(transport, request));
    } catch (e) {
      if (e instanceof GeodesicError && limits.learn(e, MAX_SOURCES, batch.length)) continue;
      throw e;
    }
    if (result === null) {
      result = part;
    } else {
      for (let i = 0; i < part.values.length; i++) {
        if (part.values[i]! < result.values[i]!) {
          result.values[i] = part.values[i]!;
          if (result.labels && part.labels) result.labels[i] = part.labels[i]! + start;
        }
      }
    }
    start += batch.length;
  }
  return result ?? { values: new Float64Array(0), labels: null };
}

/** The Path of one of Distance's results. */
export function pathOf(result: PairResultMsg): Path {
  const points = result.path?.points ?? [];
  const xyz = new Float64Array(3 * points.length);
  points.forEach((p, i) => {
    xyz[3 * i] = p.xyz?.x ?? 0;
    xyz[3 * i + 1] = p.xyz?.y ?? 0;
    xyz[3 * i + 2] = p.xyz?.z ?? 0;
  });
  return Object.freeze({
    length: result.reachable ? (result.path?.length ?? 0) : Infinity,
    xyz,
    points: Object.freeze(points.map((p) => (p.point ? formatPoint(p.point) : ""))),
  });
}

/** Distances (and with withPath, paths) between a[i] and b[i]. */
export async function distances(transport: Transport, limits: Limits, graph: GraphSelectorMsg,
  a: SurfacePointMsg[], b: SurfacePointMsg[], withPath: boolean,
  exact: boolean): Promise<{ values: Float64Array; paths: Path[] }> {
  const values = new Float64Array(a.length);
  const paths: Path[] = [];
  // Shrinks with every "too large" answer, so that a retry never repeats a
  // batch the server (or the channel) refused.
  let batch = withPath ? Math.min(limits.maxPairs, limits.pathBatch) : limits.maxPairs;
  for (let i = 0; i < a.length;) {
    const j = Math.min(a.length, i + batch);
    const pairs = [];
    for (let k = i; k < j; k++) pairs.push({ from: a[k]!, to: b[k]! });
    let response;
    try {
      response = await transport.unary("Distance", {
        graph, pairs, with_path: withPath, exact,
      }, graph.mesh);
    } catch (e) {
      const smaller = e instanceof GeodesicError
        ? limits.smallerPairBatch(e, j - i, withPath) : null;
      if (smaller === null) throw e;
      batch = smaller;
      continue;
    }
    if (response.results.length !== j - i) {
      throw new Error(`Distance: ${response.results.length} results for ${j - i} pairs`);
    }
    response.results.forEach((r, k) => { values[i + k] = r.distance; });
    if (withPath) paths.push(...response.results.map(pathOf));
    i = j;
  }
  return { values, paths };
}
