"""Python client for geodesicd: geodesic distances and paths on triangle meshes.

    import numpy as np
    from geodesic_client import Client, FacePoints

    c = Client(epsilon=1e-3)             # $GEODESIC_SERVER, else 127.0.0.1:50051
    c.request_graph("spot")                                   # waits until the graph is ready
    d = c.distances("spot", np.arange(100), FacePoints(faces, barycentrics))   # ndarray (100,)
    field = c.field("spot", [0])                              # ndarray, +inf where unreachable
    length, xyz = c.path("spot", 1, np.array([0.1, 0.2, 0.3]))    # xyz: (K, 3)

    spot = c.mesh_solver("spot")         # the same queries without mesh and epsilon
    spot.mesh.diagnostics.genus          # Mesh and MeshDiagnostics are frozen dataclasses
    d = spot.distances(np.arange(100), np.arange(100, 200))

Points are integer vertex ids, FacePoints(face_ids, barycentrics (N, 3)), (N, 3)
positions (snapped to the surface by the server) or spec strings "v:ID",
"e:EDGE:T", "f:FACE:B0,B1,B2", "xyz:X,Y,Z". Barycentrics weight a face's
vertices in the order the mesh file lists them. Errors raise GeodesicError
subclasses (grpc.RpcError with the server's status code and message).
"""
from ._errors import (AlreadyExistsError, DeadlineExceededError, FailedPreconditionError,
                      GeodesicError, InvalidArgumentError, NotFoundError, OutOfRangeError,
                      PermissionDeniedError, ResourceExhaustedError, UnauthenticatedError,
                      UnavailableError)
from ._client import Client
from ._points import EdgePoints, FacePoints, Point, Points, format_point, parse_point
from ._solver import MeshSolver
from ._types import (Graph, GraphCertificate, GraphState, Mesh, MeshDiagnostics, Path,
                     RetryPolicy, VertexCopy)
from ._version import __version__

__all__ = [
    "AlreadyExistsError", "Client", "DeadlineExceededError", "EdgePoints", "FacePoints",
    "FailedPreconditionError", "GeodesicError", "Graph", "GraphCertificate", "GraphState",
    "InvalidArgumentError", "Mesh", "MeshDiagnostics", "MeshSolver", "NotFoundError",
    "OutOfRangeError", "Path", "PermissionDeniedError", "Point", "Points",
    "ResourceExhaustedError", "RetryPolicy", "UnauthenticatedError", "UnavailableError",
    "VertexCopy", "__version__", "format_point", "parse_point",
]
