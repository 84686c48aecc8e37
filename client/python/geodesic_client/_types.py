"""Value types returned by the client."""
import enum
from dataclasses import dataclass, field
from typing import Iterator, List, Tuple

import numpy as np

from ._stubs import pb


class GraphState(enum.Enum):
    """Lifecycle of a graph on the server (geodesic.v1.GraphState)."""

    UNSPECIFIED = pb.GRAPH_STATE_UNSPECIFIED
    QUEUED = pb.GRAPH_STATE_QUEUED
    BUILDING = pb.GRAPH_STATE_BUILDING
    LOADING = pb.GRAPH_STATE_LOADING
    READY = pb.GRAPH_STATE_READY
    FAILED = pb.GRAPH_STATE_FAILED
    CANCELLED = pb.GRAPH_STATE_CANCELLED
    EVICTED = pb.GRAPH_STATE_EVICTED

    @classmethod
    def _from_proto(cls, value: int) -> "GraphState":
        try:
            return cls(value)
        except ValueError:  # a state added to the server after this client
            return cls.UNSPECIFIED

    @property
    def done(self) -> bool:
        """True for the states a graph stays in until asked again."""
        return self in (GraphState.READY, GraphState.FAILED, GraphState.CANCELLED,
                        GraphState.EVICTED)


@dataclass(frozen=True)
class Graph:
    """A graph for (mesh, epsilon) and the state of the operation that makes it."""

    mesh: str
    epsilon: float
    state: GraphState
    phase: str = ""
    progress: float = 0.0
    error: str = ""
    bytes: int = 0
    nodes: int = 0
    edges: int = 0
    build_seconds: float = 0.0
    mapped: bool = False
    from_file: bool = False
    # The graph with pseudo vertices (anisotropic meshes) rather than the
    # plain one of this epsilon: the two are separate graphs on the server.
    pseudo_vertices: bool = False

    @classmethod
    def _from_proto(cls, g) -> "Graph":
        return cls(mesh=g.mesh, epsilon=g.epsilon, state=GraphState._from_proto(g.state),
                   phase=g.phase, progress=g.progress, error=g.error, bytes=g.bytes,
                   nodes=g.nodes, edges=g.edges, build_seconds=g.build_seconds, mapped=g.mapped,
                   from_file=g.from_file, pseudo_vertices=g.pseudo_vertices)


@dataclass(frozen=True)
class Path:
    """A geodesic path; unpacks as ``length, xyz = path``.

    length: its length (+inf if the points are not connected).
    xyz: (K, 3) float64 array of the path's corners, first point to last (K = 0 if unreachable).
    points: the corners as surface point specs ("v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2").
    """

    length: float
    xyz: np.ndarray
    points: List[str] = field(default_factory=list)

    def __iter__(self) -> Iterator:
        return iter((self.length, self.xyz))


@dataclass(frozen=True)
class RetryPolicy:
    """Retries of calls failing with a transient status, with jittered exponential backoff.

    The n-th retry waits a random time in [d/2, d], d = min(initial_backoff * multiplier**(n-1),
    max_backoff). max_attempts counts the first call; 1 disables retries. UNAVAILABLE is what
    the server answers while a graph is still building or loading, and what gRPC reports
    while the server cannot be reached.
    """

    max_attempts: int = 8
    initial_backoff: float = 0.1
    multiplier: float = 2.0
    max_backoff: float = 2.0
    codes: Tuple[str, ...] = ("UNAVAILABLE",)

    def delays(self) -> Iterator[float]:
        d = self.initial_backoff
        for _ in range(self.max_attempts - 1):
            yield d
            d = min(d * self.multiplier, self.max_backoff)
