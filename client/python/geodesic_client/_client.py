"""The geodesicd client."""
import hashlib
import os
import random
import re
import time
from typing import Any, Callable, List, Literal, Optional, Tuple, Union, overload

import grpc
import numpy as np

from ._errors import GeodesicError, ResourceExhaustedError, from_rpc_error
from ._points import Point, Points, format_point, to_message, to_messages
from ._stubs import pb, rpc
from ._solver import MeshSolver
from ._types import Graph, GraphState, Mesh, Path, RetryPolicy

# Where Client() connects when given no address: $GEODESIC_SERVER, else this
# (the geodesic command line uses the same default).
DEFAULT_ADDRESS = "127.0.0.1:50051"
ADDRESS_ENV = "GEODESIC_SERVER"

# The server's defaults (geodesicd serve --max-pairs, --max-sources; its gRPC
# messages are limited to 64 MiB either way).
DEFAULT_MAX_PAIRS = 10000
DEFAULT_MAX_SOURCES = 1024
DEFAULT_MAX_MESSAGE_BYTES = 64 << 20
# Pairs per Distance call when paths are wanted: a path can hold thousands of
# points, so that whole batches stay far below the message size.
DEFAULT_PATH_BATCH = 256

_LIMIT = re.compile(r"exceed the limit of (\d+)")
_MATRIX_LIMITS = re.compile(r"limits \((\d+) sources, (\d+) targets\)")
# The server sizes an answer before computing it, and refuses one over its message cap.
_ROW_BLOCKS = re.compile(r"split it into row blocks")


def _overload_hint(e: grpc.RpcError) -> Optional[float]:
    """Seconds the server asks a client to wait when it answers RESOURCE_EXHAUSTED because it
    is overloaded (its retry-after-ms trailer); None for any other error."""
    if not hasattr(e, "code") or e.code() != grpc.StatusCode.RESOURCE_EXHAUSTED:
        return None
    trailing = e.trailing_metadata() if hasattr(e, "trailing_metadata") else None
    for key, value in trailing or ():
        if key == "retry-after-ms":
            try:
                return max(0.0, int(value) / 1e3)
            except ValueError:
                return None
    return None


