/**
 * Typed Node.js client for geodesicd: geodesic distances and paths on triangle meshes.
 *
 * ```js
 * const { Client } = require("geodesic-client");
 * const c = new Client({ epsilon: 1e-2 });        // $GEODESIC_SERVER, else 127.0.0.1:50051
 * const field = await c.field("spot", [0]);       // Float64Array, +Infinity where unreachable
 * const d = await c.distances("spot", [10, 20], ["v:30", "f:7:0.2,0.3,0.5"]);
 * const m = await c.matrix("spot", [0, 1], null); // 2 x every vertex, Float32Array rows
 * c.close();
 * ```
 * @packageDocumentation
 */
export {
  ADDRESS_ENV, Client, DEFAULT_ADDRESS,
} from "./client";
export type {
  ClientOptions, DenseMatrix, DistanceOptions, FieldOptions, GraphOptions, MatrixFile,
  MatrixOptions, NeighbourhoodOptions, RequestGraphOptions, UploadOptions,
} from "./options";
export {
  AlreadyExistsError, CancelledError, DeadlineExceededError, FailedPreconditionError,
  GeodesicError, GraphFailedError, InvalidArgumentError, NotFoundError, OutOfRangeError,
  PermissionDeniedError, ResourceExhaustedError, UnauthenticatedError, UnavailableError,
  UnimplementedError,
} from "./errors";
export { EdgePoints, FacePoints, formatPoint, parsePoint } from "./points";
export type { Point, Points } from "./points";
export { DEFAULT_RETRY, retryDelayMs, retryPolicy } from "./retry";
export { MeshSolver } from "./solver";
export type { RetryPolicy } from "./retry";
export type { Dtype, MatrixArray } from "./sinks";
export type { CsrMatrix } from "./sparse";
export { GraphState, graphStateDone } from "./types";
export type {
  Geometry, Graph, GraphCertificate, Mesh, MeshDiagnostics, Path, VertexCopy,
} from "./types";
export type { MeshArrays } from "./upload";
export { status } from "@grpc/grpc-js";
