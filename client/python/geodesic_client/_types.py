"""Value types returned by the client."""
import enum
import json
import re
from dataclasses import dataclass, field
from typing import Any, Dict, Iterator, List, Optional, Tuple

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
class GraphCertificate:
    """What the server measured of a certified graph (geodesic.v1.GraphCertificate): relative
    errors, (graph - exact) / exact, at every vertex from `sources` random vertex sources
    (seeded by `seed`). A certified graph is published only when its measured maximum keeps
    its bound with a margin; `builds` counts the builds it took."""

    max_error_bound: float
    epsilon: float
    measured_max_error: float
    measured_mean_error: float
    sources: int
    seed: int
    sound: bool
    builds: int

    @classmethod
    def _from_proto(cls, c) -> "GraphCertificate":
        return cls(max_error_bound=c.max_error_bound, epsilon=c.epsilon,
                   measured_max_error=c.measured_max_error,
                   measured_mean_error=c.measured_mean_error, sources=c.sources, seed=c.seed,
                   sound=c.sound, builds=c.builds)


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
    # Resident bytes of the landmark distances that speed up point-to-point
    # queries (0 until the server has computed them after the build).
    landmark_bytes: int = 0
    last_used_unix_ms: int = 0
    # The rest of the build record, as the server reports it.
    prune_redundant: bool = False
    exact_fans: bool = False
    candidate_rule: int = 0
    # A certified graph's bound (request_graph(..., max_error=...)); 0 for a
    # plain graph. Its epsilon is the one the server chose.
    max_error: float = 0.0
    # What the server measured of a certified graph once it is ready; None
    # for a plain graph and while a certified one is made.
    certificate: Optional[GraphCertificate] = None

    @classmethod
    def _from_proto(cls, g) -> "Graph":
        return cls(mesh=g.mesh, epsilon=g.epsilon, state=GraphState._from_proto(g.state),
                   phase=g.phase, progress=g.progress, error=g.error, bytes=g.bytes,
                   nodes=g.nodes, edges=g.edges, build_seconds=g.build_seconds, mapped=g.mapped,
                   from_file=g.from_file, pseudo_vertices=g.pseudo_vertices,
                   landmark_bytes=g.landmark_bytes, last_used_unix_ms=g.last_used_unix_ms,
                   prune_redundant=g.prune_redundant, exact_fans=g.exact_fans,
                   candidate_rule=g.candidate_rule, max_error=g.max_error,
                   certificate=(GraphCertificate._from_proto(g.certificate)
                                if g.HasField("certificate") else None))


# The keys of the server's full report (`geodesicd info --json` but
# mesh_bytes), in its order: each a field of the MeshDiagnostics message but
# "usable", which is mesh_error being empty.
_DETAIL_KEYS = (
    "path", "format", "vertices", "faces", "edges", "polygons_triangulated", "components",
    "boundary_loops", "genus", "isolated_vertices", "duplicate_vertices", "zero_area_faces",
    "near_degenerate_faces", "non_manifold_edges", "non_manifold_vertices", "faces_refused",
    "bbox_diagonal", "mean_edge_length", "min_edge_length", "anisotropy_mean", "anisotropy_p95",
    "anisotropy_max", "saddle_vertices", "boundary_vertices", "manifold", "usable", "mesh_error",
    "load_seconds")

# A server older than the typed fields printed the report's doubles with
# %.17g, which spells a non-finite one "inf" or "nan": not JSON, so such words
# are renamed to the spellings Python's json module reads rather than losing
# the whole report.
_NON_FINITE = re.compile(r"(?<=[:,\[\s])(-?)(inf|nan)(?=[,}\]\s])")


def _parse_diagnostics_json(text: str) -> Dict[str, Any]:
    if not text:
        return {}
    try:
        return json.loads(text)
    except ValueError:
        fixed = _NON_FINITE.sub(lambda m: "NaN" if m.group(2) == "nan"
                                else m.group(1) + "Infinity", text)
        return json.loads(fixed)


def _diagnostics_details(d) -> Dict[str, Any]:
    """The full report from the message's typed fields (from its superseded json field when
    the server is older than them: such a server sets no format)."""
    if not d.format and d.json:
        return _parse_diagnostics_json(d.json)
    details = {}
    for key in _DETAIL_KEYS:
        details[key] = not d.mesh_error if key == "usable" else getattr(d, key)
    # The report gives the load time to the microsecond, rounded as the
    # server's ToJson rounds it.
    details["load_seconds"] = round(d.load_seconds * 1e6) / 1e6
    return details


