// The geodesicd client: its public API, over a transport (transport.ts), the
// batching of point sets (batches.ts) and matrices (matrix.ts, sparse.ts)
// within the server's limits, and graphs' operations (graphs.ts). Names and
// defaults are the Python client's (geodesic_client.Client), in camelCase.
import * as batches from "./batches";
import { requestGraph, watchGraph } from "./graphs";
import {
  DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_MAX_PAIRS, DEFAULT_MAX_SOURCES, DEFAULT_PATH_BATCH, Limits,
} from "./limits";
import { toNumber, toUint64 } from "./longs";
import { Matrices } from "./matrix";
import type {
  ClientOptions, DenseMatrix, DistanceOptions, FieldOptions, GraphOptions, MatrixFile,
  MatrixOptions, NeighbourhoodOptions, RequestGraphOptions, UploadOptions,
} from "./options";
import {
  formatPoint, isOnePosition, Point, Points, toVertexIds, toWirePoint, toWirePoints,
  WirePoint,
} from "./points";
import { RetryPolicy, retryPolicy } from "./retry";
import { ArraySink, Dtype, FileSink, MatrixArray, Sink } from "./sinks";
import { MeshSolver } from "./solver";
import { CsrMatrix, neighbourhood } from "./sparse";
import { Transport } from "./transport";
import { Geometry, Graph, graphFromWire, Mesh, meshFromWire, Path } from "./types";
import { MeshArrays, uploadChunks } from "./upload";
import type { GraphSelectorMsg, SurfacePointMsg } from "./wire";

/** Where a Client connects when given no address: $GEODESIC_SERVER, else this (the geodesic
 * command line and the Python client use the same default). */
export const DEFAULT_ADDRESS = "127.0.0.1:50051";
export const ADDRESS_ENV = "GEODESIC_SERVER";

function checkDtype(dtype: string): Dtype {
  if (dtype !== "float32" && dtype !== "float64") {
    throw new RangeError(`dtype ${dtype} is not "float32" or "float64"`);
  }
  return dtype;
}

/** A connection to one geodesicd (or a proxy in front of several).
 *
 * Points are vertex ids, FacePoints, EdgePoints, positions (snapped by the server) or spec
 * strings (see Points). Batches larger than the server's limits are split into several calls
 * and the results reassembled in order. Calls failing with UNAVAILABLE (a graph still
 * building, the server not reachable yet) or an overload are retried per `retry`, waiting at
 * least the server's retry-after-ms. Failures reject with GeodesicError subclasses carrying
 * the gRPC code; malformed arguments with RangeError or TypeError before any call. */
export class Client {
  readonly address: string;
  /** The graph accuracy used when a call gives none (0: the server's default). */
  epsilon: number;
  private readonly transport: Transport;
  private readonly limits: Limits;
  private readonly matrices: Matrices;

  constructor(options: ClientOptions = {}) {
    this.address = options.address ?? (process.env[ADDRESS_ENV] || DEFAULT_ADDRESS);
    const retry = retryPolicy(options.retry);
    const maxMessageBytes = options.maxMessageBytes ?? DEFAULT_MAX_MESSAGE_BYTES;
    this.transport = new Transport({
      address: this.address, timeout: options.timeout ?? 600, token: options.token,
      rootCertificates: options.rootCertificates, privateKey: options.privateKey,
      certificateChain: options.certificateChain, retry, maxMessageBytes,
    });
    this.limits = new Limits(options.maxPairs ?? DEFAULT_MAX_PAIRS,
      options.maxSources ?? DEFAULT_MAX_SOURCES, maxMessageBytes,
      options.pathBatch ?? DEFAULT_PATH_BATCH);
    this.matrices = new Matrices(this.transport, this.limits);
    this.epsilon = options.epsilon ?? 0;
  }

  /** The deadline of each call, seconds; setting it changes the calls that follow. */
  get timeout(): number { return this.transport.timeout; }
  set timeout(seconds: number) {
    if (!(seconds > 0)) throw new RangeError(`timeout ${seconds} is not a positive number`);
    this.transport.timeout = seconds;
  }

