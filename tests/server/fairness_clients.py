"""Clients of the fairness tests: a well-behaved one sending light queries on the
bundled sample mesh, and careless ones that start streams and never read them.

Needs the Python client's stubs on sys.path (client/python), as the tests put them."""
import math
import time

import grpc
from geodesic_client._stubs import pb, rpc

SPOT_VERTICES = 2930
# An unread stream's client turns gRPC's BDP probing off, so that its flow-control window
# stays at its initial size and a modest answer fills it: the daemon must not depend on how
# much a client happens to buffer.
UNREAD_OPTIONS = [("grpc.http2.bdp_probe", 0), ("grpc.max_receive_message_length", 64 << 20)]


def as_client(token):
    """Metadata that makes a call its bearer token's client."""
    return [("authorization", f"Bearer {token}")]


def wait_ready(stub, mesh, eps=0.0, seconds=60, metadata=None):
    """Whether the mesh's graph at `eps` (0: the server's default) is ready within `seconds`."""
    deadline = time.time() + seconds
    while time.time() < deadline:
        try:
            if stub.GetGraph(pb.GetGraphRequest(mesh=mesh, epsilon=eps), timeout=5,
                             metadata=metadata).state == pb.GRAPH_STATE_READY:
                return True
        except grpc.RpcError as e:
            if e.code() != grpc.StatusCode.NOT_FOUND:
                raise
        time.sleep(0.05)
    return False


def light_queries(stub, n=20, pause=0.05, also=None, metadata=None):
    """n one-pair Distance calls on spot (and `also` beside each): latencies of those
    answered, and the errors."""
    latencies, errors = [], []
    for k in range(n):
        start = time.monotonic()
        try:
            req = pb.DistanceRequest(mesh="spot", pairs=[pb.PointPair(**{
                "from": pb.SurfacePoint(vertex=(37 * k) % SPOT_VERTICES),
                "to": pb.SurfacePoint(vertex=(101 * k + 7) % SPOT_VERTICES)})])
            if len(stub.Distance(req, timeout=3, metadata=metadata).results) == 1:
                latencies.append(time.monotonic() - start)
            if also:
                also()
        except grpc.RpcError as e:
            errors.append(f"{e.code().name}: {e.details()}")
        time.sleep(pause)
    return latencies, errors


def p99(latencies):
    ordered = sorted(latencies)
    return ordered[max(0, math.ceil(0.99 * len(ordered)) - 1)] if ordered else float("inf")


def unread_streams(address, call, requests):
    """Streams started and left unread, each on a channel of its own."""
    channels = [grpc.insecure_channel(address, options=UNREAD_OPTIONS) for _ in requests]
    streams = [call(rpc.GeodesicStub(ch), req) for ch, req in zip(channels, requests)]
    return channels, streams


def refused_streams(streams, expected, seconds=10):
    """The streams that ended (refused at once) once `expected` did, or after `seconds`."""
    refused, deadline = [], time.time() + seconds
    while time.time() < deadline and len(refused) < expected:
        refused = [s for s in streams if s.done()]
        time.sleep(0.05)
    return refused
