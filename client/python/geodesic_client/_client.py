"""The geodesicd client: its public API (the meshes and graphs it manages in _catalog), over a
transport (_transport) and the batching of point sets (_batches) and matrices (_matrix,
_sparse) within the server's limits."""
import os
from typing import Any, List, Literal, Optional, Tuple, Union, overload

import numpy as np

from ._batches import Batches
from ._catalog import Catalog
from ._limits import (DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_MAX_PAIRS, DEFAULT_MAX_SOURCES,
                      DEFAULT_PATH_BATCH, Limits)
from ._matrix import DTYPES, Matrices, matrix_dtype, matrix_out
from ._points import Point, Points, format_point, is_position, to_message, to_messages_ids
from ._solver import MeshSolver
from ._sparse import neighbourhood
from ._stubs import pb
from ._transport import Transport
from ._types import Path, RetryPolicy

# Where Client() connects when given no address: $GEODESIC_SERVER, else this
# (the geodesic command line uses the same default).
DEFAULT_ADDRESS = "127.0.0.1:50051"
ADDRESS_ENV = "GEODESIC_SERVER"


def _forward(holder: str, name: str, doc: str) -> Any:
    """An attribute of the client that is `name` of its `holder` (read and written there)."""
    return property(lambda self: getattr(getattr(self, holder), name),
                    lambda self, value: setattr(getattr(self, holder), name, value), doc=doc)


