"""The connection to one geodesicd: channel, TLS, the bearer token, deadlines, retries, and
failures as GeodesicError subclasses. What the calls carry is not its business."""
import random
import time
from typing import Any, Callable, List, Optional, Tuple

import grpc

from ._errors import GeodesicError, ResourceExhaustedError, from_rpc_error, trailer
from ._stubs import rpc
from ._types import RetryPolicy

# The trailer of a RESOURCE_EXHAUSTED refusal because the server is overloaded: milliseconds
# to wait. A refusal because the request itself passed a limit never carries it.
RETRY_AFTER_TRAILER = "retry-after-ms"


def overload_hint(error: GeodesicError) -> Optional[float]:
    """Seconds the server asks a client to wait when it answers RESOURCE_EXHAUSTED because it
    is overloaded (its retry-after-ms trailer); None for any other error."""
    if not isinstance(error, ResourceExhaustedError):
        return None
    value = trailer(error, RETRY_AFTER_TRAILER)
    if value is None:
        return None
    try:
        return max(0.0, int(value) / 1e3)
    except ValueError:
        return None


class Transport:
    """A channel to address and the stub on it; every call goes through call()."""

    def __init__(self, address: str, timeout: float, token: Optional[str],
                 root_certificates: Optional[bytes], private_key: Optional[bytes],
                 certificate_chain: Optional[bytes], retry: RetryPolicy,
                 max_message_bytes: int):
        """See Client: timeout is each call's deadline (seconds), root_certificates turns
        TLS on, max_message_bytes bounds the messages either way."""
        options = [("grpc.max_receive_message_length", max_message_bytes),
                   ("grpc.max_send_message_length", max_message_bytes),
                   # gRPC's own reconnect backoff would otherwise grow past the
                   # retries' (to minutes), failing every retry fast.
                   ("grpc.initial_reconnect_backoff_ms", int(1000 * retry.initial_backoff) or 1),
                   ("grpc.min_reconnect_backoff_ms", int(1000 * retry.initial_backoff) or 1),
                   ("grpc.max_reconnect_backoff_ms", int(1000 * retry.max_backoff) or 1)]
        if root_certificates is not None:
            credentials = grpc.ssl_channel_credentials(root_certificates, private_key,
                                                       certificate_chain)
            self.channel = grpc.secure_channel(address, credentials, options=options)
        else:
            self.channel = grpc.insecure_channel(address, options=options)
        self.stub = rpc.GeodesicStub(self.channel)
        self._auth = [("authorization", f"Bearer {token}")] if token else []
        self.timeout = timeout
        self.retry = retry

    def close(self) -> None:
        self.channel.close()

    def metadata(self, mesh: Optional[str]) -> List[Tuple[str, str]]:
        # Proxies route by this header, so that a mesh's queries reach the
        # replicas that hold its graph.
        return ([("x-geodesic-mesh", mesh)] if mesh else []) + self._auth

    def start(self, name: str, request: Any, mesh: Optional[str],
              deadline: bool = True) -> Any:
        """Starts method `name` of the stub: its answer, or its stream of answers (to read
        inside call()'s run). deadline: False for a call with none (a watch)."""
        return getattr(self.stub, name)(request, timeout=self.timeout if deadline else None,
                                        metadata=self.metadata(mesh))

    def call(self, name: str, run: Callable[[], Any]) -> Any:
        """run() with retries of transient codes; failures become GeodesicError."""
        delays = self.retry.delays()
        while True:
            try:
                return run()
            except grpc.RpcError as e:
                error = from_rpc_error(e, name)
                hint = overload_hint(error) if self.retry.overload else None
                retried = error.code().name in self.retry.codes or hint is not None
                delay = next(delays, None) if retried else None
                if delay is None:
                    raise error from None
                time.sleep(max(hint or 0.0, random.uniform(delay / 2, delay)))

    def unary(self, name: str, request: Any, mesh: Optional[str]) -> Any:
        """One request, one answer, retried per the policy."""
        return self.call(name, lambda: self.start(name, request, mesh))
