#!/usr/bin/python3
"""The gRPC surface that tools expect (#70), against a real daemon that
requires a bearer token:

1. A reflection-only client, which has the reflection proto and not
   geodesic.proto, lists the services through grpc.reflection.v1 (health and
   both reflections among them, no token needed), fetches the file of
   geodesic.v1.Geodesic by symbol, builds a DistanceRequest from it
   (DescriptorPool + MessageFactory) and calls Distance as raw bytes,
   getting a finite distance. It also asks by file name, for health's file
   (which has Watch), for extensions, and for an unknown symbol, file and
   type (error_response NOT_FOUND, the stream going on); v1alpha answers the
   same requests (the two versions' messages are the same on the wire).
2. health Watch streams a graph's status: SERVICE_UNKNOWN before the graph
   is requested, SERVING once built, NOT_SERVING once its mesh is unloaded.
3. RegisterMesh paths: ".." that stays under --mesh-root is accepted, ".."
   that leaves it is PERMISSION_DENIED.
4. 300 reflection streams (v1, then v1alpha) left open and idle hold no
   server thread: a query is answered beside them.

Stubs: the messages of proto/grpc/reflection/v1/reflection.proto and
proto/grpc/health/v1/health.proto are generated here with Debian's protoc
(protobuf-compiler, which scripts/setup.sh installs; Debian's python3-grpcio
has no reflection or health modules), and the calls are made with
channel.unary_unary / unary_stream / stream_stream, which need no service
stubs. Every wait is bounded by a call deadline.

Usage: grpc_surface_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import importlib.util
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grpc  # noqa: E402
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402

TOKEN = "surface-test-token"
EPS = 0.02
check = Checklist()


def generate_messages(out):
    """reflection_pb2 and health_pb2, generated into `out` by protoc."""
    protos = ["grpc/reflection/v1/reflection.proto", "grpc/health/v1/health.proto"]
    os.makedirs(out, exist_ok=True)
    subprocess.run(["protoc", f"--proto_path={SRC}/proto", f"--python_out={out}", *protos],
                   check=True, timeout=60)
    return (_load(out, "grpc/reflection/v1/reflection_pb2.py"),
            _load(out, "grpc/health/v1/health_pb2.py"))


def _load(root, relative):
    # By path: the generated package "grpc" would clash with grpcio's.
    spec = importlib.util.spec_from_file_location(relative.replace("/", "_")[:-3],
                                                  os.path.join(root, relative))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Reflection:
    """One ServerReflectionInfo stream of `version` ("v1" or "v1alpha")."""

    def __init__(self, channel, rpb, version):
        self.rpb = rpb
        self.call = channel.stream_stream(
            f"/grpc.reflection.{version}.ServerReflection/ServerReflectionInfo",
            request_serializer=rpb.ServerReflectionRequest.SerializeToString,
            response_deserializer=rpb.ServerReflectionResponse.FromString)

    def ask(self, *requests):
        """The responses to `requests`, sent on one stream (no token)."""
        reqs = [self.rpb.ServerReflectionRequest(host="test", **r) for r in requests]
        return list(self.call(iter(reqs), timeout=30))


def files_of(response):
    return [descriptor_pb2.FileDescriptorProto.FromString(b)
            for b in response.file_descriptor_response.file_descriptor_proto]


def pool_of(files):
    """A descriptor pool of `files`, each added after the files it imports."""
    pool, added, left = descriptor_pool.DescriptorPool(), set(), list(files)
    while left:
        ready = [f for f in left if all(d in added for d in f.dependency)]
        if not ready:
            raise ValueError(f"imports missing from the answer: {[f.name for f in left]}")
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            left.remove(f)
    return pool


def reflection_checks(channel, rpb, version):
    r = Reflection(channel, rpb, version)
    answers = r.ask({"list_services": ""},
                    {"file_containing_symbol": "geodesic.v1.Geodesic"},
                    {"file_containing_symbol": "geodesic.v1.NoSuchThing"},
                    {"file_by_filename": "geodesic/v1/geodesic.proto"},
                    {"file_by_filename": "no/such.proto"},
                    {"file_containing_symbol": "grpc.health.v1.Health"},
                    {"all_extension_numbers_of_type": "geodesic.v1.Mesh"},
                    {"all_extension_numbers_of_type": "geodesic.v1.NoSuchType"},
                    {"file_containing_extension": {"containing_type": "geodesic.v1.Mesh",
                                                   "extension_number": 1000}})
    check(f"{version}: one response per request, on one stream", len(answers) == 9, len(answers))
    listed = {s.name for s in answers[0].list_services_response.service}
    expected = {"geodesic.v1.Geodesic", "grpc.health.v1.Health",
                "grpc.reflection.v1.ServerReflection", "grpc.reflection.v1alpha.ServerReflection"}
    check(f"{version}: list_services names every service, both reflections and health",
          listed == expected, sorted(listed))
    check(f"{version}: the response echoes host and request",
          answers[0].valid_host == "test" and answers[0].original_request.HasField("list_services"),
          answers[0].original_request)
    files = files_of(answers[1])
    names = [f.name for f in files]
    check(f"{version}: file_containing_symbol answers geodesic.proto first, each file once",
          names and names[0] == "geodesic/v1/geodesic.proto" and len(names) == len(set(names)),
          names)
    unknown = answers[2]
    check(f"{version}: an unknown symbol is error_response NOT_FOUND",
          unknown.WhichOneof("message_response") == "error_response"
          and unknown.error_response.error_code == grpc.StatusCode.NOT_FOUND.value[0]
          # Each version names what it did not find.
          and "NoSuchThing" in unknown.error_response.error_message,
          unknown)
    check(f"{version}: file_by_filename answers the same file",
          [f.name for f in files_of(answers[3])][:1] == ["geodesic/v1/geodesic.proto"],
          answers[3].WhichOneof("message_response"))
    check(f"{version}: an unknown file is NOT_FOUND, and the stream went on after errors",
          answers[4].error_response.error_code == grpc.StatusCode.NOT_FOUND.value[0], answers[4])
    health = files_of(answers[5])
    methods = [m.name for f in health for s in f.service for m in s.method]
    check(f"{version}: health's file is described, Check and Watch",
          [f.name for f in health] == ["grpc/health/v1/health.proto"]
          and methods == ["Check", "Watch"], (answers[5].error_response, methods))
    ext = answers[6].all_extension_numbers_response
    check(f"{version}: all_extension_numbers_of_type names the type (no extensions)",
          ext.base_type_name == "geodesic.v1.Mesh" and not ext.extension_number, answers[6])
    check(f"{version}: extensions of an unknown type, or an unknown extension, are NOT_FOUND",
          answers[7].error_response.error_code == grpc.StatusCode.NOT_FOUND.value[0]
          and answers[8].error_response.error_code == grpc.StatusCode.NOT_FOUND.value[0],
          (answers[7], answers[8]))
    return files


def idle_streams(address, rpb, files, version):
    """300 reflection streams of `version` left open without a request (no
    token needed) hold no server thread: a query and a listing are answered
    beside them. The daemon's thread quota on default flags is 216 (2 x
    --max-inflight + --max-streams + 24), which gRPC's own v1alpha plugin,
    synchronous, one thread a stream, exhausted."""
    release = threading.Event()

    def nothing():
        release.wait(60)
        return
        yield

    channels = [grpc.insecure_channel(address, options=[("grpc.use_local_subchannel_pool", 1)])
                for _ in range(4)]
    streams = [channels[i % 4].stream_stream(
        f"/grpc.reflection.{version}.ServerReflection/ServerReflectionInfo",
        request_serializer=rpb.ServerReflectionRequest.SerializeToString,
        response_deserializer=rpb.ServerReflectionResponse.FromString)(nothing(), timeout=60)
        for i in range(300)]
    try:
        time.sleep(2)  # every stream reaches the server
        channel = grpc.insecure_channel(address)
        try:
            call_dynamic(channel, files, "ListMeshes", TOKEN, timeout=10)
            d = generic_distance(channel, files, quiet=True)
            check(f"300 idle reflection {version} streams: a listing and a query still answered",
                  math.isfinite(d))
        except grpc.RpcError as e:
            check(f"300 idle reflection {version} streams: a listing and a query still answered",
                  False, (e.code(), e.details()))
        channel.close()
    finally:
        release.set()
        for stream in streams:
            stream.cancel()
        for c in channels:
            c.close()


def generic_distance(channel, files, quiet=False):
    """Distance between two vertices of spot, with messages built only from
    the files reflection sent."""
    pool = pool_of(files)
    factory = message_factory.MessageFactory(pool)
    service = pool.FindServiceByName("geodesic.v1.Geodesic")
    method = service.methods_by_name["Distance"]
    Request = factory.GetPrototype(method.input_type)
    Response = factory.GetPrototype(method.output_type)
    req = Request()
    req.graph.mesh = "spot"  # the sample mesh, whose default graph the daemon builds at start
    pair = req.pairs.add()
    getattr(pair, "from").vertex = 0
    pair.to.vertex = 2000
    call = channel.unary_unary(f"/{service.full_name}/{method.name}",
                               request_serializer=Request.SerializeToString,
                               response_deserializer=Response.FromString)
    if quiet:
        return call(req, timeout=30, metadata=daemon_ports.bearer(TOKEN)).results[0].distance
    try:
        call(req, timeout=30)
        check("a geodesic.v1 call without the token is UNAUTHENTICATED", False, "answered")
    except grpc.RpcError as e:
        check("a geodesic.v1 call without the token is UNAUTHENTICATED",
              e.code() == grpc.StatusCode.UNAUTHENTICATED, e.code())
    answer = call(req, timeout=120, metadata=daemon_ports.bearer(TOKEN))
    d = answer.results[0].distance
    check("Distance through a generic call, messages from reflection: finite and positive",
          math.isfinite(d) and d > 0 and answer.results[0].reachable, answer)
    return d


def call_dynamic(channel, files, method_name, token, timeout=60, **fields):
    """A unary geodesic.v1 call by name, its messages from `files`."""
    pool = pool_of(files)
    factory = message_factory.MessageFactory(pool)
    method = pool.FindServiceByName("geodesic.v1.Geodesic").methods_by_name[method_name]
    Request = factory.GetPrototype(method.input_type)
    Response = factory.GetPrototype(method.output_type)
    req = Request()
    for key, value in fields.items():
        if isinstance(value, dict):
            for k, v in value.items():
                setattr(getattr(req, key), k, v)
        else:
            setattr(req, key, value)
    return channel.unary_unary(f"/geodesic.v1.Geodesic/{method_name}",
                               request_serializer=Request.SerializeToString,
                               response_deserializer=Response.FromString)(
        req, timeout=timeout, metadata=daemon_ports.bearer(token))


def health_checks(channel, hpb, files):
    watch = channel.unary_stream("/grpc.health.v1.Health/Watch",
                                 request_serializer=hpb.HealthCheckRequest.SerializeToString,
                                 response_deserializer=hpb.HealthCheckResponse.FromString)
    health_check = channel.unary_unary("/grpc.health.v1.Health/Check",
                                       request_serializer=hpb.HealthCheckRequest.SerializeToString,
                                       response_deserializer=hpb.HealthCheckResponse.FromString)
    Status = hpb.HealthCheckResponse
    whole = health_check(hpb.HealthCheckRequest(service=""), timeout=10)
    check("health Check of the daemon, without a token: SERVING", whole.status == Status.SERVING,
          whole)
    name = f"geodesic.v1.Geodesic/cow@{EPS:g}"
    try:
        health_check(hpb.HealthCheckRequest(service=name), timeout=10)
        check("health Check of a name never set: NOT_FOUND", False, "answered")
    except grpc.RpcError as e:
        check("health Check of a name never set: NOT_FOUND",
              e.code() == grpc.StatusCode.NOT_FOUND, e.code())
    # The whole watch within 120 s: a status that never comes ends it with
    # DEADLINE_EXCEEDED rather than hanging.
    stream = watch(hpb.HealthCheckRequest(service=name), timeout=120)
    seen = [next(stream).status]
    check("Watch of a graph not yet requested: SERVICE_UNKNOWN",
          seen == [Status.SERVICE_UNKNOWN], seen)
    call_dynamic(channel, files, "RegisterMesh", TOKEN, name="cow", path="spot.obj")
    call_dynamic(channel, files, "RequestGraph", TOKEN, graph={"mesh": "cow", "epsilon": EPS})
    try:
        while seen[-1] != Status.SERVING:
            seen.append(next(stream).status)
        check("Watch: SERVING once the graph is built", True)
        call_dynamic(channel, files, "UnloadMesh", TOKEN, name="cow")
        seen.append(next(stream).status)
        check("Watch: NOT_SERVING once its mesh is unloaded", seen[-1] == Status.NOT_SERVING,
              [Status.ServingStatus.Name(s) for s in seen])
    except grpc.RpcError as e:
        check("Watch streams the graph's changes within its deadline", False,
              (e.code(), [Status.ServingStatus.Name(s) for s in seen]))
    finally:
        stream.cancel()


def path_checks(channel, files, root):
    def register(name, path):
        try:
            call_dynamic(channel, files, "RegisterMesh", TOKEN, name=name, path=path)
            return "OK"
        except grpc.RpcError as e:
            return e.code().name

    inside = register("dotdot", "scans/../spot.obj")
    check("a path with '..' that stays under --mesh-root is accepted", inside == "OK", inside)
    for path in ("../spot.obj", "scans/../../spot.obj", "../../../etc/hostname"):
        outside = register("escape", path)
        check(f"a path with '..' leading outside --mesh-root is PERMISSION_DENIED: {path}",
              outside == "PERMISSION_DENIED", outside)


def main():
    work = tempfile.mkdtemp(prefix="grpc_surface.")
    try:
        rpb, hpb = generate_messages(os.path.join(work, "stubs"))
        root = os.path.join(work, "meshes")
        os.makedirs(os.path.join(root, "scans"))
        shutil.copy(os.path.join(SRC, "data", "spot.obj"), root)
        log = open(os.path.join(work, "daemon.log"), "w")
        daemon, ports = daemon_ports.start_daemon(
            BIN, work, ["--mesh-root", root, "--log-level", "warning"], stderr=log,
            tokens=[TOKEN])
        channel = grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}")
        files = reflection_checks(channel, rpb, "v1")
        alpha = reflection_checks(channel, rpb, "v1alpha")
        check("v1 and v1alpha send the same geodesic.proto",
              files[:1] == alpha[:1] and len(files) == 1, [f.name for f in files])
        generic_distance(channel, files)
        health_checks(channel, hpb, files)
        path_checks(channel, files, root)
        for version in ("v1", "v1alpha"):
            idle_streams(f"127.0.0.1:{ports['grpc']}", rpb, files, version)
        channel.close()
        check("the daemon stops cleanly", daemon_ports.stop(daemon) == 0)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
