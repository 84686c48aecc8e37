// Failed calls as exceptions, one class per gRPC status code, each carrying
// the code and what the server's trailers say beyond its prose: the retry
// hint, a building graph's state and progress, the limits a refused call
// passed. Code that catches plain grpc-js errors keeps working: `code` and
// `details` are where grpc-js puts them.
import { Metadata, status } from "@grpc/grpc-js";
import type { Graph } from "./types";

// The trailers the daemon sets (server/grpc/rpc_support.h, limits/admission.h).
export const RETRY_AFTER_TRAILER = "retry-after-ms";
export const GRAPH_STATE_TRAILER = "graph-state";
export const GRAPH_PROGRESS_TRAILER = "graph-progress";
export const LIMIT_TRAILER_PREFIX = "limit-";

/** A failed call: `code` is the gRPC status code, `details` the server's message. */
export class GeodesicError extends Error {
  /** The gRPC status code (grpc-js's `status` enum). */
  readonly code: status;
  /** The code's name: "UNAVAILABLE", "NOT_FOUND", ... */
  readonly codeName: string;
  /** The server's message. */
  readonly details: string;
  /** The method that failed ("Distance", "MatrixRows", ...). */
  readonly method: string;
  /** The call's trailing metadata, each key's first value. */
  readonly trailers: Readonly<Record<string, string>>;

  constructor(code: status, details: string, method = "", trailers: Record<string, string> = {}) {
    const codeName = status[code] ?? `CODE_${code}`;
    super(`${codeName}: ${details}${method ? ` (${method})` : ""}`);
    this.name = new.target.name;
    this.code = code;
    this.codeName = codeName;
    this.details = details;
    this.method = method;
    this.trailers = Object.freeze({ ...trailers });
  }

  /** Milliseconds the server asks to wait before retrying (its retry-after-ms trailer). */
  get retryAfterMs(): number | undefined {
    const value = Number.parseInt(this.trailers[RETRY_AFTER_TRAILER] ?? "", 10);
    return Number.isFinite(value) && value >= 0 ? value : undefined;
  }

  /** The per-call limits a refusal says the call passed, by name ({"max-pairs": 10000}):
   * its limit-* trailers. Empty for any other error. */
  get limits(): Readonly<Record<string, number>> {
    const out: Record<string, number> = {};
    for (const [key, value] of Object.entries(this.trailers)) {
      if (!key.startsWith(LIMIT_TRAILER_PREFIX)) continue;
      const n = Number(value);
      if (Number.isFinite(n)) out[key.slice(LIMIT_TRAILER_PREFIX.length)] = n;
    }
    return out;
  }
}

/** A graph still building or loading, or the server unreachable: retry later. */
export class UnavailableError extends GeodesicError {
  /** A graph still being made: the server's name of its state ("queued", "building",
   * "loading", ...); undefined when the refusal is not about a graph. */
  get graphState(): string | undefined {
    return this.trailers[GRAPH_STATE_TRAILER];
  }

  /** A graph still being made: its progress in [0, 1]. */
  get graphProgress(): number | undefined {
    const value = Number.parseFloat(this.trailers[GRAPH_PROGRESS_TRAILER] ?? "");
    return Number.isFinite(value) ? value : undefined;
  }
}

/** Unknown mesh or graph. */
export class NotFoundError extends GeodesicError {}
/** No graph was requested for this mesh and epsilon. */
export class FailedPreconditionError extends GeodesicError {}
/** Bad coordinates or parameters. */
export class InvalidArgumentError extends GeodesicError {}
/** A vertex, edge or face id beyond the mesh. */
export class OutOfRangeError extends GeodesicError {}
/** A request over a server limit (`limits` says which), or the server overloaded
 * (`retryAfterMs` set). */
export class ResourceExhaustedError extends GeodesicError {
  /** True when the server refused because it is overloaded, not because of the request. */
  get overloaded(): boolean {
    return this.retryAfterMs !== undefined && Object.keys(this.limits).length === 0;
  }
}
/** A path outside the server's --mesh-root. */
export class PermissionDeniedError extends GeodesicError {}
/** Missing or wrong bearer token. */
export class UnauthenticatedError extends GeodesicError {}
/** A mesh name already registered with another content. */
export class AlreadyExistsError extends GeodesicError {}
/** The call took longer than the client's timeout. */
export class DeadlineExceededError extends GeodesicError {}
/** The call was cancelled (by this client). */
export class CancelledError extends GeodesicError {}
/** A method the server does not have (an older server). */
export class UnimplementedError extends GeodesicError {}

const BY_CODE: Partial<Record<status, typeof GeodesicError>> = {
  [status.NOT_FOUND]: NotFoundError,
  [status.UNAVAILABLE]: UnavailableError,
  [status.FAILED_PRECONDITION]: FailedPreconditionError,
  [status.INVALID_ARGUMENT]: InvalidArgumentError,
  [status.OUT_OF_RANGE]: OutOfRangeError,
  [status.RESOURCE_EXHAUSTED]: ResourceExhaustedError,
  [status.PERMISSION_DENIED]: PermissionDeniedError,
  [status.UNAUTHENTICATED]: UnauthenticatedError,
  [status.ALREADY_EXISTS]: AlreadyExistsError,
  [status.DEADLINE_EXCEEDED]: DeadlineExceededError,
  [status.CANCELLED]: CancelledError,
  [status.UNIMPLEMENTED]: UnimplementedError,
};

/** The error class of a gRPC status code. */
export function errorClass(code: status): typeof GeodesicError {
  return BY_CODE[code] ?? GeodesicError;
}

function trailersOf(metadata: unknown): Record<string, string> {
  const out: Record<string, string> = {};
  if (!(metadata instanceof Metadata)) return out;
  for (const [key, values] of Object.entries(metadata.getMap())) {
    out[key] = Buffer.isBuffer(values) ? values.toString("utf8") : String(values);
  }
  return out;
}

interface GrpcErrorLike { code: number; details?: string; metadata?: unknown; message: string }

function isGrpcError(e: unknown): e is GrpcErrorLike {
  return e instanceof Error && typeof (e as Partial<GrpcErrorLike>).code === "number";
}

/** A grpc-js error as the GeodesicError of its code; anything else is returned as it is (a
 * bug or a local failure is not a server's answer). */
export function fromGrpcError(e: unknown, method: string): unknown {
  if (e instanceof GeodesicError || !isGrpcError(e)) return e;
  const Class = errorClass(e.code as status);
  return new Class(e.code as status, e.details || e.message, method, trailersOf(e.metadata));
}

/** requestGraph's wait ended with the graph failed, cancelled or evicted. */
export class GraphFailedError extends Error {
  readonly graph: Graph;

  constructor(graph: Graph, state: string) {
    super(`graph for ${graph.mesh} at eps ${graph.epsilon}: ${state}` +
      (graph.error ? ` ${graph.error}` : ""));
    this.name = "GraphFailedError";
    this.graph = graph;
  }
}
