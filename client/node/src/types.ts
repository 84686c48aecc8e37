// The values the client returns: plain frozen objects with number fields,
// built from the wire's messages here (64-bit fields converted by longs.ts).
// No client call returns a proto message.
import { toBigInt, toNumber } from "./longs";
import type { GraphCertificateMsg, GraphMsg, MeshDiagnosticsMsg, MeshMsg } from "./wire";

/** Lifecycle of a graph on the server (geodesic.v1.GraphState). */
export enum GraphState {
  UNSPECIFIED = 0,
  QUEUED = 1,
  BUILDING = 2,
  LOADING = 3,
  READY = 4,
  FAILED = 5,
  CANCELLED = 6,
  EVICTED = 7,
}

/** True for the states a graph stays in until asked again. */
export function graphStateDone(state: GraphState): boolean {
  return state === GraphState.READY || state === GraphState.FAILED ||
    state === GraphState.CANCELLED || state === GraphState.EVICTED;
}

function graphState(value: number): GraphState {
  // A state added to the server after this client reads as UNSPECIFIED.
  return value in GraphState ? (value as GraphState) : GraphState.UNSPECIFIED;
}

/** What the server measured of a certified graph (geodesic.v1.GraphCertificate). */
export interface GraphCertificate {
  readonly maxErrorBound: number;
  readonly epsilon: number;
  readonly measuredMaxError: number;
  readonly measuredMeanError: number;
  readonly sources: number;
  /** Any 64-bit value: a bigint. */
  readonly seed: bigint;
  readonly sound: boolean;
  readonly builds: number;
}

/** A graph for (mesh, epsilon) and the state of the operation that makes it. */
export interface Graph {
  readonly mesh: string;
  readonly epsilon: number;
  readonly state: GraphState;
  /** While building: candidates, pseudo, pruning, fans. */
  readonly phase: string;
  /** Fraction done, in [0, 1]. */
  readonly progress: number;
  /** Why it failed. */
  readonly error: string;
  readonly bytes: number;
  readonly nodes: number;
  readonly edges: number;
  readonly buildSeconds: number;
  readonly mapped: boolean;
  readonly fromFile: boolean;
  readonly pseudoVertices: boolean;
  readonly landmarkBytes: number;
  readonly lastUsedUnixMs: number;
  readonly pruneRedundant: boolean;
  readonly exactFans: boolean;
  readonly candidateRule: number;
  readonly estimatedBytes: number;
  readonly estimatedSeconds: number;
  /** A certified graph's bound; 0 for a plain graph. */
  readonly maxError: number;
  /** What was measured of a certified graph once ready; null otherwise. */
  readonly certificate: GraphCertificate | null;
}

function certificateFromWire(c: GraphCertificateMsg): GraphCertificate {
  return Object.freeze({
    maxErrorBound: c.max_error_bound, epsilon: c.epsilon,
    measuredMaxError: c.measured_max_error, measuredMeanError: c.measured_mean_error,
    sources: c.sources, seed: toBigInt(c.seed, "GraphCertificate.seed"), sound: c.sound,
    builds: c.builds,
  });
}

export function graphFromWire(g: GraphMsg): Graph {
  return Object.freeze({
    mesh: g.mesh, epsilon: g.epsilon, state: graphState(g.state), phase: g.phase,
    progress: g.progress, error: g.error, bytes: toNumber(g.bytes, "Graph.bytes"),
    nodes: toNumber(g.nodes, "Graph.nodes"), edges: toNumber(g.edges, "Graph.edges"),
    buildSeconds: g.build_seconds, mapped: g.mapped, fromFile: g.from_file,
    pseudoVertices: g.pseudo_vertices,
    landmarkBytes: toNumber(g.landmark_bytes, "Graph.landmark_bytes"),
    lastUsedUnixMs: toNumber(g.last_used_unix_ms, "Graph.last_used_unix_ms"),
    pruneRedundant: g.prune_redundant, exactFans: g.exact_fans,
    candidateRule: g.candidate_rule,
    estimatedBytes: toNumber(g.estimated_bytes, "Graph.estimated_bytes"),
    estimatedSeconds: g.estimated_seconds, maxError: g.max_error,
    certificate: g.certificate ? certificateFromWire(g.certificate) : null,
  });
}