  /** The retry policy of failed calls; set a Partial<RetryPolicy> to change it. */
  get retry(): RetryPolicy { return this.transport.retry; }
  set retry(policy: Partial<RetryPolicy>) { this.transport.retry = retryPolicy(policy); }

  /** Pairs (and positions, matrix columns) per call; lowered to the server's when it refuses
   * more. */
  get maxPairs(): number { return this.limits.maxPairs; }
  /** Sources per field and matrix rows per call; lowered likewise. */
  get maxSources(): number { return this.limits.maxSources; }

  close(): void {
    this.transport.close();
  }

  private selector(mesh: string, options: GraphOptions = {}): GraphSelectorMsg {
    return {
      mesh, epsilon: options.epsilon ?? this.epsilon,
      pseudo_vertices: options.pseudoVertices ?? false, max_error: options.maxError ?? 0,
    };
  }

  private resolve(mesh: string, points: WirePoint[]): Promise<SurfacePointMsg[]> {
    return batches.resolve(this.transport, this.limits, mesh, points);
  }

  /** A handle on one mesh's graph: this client's queries without the mesh and graph options
   * (epsilon: this client's unless given; maxError: the certified graph of that bound). */
  meshSolver(name: string, options: GraphOptions = {}): MeshSolver {
    return new MeshSolver(this, name, Object.freeze({
      epsilon: options.epsilon ?? this.epsilon, pseudoVertices: options.pseudoVertices ?? false,
      maxError: options.maxError ?? 0,
    }));
  }

  // -- queries ---------------------------------------------------------------

  /** Distances from the nearest of the sources to every vertex (or to `targets`), +Infinity
   * where unreachable. `sources` may be one point: an id, a spec string, or a position
   * [x, y, z] (three numbers not all integers). With nearestSource, [distances, index in
   * sources of each value's nearest source]. More sources than the server's --max-sources
   * are split into several fields and combined by their minimum. */
  field(mesh: string, sources: Points | Point,
    options: FieldOptions & { nearestSource: true }): Promise<[Float64Array, Uint32Array]>;
  field(mesh: string, sources: Points | Point,
    options?: FieldOptions & { nearestSource?: false }): Promise<Float64Array>;
  field(mesh: string, sources: Points | Point,
    options?: FieldOptions): Promise<Float64Array | [Float64Array, Uint32Array]>;
  async field(mesh: string, sources: Points | Point,
    options: FieldOptions = {}): Promise<Float64Array | [Float64Array, Uint32Array]> {
    const one = typeof sources === "number" || typeof sources === "string" ||
      isOnePosition(sources);
    const wire = one ? [toWirePoint(sources as Point)] : toWirePoints(sources as Points);
    if (wire.length === 0) throw new RangeError("field: give at least one source");
    const targets = options.targets === undefined ? [] : toVertexIds(options.targets);
    const graph = this.selector(mesh, options);
    const points = await this.resolve(mesh, wire);
    const nearestSource = options.nearestSource ?? false;
    const { values, labels } = await batches.field(this.transport, this.limits, graph, points, {
      targets, maxDistance: options.maxDistance ?? 0, method: options.method ?? "lc",
      nearestSource,
    });
    return nearestSource ? [values, labels ?? new Uint32Array(values.length)] : values;
  }

