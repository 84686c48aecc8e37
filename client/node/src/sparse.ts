// Neighbourhood matrices: the distances within a radius, as CSR arrays,
// from MatrixRows streams of sparse rows (each block's indptr is rows + 1
// little-endian uint64 offsets, from 0 within the block; indices uint32
// columns; values the distances), tile by tile within the server's limits.
// A server older than sparse rows is read densely and thresholded here.
import { Limits } from "./limits";
import { Matrices, tileRequest, tiles, WIRE_DTYPE } from "./matrix";
import { ArraySink, Dtype, MatrixArray, unpack } from "./sinks";
import type { GraphSelectorMsg, MatrixRowsChunkMsg, SurfacePointMsg } from "./wire";

/** A sparse matrix in compressed sparse row form (scipy.sparse.csr_matrix's arrays): row i's
 * entries are indices[k], data[k] for k in [indptr[i], indptr[i + 1]), columns increasing. */
export interface CsrMatrix<T extends MatrixArray = MatrixArray> {
  readonly rows: number;
  readonly cols: number;
  readonly dtype: Dtype;
  /** rows + 1 offsets: uint64 on the wire, numbers here (exact below 2^53). */
  readonly indptr: Float64Array;
  readonly indices: Uint32Array;
  readonly data: T;
}

// One block of rows of one column block, in aligned arrays.
interface Block { indptr: Float64Array; indices: Uint32Array; values: MatrixArray }

function readBlock(b: MatrixRowsChunkMsg, dtype: Dtype): Block {
  if (b.indptr.length !== 8 * (b.rows + 1)) {
    throw new Error(`MatrixRows: ${b.indptr.length} indptr bytes for ${b.rows} rows`);
  }
  // uint64 offsets at any byte offset of the message: a DataView reads
  // them where they are (a BigUint64Array could not view them).
  const view = new DataView(b.indptr.buffer, b.indptr.byteOffset, b.indptr.byteLength);
  const indptr = new Float64Array(b.rows + 1);
  for (let i = 0; i <= b.rows; i++) {
    const offset = view.getBigUint64(8 * i, true);
    if (offset > BigInt(Number.MAX_SAFE_INTEGER)) throw new RangeError(`indptr ${offset} > 2^53`);
    indptr[i] = Number(offset);
  }
  const count = indptr[b.rows]!;
  if (b.indices.length !== 4 * count) {
    throw new Error(`MatrixRows: ${b.indices.length} index bytes for ${count} entries`);
  }
  const indices = new Uint32Array(count);
  const iview = new DataView(b.indices.buffer, b.indices.byteOffset, b.indices.byteLength);
  for (let k = 0; k < count; k++) indices[k] = iview.getUint32(4 * k, true);
  return { indptr, indices, values: unpack(b.values, dtype, count) };
}

function newValues(dtype: Dtype, n: number): MatrixArray {
  return dtype === "float32" ? new Float32Array(n) : new Float64Array(n);
}

// The CSR of the whole matrix from each column block's blocks of rows (in
// row order; the column blocks in column order), columns offset by each
// column block's first column.
function assemble(rows: number, cols: number, dtype: Dtype,
  columns: { c: number; blocks: Block[] }[]): CsrMatrix {
  // Each row's block and its entries' span there, per column block.
  const spans = columns.map(({ c, blocks }) => {
    const owner: Block[] = [];
    const from = new Float64Array(rows);
    const to = new Float64Array(rows);
    let i = 0;
    for (const block of blocks) {
      for (let local = 0; local + 1 < block.indptr.length; local++, i++) {
        if (i >= rows) break;
        owner[i] = block;
        from[i] = block.indptr[local]!;
        to[i] = block.indptr[local + 1]!;
      }
    }
    if (i !== rows) throw new Error(`MatrixRows: ${i} rows of ${rows} in columns from ${c}`);
    return { c, owner, from, to };
  });
  const indptr = new Float64Array(rows + 1);
  for (let i = 0; i < rows; i++) {
    let n = 0;
    for (const span of spans) n += span.to[i]! - span.from[i]!;
    indptr[i + 1] = indptr[i]! + n;
  }
  const nnz = indptr[rows]!;
  const indices = new Uint32Array(nnz);
  const data = newValues(dtype, nnz);
  for (let i = 0; i < rows; i++) {
    let into = indptr[i]!;
    for (const { c, owner, from, to } of spans) {
      const block = owner[i]!;
      for (let k = from[i]!; k < to[i]!; k++) indices[into++] = block.indices[k]! + c;
      data.set(block.values.subarray(from[i]!, to[i]!), into - (to[i]! - from[i]!));
    }
  }
  return Object.freeze({ rows, cols, dtype, indptr, indices, data });
}

/** The entries of a dense row-major matrix within `radius`, zeros kept. */
export function threshold(dense: Float64Array, rows: number, cols: number, radius: number,
  dtype: Dtype): CsrMatrix {
  const indptr = new Float64Array(rows + 1);
  for (let i = 0; i < rows; i++) {
    let n = 0;
    for (let j = 0; j < cols; j++) if (dense[i * cols + j]! <= radius) n++;
    indptr[i + 1] = indptr[i]! + n;
  }
  const indices = new Uint32Array(indptr[rows]!);
  const data = newValues(dtype, indptr[rows]!);
  let k = 0;
  for (let i = 0; i < rows; i++) {
    for (let j = 0; j < cols; j++) {
      const d = dense[i * cols + j]!;
      if (d <= radius) {
        indices[k] = j;
        data[k++] = d;
      }
    }
  }
  return Object.freeze({ rows, cols, dtype, indptr, indices, data });
}

/** The CSR of the distances from ps to pt (null: every vertex) within radius. */
export async function neighbourhood(matrices: Matrices, limits: Limits, graph: GraphSelectorMsg,
  exact: boolean, radius: number, ps: SurfacePointMsg[] | null, pt: SurfacePointMsg[] | null,
  rows: number, cols: number, dtype: Dtype): Promise<CsrMatrix> {
  const base = { graph, exact, dtype: WIRE_DTYPE[dtype], radius };
  if (matrices.packedRows && rows > 0 && cols > 0) {
    const columns = await matrices.withinLimits(async () => {
      const out: { c: number; blocks: Block[] }[] = [];
      for (const tile of tiles(limits, ps, pt, rows, cols)) {
        const request = tileRequest(base, ps, pt, tile);
        const blocks = await matrices.transport.call(async () => {
          const got: Block[] = [];
          for await (const b of matrices.transport.stream("MatrixRows", request, graph.mesh)) {
            if (b.dtype !== request.dtype) return null;  // an older server
            got.push(readBlock(b, dtype));
          }
          return got;
        });
        if (blocks === null) return null;
        const column = out.find((x) => x.c === tile.c);
        if (column) column.blocks.push(...blocks);
        else out.push({ c: tile.c, blocks });
      }
      return out;
    });
    if (columns !== null) return assemble(rows, cols, dtype, columns);
  }
  const dense = new Float64Array(rows * cols);
  if (rows > 0 && cols > 0) {
    await matrices.dense(graph, exact, ps, pt, new ArraySink(rows, cols, "float64", dense));
  }
  return threshold(dense, rows, cols, radius, dtype);
}