class Client(Catalog):
    """A connection to one geodesicd (or a proxy in front of several).

    Points are given as numpy arrays (see geodesic_client.Points): integer vertex ids,
    FacePoints(face_ids, barycentrics), (N, 3) positions (snapped by the server), or spec
    strings. Batches larger than the server's limits are split into several calls and the
    results reassembled in order. Calls failing with UNAVAILABLE (a graph still building, the
    server not reachable yet) are retried per `retry`. Failures raise GeodesicError subclasses
    (which are grpc.RpcError); malformed arguments raise ValueError before any call.
    """

    def __init__(self, address: Optional[str] = None, timeout: float = 600.0,
                 token: Optional[str] = None, root_certificates: Optional[bytes] = None,
                 private_key: Optional[bytes] = None, certificate_chain: Optional[bytes] = None,
                 *, epsilon: float = 0.0, retry: RetryPolicy = RetryPolicy(),
                 max_pairs: int = DEFAULT_MAX_PAIRS, max_sources: int = DEFAULT_MAX_SOURCES,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 path_batch: int = DEFAULT_PATH_BATCH):
        """address: HOST:PORT; None: $GEODESIC_SERVER if set, else 127.0.0.1:50051.
        timeout: deadline of each call, seconds.
        token: sent as "authorization: Bearer <token>" (geodesicd --auth-token-file).
        root_certificates: PEM bytes of the CA that signed the server's certificate; turns TLS
        on. private_key, certificate_chain: PEM bytes of a client certificate, for servers that
        require one (--tls-client-ca).
        epsilon: the graph accuracy used when a call gives none (0: the server's default).
        max_pairs, max_sources: the server's --max-pairs and --max-sources; a lower limit
        reported by the server is learnt from its error. max_message_bytes: the largest gRPC
        message either side accepts."""
        if address is None:
            address = os.environ.get(ADDRESS_ENV) or DEFAULT_ADDRESS
        self.address = address
        self._transport = Transport(address, timeout, token, root_certificates, private_key,
                                    certificate_chain, retry, max_message_bytes)
        self._limits = Limits(max_pairs, max_sources, max_message_bytes, path_batch)
        self._batches = Batches(self._transport, self._limits)
        self._matrices = Matrices(self._transport, self._limits)
        self.epsilon = epsilon

    # What the transport and the limits hold, as attributes of the client: each call reads
    # them when it is made, so that setting one changes the calls that follow.
    timeout = _forward("_transport", "timeout", "The deadline of each call, seconds.")
    retry = _forward("_transport", "retry", "The RetryPolicy of failed calls.")
    max_pairs = _forward("_limits", "max_pairs", "Pairs (and positions, matrix columns) per "
                         "call; lowered to the server's when it refuses more.")
    max_sources = _forward("_limits", "max_sources", "Sources per field and matrix rows per "
                           "call; lowered to the server's when it refuses more.")
    path_batch = _forward("_limits", "path_batch", "Pairs per call when paths are wanted.")
    _stub = _forward("_transport", "stub", "The stub every call goes through.")
    _channel = _forward("_transport", "channel", "The gRPC channel.")

    def close(self) -> None:
        self._transport.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _resolve(self, mesh: str, points: Points) -> List[Any]:
        """SurfacePoints for a point set, positions snapped in batches."""
        return self._batches.resolve(mesh, points)

    def mesh_solver(self, name: str, epsilon: Optional[float] = None,
                    pseudo_vertices: bool = False, max_error: float = 0.0) -> MeshSolver:
        """A handle on one mesh's graph: this client's queries without the mesh, epsilon,
        pseudo_vertices and max_error arguments (see MeshSolver). epsilon: None takes this
        client's; max_error: the certified graph of that bound."""
        return MeshSolver(self, name, self._eps(epsilon), pseudo_vertices, max_error)

    # -- queries --------------------------------------------------------------
    # Every query takes pseudo_vertices: True asks the graph with pseudo
    # vertices (request_graph(..., pseudo_vertices=True)) instead of the
    # plain one of the same epsilon; and max_error: the certified graph of
    # that bound (request_graph(..., max_error=...)), whose epsilon the
    # server chose.
    #
    # field and distances return a pair when nearest_source / with_path is
    # True: their overloads tell type checkers which shape a call gets (the
    # flag given positionally or by keyword, or as a plain bool).

    @overload
    def field(self, mesh: str, sources: Union[Points, Point], epsilon: Optional[float] = ...,
              max_distance: float = ..., targets: Optional[Any] = ..., method: str = ...,
              nearest_source: Literal[False] = ..., pseudo_vertices: bool = ...,
              max_error: float = ...) -> np.ndarray: ...

    @overload
    def field(self, mesh: str, sources: Union[Points, Point], epsilon: Optional[float] = ...,
              max_distance: float = ..., targets: Optional[Any] = ..., method: str = ...,
              *, nearest_source: Literal[True], pseudo_vertices: bool = ...,
              max_error: float = ...) -> Tuple[np.ndarray, np.ndarray]: ...

    @overload
    def field(self, mesh: str, sources: Union[Points, Point], epsilon: Optional[float],
              max_distance: float, targets: Optional[Any], method: str,
              nearest_source: Literal[True], pseudo_vertices: bool = ...,
              max_error: float = ...) -> Tuple[np.ndarray, np.ndarray]: ...

    @overload
    def field(self, mesh: str, sources: Union[Points, Point], epsilon: Optional[float] = ...,
              max_distance: float = ..., targets: Optional[Any] = ..., method: str = ...,
              nearest_source: bool = ..., pseudo_vertices: bool = ...,
              max_error: float = ...) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]: ...

    def field(self, mesh: str, sources: Union[Points, Point], epsilon: Optional[float] = None,
              max_distance: float = 0.0, targets: Optional[Any] = None, method: str = "lc",
              nearest_source: bool = False, pseudo_vertices: bool = False,
              max_error: float = 0.0) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]:
        """Distances from the nearest of the sources, as a float64 array (+inf: unreachable).

        One value per vertex, or per target if targets (vertex ids) are given. With
        nearest_source, also returns the index in sources of each value's nearest source.
        More sources than the server's --max-sources are split into several fields and
        combined by their minimum.
        """
        if isinstance(sources, (str, int, np.integer)):
            sources = [sources]
        elif is_position(sources):
            sources = np.asarray(sources, dtype=np.float64).reshape(1, 3)

        points = self._resolve(mesh, sources)
        if not points:
            raise ValueError("field: give at least one source")
        target_ids = [] if targets is None else to_messages_ids(targets)
        values, labels = self._batches.field(
            self._graph(mesh, epsilon, pseudo_vertices, max_error), points, target_ids,
            max_distance, method, nearest_source)
        return (values, labels) if nearest_source else values

    @overload
    def distances(self, mesh: str, a: Points, b: Points, epsilon: Optional[float] = ...,
                  with_path: Literal[False] = ..., pseudo_vertices: bool = ...,
                  exact: bool = ..., max_error: float = ...) -> np.ndarray: ...

    @overload
    def distances(self, mesh: str, a: Points, b: Points, epsilon: Optional[float] = ...,
                  *, with_path: Literal[True], pseudo_vertices: bool = ...,
                  exact: bool = ..., max_error: float = ...) -> Tuple[np.ndarray, List[Path]]: ...

    @overload
    def distances(self, mesh: str, a: Points, b: Points, epsilon: Optional[float],
                  with_path: Literal[True], pseudo_vertices: bool = ...,
                  exact: bool = ..., max_error: float = ...) -> Tuple[np.ndarray, List[Path]]: ...

    @overload
    def distances(self, mesh: str, a: Points, b: Points, epsilon: Optional[float] = ...,
                  with_path: bool = ..., pseudo_vertices: bool = ..., exact: bool = ...,
                  max_error: float = ...) -> Union[np.ndarray, Tuple[np.ndarray, List[Path]]]: ...

    def distances(self, mesh: str, a: Points, b: Points, epsilon: Optional[float] = None,
                  with_path: bool = False, pseudo_vertices: bool = False, exact: bool = False,
                  max_error: float = 0.0) -> Union[np.ndarray, Tuple[np.ndarray, List[Path]]]:
        """Geodesic distances between a[i] and b[i], as a float64 array (+inf: unreachable).

        a and b are point sets of the same length. With with_path, returns (distances, paths),
        paths[i] a Path whose xyz is a (K, 3) array. With exact, the exact polyhedral
        distances (and geodesics) instead of the graph's: one window propagation per pair,
        bounded by the graph's answer.
        """
        pa, pb_ = self._resolve(mesh, a), self._resolve(mesh, b)
        if len(pa) != len(pb_):
            raise ValueError(f"distances: {len(pa)} points in a but {len(pb_)} in b")
        out, paths = self._batches.distances(
            self._graph(mesh, epsilon, pseudo_vertices, max_error), pa, pb_, with_path, exact)
        return (out, paths) if with_path else out

    def distance(self, mesh: str, a: Point, b: Point, epsilon: Optional[float] = None,
                 pseudo_vertices: bool = False, exact: bool = False,
                 max_error: float = 0.0) -> float:
        """Geodesic distance between two surface points (+inf if unreachable); exact: the
        exact polyhedral distance."""
        return float(self.distances(mesh, [to_message(a)], [to_message(b)], epsilon,
                                    pseudo_vertices=pseudo_vertices, exact=exact,
                                    max_error=max_error)[0])

    def path(self, mesh: str, a: Point, b: Point, epsilon: Optional[float] = None,
             pseudo_vertices: bool = False, exact: bool = False, max_error: float = 0.0) -> Path:
        """The geodesic path from a to b (unpacks as ``length, xyz = path``); exact: the
        exact geodesic."""
        _, (p,) = self.distances(mesh, [to_message(a)], [to_message(b)], epsilon, with_path=True,
                                 pseudo_vertices=pseudo_vertices, exact=exact,
                                 max_error=max_error)
        return p

    def matrix(self, mesh: str, sources: Optional[Points] = None,
               targets: Optional[Points] = None, epsilon: Optional[float] = None,
               pseudo_vertices: bool = False, exact: bool = False, max_error: float = 0.0, *,
               dtype: Any = None, out: Any = None) -> np.ndarray:
        """(len(sources), len(targets)) array of distances (+inf where unreachable); exact:
        every row exact.

        sources, targets: None means every mesh vertex in file order (no id list travels, and
        the rows stream from the server whatever the mesh's size).
        dtype: numpy.float32 or numpy.float64. None chooses float64 when both sources and
        targets are given (what matrix always returned, so older callers get the same array)
        and float32 when either is None (the whole-mesh form, for large matrices); with an
        `out` array, its dtype. float32 values are the float64 ones rounded to nearest, and
        halve what travels and what the matrix holds.
        out: None for a new array; a path, for a .npy file created with
        numpy.lib.format.open_memmap and returned as that memmap; or a writable (rows, cols)
        float32/float64 array or memmap, filled and returned. Blocks of rows go from the
        server's packed bytes (numpy.frombuffer) straight into it, with no float64 copy of
        the matrix; a server older than packed rows is read through its float64 answers,
        tile by tile."""
        ps = None if sources is None else self._resolve(mesh, sources)
        pt = None if targets is None else self._resolve(mesh, targets)
        vertices = self._matrices.vertex_count(mesh) if ps is None or pt is None else 0
        shape = (vertices if ps is None else len(ps), vertices if pt is None else len(pt))
        want = matrix_dtype(dtype, out, ps is None or pt is None)
        return self._matrices.dense(self._graph(mesh, epsilon, pseudo_vertices, max_error),
                                    exact, ps, pt, vertices, matrix_out(out, shape, want))

    def neighbourhood_matrix(self, mesh: str, radius: float, sources: Optional[Points] = None,
                             targets: Optional[Points] = None, dtype: Any = np.float32,
                             epsilon: Optional[float] = None, pseudo_vertices: bool = False,
                             exact: bool = False, max_error: float = 0.0) -> Any:
        """The distances within `radius` as a scipy.sparse.csr_matrix of shape
        (len(sources), len(targets)), None meaning every mesh vertex in file order: entry
        (i, j) is stored exactly when matrix()[i, j] <= radius (zeros, such as a vertex's own
        distance, included; unreachable pairs never), with the same value. dtype: numpy.float32
        (default) or numpy.float64. The server sends only those entries; a server older than
        sparse rows is read densely and thresholded here."""
        import scipy.sparse  # noqa: F401  only this method needs scipy: without it, fail here
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"radius {radius} is not a finite distance > 0")
        want = np.dtype(dtype)
        if want.type not in DTYPES:
            raise ValueError(f"dtype {want} is not float32 or float64")
        ps = None if sources is None else self._resolve(mesh, sources)
        pt = None if targets is None else self._resolve(mesh, targets)
        vertices = self._matrices.vertex_count(mesh) if ps is None or pt is None else 0
        graph = self._graph(mesh, epsilon, pseudo_vertices, max_error)
        return neighbourhood(self._matrices, graph, exact, radius, ps, pt, vertices, want)

    def snap(self, mesh: str, positions: Any) -> List[str]:
        """Nearest surface points to (N, 3) positions, as spec strings."""
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        return [format_point(p) for p in self._resolve(mesh, positions)]

    def sample_points(self, mesh: str, count: int, seed: int = 0,
                      epsilon: Optional[float] = None, pseudo_vertices: bool = False,
                      max_error: float = 0.0) -> Tuple[np.ndarray, float]:
        """Geodesic farthest-point sampling: (vertex ids as a uint32 array, in the order chosen,
        covering radius), every vertex lying within the covering radius (graph distance) of a
        sample (+inf while a component has none). The seed picks the first vertex."""
        resp = self._unary("SamplePoints", pb.SamplePointsRequest(
            graph=self._graph(mesh, epsilon, pseudo_vertices, max_error), count=count,
            seed=seed), mesh)
        return np.asarray(resp.vertices, dtype=np.uint32), float(resp.covering_radius)