@dataclass(frozen=True)
class MeshDiagnostics:
    """What the server found when it read a mesh (geodesicd info reports the same).

    Counts are of the mesh as registered (after any repair). genus is meaningful only for a
    manifold mesh; bbox_diagonal is the length of the bounding box's diagonal;
    anisotropy_mean is the mean over faces of longest edge / (2 sqrt(3) inradius), 1 for
    equilateral triangles.
    details: every key of the server's full report (`geodesicd info --json`), such as
    "zero_area_faces", "non_manifold_edges", "anisotropy_max", "manifold", "mesh_error",
    from the message's typed fields;
    json: that report as JSON text, as the server sent it (superseded by details).
    """

    vertices: int
    faces: int
    edges: int
    components: int
    boundary_loops: int
    genus: int
    isolated_vertices: int
    non_manifold_vertices: int
    bbox_diagonal: float
    anisotropy_mean: float
    # Excluded from the hash: a dict has none, and the other fields already
    # tell two meshes' diagnostics apart.
    details: Dict[str, Any] = field(default_factory=dict, hash=False, repr=False)
    json: str = field(default="", repr=False)

    @classmethod
    def _from_proto(cls, d) -> "MeshDiagnostics":
        return cls(vertices=d.vertices, faces=d.faces, edges=d.edges, components=d.components,
                   boundary_loops=d.boundary_loops, genus=d.genus,
                   isolated_vertices=d.isolated_vertices,
                   non_manifold_vertices=d.non_manifold_vertices, bbox_diagonal=d.bbox_diagonal,
                   anisotropy_mean=d.anisotropy_mean,
                   details=_diagnostics_details(d), json=d.json)


@dataclass(frozen=True)
class VertexCopy:
    """A vertex added by repair_non_manifold: copy takes over one fan of original."""

    original: int
    copy: int


@dataclass(frozen=True)
class Mesh:
    """A mesh registered on the server.

    fingerprint: hex xxHash64 of its positions and faces (graphs are keyed by it).
    source: the server-side path it was read from, or "upload".
    restored: read back from the server's snapshot of the same file bytes (usual after a
    restart) rather than parsed again.
    repair_non_manifold: registered with that option; vertex_copies then lists the vertices
    it added, one per extra fan of a non-manifold vertex, numbered after the file's vertices.
    parent: for a region (Client.register_region), the mesh it was cut from ("" otherwise),
    and that mesh's vertex and face counts. A region's vertices are the parent's that its
    faces use, in the parent's order; its faces keep the parent's order.
    """

    name: str
    fingerprint: str
    source: str
    restored: bool
    repair_non_manifold: bool
    vertex_copies: Tuple[VertexCopy, ...]
    diagnostics: MeshDiagnostics
    parent: str = ""
    parent_vertices: int = 0
    parent_faces: int = 0

    @classmethod
    def _from_proto(cls, m) -> "Mesh":
        return cls(name=m.name, fingerprint=m.fingerprint, source=m.source, restored=m.restored,
                   repair_non_manifold=m.repair_non_manifold,
                   vertex_copies=tuple(VertexCopy(c.original, c.copy) for c in m.vertex_copies),
                   diagnostics=MeshDiagnostics._from_proto(m.diagnostics), parent=m.parent,
                   parent_vertices=m.parent_vertices, parent_faces=m.parent_faces)


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
    while the server cannot be reached. With `overload`, RESOURCE_EXHAUSTED answers that say
    the server is overloaded (those carrying its retry-after-ms hint; never a limit the request
    itself passes) are retried too, waiting at least the hint.
    """

    max_attempts: int = 8
    initial_backoff: float = 0.1
    multiplier: float = 2.0
    max_backoff: float = 2.0
    codes: Tuple[str, ...] = ("UNAVAILABLE",)
    overload: bool = True

    def delays(self) -> Iterator[float]:
        d = self.initial_backoff
        for _ in range(self.max_attempts - 1):
            yield d
            d = min(d * self.multiplier, self.max_backoff)
