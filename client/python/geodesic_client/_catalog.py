"""The meshes and graphs a server holds: Client's methods that register, upload, unload and
describe meshes, and request, watch and cancel their graphs."""
from typing import Any, Callable, List, Optional, Tuple

import numpy as np

from ._stubs import pb
from ._transport import Transport
from ._types import Graph, GraphState, Mesh
from ._upload import upload_chunks


class Catalog:
    """The part of Client that manages what the server holds (see Client)."""

    # What Client.__init__ sets.
    _transport: Transport
    epsilon: float

    # -- plumbing -------------------------------------------------------------

    def _eps(self, epsilon: Optional[float]) -> float:
        return self.epsilon if epsilon is None else epsilon

    def _graph(self, mesh: str, epsilon: Optional[float], pseudo_vertices: bool,
               max_error: float = 0.0) -> Any:
        """The GraphSelector every request that names a graph carries in its `graph` (the
        requests' own mesh, epsilon and pseudo_vertices fields are what it superseded).
        max_error: a certified graph (its epsilon the server's choice), 0 for a plain one."""
        return pb.GraphSelector(mesh=mesh, epsilon=self._eps(epsilon),
                                pseudo_vertices=pseudo_vertices, max_error=max_error)

    def _unary(self, name: str, request: Any, mesh: Optional[str]) -> Any:
        return self._transport.unary(name, request, mesh)

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
        chunks = upload_chunks(name, filename, chunk_bytes, vertices, faces,
                               repair_non_manifold)
        return Mesh._from_proto(self._transport.call(
            "UploadMesh", lambda: self._transport.start("UploadMesh", chunks(), name)))

    def geometry(self, name: str) -> Tuple[np.ndarray, np.ndarray]:
        """A registered mesh's (vertices (N, 3) float64, faces (M, 3) uint32), in file order:
        the arrays an upload of arrays gave, and what face ids and barycentrics refer to."""
        def fetch() -> Tuple[np.ndarray, np.ndarray]:
            vertices: List[float] = []
            faces: List[int] = []
            for chunk in self._transport.start("GetGeometry", pb.GetMeshRequest(name=name), name):
                vertices.extend(chunk.vertices)
                faces.extend(chunk.faces)
            return (np.array(vertices, dtype=np.float64).reshape(-1, 3),
                    np.array(faces, dtype=np.uint32).reshape(-1, 3))
        return self._transport.call("GetGeometry", fetch)

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
            watch = pb.GetGraphRequest(graph=self._graph(mesh, g.epsilon, pseudo_vertices,
                                                         max_error))
            g = self._transport.call("WatchGraph", lambda: self._last(self._transport.start(
                "WatchGraph", watch, mesh, deadline=False), g, progress))
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
