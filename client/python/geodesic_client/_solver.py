"""MeshSolver: one mesh's graph as an object that answers queries."""
from typing import Any, Callable, List, Literal, Optional, Protocol, Tuple, Union, overload

import numpy as np

from ._points import Point, Points
from ._types import Graph, Mesh, Path


class Queries(Protocol):
    """What a MeshSolver asks of its client (a Client): the client's methods of the same
    names, whose arguments it fills in."""

    def mesh(self, name: str) -> Mesh: ...

    def request_graph(self, mesh: str, epsilon: Optional[float] = ..., wait: bool = ...,
                      pseudo_vertices: bool = ...,
                      progress: Optional[Callable[[Graph], None]] = ...,
                      max_error: float = ...) -> Graph: ...

    def graph(self, mesh: str, epsilon: Optional[float] = ..., pseudo_vertices: bool = ...,
              max_error: float = ...) -> Graph: ...

    def cancel_graph(self, mesh: str, epsilon: Optional[float] = ...,
                     pseudo_vertices: bool = ..., max_error: float = ...) -> Graph: ...

    def field(self, mesh: str, sources: Union[Points, Point], epsilon: Optional[float] = ...,
              max_distance: float = ..., targets: Optional[Any] = ..., method: str = ...,
              nearest_source: bool = ..., pseudo_vertices: bool = ...,
              max_error: float = ...) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]: ...

    def distances(self, mesh: str, a: Points, b: Points, epsilon: Optional[float] = ...,
                  with_path: bool = ..., pseudo_vertices: bool = ..., exact: bool = ...,
                  max_error: float = ...) -> Union[np.ndarray, Tuple[np.ndarray, List[Path]]]: ...

    def distance(self, mesh: str, a: Point, b: Point, epsilon: Optional[float] = ...,
                 pseudo_vertices: bool = ..., exact: bool = ...,
                 max_error: float = ...) -> float: ...

    def path(self, mesh: str, a: Point, b: Point, epsilon: Optional[float] = ...,
             pseudo_vertices: bool = ..., exact: bool = ..., max_error: float = ...) -> Path: ...

    def matrix(self, mesh: str, sources: Optional[Points] = ...,
               targets: Optional[Points] = ..., epsilon: Optional[float] = ...,
               pseudo_vertices: bool = ..., exact: bool = ..., max_error: float = ..., *,
               dtype: Any = ..., out: Any = ...) -> np.ndarray: ...

    def neighbourhood_matrix(self, mesh: str, radius: float, sources: Optional[Points] = ...,
                             targets: Optional[Points] = ..., dtype: Any = ...,
                             epsilon: Optional[float] = ..., pseudo_vertices: bool = ...,
                             exact: bool = ..., max_error: float = ...) -> Any: ...

    def sample_points(self, mesh: str, count: int, seed: int = ...,
                      epsilon: Optional[float] = ..., pseudo_vertices: bool = ...,
                      max_error: float = ...) -> Tuple[np.ndarray, float]: ...

    def snap(self, mesh: str, positions: Any) -> List[str]: ...


