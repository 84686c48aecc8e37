// MeshSolver: one mesh's graph as an object that answers queries (the
// Python client's MeshSolver, in the manner of potpourri3d's solvers). Each
// method calls the Client method of the same name with the solver's mesh and
// graph options, so both answer alike; the graph lives on the server, so
// solvers are cheap and share the client's connection, limits and retries.
import type { Client } from "./client";
import type {
  DenseMatrix, DistanceOptions, FieldOptions, GraphOptions, MatrixFile, MatrixOptions,
  NeighbourhoodOptions, RequestGraphOptions,
} from "./options";
import type { Point, Points } from "./points";
import type { MatrixArray } from "./sinks";
import type { CsrMatrix } from "./sparse";
import type { Graph, Mesh, Path } from "./types";

// A call's options without the graph's, which the solver fills in.
type Without<T> = Omit<T, keyof GraphOptions>;

/** One mesh's graph, queried without repeating the mesh, epsilon, pseudoVertices and
 * maxError (Client.meshSolver makes one). */
export class MeshSolver {
  private meshAnswer: Promise<Mesh> | undefined;

  constructor(readonly client: Client, readonly name: string,
    readonly graphOptions: Readonly<GraphOptions>) {}

  /** The registered mesh, fetched once. */
  mesh(): Promise<Mesh> {
    this.meshAnswer ??= this.client.mesh(this.name);
    return this.meshAnswer;
  }

  requestGraph(options: Without<RequestGraphOptions> = {}): Promise<Graph> {
    return this.client.requestGraph(this.name, { ...options, ...this.graphOptions });
  }

  graph(): Promise<Graph> {
    return this.client.graph(this.name, this.graphOptions);
  }

  cancelGraph(): Promise<Graph> {
    return this.client.cancelGraph(this.name, this.graphOptions);
  }

  field(sources: Points | Point,
    options: Without<FieldOptions> & { nearestSource: true }
  ): Promise<[Float64Array, Uint32Array]>;
  field(sources: Points | Point,
    options?: Without<FieldOptions> & { nearestSource?: false }): Promise<Float64Array>;
  field(sources: Points | Point,
    options: Without<FieldOptions> = {}): Promise<Float64Array | [Float64Array, Uint32Array]> {
    return this.client.field(this.name, sources, { ...options, ...this.graphOptions });
  }

  distances(a: Points, b: Points,
    options: Without<DistanceOptions> & { withPath: true }): Promise<[Float64Array, Path[]]>;
  distances(a: Points, b: Points,
    options?: Without<DistanceOptions> & { withPath?: false }): Promise<Float64Array>;
  distances(a: Points, b: Points,
    options: Without<DistanceOptions> = {}): Promise<Float64Array | [Float64Array, Path[]]> {
    return this.client.distances(this.name, a, b, { ...options, ...this.graphOptions });
  }

  distance(a: Point, b: Point, options: Without<Omit<DistanceOptions, "withPath">> = {}):
    Promise<number> {
    return this.client.distance(this.name, a, b, { ...options, ...this.graphOptions });
  }

  path(a: Point, b: Point, options: Without<Omit<DistanceOptions, "withPath">> = {}):
    Promise<Path> {
    return this.client.path(this.name, a, b, { ...options, ...this.graphOptions });
  }

  matrix(sources: Points | null | undefined, targets: Points | null | undefined,
    options: Without<MatrixOptions> & { out: string }): Promise<MatrixFile>;
  matrix(sources?: Points | null, targets?: Points | null,
    options?: Without<MatrixOptions> & { out?: MatrixArray }): Promise<DenseMatrix>;
  matrix(sources?: Points | null, targets?: Points | null,
    options: Without<MatrixOptions> = {}): Promise<DenseMatrix | MatrixFile> {
    return this.client.matrix(this.name, sources, targets, { ...options, ...this.graphOptions });
  }

  neighbourhoodMatrix(radius: number,
    options: Without<NeighbourhoodOptions> = {}): Promise<CsrMatrix> {
    return this.client.neighbourhoodMatrix(this.name, radius,
      { ...options, ...this.graphOptions });
  }

  samplePoints(count: number, options: { seed?: number | bigint } = {}):
    Promise<[Uint32Array, number]> {
    return this.client.samplePoints(this.name, count, { ...options, ...this.graphOptions });
  }

  snap(positions: Float64Array | Float32Array | readonly number[]): Promise<string[]> {
    return this.client.snap(this.name, positions);
  }
}