  /** Geodesic distances between a[i] and b[i] (+Infinity: unreachable). With withPath,
   * [distances, a Path per pair]. With exact, the exact polyhedral distances (one window
   * propagation per pair, bounded by the graph's answer). */
  distances(mesh: string, a: Points, b: Points,
    options: DistanceOptions & { withPath: true }): Promise<[Float64Array, Path[]]>;
  distances(mesh: string, a: Points, b: Points,
    options?: DistanceOptions & { withPath?: false }): Promise<Float64Array>;
  distances(mesh: string, a: Points, b: Points,
    options?: DistanceOptions): Promise<Float64Array | [Float64Array, Path[]]>;
  async distances(mesh: string, a: Points, b: Points,
    options: DistanceOptions = {}): Promise<Float64Array | [Float64Array, Path[]]> {
    const wa = toWirePoints(a);
    const wb = toWirePoints(b);
    if (wa.length !== wb.length) {
      throw new RangeError(`distances: ${wa.length} points in a but ${wb.length} in b`);
    }
    const graph = this.selector(mesh, options);
    const [pa, pb] = [await this.resolve(mesh, wa), await this.resolve(mesh, wb)];
    const withPath = options.withPath ?? false;
    const { values, paths } = await batches.distances(this.transport, this.limits, graph, pa, pb,
      withPath, options.exact ?? false);
    return withPath ? [values, paths] : values;
  }

  /** The geodesic distance between two surface points (+Infinity if unreachable). */
  async distance(mesh: string, a: Point, b: Point,
    options: Omit<DistanceOptions, "withPath"> = {}): Promise<number> {
    const d = await this.distances(mesh, [a], [b], { ...options, withPath: false });
    return d[0]!;
  }

  /** The geodesic path from a to b; exact: the exact geodesic. */
  async path(mesh: string, a: Point, b: Point,
    options: Omit<DistanceOptions, "withPath"> = {}): Promise<Path> {
    const [, paths] = await this.distances(mesh, [a], [b], { ...options, withPath: true });
    return paths[0]!;
  }

  /** sources x targets distances, row-major (+Infinity where unreachable). sources, targets:
   * null or undefined for every mesh vertex in file order (no id list travels, and the rows
   * stream whatever the mesh's size). See MatrixOptions for dtype and out. */
  matrix(mesh: string, sources: Points | null | undefined, targets: Points | null | undefined,
    options: MatrixOptions & { out: string }): Promise<MatrixFile>;
  matrix(mesh: string, sources: Points | null | undefined, targets: Points | null | undefined,
    options: MatrixOptions & ({ dtype: "float32"; out?: Float32Array } | { out: Float32Array })
  ): Promise<DenseMatrix<Float32Array>>;
  matrix(mesh: string, sources: Points | null | undefined, targets: Points | null | undefined,
    options: MatrixOptions & ({ dtype: "float64"; out?: Float64Array } | { out: Float64Array })
  ): Promise<DenseMatrix<Float64Array>>;
  matrix(mesh: string, sources?: Points | null, targets?: Points | null,
    options?: MatrixOptions & { out?: MatrixArray }): Promise<DenseMatrix>;
  matrix(mesh: string, sources?: Points | null, targets?: Points | null,
    options?: MatrixOptions): Promise<DenseMatrix | MatrixFile>;
  async matrix(mesh: string, sources?: Points | null, targets?: Points | null,
    options: MatrixOptions = {}): Promise<DenseMatrix | MatrixFile> {
    const ws = sources == null ? null : toWirePoints(sources);
    const wt = targets == null ? null : toWirePoints(targets);
    const out = options.out;
    const whole = ws === null || wt === null;
    const dtype = checkDtype(options.dtype ?? (out instanceof Float32Array ? "float32"
      : out instanceof Float64Array ? "float64" : whole ? "float32" : "float64"));
    const graph = this.selector(mesh, options);
    const ps = ws === null ? null : await this.resolve(mesh, ws);
    const pt = wt === null ? null : await this.resolve(mesh, wt);
    const vertices = whole ? await this.matrices.vertexCount(mesh) : 0;
    const rows = ps?.length ?? vertices;
    const cols = pt?.length ?? vertices;
    const exact = options.exact ?? false;
    if (typeof out === "string") {
      const sink = await FileSink.open(out, rows, cols, dtype);
      let complete = false;
      try {
        await this.matrices.dense(graph, exact, ps, pt, sink);
        complete = true;
      } finally {
        await sink.finish(complete);
      }
      return Object.freeze({ rows, cols, dtype, path: out });
    }
    if (out !== undefined && (out instanceof Float32Array) !== (dtype === "float32")) {
      throw new RangeError(`out: a ${out.constructor.name} for a ${dtype} matrix`);
    }
    const data = out ?? (dtype === "float32" ? new Float32Array(rows * cols)
      : new Float64Array(rows * cols));
    const sink: Sink = new ArraySink(rows, cols, dtype, data);
    await this.matrices.dense(graph, exact, ps, pt, sink);
    return Object.freeze({ rows, cols, dtype, data });
  }

