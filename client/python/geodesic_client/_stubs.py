"""The generated protobuf and gRPC modules, with a clear message when absent."""
try:
    from ._proto import geodesic_pb2 as pb
    from ._proto import geodesic_pb2_grpc as rpc
except ImportError as e:  # pragma: no cover - depends on how the package was installed
    raise ImportError(
        "geodesic_client's gRPC stubs are missing: install the package "
        "(pip install ./client/python) or build the CMake target geodesic_python_stubs "
        f"({e})") from e

__all__ = ["pb", "rpc"]
