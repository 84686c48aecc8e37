"""The messages of an UploadMesh stream: a header declaring the upload's size and SHA-256,
then the mesh's bytes (a file) or arrays in chunks. Arguments are checked, and a file read
and hashed, before any call."""
import hashlib
import os
from typing import Any, Callable, Iterator, Optional

import numpy as np

from ._stubs import pb

Chunks = Callable[[], Iterator[Any]]


def upload_chunks(name: str, filename: Optional[str], chunk_bytes: int, vertices: Any,
                  faces: Any, repair_non_manifold: bool) -> Chunks:
    """What makes the stream of Client.upload_mesh's arguments, anew for every attempt."""
    if filename is None:
        if vertices is None or faces is None:
            raise ValueError("upload_mesh: give a filename, or both vertices and faces")
        return _array_chunks(name, vertices, faces, chunk_bytes, repair_non_manifold)
    if vertices is not None or faces is not None:
        raise ValueError("upload_mesh: give a filename or arrays, not both")
    return _file_chunks(name, filename, chunk_bytes, repair_non_manifold)


def _file_chunks(name: str, filename: str, chunk_bytes: int,
                 repair_non_manifold: bool) -> Chunks:
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

    def chunks() -> Iterator[Any]:
        # A file changed since it was hashed fails the server's check.
        with open(filename, "rb") as f:
            first = True
            while True:
                data = f.read(chunk_bytes)
                if not data and not first:
                    return
                yield pb.UploadMeshRequest(data=data, **(header if first else {}))
                first = False

    return chunks


def _array_chunks(name: str, vertices: Any, faces: Any, chunk_bytes: int,
                  repair_non_manifold: bool) -> Chunks:
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

    def chunks() -> Iterator[Any]:
        yield pb.UploadMeshRequest(**header)
        for i in range(0, len(flat_v), step_v):
            yield pb.UploadMeshRequest(vertices=flat_v[i:i + step_v].tolist())
        for i in range(0, len(flat_f), step_f):
            yield pb.UploadMeshRequest(faces=flat_f[i:i + step_f].tolist())

    return chunks