/** What the server found when it read a mesh (geodesic.v1.MeshDiagnostics). */
export interface MeshDiagnostics {
  readonly vertices: number;
  readonly faces: number;
  readonly edges: number;
  readonly components: number;
  readonly boundaryLoops: number;
  /** Meaningful only when manifold; an int64, negative for some meshes. */
  readonly genus: number;
  readonly isolatedVertices: number;
  readonly nonManifoldVertices: number;
  readonly bboxDiagonal: number;
  readonly anisotropyMean: number;
  readonly path: string;
  readonly format: string;
  readonly polygonsTriangulated: number;
  readonly duplicateVertices: number;
  readonly zeroAreaFaces: number;
  readonly nearDegenerateFaces: number;
  readonly nonManifoldEdges: number;
  readonly facesRefused: number;
  readonly meanEdgeLength: number;
  readonly minEdgeLength: number;
  readonly anisotropyP95: number;
  readonly anisotropyMax: number;
  readonly saddleVertices: number;
  readonly boundaryVertices: number;
  readonly manifold: boolean;
  readonly loadSeconds: number;
  /** Why the mesh cannot be used for geodesics; empty when it can. */
  readonly meshError: string;
}

function diagnosticsFromWire(d: MeshDiagnosticsMsg): MeshDiagnostics {
  const n = (field: keyof MeshDiagnosticsMsg): number =>
    toNumber(d[field] as string | number, `MeshDiagnostics.${field}`);
  return Object.freeze({
    vertices: n("vertices"), faces: n("faces"), edges: n("edges"), components: n("components"),
    boundaryLoops: n("boundary_loops"), genus: n("genus"),
    isolatedVertices: n("isolated_vertices"), nonManifoldVertices: n("non_manifold_vertices"),
    bboxDiagonal: d.bbox_diagonal, anisotropyMean: d.anisotropy_mean, path: d.path,
    format: d.format, polygonsTriangulated: n("polygons_triangulated"),
    duplicateVertices: n("duplicate_vertices"), zeroAreaFaces: n("zero_area_faces"),
    nearDegenerateFaces: n("near_degenerate_faces"), nonManifoldEdges: n("non_manifold_edges"),
    facesRefused: n("faces_refused"), meanEdgeLength: d.mean_edge_length,
    minEdgeLength: d.min_edge_length, anisotropyP95: d.anisotropy_p95,
    anisotropyMax: d.anisotropy_max, saddleVertices: n("saddle_vertices"),
    boundaryVertices: n("boundary_vertices"), manifold: d.manifold,
    loadSeconds: d.load_seconds, meshError: d.mesh_error,
  });
}

/** A vertex added by repairNonManifold: copy takes over one fan of original. */
export interface VertexCopy {
  readonly original: number;
  readonly copy: number;
}

/** A mesh registered on the server. */
export interface Mesh {
  readonly name: string;
  /** Hex xxHash64 of its positions and faces (graphs are keyed by it). */
  readonly fingerprint: string;
  /** The server-side path it was read from, or "upload". */
  readonly source: string;
  readonly restored: boolean;
  readonly repairNonManifold: boolean;
  readonly vertexCopies: readonly VertexCopy[];
  readonly diagnostics: MeshDiagnostics | null;
  /** A region's parent mesh ("" for a whole mesh), and that mesh's size. */
  readonly parent: string;
  readonly parentVertices: number;
  readonly parentFaces: number;
}

export function meshFromWire(m: MeshMsg): Mesh {
  return Object.freeze({
    name: m.name, fingerprint: m.fingerprint, source: m.source, restored: m.restored,
    repairNonManifold: m.repair_non_manifold,
    vertexCopies: Object.freeze(m.vertex_copies.map((c) =>
      Object.freeze({ original: c.original, copy: c.copy }))),
    diagnostics: m.diagnostics ? diagnosticsFromWire(m.diagnostics) : null,
    parent: m.parent, parentVertices: toNumber(m.parent_vertices, "Mesh.parent_vertices"),
    parentFaces: toNumber(m.parent_faces, "Mesh.parent_faces"),
  });
}

/** A geodesic path. */
export interface Path {
  /** Its length; +Infinity if the points are not connected. */
  readonly length: number;
  /** x, y, z of each corner, first point to last, flattened (3 K values; empty if unreachable). */
  readonly xyz: Float64Array;
  /** The corners as surface point specs ("v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2"). */
  readonly points: readonly string[];
}

/** A registered mesh's positions and triangles, in file order. */
export interface Geometry {
  /** x, y, z of each vertex, flattened. */
  readonly vertices: Float64Array;
  /** Three vertex ids per face, flattened. */
  readonly faces: Uint32Array;
}