  /** The distances within `radius` as CSR arrays: entry (i, j) is stored exactly when
   * matrix()'s (i, j) is <= radius (zeros, such as a vertex's own distance, included;
   * unreachable pairs never), with the same value. The server sends only those entries. */
  async neighbourhoodMatrix(mesh: string, radius: number,
    options: NeighbourhoodOptions = {}): Promise<CsrMatrix> {
    if (!(Number.isFinite(radius) && radius > 0)) {
      throw new RangeError(`radius ${radius} is not a finite distance > 0`);
    }
    const dtype = checkDtype(options.dtype ?? "float32");
    const ws = options.sources == null ? null : toWirePoints(options.sources);
    const wt = options.targets == null ? null : toWirePoints(options.targets);
    const graph = this.selector(mesh, options);
    const ps = ws === null ? null : await this.resolve(mesh, ws);
    const pt = wt === null ? null : await this.resolve(mesh, wt);
    const vertices = ps === null || pt === null ? await this.matrices.vertexCount(mesh) : 0;
    return neighbourhood(this.matrices, this.limits, graph, options.exact ?? false, radius, ps,
      pt, ps?.length ?? vertices, pt?.length ?? vertices, dtype);
  }

  /** Nearest surface points to positions (x, y, z of each, flattened), as spec strings. */
  async snap(mesh: string,
    positions: Float64Array | Float32Array | readonly number[]): Promise<string[]> {
    const points = toWirePoints(Float64Array.from(positions));
    return (await this.resolve(mesh, points)).map(formatPoint);
  }

  /** Geodesic farthest-point sampling: the vertex ids in the order chosen, and the covering
   * radius (every vertex lies within it of a sample, graph distance). */
  async samplePoints(mesh: string, count: number,
    options: GraphOptions & { seed?: number | bigint } = {}): Promise<[Uint32Array, number]> {
    const response = await this.transport.unary("SamplePoints", {
      graph: this.selector(mesh, options), count, seed: toUint64(options.seed ?? 0, "seed"),
    }, mesh);
    return [Uint32Array.from(response.vertices), response.covering_radius];
  }

  // -- meshes ----------------------------------------------------------------

  /** The registered meshes, with their diagnostics. */
  async meshes(): Promise<Mesh[]> {
    return (await this.transport.unary("ListMeshes", {}, undefined)).meshes.map(meshFromWire);
  }

  /** One registered mesh. */
  async mesh(name: string): Promise<Mesh> {
    return meshFromWire(await this.transport.unary("GetMesh", { name }, name));
  }

  /** Registers a mesh from a file under the server's --mesh-root. */
  async registerMesh(name: string, path: string,
    options: { repairNonManifold?: boolean } = {}): Promise<Mesh> {
    return meshFromWire(await this.transport.unary("RegisterMesh", {
      name, path, repair_non_manifold: options.repairNonManifold ?? false,
    }, name));
  }

  /** Registers part of a registered mesh as a mesh of its own: exactly one of `vertices` (the
   * parent's vertex ids whose faces, all three corners listed, make the region) or `faces`. */
  async registerRegion(name: string, parent: string,
    region: { vertices: ArrayLike<number> } | { faces: ArrayLike<number> }): Promise<Mesh> {
    const byVertices = "vertices" in region;
    const ids = toVertexIds(byVertices ? region.vertices : region.faces, "region ids");
    return meshFromWire(await this.transport.unary("RegisterRegion", {
      name, parent, vertex_ids: byVertices ? ids : [], face_ids: byVertices ? [] : ids,
    }, name));
  }

