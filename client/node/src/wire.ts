// The daemon's API as proto-loader decodes it: the loader's options, the
// shapes of the messages this package reads and writes, and the service's
// method definitions, typed by name. Nothing here is public API: the client
// turns every message into the types of types.ts before a caller sees it.
import { join } from "node:path";
import type { MethodDefinition } from "@grpc/grpc-js";
import * as protoLoader from "@grpc/proto-loader";

// Where the package carries its copy of proto/geodesic/v1/geodesic.proto
// (scripts/copy-proto.mjs puts it there at build time): beside dist/.
export const PROTO_PATH = join(__dirname, "..", "proto", "geodesic", "v1", "geodesic.proto");

// How messages are decoded. Each option answers a trap of proto-loader's
// defaults:
// - longs: String. 64-bit fields (offsets, totals, counts, sizes, genus)
//   otherwise arrive as Long objects; as strings they are at least exact,
//   and longs.ts turns them into numbers (or bigints) before any arithmetic,
//   since `offset + i` on a string concatenates.
// - defaults: true. Without it a field holding its zero value is absent:
//   a distance of 0, the first chunk's offset 0, MATRIX_DTYPE_DEFAULT.
// - oneofs: true. SurfacePoint.point names the member that is set.
// - bytes: Buffer. Packed rows are Buffers into the message's own memory:
//   matrix.ts copies them out rather than viewing them (they are unaligned).
export const LOADER_OPTIONS: protoLoader.Options = {
  keepCase: true,
  longs: String,
  enums: Number,
  defaults: true,
  oneofs: true,
  bytes: Buffer,
};

// A 64-bit integer as decoded (a decimal string), or as a caller may give
// one in a request.
export type Int64 = string | number;

export interface EdgePointMsg { edge: number; t: number }
export interface FacePointMsg { face: number; b0: number; b1: number; b2: number }
export interface SurfacePointMsg {
  vertex?: number;
  edge?: EdgePointMsg | null;
  face?: FacePointMsg | null;
  point?: "vertex" | "edge" | "face";
}
export interface Vec3Msg { x: number; y: number; z: number }

export interface GraphSelectorMsg {
  mesh: string;
  epsilon: number;
  pseudo_vertices: boolean;
  max_error: number;
}

export interface MeshDiagnosticsMsg {
  vertices: Int64; faces: Int64; edges: Int64; components: Int64; boundary_loops: Int64;
  genus: Int64; isolated_vertices: Int64; non_manifold_vertices: Int64; bbox_diagonal: number;
  anisotropy_mean: number; json: string; path: string; format: string;
  polygons_triangulated: Int64; duplicate_vertices: Int64; zero_area_faces: Int64;
  near_degenerate_faces: Int64; non_manifold_edges: Int64; faces_refused: Int64;
  mean_edge_length: number; min_edge_length: number; anisotropy_p95: number;
  anisotropy_max: number; saddle_vertices: Int64; boundary_vertices: Int64; manifold: boolean;
  load_seconds: number; mesh_error: string;
}

export interface MeshMsg {
  name: string; fingerprint: string; source: string; diagnostics: MeshDiagnosticsMsg | null;
  restored: boolean; vertex_copies: { original: number; copy: number }[];
  repair_non_manifold: boolean; parent: string; parent_vertices: Int64; parent_faces: Int64;
}

export interface GraphCertificateMsg {
  max_error_bound: number; epsilon: number; measured_max_error: number;
  measured_mean_error: number; sources: number; seed: Int64; sound: boolean; builds: number;
}

export interface GraphMsg {
  mesh: string; epsilon: number; state: number; phase: string; progress: number; error: string;
  bytes: Int64; mapped: boolean; nodes: Int64; edges: Int64; build_seconds: number;
  last_used_unix_ms: Int64; from_file: boolean; landmark_bytes: Int64;
  pseudo_vertices: boolean; prune_redundant: boolean; exact_fans: boolean;
  candidate_rule: number; estimated_bytes: Int64; estimated_seconds: number; max_error: number;
  certificate: GraphCertificateMsg | null;
}

export interface QueryEchoMsg { graph: GraphSelectorMsg | null; method: string }

export interface RegisterMeshRequest { name: string; path: string; repair_non_manifold: boolean }
export interface RegisterRegionRequest {
  name: string; parent: string; vertex_ids: number[]; face_ids: number[];
}
export interface UploadMeshRequest {
  name?: string; format?: string; data?: Buffer; repair_non_manifold?: boolean;
  total_bytes?: Int64; sha256?: string; vertices?: number[]; faces?: number[];
}
export interface GeometryChunkMsg {
  name: string; fingerprint: string; total_vertices: Int64; total_faces: Int64;
  vertices: number[]; faces: number[];
}
export interface NameRequest { name: string }
export interface GraphRequest { graph: GraphSelectorMsg }

export interface DistanceFieldRequest {
  graph: GraphSelectorMsg; sources: SurfacePointMsg[]; max_distance: number; targets: number[];
  nearest_source: boolean; method: string;
}
export interface DistanceFieldChunkMsg {
  echo: QueryEchoMsg | null; offset: Int64; values: number[]; values_f32: number[];
  nearest_source: number[]; total: Int64;
}