class Client:
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
        self._max_message = max_message_bytes
        options = [("grpc.max_receive_message_length", max_message_bytes),
                   ("grpc.max_send_message_length", max_message_bytes),
                   # gRPC's own reconnect backoff would otherwise grow past the
                   # retries' (to minutes), failing every retry fast.
                   ("grpc.initial_reconnect_backoff_ms", int(1000 * retry.initial_backoff) or 1),
                   ("grpc.min_reconnect_backoff_ms", int(1000 * retry.initial_backoff) or 1),
                   ("grpc.max_reconnect_backoff_ms", int(1000 * retry.max_backoff) or 1)]
        if root_certificates is not None:
            credentials = grpc.ssl_channel_credentials(root_certificates, private_key,
                                                       certificate_chain)
            self._channel = grpc.secure_channel(address, credentials, options=options)
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        self._stub = rpc.GeodesicStub(self._channel)
        self._auth = [("authorization", f"Bearer {token}")] if token else []
        self.timeout = timeout
        self.epsilon = epsilon
        self.retry = retry
        self.max_pairs = max_pairs
        self.max_sources = max_sources
        self.path_batch = path_batch
        # False once the server has answered a matrix without packed rows (older than them):
        # later matrices go straight to its float64 answers.
        self._packed_rows = True

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- plumbing -------------------------------------------------------------

    def _meta(self, mesh: Optional[str]) -> List[Tuple[str, str]]:
        # Proxies route by this header, so that a mesh's queries reach the
        # replicas that hold its graph.
        return ([("x-geodesic-mesh", mesh)] if mesh else []) + self._auth

    def _eps(self, epsilon: Optional[float]) -> float:
        return self.epsilon if epsilon is None else epsilon

    def _graph(self, mesh: str, epsilon: Optional[float], pseudo_vertices: bool,
               max_error: float = 0.0) -> Any:
        """The GraphSelector every request that names a graph carries in its `graph` (the
        requests' own mesh, epsilon and pseudo_vertices fields are what it superseded).
        max_error: a certified graph (its epsilon the server's choice), 0 for a plain one."""
        return pb.GraphSelector(mesh=mesh, epsilon=self._eps(epsilon),
                                pseudo_vertices=pseudo_vertices, max_error=max_error)

    def _call(self, name: str, run: Callable[[], Any]) -> Any:
        """run() with retries of transient codes; failures become GeodesicError."""
        delays = self.retry.delays()
        while True:
            try:
                return run()
            except grpc.RpcError as e:
                error = from_rpc_error(e, name)
                hint = _overload_hint(e) if self.retry.overload else None
                retried = error.code().name in self.retry.codes or hint is not None
                delay = next(delays, None) if retried else None
                if delay is None:
                    raise error from None
                time.sleep(max(hint or 0.0, random.uniform(delay / 2, delay)))

    def _unary(self, name: str, request: Any, mesh: Optional[str]) -> Any:
        method = getattr(self._stub, name)
        return self._call(name, lambda: method(request, timeout=self.timeout,
                                                metadata=self._meta(mesh)))

    def _resolve(self, mesh: str, points: Points) -> List[Any]:
        """SurfacePoints for a point set, positions snapped in batches."""
        messages = to_messages(points)
        at = [i for i, m in enumerate(messages) if isinstance(m, pb.Vec3)]
        start = 0
        while start < len(at):
            chunk = at[start:start + self.max_pairs]
            try:
                snapped = self._unary("Snap", pb.SnapRequest(
                    mesh=mesh, positions=[messages[i] for i in chunk]), mesh)
            except GeodesicError as e:
                if self._learn_limit(e, "max_pairs", len(chunk)):
                    continue
                raise
            for i, p in zip(chunk, snapped.points):
                messages[i] = p
            start += len(chunk)
        return messages

    def _resolve_one(self, mesh: str, point: Point) -> Any:
        return self._resolve(mesh, [to_message(point)])[0]

    def _learn_limit(self, error: GeodesicError, attr: str, size: int) -> bool:
        """After RESOURCE_EXHAUSTED naming a server limit below `size`, lowers self.<attr> to
        it and returns True (retry); otherwise False."""
        limit = _LIMIT.search(error.details() or "")
        if not isinstance(error, ResourceExhaustedError) or not limit:
            return False
        if not 0 < int(limit.group(1)) < size:
            return False
        setattr(self, attr, int(limit.group(1)))
        return True

    @staticmethod
    def _smaller_batch(error: GeodesicError, size: int) -> Optional[int]:
        """The batch size to retry with after RESOURCE_EXHAUSTED, or None to give up."""
        if not isinstance(error, ResourceExhaustedError):
            return None
        limit = _LIMIT.search(error.details())
        if limit and 0 < int(limit.group(1)) < size:
            return int(limit.group(1))
        if "larger than max" in error.details() and size > 1:
            return size // 2
        return None

    # -- meshes ---------------------------------------------------------------

    def meshes(self) -> List[Mesh]:
        """The registered meshes, with their diagnostics."""
        return [Mesh._from_proto(m)
                for m in self._unary("ListMeshes", pb.ListMeshesRequest(), None).meshes]

    def mesh(self, name: str) -> Mesh:
        """One registered mesh, with its diagnostics."""
        return Mesh._from_proto(self._unary("GetMesh", pb.GetMeshRequest(name=name), name))

    def register_mesh(self, name: str, path: str, repair_non_manifold: bool = False) -> Mesh:
        """Registers a mesh from a file under the server's --mesh-root.

        repair_non_manifold: split each non-manifold vertex into one copy per fan instead of
        refusing the mesh (the copies are listed in the returned Mesh's vertex_copies).
        """
        return Mesh._from_proto(self._unary("RegisterMesh", pb.RegisterMeshRequest(
            name=name, path=path, repair_non_manifold=repair_non_manifold), name))

    def register_region(self, name: str, parent: str, *, vertices: Any = None,
                        faces: Any = None) -> Mesh:
        """Registers part of a registered mesh as a mesh of its own, whose distances and paths
        never leave it (e.g. a cortical surface without its medial wall).

        Exactly one of: vertices, the parent's vertex ids whose faces (all three corners
        listed) make the region; faces, the parent's face ids. Any order, repeats allowed.
        The returned Mesh names its parent; the parent cannot be unloaded while it has one."""
        if (vertices is None) == (faces is None):
            raise ValueError("register_region: give either vertices or faces")
        ids = np.asarray(vertices if faces is None else faces).ravel()
        if ids.size and (not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0):
            raise ValueError("register_region: ids must be non-negative integers")
        request = pb.RegisterRegionRequest(name=name, parent=parent)
        (request.vertex_ids if faces is None else request.face_ids).extend(ids.tolist())
        return Mesh._from_proto(self._unary("RegisterRegion", request, name))

    def mesh_solver(self, name: str, epsilon: Optional[float] = None,
                    pseudo_vertices: bool = False, max_error: float = 0.0) -> MeshSolver:
        """A handle on one mesh's graph: this client's queries without the mesh, epsilon,
        pseudo_vertices and max_error arguments (see MeshSolver). epsilon: None takes this
        client's; max_error: the certified graph of that bound."""
        return MeshSolver(self, name, self._eps(epsilon), pseudo_vertices, max_error)

    def unload_mesh(self, name: str) -> None:
        """Forgets a mesh and drops its graphs from memory (their files stay)."""
        self._unary("UnloadMesh", pb.UnloadMeshRequest(name=name), name)

    def upload_mesh(self, name: str, filename: Optional[str] = None, chunk_bytes: int = 1 << 20,
                    *, vertices: Any = None, faces: Any = None,
                    repair_non_manifold: bool = False) -> Mesh:
        """Uploads a mesh and registers it under name: a local .obj/.off/.ply/.stl/.surf.gii
        file, or arrays (vertices: (N, 3) floats, faces: (M, 3) vertex ids, in place of
        filename).

        The upload declares its size and SHA-256 first, and the server registers it only if
        exactly those bytes arrive: an upload that fails or is interrupted leaves nothing
        behind, and can simply be made again. Returns the registered Mesh."""
        if filename is None:
            if vertices is None or faces is None:
                raise ValueError("upload_mesh: give a filename, or both vertices and faces")
            return self._upload_arrays(name, vertices, faces, chunk_bytes, repair_non_manifold)
        if vertices is not None or faces is not None:
            raise ValueError("upload_mesh: give a filename or arrays, not both")
        fmt = os.path.splitext(filename)[1][1:].lower()
        if not fmt:
            raise ValueError(f"upload_mesh: {filename} has no extension naming its format "
                             "(.obj, .off, .ply, .stl or .surf.gii)")
        # Read before the call, so a missing file raises here by name instead
        # of inside gRPC's request iterator ("Exception iterating requests!").
        digest = hashlib.sha256()
        total = 0
        with open(filename, "rb") as f:
            for data in iter(lambda: f.read(chunk_bytes), b""):
                digest.update(data)
                total += len(data)
        if total == 0:
            raise ValueError(f"upload_mesh: {filename} is empty")
        header = dict(name=name, format=fmt, total_bytes=total, sha256=digest.hexdigest(),
                      repair_non_manifold=repair_non_manifold)

        def chunks():
            # A file changed since it was hashed fails the server's check.
            with open(filename, "rb") as f:
                first = True
                while True:
                    data = f.read(chunk_bytes)
                    if not data and not first:
                        return
                    yield pb.UploadMeshRequest(data=data, **(header if first else {}))
                    first = False

        return Mesh._from_proto(self._call("UploadMesh", lambda: self._stub.UploadMesh(
            chunks(), timeout=self.timeout, metadata=self._meta(name))))

    def _upload_arrays(self, name: str, vertices: Any, faces: Any, chunk_bytes: int,
                       repair_non_manifold: bool) -> Mesh:
        v = np.ascontiguousarray(vertices, dtype="<f8")
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise ValueError(f"upload_mesh: vertices must be an (N, 3) array, not {v.shape}")
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ValueError(f"upload_mesh: faces must be an (M, 3) array, not {f.shape}")
        if not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"upload_mesh: faces must hold integer vertex ids, not {f.dtype}")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"upload_mesh: face vertex ids must be in [0, {len(v)})")
        f = np.ascontiguousarray(f, dtype="<u4")
        # The checksum is over the arrays' little-endian bytes, vertices then
        # faces (geodesic.proto, UploadMeshRequest).
        digest = hashlib.sha256(v.tobytes())
        digest.update(f.tobytes())
        header = dict(name=name, total_bytes=v.nbytes + f.nbytes, sha256=digest.hexdigest(),
                      repair_non_manifold=repair_non_manifold)
        flat_v, flat_f = v.reshape(-1), f.reshape(-1)
        step_v, step_f = max(1, chunk_bytes // 8), max(1, chunk_bytes // 4)

        def chunks():
            yield pb.UploadMeshRequest(**header)
            for i in range(0, len(flat_v), step_v):
                yield pb.UploadMeshRequest(vertices=flat_v[i:i + step_v].tolist())
            for i in range(0, len(flat_f), step_f):
                yield pb.UploadMeshRequest(faces=flat_f[i:i + step_f].tolist())

        return Mesh._from_proto(self._call("UploadMesh", lambda: self._stub.UploadMesh(
            chunks(), timeout=self.timeout, metadata=self._meta(name))))

    def geometry(self, name: str) -> Tuple[np.ndarray, np.ndarray]:
        """A registered mesh's (vertices (N, 3) float64, faces (M, 3) uint32), in file order:
        the arrays an upload of arrays gave, and what face ids and barycentrics refer to."""
        def fetch() -> Tuple[np.ndarray, np.ndarray]:
            vertices: List[float] = []
            faces: List[int] = []
            for chunk in self._stub.GetGeometry(pb.GetMeshRequest(name=name),
                                                timeout=self.timeout, metadata=self._meta(name)):
                vertices.extend(chunk.vertices)
                faces.extend(chunk.faces)
            return (np.array(vertices, dtype=np.float64).reshape(-1, 3),
                    np.array(faces, dtype=np.uint32).reshape(-1, 3))
        return self._call("GetGeometry", fetch)

    # -- graphs ---------------------------------------------------------------

    def request_graph(self, mesh: str, epsilon: Optional[float] = None, wait: bool = True,
                      pseudo_vertices: bool = False,
                      progress: Optional[Callable[[Graph], None]] = None,
                      max_error: float = 0.0) -> Graph:
        """Requests the graph of mesh at epsilon; with wait, blocks until it is ready.

        max_error: a certified graph instead, its relative errors measured at most this
        (in [1e-5, 0.5]): the server chooses the epsilon (epsilon is ignored), builds,
        measures the graph against exact distances and rebuilds it tighter until the bound
        holds; the Graph's certificate says what was measured. A graph of its own: pass the
        same max_error to queries to use it.

        progress: with wait, called with a Graph for every status the server reports while
        waiting (state, phase, progress in [0, 1]), the last one READY when the call returns;
        e.g. ``progress=lambda g: print(f"{g.phase} {g.progress:.0%}")``. A graph already ready
        gives one call. An exception it raises ends the wait and propagates.
        Raises RuntimeError if the graph failed or was cancelled while waiting.
        """
        request = pb.RequestGraphRequest(
            graph=self._graph(mesh, epsilon, pseudo_vertices, max_error))
        g = self._unary("RequestGraph", request, mesh)
        # Under memory pressure a graph can be evicted again before this
        # client sees it ready; asking again brings it back from its file.
        # The watch has no deadline: `timeout` bounds calls, not a build,
        # and the stream ends when the graph is ready, failed or cancelled.
        for _ in range(10 if wait else 0):
            g = self._call("WatchGraph", lambda: self._last(self._stub.WatchGraph(
                pb.GetGraphRequest(graph=self._graph(mesh, g.epsilon, pseudo_vertices, max_error)),
                timeout=None, metadata=self._meta(mesh)), g, progress))
            if g.state != pb.GRAPH_STATE_EVICTED:
                break
            g = self._unary("RequestGraph", request, mesh)
        graph = Graph._from_proto(g)
        if wait and graph.state != GraphState.READY:
            raise RuntimeError(f"graph for {mesh} at eps {graph.epsilon}: {graph.state.name} "
                               f"{graph.error}")
        return graph

    @staticmethod
    def _last(stream: Any, default: Any,
              progress: Optional[Callable[[Graph], None]] = None) -> Any:
        """The last message of a WatchGraph stream (default if none), each one passed to
        progress as a Graph on the way."""
        try:
            for item in stream:
                default = item
                if progress is not None:
                    progress(Graph._from_proto(item))
            return default
        finally:
            # Also when progress raised or the wait was interrupted: the
            # server stops watching instead of writing to nobody.
            stream.cancel()

    def graph(self, mesh: str, epsilon: Optional[float] = None,
              pseudo_vertices: bool = False, max_error: float = 0.0) -> Graph:
        """The state of the graph of mesh at epsilon."""
        return Graph._from_proto(self._unary("GetGraph", pb.GetGraphRequest(
            graph=self._graph(mesh, epsilon, pseudo_vertices, max_error)), mesh))

    def graphs(self) -> List[Graph]:
        """Every graph the server knows of."""
        return [Graph._from_proto(g)
                for g in self._unary("ListGraphs", pb.ListGraphsRequest(), None).graphs]

    def cancel_graph(self, mesh: str, epsilon: Optional[float] = None,
                     pseudo_vertices: bool = False, max_error: float = 0.0) -> Graph:
        """Cancels the build of a graph."""
        return Graph._from_proto(self._unary("CancelGraph", pb.CancelGraphRequest(
            graph=self._graph(mesh, epsilon, pseudo_vertices, max_error)), mesh))

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
        elif _is_position(sources):
            sources = np.asarray(sources, dtype=np.float64).reshape(1, 3)

        points = self._resolve(mesh, sources)
        if not points:
            raise ValueError("field: give at least one source")
        target_ids = [] if targets is None else to_messages_ids(targets)
        values, labels = None, None
        start = 0
        while start < len(points):
            batch = points[start:start + self.max_sources]
            req = pb.DistanceFieldRequest(
                graph=self._graph(mesh, epsilon, pseudo_vertices, max_error),
                max_distance=max_distance,
                sources=batch, targets=target_ids, method=method, nearest_source=nearest_source)
            try:
                part, part_labels = self._call("DistanceField", lambda: self._field_stream(req))
            except GeodesicError as e:
                if self._learn_limit(e, "max_sources", len(batch)):
                    continue
                raise
            if values is None:
                values, labels = part, part_labels
                if labels is not None:
                    labels = labels.astype(np.int64)
            else:
                closer = part < values
                values = np.where(closer, part, values)
                if labels is not None:
                    labels = np.where(closer, part_labels.astype(np.int64) + start, labels)
            start += len(batch)
        return (values, labels) if nearest_source else values

    def _field_stream(self, req: Any) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        values, labels = np.empty(0), None
        for chunk in self._stub.DistanceField(req, timeout=self.timeout,
                                              metadata=self._meta(req.mesh)):
            if chunk.offset == 0 and len(values) != chunk.total:
                values = np.empty(chunk.total, dtype=np.float64)
                labels = np.empty(chunk.total, dtype=np.uint32) if req.nearest_source else None
            end = chunk.offset + len(chunk.values)
            values[chunk.offset:end] = chunk.values
            if req.nearest_source:
                labels[chunk.offset:end] = chunk.nearest_source
        return values, labels

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
        out = np.empty(len(pa), dtype=np.float64)
        paths: List[Path] = []
        i = 0
        # Shrinks with every "too large" answer, so a retry never repeats a
        # batch the server (or the channel) refused.
        batch = min(self.max_pairs, self.path_batch) if with_path else self.max_pairs
        while i < len(pa):
            j = min(len(pa), i + batch)
            req = pb.DistanceRequest(graph=self._graph(mesh, epsilon, pseudo_vertices, max_error),
                                     with_path=with_path, exact=exact,
                                     pairs=[pb.PointPair(**{"from": pa[k], "to": pb_[k]})
                                            for k in range(i, j)])
            try:
                resp = self._unary("Distance", req, mesh)
            except GeodesicError as e:
                smaller = self._smaller_batch(e, j - i)
                if smaller is None:
                    raise
                batch = smaller
                if with_path:
                    self.path_batch = smaller
                # An exact cap (--max-exact-pairs) says nothing of graph pairs.
                if smaller < self.max_pairs and _LIMIT.search(e.details()) and not exact:
                    self.max_pairs = smaller
                continue
            out[i:j] = [r.distance for r in resp.results]
            if with_path:
                paths.extend(_path(r) for r in resp.results)
            i = j
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
        vertices = self._vertex_count(mesh) if ps is None or pt is None else 0
        shape = (vertices if ps is None else len(ps), vertices if pt is None else len(pt))
        want = _matrix_dtype(dtype, out, ps is None or pt is None)
        result = _matrix_out(out, shape, want)
        if result.size == 0:
            return result
        request = dict(graph=self._graph(mesh, epsilon, pseudo_vertices, max_error), exact=exact,
                       dtype=_DTYPES[want.type])
        if self._packed_rows and self._matrix_packed(mesh, ps, pt, request, result):
            return result
        # An older server: its float64 answers, tile by tile, with the whole-mesh selectors
        # spelt out as vertex ids.
        all_vertices = [pb.SurfacePoint(vertex=v) for v in range(vertices)]
        self._matrix_float64(mesh, all_vertices if ps is None else ps,
                             all_vertices if pt is None else pt, epsilon, pseudo_vertices,
                             exact, max_error, result)
        return result

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
        import scipy.sparse  # only this method needs scipy
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"radius {radius} is not a finite distance > 0")
        want = np.dtype(dtype)
        if want.type not in _DTYPES:
            raise ValueError(f"dtype {want} is not float32 or float64")
        ps = None if sources is None else self._resolve(mesh, sources)
        pt = None if targets is None else self._resolve(mesh, targets)
        vertices = self._vertex_count(mesh) if ps is None or pt is None else 0
        shape = (vertices if ps is None else len(ps), vertices if pt is None else len(pt))
        request = dict(graph=self._graph(mesh, epsilon, pseudo_vertices, max_error), exact=exact,
                       dtype=_DTYPES[want.type], radius=radius)
        if self._packed_rows and shape[0] and shape[1]:
            tiles = self._sparse_tiles(mesh, ps, pt, request, shape, want)
            if tiles is not None:
                if len(tiles) == 1:
                    return tiles[0]
                return scipy.sparse.hstack(tiles, format="csr")
        dense = self.matrix(mesh, ps, pt, epsilon, pseudo_vertices, exact, max_error,
                            dtype=np.float64) if shape[0] and shape[1] else \
            np.empty(shape, dtype=np.float64)
        return _threshold(dense, radius, want)

    def _vertex_count(self, mesh: str) -> int:
        """What the whole-mesh selectors stand for: the registered mesh's vertices."""
        return int(self._unary("GetMesh", pb.GetMeshRequest(name=mesh), mesh).diagnostics.vertices)

    def _tiles(self, ps: Optional[List[Any]], pt: Optional[List[Any]],
               shape: Tuple[int, int]) -> List[Tuple[int, int, int, int]]:
        """(first row, rows, first column, columns) of the requests a matrix takes: explicit
        lists within the server's limits, a whole-mesh selector whole (it streams)."""
        rstep = shape[0] if ps is None else max(1, self.max_sources)
        cstep = shape[1] if pt is None else max(1, self.max_pairs)
        return [(r, min(rstep, shape[0] - r), c, min(cstep, shape[1] - c))
                for c in range(0, shape[1], cstep) for r in range(0, shape[0], rstep)]

    def _tile_request(self, request: dict, ps: Optional[List[Any]], pt: Optional[List[Any]],
                      tile: Tuple[int, int, int, int]) -> Any:
        r, rows, c, cols = tile
        return pb.MatrixRequest(
            **request, all_sources=ps is None, all_targets=pt is None,
            sources=[] if ps is None else ps[r:r + rows],
            targets=[] if pt is None else pt[c:c + cols])

    def _learn_matrix_limits(self, e: GeodesicError) -> bool:
        """After a refusal naming smaller matrix limits, adopts them (True: tile again)."""
        limits = _MATRIX_LIMITS.search(e.details() or "")
        if not isinstance(e, ResourceExhaustedError) or not limits:
            return False
        max_sources, max_targets = (int(x) for x in limits.groups())
        if not (0 < max_sources < self.max_sources or 0 < max_targets < self.max_pairs):
            return False
        self.max_sources = min(self.max_sources, max(1, max_sources))
        self.max_pairs = min(self.max_pairs, max(1, max_targets))
        return True

    def _matrix_packed(self, mesh: str, ps: Optional[List[Any]], pt: Optional[List[Any]],
                       request: dict, out: np.ndarray) -> bool:
        """Fills `out` with packed rows: a tile whose answer fits one message well from
        Matrix, others streamed by MatrixRows. False (nothing to rely on in `out`) when the
        server answers without packed rows: an older server."""
        wire = np.dtype("<f4") if request["dtype"] == pb.MATRIX_DTYPE_FLOAT32 else np.dtype("<f8")
        while True:
            try:
                for tile in self._tiles(ps, pt, out.shape):
                    req = self._tile_request(request, ps, pt, tile)
                    r, rows, c, cols = tile
                    unary = ps is not None and pt is not None and \
                        rows * cols * wire.itemsize <= self._max_message // 2
                    if unary:
                        try:
                            resp = self._unary("Matrix", req, mesh)
                        except ResourceExhaustedError as e:
                            # Over a server's smaller message cap: streamed instead.
                            if not _ROW_BLOCKS.search(e.details() or ""):
                                raise
                            unary = False
                        else:
                            if resp.dtype != req.dtype:
                                self._packed_rows = False
                                return False
                            out[r:r + rows, c:c + cols] = _packed_block(
                                resp.packed, wire, resp.rows, resp.cols)
                    if unary:
                        continue

                    def blocks(req: Any = req, r: int = r, c: int = c) -> bool:
                        stream = self._stub.MatrixRows(req, timeout=self.timeout,
                                                       metadata=self._meta(mesh))
                        for b in stream:
                            if b.dtype != req.dtype:
                                stream.cancel()
                                return False
                            first = r + b.first_row
                            out[first:first + b.rows, c:c + b.cols] = _packed_block(
                                b.packed, wire, b.rows, b.cols)
                        return True

                    if not self._call("MatrixRows", blocks):
                        self._packed_rows = False
                        return False
                return True
            except GeodesicError as e:
                if e.code() == grpc.StatusCode.UNIMPLEMENTED:
                    self._packed_rows = False
                    return False
                if not self._learn_matrix_limits(e):
                    raise

    def _sparse_tiles(self, mesh: str, ps: Optional[List[Any]], pt: Optional[List[Any]],
                      request: dict, shape: Tuple[int, int],
                      want: np.dtype) -> Optional[List[Any]]:
        """csr_matrix blocks of columns, in order, from MatrixRows streams of sparse rows;
        None when the server answers without them (an older server)."""
        import scipy.sparse
        wire = want.newbyteorder("<")
        while True:
            try:
                tiles = []
                for c, cols in sorted({(t[2], t[3]) for t in self._tiles(ps, pt, shape)}):
                    indptr, indices, values = [np.zeros(1, dtype=np.int64)], [], []
                    for tile in self._tiles(ps, pt, shape):
                        if tile[2] != c:
                            continue
                        req = self._tile_request(request, ps, pt, tile)
                        got: List[Any] = []

                        def blocks(req: Any = req, got: List[Any] = got) -> bool:
                            got.clear()
                            stream = self._stub.MatrixRows(req, timeout=self.timeout,
                                                           metadata=self._meta(mesh))
                            for b in stream:
                                if b.dtype != req.dtype:
                                    stream.cancel()
                                    return False
                                got.append((np.frombuffer(b.indptr, dtype="<u8"),
                                            np.frombuffer(b.indices, dtype="<u4"),
                                            np.frombuffer(b.values, dtype=wire)))
                            return True

                        if not self._call("MatrixRows", blocks):
                            self._packed_rows = False
                            return None
                        for ptr, idx, val in got:
                            indptr.append(ptr[1:].astype(np.int64) + indptr[-1][-1])
                            indices.append(idx)
                            values.append(val)
                    index_type = np.int32 if shape[1] < 2**31 else np.int64
                    tiles.append(scipy.sparse.csr_matrix(
                        (np.concatenate(values) if values else np.empty(0, dtype=want),
                         np.concatenate(indices).astype(index_type) if indices
                         else np.empty(0, dtype=index_type),
                         np.concatenate(indptr)), shape=(shape[0], cols)))
                return tiles
            except GeodesicError as e:
                if e.code() == grpc.StatusCode.UNIMPLEMENTED:
                    self._packed_rows = False
                    return None
                if not self._learn_matrix_limits(e):
                    raise

    def _matrix_float64(self, mesh: str, ps: List[Any], pt: List[Any],
                        epsilon: Optional[float], pseudo_vertices: bool, exact: bool,
                        max_error: float, out: np.ndarray) -> None:
        """Fills `out` from the float64 answers every server gives, in tiles that fit its
        limits."""
        # Beyond what one tile holds, MatrixRows streams blocks of rows, so neither side holds
        # a whole tile's message; a server without it answers tiles of Matrix.
        if len(ps) * len(pt) * 8 > self._max_message // 2 and \
                self._matrix_rows(mesh, ps, pt, epsilon, pseudo_vertices, exact, out,
                                  max_error):
            return
        row_cap = self.max_sources
        while True:
            cols = max(1, min(self.max_pairs, len(pt)))
            # Half the message size: the repeated doubles plus their framing.
            rows = max(1, min(self.max_sources, row_cap, self._max_message // 2 // (8 * cols)))
            try:
                for r in range(0, len(ps), rows):
                    for c in range(0, len(pt), cols):
                        resp = self._unary("Matrix", pb.MatrixRequest(
                            graph=self._graph(mesh, epsilon, pseudo_vertices, max_error),
                            exact=exact,
                            sources=ps[r:r + rows], targets=pt[c:c + cols]), mesh)
                        out[r:r + resp.rows, c:c + resp.cols] = np.asarray(
                            resp.distances, dtype=np.float64).reshape(resp.rows, resp.cols)
                return
            except ResourceExhaustedError as e:
                # An answer over a server's smaller message cap: fewer rows per tile.
                if _ROW_BLOCKS.search(e.details() or "") and rows > 1:
                    row_cap = rows // 2
                    continue
                # The server's own limits, learnt: tile again with them.
                if not self._learn_matrix_limits(e):
                    raise

    def _matrix_rows(self, mesh: str, ps: List[Any], pt: List[Any], epsilon: Optional[float],
                     pseudo_vertices: bool, exact: bool, out: np.ndarray,
                     max_error: float = 0.0) -> bool:
        """Fills `out` from MatrixRows streams, a request per max_sources x max_pairs tile.
        False (nothing to rely on in `out`) when the server lacks MatrixRows or names smaller
        limits, for the caller to tile with Matrix."""
        cols = max(1, min(self.max_pairs, len(pt)))
        rows = max(1, self.max_sources)
        try:
            for r in range(0, len(ps), rows):
                for c in range(0, len(pt), cols):
                    req = pb.MatrixRequest(graph=self._graph(mesh, epsilon, pseudo_vertices,
                                                             max_error),
                                           exact=exact, sources=ps[r:r + rows],
                                           targets=pt[c:c + cols])

                    def blocks(req: Any = req, r: int = r, c: int = c) -> None:
                        for b in self._stub.MatrixRows(req, timeout=self.timeout,
                                                       metadata=self._meta(mesh)):
                            first = r + b.first_row
                            out[first:first + b.rows, c:c + b.cols] = np.asarray(
                                b.distances, dtype=np.float64).reshape(b.rows, b.cols)

                    self._call("MatrixRows", blocks)
        except GeodesicError as e:
            if e.code() == grpc.StatusCode.UNIMPLEMENTED or (
                    isinstance(e, ResourceExhaustedError)
                    and _MATRIX_LIMITS.search(e.details() or "")):
                return False
            raise
        return True

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


# The wire's dtype for each numpy type a matrix may take.
_DTYPES = {np.float32: pb.MATRIX_DTYPE_FLOAT32, np.float64: pb.MATRIX_DTYPE_FLOAT64}


def _matrix_dtype(dtype: Any, out: Any, whole_mesh: bool) -> np.dtype:
    """The dtype matrix() answers in (see its docstring)."""
    if dtype is not None:
        want = np.dtype(dtype)
    elif isinstance(out, np.ndarray):
        want = out.dtype
    else:
        want = np.dtype(np.float32 if whole_mesh else np.float64)
    if want.type not in _DTYPES:
        raise ValueError(f"dtype {want} is not float32 or float64")
    return want


def _matrix_out(out: Any, shape: Tuple[int, int], dtype: np.dtype) -> np.ndarray:
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


def _packed_block(packed: bytes, wire: np.dtype, rows: int, cols: int) -> np.ndarray:
    """A block of packed rows as a (rows, cols) view of the message's bytes."""
    block = np.frombuffer(packed, dtype=wire)
    if block.size != rows * cols:
        raise ValueError(f"the server sent {block.size} values for a {rows} x {cols} block")
    return block.reshape(rows, cols)


def _threshold(dense: np.ndarray, radius: float, dtype: np.dtype) -> Any:
    """The entries of `dense` within `radius` as a csr_matrix, zeros kept."""
    import scipy.sparse
    rows, cols = np.nonzero(dense <= radius)
    values = dense[rows, cols].astype(dtype)
    index_type = np.int32 if dense.shape[1] < 2**31 else np.int64
    indptr = np.zeros(dense.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=dense.shape[0]), out=indptr[1:])
    return scipy.sparse.csr_matrix((values, cols.astype(index_type), indptr), shape=dense.shape)


def _is_position(value: Any) -> bool:
    """One (x, y, z) position given as a 3-vector of floats (a list of three ints are vertex
    ids)."""
    if isinstance(value, np.ndarray):
        return value.shape == (3,) and np.issubdtype(value.dtype, np.floating)
    return (isinstance(value, list) and len(value) == 3 and
            all(isinstance(x, (float, np.floating)) for x in value))


def to_messages_ids(targets: Any) -> List[int]:
    ids = np.asarray(targets)
    if ids.ndim != 1 or not (np.issubdtype(ids.dtype, np.integer) or ids.size == 0):
        raise ValueError(f"targets: expected 1-D vertex ids, got shape {ids.shape} {ids.dtype}")
    if ids.size and (ids.min() < 0 or ids.max() >= 2**32):
        raise ValueError("targets: vertex ids must lie in [0, 2^32)")
    return ids.astype(np.int64).tolist()


def _path(result: Any) -> Path:
    points = result.path.points
    xyz = np.array([(p.xyz.x, p.xyz.y, p.xyz.z) for p in points],
                   dtype=np.float64).reshape(len(points), 3)
    length = result.path.length if result.reachable else float("inf")
    return Path(length=length, xyz=xyz, points=[format_point(p.point) for p in points])
