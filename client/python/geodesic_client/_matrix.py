"""Distance matrices cut into tiles within the server's limits: blocks of max_sources rows by
max_pairs columns, fewer rows when an answer would pass the message size, whole-mesh
selectors streamed whole. Dense rows here; sparse ones in _sparse."""
import os
from typing import Any, Callable, List, Optional, Tuple, TypeVar

import grpc
import numpy as np

from ._errors import GeodesicError, ResourceExhaustedError
from ._limits import Limits, over_matrix_limits, over_message_cap
from ._stubs import pb
from ._transport import Transport

T = TypeVar("T")

# The wire's dtype for each numpy type a matrix may take.
DTYPES = {np.float32: pb.MATRIX_DTYPE_FLOAT32, np.float64: pb.MATRIX_DTYPE_FLOAT64}

Tile = Tuple[int, int, int, int]  # first row, rows, first column, columns


class Matrices:
    """The matrix calls of one client, over its transport and with its limits."""

    def __init__(self, transport: Transport, limits: Limits):
        self.transport = transport
        self.limits = limits
        # False once the server has answered a matrix without packed rows (older than them):
        # later matrices go straight to its float64 answers.
        self.packed_rows = True

    def vertex_count(self, mesh: str) -> int:
        """What the whole-mesh selectors stand for: the registered mesh's vertices."""
        return int(self.transport.unary("GetMesh", pb.GetMeshRequest(name=mesh),
                                        mesh).diagnostics.vertices)

    def dense(self, graph: Any, exact: bool, ps: Optional[List[Any]], pt: Optional[List[Any]],
              vertices: int, out: np.ndarray) -> np.ndarray:
        """Fills `out` with the distances from ps to pt (SurfacePoints, None: the mesh's
        `vertices` vertices) and returns it."""
        if out.size == 0:
            return out
        request = dict(graph=graph, exact=exact, dtype=DTYPES[out.dtype.type])
        if self.packed_rows and self._packed(graph.mesh, ps, pt, request, out):
            return out
        # An older server: its float64 answers, tile by tile, with the whole-mesh selectors
        # spelt out as vertex ids.
        all_vertices = [pb.SurfacePoint(vertex=v) for v in range(vertices)]
        self._float64(graph, all_vertices if ps is None else ps,
                      all_vertices if pt is None else pt, exact, out)
        return out

    def tiles(self, ps: Optional[List[Any]], pt: Optional[List[Any]],
              shape: Tuple[int, int]) -> List[Tile]:
        """(first row, rows, first column, columns) of the requests a matrix takes: explicit
        lists within the server's limits, a whole-mesh selector whole (it streams)."""
        rstep = shape[0] if ps is None else max(1, self.limits.max_sources)
        cstep = shape[1] if pt is None else max(1, self.limits.max_pairs)
        return [(r, min(rstep, shape[0] - r), c, min(cstep, shape[1] - c))
                for c in range(0, shape[1], cstep) for r in range(0, shape[0], rstep)]

    @staticmethod
    def tile_request(request: dict, ps: Optional[List[Any]], pt: Optional[List[Any]],
                     tile: Tile) -> Any:
        r, rows, c, cols = tile
        return pb.MatrixRequest(
            **request, all_sources=ps is None, all_targets=pt is None,
            sources=[] if ps is None else ps[r:r + rows],
            targets=[] if pt is None else pt[c:c + cols])

    def _packed(self, mesh: str, ps: Optional[List[Any]], pt: Optional[List[Any]],
                request: dict, out: np.ndarray) -> bool:
        """Fills `out` with packed rows: a tile whose answer fits one message well from
        Matrix, others streamed by MatrixRows. False (nothing to rely on in `out`) when the
        server answers without packed rows: an older server."""
        wire = np.dtype("<f4") if request["dtype"] == pb.MATRIX_DTYPE_FLOAT32 else np.dtype("<f8")

        def fill() -> Optional[bool]:
            for tile in self.tiles(ps, pt, out.shape):
                if not self._packed_tile(mesh, self.tile_request(request, ps, pt, tile), tile,
                                         ps is not None and pt is not None, wire, out):
                    return None
            return True
        return self.within_limits(fill) is not None

    def within_limits(self, attempt: Callable[[], Optional[T]]) -> Optional[T]:
        """attempt() again after each refusal the server's matrix limits explain, once they are
        learnt; None, and packed rows no longer asked for, when attempt() says the server
        answers without them (None) or the server has no such call: an older server."""
        while True:
            try:
                result = attempt()
            except GeodesicError as e:
                if e.code() != grpc.StatusCode.UNIMPLEMENTED:
                    if self.limits.learn_matrix(e):
                        continue
                    raise
                result = None
            if result is None:
                self.packed_rows = False
            return result

    def _packed_tile(self, mesh: str, req: Any, tile: Tile, listed: bool, wire: np.dtype,
                     out: np.ndarray) -> bool:
        """One tile of packed rows into `out`; False when they came without them."""
        r, rows, c, cols = tile
        if listed and rows * cols * wire.itemsize <= self.limits.max_message_bytes // 2:
            try:
                resp = self.transport.unary("Matrix", req, mesh)
            except ResourceExhaustedError as e:
                # Over a server's smaller message cap: streamed instead.
                if not over_message_cap(e):
                    raise
            else:
                if resp.dtype != req.dtype:
                    return False
                out[r:r + rows, c:c + cols] = packed_block(resp.packed, wire, resp.rows,
                                                           resp.cols)
                return True

        def blocks() -> bool:
            stream = self.transport.start("MatrixRows", req, mesh)
            for b in stream:
                if b.dtype != req.dtype:
                    stream.cancel()
                    return False
                first = r + b.first_row
                out[first:first + b.rows, c:c + b.cols] = packed_block(
                    b.packed, wire, b.rows, b.cols)
            return True

        return self.transport.call("MatrixRows", blocks)

    def _float64(self, graph: Any, ps: List[Any], pt: List[Any], exact: bool,
                 out: np.ndarray) -> None:
        """Fills `out` from the float64 answers every server gives, in tiles that fit its
        limits."""
        max_message = self.limits.max_message_bytes
        # Beyond what one tile holds, MatrixRows streams blocks of rows, so neither side holds
        # a whole tile's message; a server without it answers tiles of Matrix.
        if len(ps) * len(pt) * 8 > max_message // 2 and \
                self._float64_rows(graph, ps, pt, exact, out):
            return
        row_cap = self.limits.max_sources
        while True:
            cols = max(1, min(self.limits.max_pairs, len(pt)))
            # Half the message size: the repeated doubles plus their framing.
            rows = max(1, min(self.limits.max_sources, row_cap, max_message // 2 // (8 * cols)))
            try:
                for r in range(0, len(ps), rows):
                    for c in range(0, len(pt), cols):
                        resp = self.transport.unary("Matrix", pb.MatrixRequest(
                            graph=graph, exact=exact,
                            sources=ps[r:r + rows], targets=pt[c:c + cols]), graph.mesh)
                        out[r:r + resp.rows, c:c + resp.cols] = np.asarray(
                            resp.distances, dtype=np.float64).reshape(resp.rows, resp.cols)
                return
            except ResourceExhaustedError as e:
                # An answer over a server's smaller message cap: fewer rows per tile.
                if over_message_cap(e) and rows > 1:
                    row_cap = rows // 2
                    continue
                # The server's own limits, learnt: tile again with them.
                if not self.limits.learn_matrix(e):
                    raise

    def _float64_rows(self, graph: Any, ps: List[Any], pt: List[Any], exact: bool,
                      out: np.ndarray) -> bool:
        """Fills `out` from MatrixRows streams, a request per max_sources x max_pairs tile.
        False (nothing to rely on in `out`) when the server lacks MatrixRows or names smaller
        limits, for the caller to tile with Matrix."""
        cols = max(1, min(self.limits.max_pairs, len(pt)))
        rows = max(1, self.limits.max_sources)
        try:
            for r in range(0, len(ps), rows):
                for c in range(0, len(pt), cols):
                    req = pb.MatrixRequest(graph=graph, exact=exact, sources=ps[r:r + rows],
                                           targets=pt[c:c + cols])

                    def blocks(req: Any = req, r: int = r, c: int = c) -> None:
                        for b in self.transport.start("MatrixRows", req, graph.mesh):
                            first = r + b.first_row
                            out[first:first + b.rows, c:c + b.cols] = np.asarray(
                                b.distances, dtype=np.float64).reshape(b.rows, b.cols)

                    self.transport.call("MatrixRows", blocks)
        except GeodesicError as e:
            if e.code() == grpc.StatusCode.UNIMPLEMENTED or over_matrix_limits(e):
                return False
            raise
        return True


def matrix_dtype(dtype: Any, out: Any, whole_mesh: bool) -> np.dtype:
    """The dtype matrix() answers in (see its docstring)."""
    if dtype is not None:
        want = np.dtype(dtype)
    elif isinstance(out, np.ndarray):
        want = out.dtype
    else:
        want = np.dtype(np.float32 if whole_mesh else np.float64)
    if want.type not in DTYPES:
        raise ValueError(f"dtype {want} is not float32 or float64")
    return want


def matrix_out(out: Any, shape: Tuple[int, int], dtype: np.dtype) -> np.ndarray:
    """Where matrix() writes: a new array, a new .npy memmap at a path, or the caller's."""
    if out is None:
        return np.empty(shape, dtype=dtype)
    if isinstance(out, (str, os.PathLike)):
        if 0 in shape:  # nothing to map: the file alone
            np.save(os.fspath(out), np.empty(shape, dtype=dtype))
            return np.load(os.fspath(out))
        return np.lib.format.open_memmap(os.fspath(out), mode="w+", dtype=dtype, shape=shape)
    if not isinstance(out, np.ndarray):
        raise ValueError(f"out: expected a path or a numpy array, got {type(out).__name__}")
    if out.shape != shape or out.dtype != dtype or not out.flags.writeable:
        state = "" if out.flags.writeable else "read-only "
        raise ValueError(f"out: expected a writable {shape} {dtype} array, got a {state}"
                         f"{out.shape} {out.dtype} one")
    return out


def packed_block(packed: bytes, wire: np.dtype, rows: int, cols: int) -> np.ndarray:
    """A block of packed rows as a (rows, cols) view of the message's bytes."""
    block = np.frombuffer(packed, dtype=wire)
    if block.size != rows * cols:
        raise ValueError(f"the server sent {block.size} values for a {rows} x {cols} block")
    return block.reshape(rows, cols)
