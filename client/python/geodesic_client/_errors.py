"""Server errors as exceptions, one class per gRPC status code.

Every class derives from grpc.RpcError and keeps its code() and details(), so
code written against plain grpc errors keeps working.
"""
from typing import Dict, Optional, Tuple, Type

import grpc


class GeodesicError(grpc.RpcError):
    """A failed call: code() is the grpc.StatusCode, details() the server's message."""

    # The call's trailing metadata, (key, value) pairs: what a refusal says beyond its
    # prose (the limit it passed, a retry hint), read by the client's own modules.
    _trailers: Tuple[Tuple[str, str], ...] = ()

    def __init__(self, code: grpc.StatusCode, details: str, method: str = ""):
        super().__init__(f"{code.name}: {details}" + (f" ({method})" if method else ""))
        self._code = code
        self._details = details
        self.method = method

    def code(self) -> grpc.StatusCode:
        return self._code

    def details(self) -> str:
        return self._details


class NotFoundError(GeodesicError):
    """Unknown mesh or graph."""


class UnavailableError(GeodesicError):
    """Graph still building or loading, or the server unreachable: retry later."""


class FailedPreconditionError(GeodesicError):
    """No graph was requested for this mesh and epsilon."""


class InvalidArgumentError(GeodesicError):
    """Bad coordinates or parameters."""


class OutOfRangeError(GeodesicError):
    """A vertex, edge or face id beyond the mesh."""


class ResourceExhaustedError(GeodesicError):
    """A request over a server limit, or the server overloaded."""


class PermissionDeniedError(GeodesicError):
    """A path outside the server's --mesh-root."""


class UnauthenticatedError(GeodesicError):
    """Missing or wrong bearer token."""


class AlreadyExistsError(GeodesicError):
    """A mesh name already registered with another content."""


class DeadlineExceededError(GeodesicError):
    """The call took longer than the client's timeout."""


_BY_CODE: Dict[grpc.StatusCode, Type[GeodesicError]] = {
    grpc.StatusCode.NOT_FOUND: NotFoundError,
    grpc.StatusCode.UNAVAILABLE: UnavailableError,
    grpc.StatusCode.FAILED_PRECONDITION: FailedPreconditionError,
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgumentError,
    grpc.StatusCode.OUT_OF_RANGE: OutOfRangeError,
    grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhaustedError,
    grpc.StatusCode.PERMISSION_DENIED: PermissionDeniedError,
    grpc.StatusCode.UNAUTHENTICATED: UnauthenticatedError,
    grpc.StatusCode.ALREADY_EXISTS: AlreadyExistsError,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceededError,
}


def from_rpc_error(e: grpc.RpcError, method: str = "") -> GeodesicError:
    if isinstance(e, GeodesicError):
        return e
    code: Optional[grpc.StatusCode] = e.code() if hasattr(e, "code") else None
    code = code or grpc.StatusCode.UNKNOWN
    details = (e.details() if hasattr(e, "details") else None) or str(e)
    error = _BY_CODE.get(code, GeodesicError)(code, details, method)
    trailing = e.trailing_metadata() if hasattr(e, "trailing_metadata") else None
    error._trailers = tuple((key, value) for key, value in trailing or ())
    return error


def trailer(error: GeodesicError, key: str) -> Optional[str]:
    """The value of one of a failed call's trailers, None if it had none of that name."""
    for name, value in error._trailers:
        if name == key:
            return value
    return None
