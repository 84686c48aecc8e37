// The options of Client's calls and the shapes of its matrices: the
// Python client's keyword arguments, in camelCase, as typed objects.
import type { Points } from "./points";
import type { RetryPolicy } from "./retry";
import type { Dtype, MatrixArray } from "./sinks";
import type { Graph } from "./types";

export interface ClientOptions {
  /** HOST:PORT; default $GEODESIC_SERVER if set, else 127.0.0.1:50051. */
  address?: string;
  /** The deadline of each call, seconds (default 600). */
  timeout?: number;
  /** Sent as "authorization: Bearer <token>" on every call (geodesicd --auth-token-file). */
  token?: string;
  /** PEM of the CA that signed the server's certificate: turns TLS on. */
  rootCertificates?: Buffer;
  /** PEM of a client certificate and its key, for servers that require one (--tls-client-ca). */
  privateKey?: Buffer;
  certificateChain?: Buffer;
  /** The graph accuracy used when a call gives none (0, the default: the server's). */
  epsilon?: number;
  /** Retries of failed calls: the defaults of RetryPolicy with these changes. */
  retry?: Partial<RetryPolicy>;
  /** The server's --max-pairs and --max-sources; a lower limit the server reports is learnt
   * from its refusal. */
  maxPairs?: number;
  maxSources?: number;
  /** The largest gRPC message either side accepts (default 64 MiB). */
  maxMessageBytes?: number;
  /** Pairs per call when paths are wanted (default 256). */
  pathBatch?: number;
}

/** Which graph a call uses: the client's epsilon unless given; pseudoVertices: the graph with
 * pseudo vertices; maxError: the certified graph of that bound (the server chose its
 * epsilon). */
export interface GraphOptions {
  epsilon?: number;
  pseudoVertices?: boolean;
  maxError?: number;
}

export interface FieldOptions extends GraphOptions {
  /** Only vertices within this distance are settled, the others +Infinity (0: no limit). */
  maxDistance?: number;
  /** Vertex ids whose distances are returned, in this order (default: every vertex). */
  targets?: ArrayLike<number>;
  /** "lc" (default) or "dijkstra": the same distances, found two ways. */
  method?: string;
  /** Also return each value's nearest source (its index in `sources`). */
  nearestSource?: boolean;
}

export interface DistanceOptions extends GraphOptions {
  /** Also return the path of each pair. */
  withPath?: boolean;
  /** The exact polyhedral distances (and geodesics) instead of the graph's. */
  exact?: boolean;
}

export interface MatrixOptions extends GraphOptions {
  /** Every row exact. */
  exact?: boolean;
  /** Default: "float64" when both sources and targets are given, "float32" when either is
   * null (the whole-mesh form, for large matrices); with an `out` array, its type. float32
   * values are the float64 ones rounded to nearest. */
  dtype?: Dtype;
  /** A Float32Array/Float64Array of rows x cols values to fill; or a path, written as the
   * rows arrive: .npy (numpy.load reads it) or raw little-endian values for any other
   * extension. */
  out?: string | MatrixArray;
}

export interface NeighbourhoodOptions extends GraphOptions {
  /** Default null: every vertex of the mesh. */
  sources?: Points | null;
  targets?: Points | null;
  /** Default "float32". */
  dtype?: Dtype;
  exact?: boolean;
}

export interface RequestGraphOptions extends GraphOptions {
  /** Wait until the graph is ready (default true). */
  wait?: boolean;
  /** With wait, called with every state the server reports while waiting (state, phase,
   * progress in [0, 1]), the last one READY. An exception it throws ends the wait. */
  progress?: (graph: Graph) => void;
}

export interface UploadOptions {
  /** Payload bytes per message (default 1 MiB). */
  chunkBytes?: number;
  /** Split non-manifold vertices into one copy per fan instead of refusing the mesh. */
  repairNonManifold?: boolean;
}

/** A dense matrix, row-major: entry (i, j) is data[i * cols + j], +Infinity where unreachable. */
export interface DenseMatrix<T extends MatrixArray = MatrixArray> {
  readonly rows: number;
  readonly cols: number;
  readonly dtype: Dtype;
  readonly data: T;
}

/** A matrix written to a file (MatrixOptions.out a path). */
export interface MatrixFile {
  readonly rows: number;
  readonly cols: number;
  readonly dtype: Dtype;
  readonly path: string;
}