class MeshSolver:
    """One mesh's graph at one epsilon, queried without repeating them.

        solver = client.mesh_solver("spot", epsilon=1e-3)
        solver.request_graph(progress=lambda g: print(f"{g.phase} {g.progress:.0%}"))
        d = solver.distances(np.arange(10), np.arange(10, 20))

    Each method calls the Client method of the same name with this solver's mesh, epsilon
    and pseudo_vertices, and returns what it returns; the graph lives on the server, so
    solvers are cheap and share the client's connection, limits and retries.
    """

    def __init__(self, client: Queries, name: str, epsilon: float,
                 pseudo_vertices: bool = False, max_error: float = 0.0):
        """Prefer Client.mesh_solver. epsilon: 0 means the server's --default-epsilon.
        max_error: the certified graph of that bound instead (its epsilon the server's)."""
        self.client = client
        self.name = name
        self.epsilon = epsilon
        self.pseudo_vertices = pseudo_vertices
        self.max_error = max_error
        self._mesh: Optional[Mesh] = None

    def __repr__(self) -> str:
        return (f"MeshSolver({self.name!r}, epsilon={self.epsilon!r}, "
                f"pseudo_vertices={self.pseudo_vertices!r}"
                + (f", max_error={self.max_error!r})" if self.max_error else ")"))

    @property
    def mesh(self) -> Mesh:
        """The mesh and its diagnostics, fetched from the server on first use."""
        if self._mesh is None:
            self._mesh = self.client.mesh(self.name)
        return self._mesh

    # -- the graph ------------------------------------------------------------

    def request_graph(self, wait: bool = True,
                      progress: Optional[Callable[[Graph], None]] = None) -> Graph:
        """Makes the graph available; see Client.request_graph for wait and progress."""
        return self.client.request_graph(self.name, self.epsilon, wait=wait,
                                         pseudo_vertices=self.pseudo_vertices, progress=progress,
                                         max_error=self.max_error)

    def graph(self) -> Graph:
        """The graph's current state."""
        return self.client.graph(self.name, self.epsilon, pseudo_vertices=self.pseudo_vertices,
                                 max_error=self.max_error)

    def cancel_graph(self) -> Graph:
        """Cancels the graph's build."""
        return self.client.cancel_graph(self.name, self.epsilon,
                                        pseudo_vertices=self.pseudo_vertices,
                                        max_error=self.max_error)

    # -- queries --------------------------------------------------------------
    # Options after the points are keyword-only, so that the overloads can
    # tell a type checker the shape of what comes back.

    @overload
    def field(self, sources: Union[Points, Point], *, max_distance: float = ...,
              targets: Optional[Any] = ..., method: str = ...,
              nearest_source: Literal[False] = ...) -> np.ndarray: ...

    @overload
    def field(self, sources: Union[Points, Point], *, max_distance: float = ...,
              targets: Optional[Any] = ..., method: str = ...,
              nearest_source: Literal[True]) -> Tuple[np.ndarray, np.ndarray]: ...

    @overload
    def field(self, sources: Union[Points, Point], *, max_distance: float = ...,
              targets: Optional[Any] = ..., method: str = ...,
              nearest_source: bool = ...) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]: ...

    def field(self, sources: Union[Points, Point], *, max_distance: float = 0.0,
              targets: Optional[Any] = None, method: str = "lc",
              nearest_source: bool = False) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]:
        """Distances from the nearest source, per vertex or per target; see Client.field."""
        return self.client.field(self.name, sources, self.epsilon, max_distance=max_distance,
                                 targets=targets, method=method, nearest_source=nearest_source,
                                 pseudo_vertices=self.pseudo_vertices,
                                 max_error=self.max_error)

    @overload
    def distances(self, a: Points, b: Points, *,
                  with_path: Literal[False] = ..., exact: bool = ...) -> np.ndarray: ...

    @overload
    def distances(self, a: Points, b: Points, *,
                  with_path: Literal[True], exact: bool = ...
                  ) -> Tuple[np.ndarray, List[Path]]: ...

    @overload
    def distances(self, a: Points, b: Points, *, with_path: bool = ..., exact: bool = ...
                  ) -> Union[np.ndarray, Tuple[np.ndarray, List[Path]]]: ...

    def distances(self, a: Points, b: Points, *, with_path: bool = False, exact: bool = False
                  ) -> Union[np.ndarray, Tuple[np.ndarray, List[Path]]]:
        """Distances between a[i] and b[i] (and their paths); see Client.distances."""
        return self.client.distances(self.name, a, b, self.epsilon, with_path=with_path,
                                     pseudo_vertices=self.pseudo_vertices, exact=exact,
                                     max_error=self.max_error)

    def distance(self, a: Point, b: Point, *, exact: bool = False) -> float:
        """The distance between two surface points (+inf if unreachable)."""
        return self.client.distance(self.name, a, b, self.epsilon,
                                    pseudo_vertices=self.pseudo_vertices, exact=exact,
                                    max_error=self.max_error)

    def path(self, a: Point, b: Point, *, exact: bool = False) -> Path:
        """The geodesic path from a to b (unpacks as ``length, xyz = path``)."""
        return self.client.path(self.name, a, b, self.epsilon,
                                pseudo_vertices=self.pseudo_vertices, exact=exact,
                                max_error=self.max_error)

    def matrix(self, sources: Optional[Points] = None, targets: Optional[Points] = None, *,
               exact: bool = False, dtype: Any = None, out: Any = None) -> np.ndarray:
        """(len(sources), len(targets)) array of distances, None meaning every vertex; dtype
        and out as Client.matrix."""
        return self.client.matrix(self.name, sources, targets, self.epsilon,
                                  pseudo_vertices=self.pseudo_vertices, exact=exact,
                                  max_error=self.max_error, dtype=dtype, out=out)

    def neighbourhood_matrix(self, radius: float, sources: Optional[Points] = None,
                             targets: Optional[Points] = None, dtype: Any = np.float32, *,
                             exact: bool = False) -> Any:
        """The distances within radius as a scipy.sparse.csr_matrix; see
        Client.neighbourhood_matrix."""
        return self.client.neighbourhood_matrix(self.name, radius, sources, targets, dtype,
                                                self.epsilon,
                                                pseudo_vertices=self.pseudo_vertices,
                                                exact=exact, max_error=self.max_error)

    def sample_points(self, count: int, seed: int = 0) -> Tuple[np.ndarray, float]:
        """Farthest-point sampling: (vertex ids, covering radius); see Client.sample_points."""
        return self.client.sample_points(self.name, count, seed=seed, epsilon=self.epsilon,
                                         pseudo_vertices=self.pseudo_vertices,
                                         max_error=self.max_error)

    def snap(self, positions: Any) -> List[str]:
        """Nearest surface points to (N, 3) positions, as spec strings (no graph needed)."""
        return self.client.snap(self.name, positions)
