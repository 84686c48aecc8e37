"""Surface points: from numpy arrays, ids and spec strings to protobuf messages."""
from typing import Any, List, NamedTuple, Sequence, Union

import numpy as np

from ._stubs import pb


class FacePoints(NamedTuple):
    """N points inside faces: face ids (N,) and barycentric coordinates (N, 3).

    The coordinates weight each face's vertices in the order the mesh file lists them; they
    must be non-negative and sum to 1 (within 1e-6).
    """

    faces: Any
    barycentrics: Any


class EdgePoints(NamedTuple):
    """N points on edges: edge ids (N,) and t (N,), the point (1 - t) * first + t * second."""

    edges: Any
    t: Any


# What the client accepts wherever a set of N points is expected:
# - integer array or sequence of ints: vertex ids;
# - FacePoints, or a tuple (face_ids (N,), barycentrics (N, 3)): face points;
# - EdgePoints;
# - float array (N, 3): positions, snapped to the nearest surface point by the server;
# - a sequence of specs "v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2", "xyz:X,Y,Z" (may mix with ints).
Points = Union[Sequence[Any], np.ndarray, FacePoints, EdgePoints]
Point = Union[int, str, Sequence[float], np.ndarray]

_MAX_ID = 2**32 - 1


def parse_point(text: str):
    """Parses "v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2" or "xyz:X,Y,Z".

    Returns a SurfacePoint, or a Vec3 for a position that still has to be snapped.
    """
    kind, _, rest = text.partition(":")
    try:
        if kind == "v":
            return pb.SurfacePoint(vertex=_id(int(rest), text))
        if kind == "e":
            edge, _, t = rest.partition(":")
            return pb.SurfacePoint(edge=pb.EdgePoint(edge=_id(int(edge), text), t=float(t)))
        if kind == "f":
            face, _, bary = rest.partition(":")
            b = [float(x) for x in bary.split(",")]
            if len(b) != 3:
                raise ValueError(f"face point {text!r} needs three barycentric coordinates")
            return pb.SurfacePoint(face=pb.FacePoint(face=_id(int(face), text), b0=b[0], b1=b[1],
                                                     b2=b[2]))
        if kind == "xyz":
            x = [float(v) for v in rest.split(",")]
            if len(x) != 3:
                raise ValueError(f"position {text!r} needs three coordinates")
            return pb.Vec3(x=x[0], y=x[1], z=x[2])
    except ValueError as e:
        raise ValueError(f"bad surface point {text!r}: {e}") from None
    raise ValueError(f"bad surface point {text!r}: expected v:, e:, f: or xyz:")


def format_point(p) -> str:
    """The spec string of a SurfacePoint, exact (floats in repr)."""
    which = p.WhichOneof("point")
    if which == "vertex":
        return f"v:{p.vertex}"
    if which == "edge":
        return f"e:{p.edge.edge}:{p.edge.t!r}"
    return f"f:{p.face.face}:{p.face.b0!r},{p.face.b1!r},{p.face.b2!r}"


def _id(value: int, what: Any) -> int:
    if not 0 <= value <= _MAX_ID:
        raise ValueError(f"id {value} of {what!r} is not in [0, 2^32)")
    return value


def _ids(array: Any, name: str) -> np.ndarray:
    a = np.asarray(array)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.integer) or a.size == 0):
        raise ValueError(f"{name}: expected a 1-D integer array, got shape {a.shape} {a.dtype}")
    a = a.astype(np.int64)
    bad = np.flatnonzero((a < 0) | (a > _MAX_ID))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] = {a[bad[0]]} is not an id in [0, 2^32)")
    return a


def _is_face_tuple(points: Any) -> bool:
    if not isinstance(points, tuple) or len(points) != 2:
        return False
    faces, bary = np.asarray(points[0]), np.asarray(points[1])
    return (faces.ndim == 1 and np.issubdtype(faces.dtype, np.integer) and bary.ndim == 2
            and bary.shape[1:] == (3,))


def to_messages(points: Points) -> List[Any]:
    """Converts a point set to a list of SurfacePoint (or Vec3 for positions to snap)."""
    if isinstance(points, FacePoints) or _is_face_tuple(points):
        faces = _ids(points[0], "face ids")
        bary = np.asarray(points[1], dtype=np.float64)
        if bary.shape != (len(faces), 3):
            raise ValueError(f"barycentrics: expected shape ({len(faces)}, 3), got {bary.shape}")
        return [pb.SurfacePoint(face=pb.FacePoint(face=f, b0=b[0], b1=b[1], b2=b[2]))
                for f, b in zip(faces.tolist(), bary.tolist())]
    if isinstance(points, EdgePoints):
        edges = _ids(points.edges, "edge ids")
        t = np.asarray(points.t, dtype=np.float64)
        if t.shape != edges.shape:
            raise ValueError(f"edge t: expected shape {edges.shape}, got {t.shape}")
        return [pb.SurfacePoint(edge=pb.EdgePoint(edge=e, t=x))
                for e, x in zip(edges.tolist(), t.tolist())]
    if isinstance(points, (str, bytes, int, np.integer)):
        raise ValueError(f"expected a set of points, got the single point {points!r}: "
                         "wrap it in a list")
    if isinstance(points, np.ndarray):
        if points.ndim == 1 and (np.issubdtype(points.dtype, np.integer) or points.size == 0):
            return [pb.SurfacePoint(vertex=v) for v in _ids(points, "vertex ids").tolist()]
        if points.ndim == 2 and points.shape[1] == 3 and np.issubdtype(points.dtype, np.number):
            return [pb.Vec3(x=x, y=y, z=z) for x, y, z in points.astype(np.float64).tolist()]
        raise ValueError(f"points: expected vertex ids (N,) or positions (N, 3), got an array of "
                         f"shape {points.shape} and dtype {points.dtype}")
    return [to_message(p, f"point {i}") for i, p in enumerate(points)]


def to_message(point: Point, what: str = "point") -> Any:
    """One point: a vertex id, a spec string, a position (x, y, z) or a protobuf message."""
    if isinstance(point, (pb.SurfacePoint, pb.Vec3)):
        return point
    if isinstance(point, str):
        return parse_point(point)
    if isinstance(point, (int, np.integer)) and not isinstance(point, bool):
        return pb.SurfacePoint(vertex=_id(int(point), what))
    a = np.asarray(point)
    if a.shape == (3,) and np.issubdtype(a.dtype, np.number):
        x, y, z = a.astype(np.float64).tolist()
        return pb.Vec3(x=x, y=y, z=z)
    raise ValueError(f"{what}: {point!r} is not a vertex id, a spec string or a position (x, y, z)")


def is_position(value: Any) -> bool:
    """One (x, y, z) position given as a 3-vector of floats (a list of three ints are vertex
    ids)."""
    if isinstance(value, np.ndarray):
        return value.shape == (3,) and np.issubdtype(value.dtype, np.floating)
    return (isinstance(value, list) and len(value) == 3 and
            all(isinstance(x, (float, np.floating)) for x in value))


def to_messages_ids(targets: Any) -> List[int]:
    """Target vertex ids as a list of ints, checked."""
    ids = np.asarray(targets)
    if ids.ndim != 1 or not (np.issubdtype(ids.dtype, np.integer) or ids.size == 0):
        raise ValueError(f"targets: expected 1-D vertex ids, got shape {ids.shape} {ids.dtype}")
    if ids.size and (ids.min() < 0 or ids.max() >= 2**32):
        raise ValueError("targets: vertex ids must lie in [0, 2^32)")
    return ids.astype(np.int64).tolist()