export interface PointPairMsg { from: SurfacePointMsg; to: SurfacePointMsg }
export interface DistanceRequest {
  graph: GraphSelectorMsg; pairs: PointPairMsg[]; with_path: boolean; exact: boolean;
}
export interface PathPointMsg { point: SurfacePointMsg | null; xyz: Vec3Msg | null }
export interface PairResultMsg {
  distance: number; reachable: boolean; path: { length: number; points: PathPointMsg[] } | null;
  exact: boolean;
}
export interface DistanceResponseMsg { echo: QueryEchoMsg | null; results: PairResultMsg[] }

// geodesic.v1.MatrixDtype.
export const MATRIX_DTYPE_DEFAULT = 0;
export const MATRIX_DTYPE_FLOAT64 = 1;
export const MATRIX_DTYPE_FLOAT32 = 2;

export interface MatrixRequest {
  graph: GraphSelectorMsg; sources: SurfacePointMsg[]; targets: SurfacePointMsg[];
  all_sources: boolean; all_targets: boolean; exact: boolean; dtype: number; radius: number;
}
export interface MatrixResponseMsg {
  echo: QueryEchoMsg | null; rows: number; cols: number; distances: number[]; packed: Buffer;
  dtype: number;
}
export interface MatrixRowsChunkMsg {
  echo: QueryEchoMsg | null; first_row: number; rows: number; cols: number;
  distances: number[]; total_rows: number; dtype: number; packed: Buffer; indptr: Buffer;
  indices: Buffer; values: Buffer;
}

export interface SnapRequest { mesh: string; positions: Vec3Msg[] }
export interface SnapResponseMsg { points: SurfacePointMsg[]; distances: number[] }
export interface SamplePointsRequest { graph: GraphSelectorMsg; count: number; seed: Int64 }
export interface SamplePointsResponseMsg {
  echo: QueryEchoMsg | null; vertices: number[]; covering_radius: number;
}

// Each method of geodesic.v1.Geodesic: [request, response].
export interface Api {
  RegisterMesh: [RegisterMeshRequest, MeshMsg];
  UploadMesh: [UploadMeshRequest, MeshMsg];
  RegisterRegion: [RegisterRegionRequest, MeshMsg];
  ListMeshes: [Record<string, never>, { meshes: MeshMsg[] }];
  GetMesh: [NameRequest, MeshMsg];
  UnloadMesh: [NameRequest, Record<string, never>];
  GetGeometry: [NameRequest, GeometryChunkMsg];
  RequestGraph: [GraphRequest, GraphMsg];
  GetGraph: [GraphRequest, GraphMsg];
  WatchGraph: [GraphRequest, GraphMsg];
  CancelGraph: [GraphRequest, GraphMsg];
  ListGraphs: [Record<string, never>, { graphs: GraphMsg[] }];
  DistanceField: [DistanceFieldRequest, DistanceFieldChunkMsg];
  Distance: [DistanceRequest, DistanceResponseMsg];
  Matrix: [MatrixRequest, MatrixResponseMsg];
  MatrixRows: [MatrixRequest, MatrixRowsChunkMsg];
  Snap: [SnapRequest, SnapResponseMsg];
  SamplePoints: [SamplePointsRequest, SamplePointsResponseMsg];
}
export type MethodName = keyof Api;
export type RequestOf<K extends MethodName> = Api[K][0];
export type ResponseOf<K extends MethodName> = Api[K][1];
export type Methods = { [K in MethodName]: MethodDefinition<RequestOf<K>, ResponseOf<K>> };

// Which methods stream which way, as the proto declares them: checked
// against the loaded definitions, so that a proto and this file that
// disagree fail at the first call instead of misbehaving.
export const STREAMING: { [K in MethodName]: "unary" | "server" | "client" } = {
  RegisterMesh: "unary", UploadMesh: "client", RegisterRegion: "unary", ListMeshes: "unary",
  GetMesh: "unary", UnloadMesh: "unary", GetGeometry: "server", RequestGraph: "unary",
  GetGraph: "unary", WatchGraph: "server", CancelGraph: "unary", ListGraphs: "unary",
  DistanceField: "server", Distance: "unary", Matrix: "unary", MatrixRows: "server",
  Snap: "unary", SamplePoints: "unary",
};

let loaded: Methods | undefined;

// The service's method definitions, loaded from the package's proto once.
export function methods(protoPath: string = PROTO_PATH): Methods {
  if (loaded !== undefined && protoPath === PROTO_PATH) return loaded;
  const definition = protoLoader.loadSync(protoPath, LOADER_OPTIONS);
  const service = definition["geodesic.v1.Geodesic"];
  if (service === undefined || "format" in service) {
    throw new Error(`${protoPath} defines no service geodesic.v1.Geodesic`);
  }
  const table = service as Record<string, MethodDefinition<object, object>>;
  for (const [name, kind] of Object.entries(STREAMING)) {
    const method = table[name];
    if (method === undefined) throw new Error(`${protoPath}: geodesic.v1.Geodesic has no ${name}`);
    const found = method.requestStream ? "client" : method.responseStream ? "server" : "unary";
    if (found !== kind) throw new Error(`${protoPath}: ${name} is ${found}, expected ${kind}`);
  }
  const result = table as unknown as Methods;
  if (protoPath === PROTO_PATH) loaded = result;
  return result;
}
