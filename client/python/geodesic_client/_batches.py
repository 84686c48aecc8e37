"""Point sets cut into calls within the server's limits: positions snapped max_pairs at a
time, fields max_sources sources at a time (combined by their minimum), distances max_pairs
pairs at a time (fewer with paths), each batch shrunk when the server refuses it."""
from typing import Any, List, Optional, Tuple

import numpy as np

from ._errors import GeodesicError
from ._limits import MAX_PAIRS, MAX_SOURCES, Limits
from ._points import Points, format_point, to_messages
from ._stubs import pb
from ._transport import Transport
from ._types import Path


class Batches:
    """The batched calls of one client, over its transport and with its limits."""

    def __init__(self, transport: Transport, limits: Limits):
        self.transport = transport
        self.limits = limits

    def resolve(self, mesh: str, points: Points) -> List[Any]:
        """SurfacePoints for a point set, positions snapped in batches."""
        messages = to_messages(points)
        at = [i for i, m in enumerate(messages) if isinstance(m, pb.Vec3)]
        start = 0
        while start < len(at):
            chunk = at[start:start + self.limits.max_pairs]
            try:
                snapped = self.transport.unary("Snap", pb.SnapRequest(
                    mesh=mesh, positions=[messages[i] for i in chunk]), mesh)
            except GeodesicError as e:
                if self.limits.learn(e, MAX_PAIRS, len(chunk)):
                    continue
                raise
            for i, p in zip(chunk, snapped.points):
                messages[i] = p
            start += len(chunk)
        return messages

    def field(self, graph: Any, points: List[Any], target_ids: List[int],
              max_distance: float, method: str,
              nearest_source: bool) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        """(values, labels or None) of the field of `points` (SurfacePoints), computed
        max_sources sources at a time and combined by their minimum."""
        values, labels = None, None
        start = 0
        while start < len(points):
            batch = points[start:start + self.limits.max_sources]
            req = pb.DistanceFieldRequest(
                graph=graph, max_distance=max_distance, sources=batch, targets=target_ids,
                method=method, nearest_source=nearest_source)
            try:
                part, part_labels = self.transport.call(
                    "DistanceField", lambda: self._field_stream(req))
            except GeodesicError as e:
                if self.limits.learn(e, MAX_SOURCES, len(batch)):
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
        return values, labels

    def _field_stream(self, req: Any) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        values, labels = np.empty(0), None
        # Routed by the graph's mesh: the request's own mesh field is the one it superseded.
        for chunk in self.transport.start("DistanceField", req, req.graph.mesh):
            if chunk.offset == 0 and len(values) != chunk.total:
                values = np.empty(chunk.total, dtype=np.float64)
                labels = np.empty(chunk.total, dtype=np.uint32) if req.nearest_source else None
            end = chunk.offset + len(chunk.values)
            values[chunk.offset:end] = chunk.values
            if req.nearest_source:
                labels[chunk.offset:end] = chunk.nearest_source
        return values, labels

    def distances(self, graph: Any, pa: List[Any], pb_: List[Any], with_path: bool,
                  exact: bool) -> Tuple[np.ndarray, List[Path]]:
        """Distances (and with_path, paths) between pa[i] and pb_[i] (SurfacePoints)."""
        out = np.empty(len(pa), dtype=np.float64)
        paths: List[Path] = []
        i = 0
        # Shrinks with every "too large" answer, so a retry never repeats a
        # batch the server (or the channel) refused.
        limits = self.limits
        batch = min(limits.max_pairs, limits.path_batch) if with_path else limits.max_pairs
        while i < len(pa):
            j = min(len(pa), i + batch)
            req = pb.DistanceRequest(graph=graph, with_path=with_path, exact=exact,
                                     pairs=[pb.PointPair(**{"from": pa[k], "to": pb_[k]})
                                            for k in range(i, j)])
            try:
                resp = self.transport.unary("Distance", req, graph.mesh)
            except GeodesicError as e:
                smaller = limits.smaller_pair_batch(e, j - i, with_path)
                if smaller is None:
                    raise
                batch = smaller
                continue
            out[i:j] = [r.distance for r in resp.results]
            if with_path:
                paths.extend(path_of(r) for r in resp.results)
            i = j
        return out, paths


def path_of(result: Any) -> Path:
    """The Path of one of Distance's results."""
    points = result.path.points
    xyz = np.array([(p.xyz.x, p.xyz.y, p.xyz.z) for p in points],
                   dtype=np.float64).reshape(len(points), 3)
    length = result.path.length if result.reachable else float("inf")
    return Path(length=length, xyz=xyz, points=[format_point(p.point) for p in points])
