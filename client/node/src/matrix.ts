// Dense distance matrices cut into tiles within the server's limits: blocks
// of maxSources rows by maxPairs columns, whole-mesh selectors streamed
// whole. Each tile's packed rows go straight into the sink (sinks.ts): a
// tile whose answer fits one message well from Matrix, others streamed by
// MatrixRows. A server older than packed rows is read through its float64
// answers instead. Sparse rows are sparse.ts's.
import { GeodesicError, ResourceExhaustedError, UnimplementedError } from "./errors";
import { Limits, overMessageCap } from "./limits";
import { toNumber } from "./longs";
import { Dtype, ITEM_BYTES, Sink } from "./sinks";
import type { Transport } from "./transport";
import {
  GraphSelectorMsg, MATRIX_DTYPE_DEFAULT, MATRIX_DTYPE_FLOAT32, MATRIX_DTYPE_FLOAT64,
  MatrixRequest, SurfacePointMsg,
} from "./wire";

export const WIRE_DTYPE: Record<Dtype, number> = {
  float32: MATRIX_DTYPE_FLOAT32, float64: MATRIX_DTYPE_FLOAT64,
};

/** First row, rows, first column, columns. */
export interface Tile { r: number; rows: number; c: number; cols: number }

/** The requests a matrix takes: explicit lists within the server's limits, a whole-mesh
 * selector (null) whole, since its rows stream. */
export function tiles(limits: Limits, ps: SurfacePointMsg[] | null,
  pt: SurfacePointMsg[] | null, rows: number, cols: number): Tile[] {
  const rstep = ps === null ? rows : Math.max(1, limits.maxSources);
  const cstep = pt === null ? cols : Math.max(1, limits.maxPairs);
  const out: Tile[] = [];
  for (let c = 0; c < cols; c += cstep) {
    for (let r = 0; r < rows; r += rstep) {
      out.push({ r, rows: Math.min(rstep, rows - r), c, cols: Math.min(cstep, cols - c) });
    }
  }
  return out;
}

export function tileRequest(base: Omit<MatrixRequest, "sources" | "targets" | "all_sources" |
  "all_targets">, ps: SurfacePointMsg[] | null, pt: SurfacePointMsg[] | null,
tile: Tile): MatrixRequest {
  return {
    ...base, all_sources: ps === null, all_targets: pt === null,
    sources: ps === null ? [] : ps.slice(tile.r, tile.r + tile.rows),
    targets: pt === null ? [] : pt.slice(tile.c, tile.c + tile.cols),
  };
}

/** The matrix calls of one client, over its transport and with its limits. */
export class Matrices {
  // False once the server has answered a matrix without packed rows (older
  // than them): later matrices go straight to its float64 answers.
  packedRows = true;

  constructor(readonly transport: Transport, readonly limits: Limits) {}

  /** What the whole-mesh selectors stand for: the registered mesh's vertices. */
  async vertexCount(mesh: string): Promise<number> {
    const m = await this.transport.unary("GetMesh", { name: mesh }, mesh);
    return toNumber(m.diagnostics?.vertices, "MeshDiagnostics.vertices");
  }

  /** attempt() again after each refusal the server's matrix limits explain, once learnt; null
   * (and packed rows no longer asked for) when attempt() says the server answers without
   * them or the server has no such call: an older server. */
  async withinLimits<T>(attempt: () => Promise<T | null>): Promise<T | null> {
    for (;;) {
      let result: T | null;
      try {
        result = await attempt();
      } catch (e) {
        if (!(e instanceof UnimplementedError)) {
          if (e instanceof GeodesicError && this.limits.learnMatrix(e)) continue;
          throw e;
        }
        result = null;
      }
      if (result === null) this.packedRows = false;
      return result;
    }
  }

  /** Writes the distances from ps to pt (null: every vertex of the mesh) into `sink`. */
  async dense(graph: GraphSelectorMsg, exact: boolean, ps: SurfacePointMsg[] | null,
    pt: SurfacePointMsg[] | null, sink: Sink): Promise<void> {
    if (sink.rows === 0 || sink.cols === 0) return;
    const base = { graph, exact, dtype: WIRE_DTYPE[sink.dtype], radius: 0 };
    if (this.packedRows) {
      const done = await this.withinLimits(async () => {
        for (const tile of tiles(this.limits, ps, pt, sink.rows, sink.cols)) {
          const request = tileRequest(base, ps, pt, tile);
          if (!await this.packedTile(request, tile, ps !== null && pt !== null, sink)) return null;
        }
        return true;
      });
      if (done) return;
    }
    await this.float64(graph, exact, ps, pt, sink);
  }

  // One tile of packed rows into the sink; false when they came without.
  private async packedTile(request: MatrixRequest, tile: Tile, listed: boolean,
    sink: Sink): Promise<boolean> {
    const mesh = request.graph.mesh;
    const bytes = tile.rows * tile.cols * ITEM_BYTES[sink.dtype];
    if (listed && bytes <= this.limits.maxMessageBytes / 2) {
      try {
        const response = await this.transport.unary("Matrix", request, mesh);
        if (response.dtype !== request.dtype) return false;
        await sink.writePacked(tile.r, tile.c, response.rows, response.cols, response.packed);
        return true;
      } catch (e) {
        // Over a server's smaller message cap: streamed instead.
        if (!(e instanceof ResourceExhaustedError && overMessageCap(e))) throw e;
      }
    }
    return this.transport.call(async () => {
      for await (const block of this.transport.stream("MatrixRows", request, mesh)) {
        if (block.dtype !== request.dtype) return false;  // leaving the loop cancels the call
        await sink.writePacked(tile.r + block.first_row, tile.c, block.rows, block.cols,
          block.packed);
      }
      return true;
    });
  }

  // An older server: its float64 answers from Matrix, in tiles within its
  // limits, the whole-mesh selectors spelt out as vertex ids.
  private async float64(graph: GraphSelectorMsg, exact: boolean, ps: SurfacePointMsg[] | null,
    pt: SurfacePointMsg[] | null, sink: Sink): Promise<void> {
    const all = (n: number): SurfacePointMsg[] =>
      Array.from({ length: n }, (_, v) => ({ vertex: v }));
    const sources = ps ?? all(sink.rows);
    const targets = pt ?? all(sink.cols);
    for (;;) {
      const cols = Math.max(1, Math.min(this.limits.maxPairs, targets.length));
      // Half the message size: the repeated doubles and their framing.
      const rows = Math.max(1, Math.min(this.limits.maxSources,
        Math.floor(this.limits.maxMessageBytes / 2 / (8 * cols))));
      try {
        for (let r = 0; r < sources.length; r += rows) {
          for (let c = 0; c < targets.length; c += cols) {
            const response = await this.transport.unary("Matrix", {
              graph, exact, dtype: MATRIX_DTYPE_DEFAULT, radius: 0, all_sources: false,
              all_targets: false, sources: sources.slice(r, r + rows),
              targets: targets.slice(c, c + cols),
            }, graph.mesh);
            await sink.writeValues(r, c, response.rows, response.cols, response.distances);
          }
        }
        return;
      } catch (e) {
        if (!(e instanceof GeodesicError && this.limits.learnMatrix(e))) throw e;
      }
    }
  }
}
