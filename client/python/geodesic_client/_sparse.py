"""Neighbourhood matrices: the distances within a radius as a scipy.sparse.csr_matrix, from
MatrixRows streams of sparse rows in the tiles of _matrix, or from a server older than them
densely and thresholded here. scipy is imported only when one is asked for."""
from typing import Any, List, Optional, Tuple

import numpy as np

from ._matrix import DTYPES, Matrices


def neighbourhood(matrices: Matrices, graph: Any, exact: bool, radius: float,
                  ps: Optional[List[Any]], pt: Optional[List[Any]], vertices: int,
                  want: np.dtype) -> Any:
    """The csr_matrix of the distances from ps to pt (SurfacePoints, None: the mesh's
    `vertices` vertices) within radius, in dtype `want`."""
    import scipy.sparse
    shape = (vertices if ps is None else len(ps), vertices if pt is None else len(pt))
    request = dict(graph=graph, exact=exact, dtype=DTYPES[want.type], radius=radius)
    if matrices.packed_rows and shape[0] and shape[1]:
        tiles = _sparse_tiles(matrices, graph.mesh, ps, pt, request, shape, want)
        if tiles is not None:
            if len(tiles) == 1:
                return tiles[0]
            return scipy.sparse.hstack(tiles, format="csr")
    dense = np.empty(shape, dtype=np.float64)
    if shape[0] and shape[1]:
        matrices.dense(graph, exact, ps, pt, vertices, dense)
    return threshold(dense, radius, want)


def _sparse_tiles(matrices: Matrices, mesh: str, ps: Optional[List[Any]],
                  pt: Optional[List[Any]], request: dict, shape: Tuple[int, int],
                  want: np.dtype) -> Optional[List[Any]]:
    """csr_matrix blocks of columns, in order, from MatrixRows streams of sparse rows;
    None when the server answers without them (an older server)."""
    def collect() -> Optional[List[Any]]:
        tiles = []
        for c, cols in sorted({(t[2], t[3]) for t in matrices.tiles(ps, pt, shape)}):
            column = _sparse_column(matrices, mesh, ps, pt, request, shape, want, c)
            if column is None:
                return None
            tiles.append(_csr(column, (shape[0], cols), shape[1], want))
        return tiles
    return matrices.within_limits(collect)


def _sparse_column(matrices: Matrices, mesh: str, ps: Optional[List[Any]],
                   pt: Optional[List[Any]], request: dict, shape: Tuple[int, int],
                   want: np.dtype, c: int) -> Optional[List[Any]]:
    """The (indptr, indices, values) blocks of the tiles of the block of columns starting
    at c, in row order; None when the server answers without sparse rows."""
    wire = want.newbyteorder("<")
    got: List[Any] = []
    for tile in matrices.tiles(ps, pt, shape):
        if tile[2] != c:
            continue
        req = matrices.tile_request(request, ps, pt, tile)
        blocks: List[Any] = []

        def read(req: Any = req, blocks: List[Any] = blocks) -> bool:
            blocks.clear()
            stream = matrices.transport.start("MatrixRows", req, mesh)
            for b in stream:
                if b.dtype != req.dtype:
                    stream.cancel()
                    return False
                blocks.append((np.frombuffer(b.indptr, dtype="<u8"),
                               np.frombuffer(b.indices, dtype="<u4"),
                               np.frombuffer(b.values, dtype=wire)))
            return True

        if not matrices.transport.call("MatrixRows", read):
            return None
        got.extend(blocks)
    return got


def _csr(blocks: List[Any], shape: Tuple[int, int], width: int, want: np.dtype) -> Any:
    """One csr_matrix of `shape` from its blocks of rows, in order; width: the whole
    matrix's columns (which choose the index type)."""
    import scipy.sparse
    indptr, indices, values = [np.zeros(1, dtype=np.int64)], [], []
    for ptr, idx, val in blocks:
        indptr.append(ptr[1:].astype(np.int64) + indptr[-1][-1])
        indices.append(idx)
        values.append(val)
    index_type = np.int32 if width < 2**31 else np.int64
    return scipy.sparse.csr_matrix(
        (np.concatenate(values) if values else np.empty(0, dtype=want),
         np.concatenate(indices).astype(index_type) if indices
         else np.empty(0, dtype=index_type),
         np.concatenate(indptr)), shape=shape)


def threshold(dense: np.ndarray, radius: float, dtype: np.dtype) -> Any:
    """The entries of `dense` within `radius` as a csr_matrix, zeros kept."""
    import scipy.sparse
    rows, cols = np.nonzero(dense <= radius)
    values = dense[rows, cols].astype(dtype)
    index_type = np.int32 if dense.shape[1] < 2**31 else np.int64
    indptr = np.zeros(dense.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=dense.shape[0]), out=indptr[1:])
    return scipy.sparse.csr_matrix((values, cols.astype(index_type), indptr), shape=dense.shape)
