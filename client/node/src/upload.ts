// The messages of an UploadMesh stream: a header declaring the upload's size
// and SHA-256, then the mesh's bytes (a file) or arrays in chunks. Arguments
// are checked, and a file read and hashed, before any call: the server
// registers the mesh only if exactly the declared bytes arrive.
import { createHash } from "node:crypto";
import { createReadStream, promises as fs } from "node:fs";
import { extname } from "node:path";
import { toUint64 } from "./longs";
import type { UploadMeshRequest } from "./wire";

/** A mesh as arrays: x, y, z of each vertex and the three vertex ids of each triangle, each
 * flattened (as geometry() returns them). */
export interface MeshArrays {
  vertices: Float64Array | Float32Array | readonly number[];
  faces: Uint32Array | Int32Array | readonly number[];
}

/** What makes an upload's stream, anew for every attempt. */
export type Chunks = () => AsyncIterable<UploadMeshRequest>;

async function fileChunks(name: string, path: string, chunkBytes: number,
  repair: boolean): Promise<Chunks> {
  const format = extname(path).slice(1).toLowerCase();
  if (!format) {
    throw new Error(`uploadMesh: ${path} has no extension naming its format ` +
      "(.obj, .off, .ply, .stl or .surf.gii)");
  }
  // Read before the call, so that a missing file fails here, by name.
  const digest = createHash("sha256");
  let total = 0;
  for await (const data of createReadStream(path, { highWaterMark: chunkBytes })) {
    digest.update(data as Buffer);
    total += (data as Buffer).length;
  }
  if (total === 0) throw new Error(`uploadMesh: ${path} is empty`);
  const header: UploadMeshRequest = {
    name, format, total_bytes: toUint64(total, "total_bytes"), sha256: digest.digest("hex"),
    repair_non_manifold: repair,
  };
  return async function* chunks() {
    // A file changed since it was hashed fails the server's check.
    let first = true;
    for await (const data of createReadStream(path, { highWaterMark: chunkBytes })) {
      yield first ? { ...header, data: data as Buffer } : { data: data as Buffer };
      first = false;
    }
  };
}

function arrayChunks(name: string, mesh: MeshArrays, chunkBytes: number,
  repair: boolean): Chunks {
  const vertices = Float64Array.from(mesh.vertices);
  if (vertices.length === 0 || vertices.length % 3 !== 0) {
    throw new RangeError(`uploadMesh: ${vertices.length} vertex coordinates are not x, y, z ` +
      "triples of at least one vertex");
  }
  if (!vertices.every(Number.isFinite)) {
    throw new RangeError("uploadMesh: a vertex coordinate is not finite");
  }
  const n = vertices.length / 3;
  const faces = new Uint32Array(mesh.faces.length);
  for (let i = 0; i < mesh.faces.length; i++) {
    const v = Number(mesh.faces[i]);
    if (!Number.isInteger(v) || v < 0 || v >= n) {
      throw new RangeError(`uploadMesh: faces[${i}] = ${v} is not a vertex id in [0, ${n})`);
    }
    faces[i] = v;
  }
  if (faces.length === 0 || faces.length % 3 !== 0) {
    throw new RangeError(`uploadMesh: ${faces.length} face indices are not triangles`);
  }
  // The checksum is over the arrays' little-endian bytes, vertices then
  // faces (geodesic.proto, UploadMeshRequest).
  const vbytes = Buffer.alloc(vertices.length * 8);
  vertices.forEach((x, i) => vbytes.writeDoubleLE(x, 8 * i));
  const fbytes = Buffer.alloc(faces.length * 4);
  faces.forEach((f, i) => fbytes.writeUInt32LE(f, 4 * i));
  const header: UploadMeshRequest = {
    name, total_bytes: toUint64(vbytes.length + fbytes.length, "total_bytes"),
    sha256: createHash("sha256").update(vbytes).update(fbytes).digest("hex"),
    repair_non_manifold: repair,
  };
  const stepV = Math.max(1, Math.floor(chunkBytes / 8));
  const stepF = Math.max(1, Math.floor(chunkBytes / 4));
  return async function* chunks() {
    yield header;
    for (let i = 0; i < vertices.length; i += stepV) {
      yield { vertices: Array.from(vertices.subarray(i, i + stepV)) };
    }
    for (let i = 0; i < faces.length; i += stepF) {
      yield { faces: Array.from(faces.subarray(i, i + stepF)) };
    }
  };
}

/** The chunks of an upload of a file (a path) or of arrays. */
export async function uploadChunks(name: string, source: string | MeshArrays,
  chunkBytes: number, repair: boolean): Promise<Chunks> {
  if (!(Number.isInteger(chunkBytes) && chunkBytes > 0)) {
    throw new RangeError(`uploadMesh: chunkBytes ${chunkBytes} is not a positive integer`);
  }
  if (typeof source === "string") {
    await fs.access(source);
    return fileChunks(name, source, chunkBytes, repair);
  }
  return arrayChunks(name, source, chunkBytes, repair);
}