  /** Forgets a mesh and drops its graphs from memory (their files stay). */
  async unloadMesh(name: string): Promise<void> {
    await this.transport.unary("UnloadMesh", { name }, name);
  }

  /** Uploads a mesh and registers it under `name`: a local file (its extension names the
   * format: .obj, .off, .ply, .stl, .surf.gii) or arrays. The upload declares its size and
   * SHA-256 first and the server registers it only if exactly those bytes arrive: an upload
   * that fails leaves nothing behind, and is retried whole. */
  async uploadMesh(name: string, source: string | MeshArrays,
    options: UploadOptions = {}): Promise<Mesh> {
    const chunks = await uploadChunks(name, source, options.chunkBytes ?? 1 << 20,
      options.repairNonManifold ?? false);
    return meshFromWire(await this.transport.call(
      () => this.transport.clientStream("UploadMesh", chunks(), name)));
  }

  /** A registered mesh's positions and faces, in file order (what face ids and barycentrics
   * refer to). */
  async geometry(name: string): Promise<Geometry> {
    return this.transport.call(async () => {
      // Sized by the first chunk's totals (uint64 on the wire), then filled
      // in order: all the vertex chunks, then all the face chunks.
      let vertices = new Float64Array(0);
      let faces = new Uint32Array(0);
      let v = 0;
      let f = 0;
      let first = true;
      for await (const chunk of this.transport.stream("GetGeometry", { name }, name)) {
        if (first) {
          first = false;
          vertices = new Float64Array(3 * toNumber(chunk.total_vertices, "total_vertices"));
          faces = new Uint32Array(3 * toNumber(chunk.total_faces, "total_faces"));
        }
        if (v + chunk.vertices.length > vertices.length ||
          f + chunk.faces.length > faces.length) {
          throw new Error(`GetGeometry: more than the ${vertices.length / 3} vertices and ` +
            `${faces.length / 3} faces announced`);
        }
        vertices.set(chunk.vertices, v);
        faces.set(chunk.faces, f);
        v += chunk.vertices.length;
        f += chunk.faces.length;
      }
      if (v !== vertices.length || f !== faces.length) {
        throw new Error(`GetGeometry: ${v / 3} of ${vertices.length / 3} vertices and ` +
          `${f / 3} of ${faces.length / 3} faces`);
      }
      return Object.freeze({ vertices, faces });
    });
  }

  // -- graphs ----------------------------------------------------------------

  /** Requests the graph of a mesh at an epsilon; with wait (the default), resolves when it is
   * ready (rejects with GraphFailedError if it failed or was cancelled meanwhile). */
  requestGraph(mesh: string, options: RequestGraphOptions = {}): Promise<Graph> {
    return requestGraph(this.transport, this.selector(mesh, options), options.wait ?? true,
      options.progress);
  }

  /** The state of a graph. */
  async graph(mesh: string, options: GraphOptions = {}): Promise<Graph> {
    return graphFromWire(await this.transport.unary("GetGraph",
      { graph: this.selector(mesh, options) }, mesh));
  }

  /** Every graph the server knows of. */
  async graphs(): Promise<Graph[]> {
    return (await this.transport.unary("ListGraphs", {}, undefined)).graphs.map(graphFromWire);
  }

  /** Cancels the build of a graph; its state turns CANCELLED (watchGraph sees it). */
  async cancelGraph(mesh: string, options: GraphOptions = {}): Promise<Graph> {
    return graphFromWire(await this.transport.unary("CancelGraph",
      { graph: this.selector(mesh, options) }, mesh));
  }

  /** A graph's states as the server streams them, until it is ready, failed or cancelled
   * (`for await (const g of client.watchGraph(...))`; leaving the loop ends the watch). */
  watchGraph(mesh: string, options: GraphOptions = {}): AsyncGenerator<Graph, void, undefined> {
    return watchGraph(this.transport, this.selector(mesh, options));
  }
}
