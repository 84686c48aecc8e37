"""Python client for geodesicd.

    from geodesic_client import Client
    c = Client("127.0.0.1:50051")
    c.request_graph("spot", epsilon=1e-3, wait=True)
    field = c.field("spot", sources=["v:0"])          # numpy array, +inf where unreachable
    d = c.distance("spot", "f:0:0.2,0.3,0.5", "v:1500")
    path = c.path("spot", "v:1", "v:2000")             # (length, [(point, (x, y, z)), ...])

Surface points are written as in the CLI: "v:ID", "e:EDGE:T",
"f:FACE:B0,B1,B2" (barycentrics weight the face's vertices in the order the
mesh file lists them) or "xyz:X,Y,Z" (snapped to the surface by the server).
Errors raise grpc.RpcError with the server's status code and message.
"""
import os
import sys

import grpc
import numpy as np

_GEN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_gen")
if _GEN not in sys.path:
    sys.path.insert(0, _GEN)
from geodesic.v1 import geodesic_pb2 as pb  # noqa: E402  (generated at build time)
from geodesic.v1 import geodesic_pb2_grpc as rpc  # noqa: E402

__all__ = ["Client", "parse_point", "format_point"]


def parse_point(text):
    """Parses "v:ID", "e:EDGE:T", "f:FACE:B0,B1,B2"; returns a SurfacePoint or a position."""
    kind, _, rest = text.partition(":")
    if kind == "v":
        return pb.SurfacePoint(vertex=int(rest))
    if kind == "e":
        edge, _, t = rest.partition(":")
        return pb.SurfacePoint(edge=pb.EdgePoint(edge=int(edge), t=float(t)))
    if kind == "f":
        face, _, bary = rest.partition(":")
        b = [float(x) for x in bary.split(",")]
        if len(b) != 3:
            raise ValueError(f"face point {text!r} needs three barycentric coordinates")
        return pb.SurfacePoint(face=pb.FacePoint(face=int(face), b0=b[0], b1=b[1], b2=b[2]))
    if kind == "xyz":
        x = [float(v) for v in rest.split(",")]
        return pb.Vec3(x=x[0], y=x[1], z=x[2])
    raise ValueError(f"bad surface point {text!r}: expected v:, e:, f: or xyz:")


def format_point(p):
    which = p.WhichOneof("point")
    if which == "vertex":
        return f"v:{p.vertex}"
    if which == "edge":
        return f"e:{p.edge.edge}:{p.edge.t!r}"
    return f"f:{p.face.face}:{p.face.b0!r},{p.face.b1!r},{p.face.b2!r}"


class Client:
    """A connection to one geodesicd (or a proxy in front of several)."""

    def __init__(self, address="127.0.0.1:50051", timeout=600.0, token=None,
                 root_certificates=None, private_key=None, certificate_chain=None):
        """token: sent as "authorization: Bearer <token>" (geodesicd --auth-token-file).
        root_certificates: PEM bytes of the CA that signed the server's certificate; turns
        TLS on. private_key, certificate_chain: PEM bytes of a client certificate, for
        servers that require one (--tls-client-ca)."""
        options = [("grpc.max_receive_message_length", 256 << 20)]
        if root_certificates is not None:
            credentials = grpc.ssl_channel_credentials(root_certificates, private_key,
                                                       certificate_chain)
            self._channel = grpc.secure_channel(address, credentials, options=options)
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        self._stub = rpc.GeodesicStub(self._channel)
        self._auth = [("authorization", f"Bearer {token}")] if token else []
        self.timeout = timeout

    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _meta(self, mesh):
        # Proxies route by this header, so that a mesh's queries reach the
        # replicas that hold its graph.
        return [("x-geodesic-mesh", mesh)] + self._auth

    def _points(self, mesh, specs):
        parsed = [parse_point(s) if isinstance(s, str) else s for s in specs]
        positions = [p for p in parsed if isinstance(p, pb.Vec3)]
        if positions:
            snapped = iter(self._stub.Snap(pb.SnapRequest(mesh=mesh, positions=positions),
                                           timeout=self.timeout, metadata=self._meta(mesh)).points)
            parsed = [next(snapped) if isinstance(p, pb.Vec3) else p for p in parsed]
        return parsed

    def meshes(self):
        return list(self._stub.ListMeshes(pb.ListMeshesRequest(), timeout=self.timeout,
                                          metadata=self._auth).meshes)

    def register_mesh(self, name, path):
        return self._stub.RegisterMesh(pb.RegisterMeshRequest(name=name, path=path),
                                       timeout=self.timeout, metadata=self._meta(name))

    def unload_mesh(self, name):
        """Forgets a mesh and drops its graphs from memory (their files stay)."""
        self._stub.UnloadMesh(pb.UnloadMeshRequest(name=name), timeout=self.timeout,
                              metadata=self._meta(name))

    def upload_mesh(self, name, filename, chunk_bytes=1 << 20):
        fmt = filename.rsplit(".", 1)[-1].lower()

        def chunks():
            with open(filename, "rb") as f:
                first = True
                while True:
                    data = f.read(chunk_bytes)
                    if not data and not first:
                        return
                    yield pb.UploadMeshRequest(name=name if first else "",
                                               format=fmt if first else "", data=data)
                    first = False

        return self._stub.UploadMesh(chunks(), timeout=self.timeout, metadata=self._meta(name))

    def request_graph(self, mesh, epsilon=0.0, wait=True, pseudo_vertices=False):
        """Requests the graph; with wait=True, blocks until it is ready (or raises)."""
        request = pb.RequestGraphRequest(mesh=mesh, epsilon=epsilon,
                                         pseudo_vertices=pseudo_vertices)
        g = self._stub.RequestGraph(request, timeout=self.timeout, metadata=self._meta(mesh))
        # Under memory pressure a graph can be evicted again before this
        # client sees it ready; asking again brings it back from its file.
        for _ in range(10 if wait else 0):
            for g in self._stub.WatchGraph(pb.GetGraphRequest(mesh=mesh, epsilon=g.epsilon),
                                           timeout=self.timeout, metadata=self._meta(mesh)):
                pass
            if g.state != pb.GRAPH_STATE_EVICTED:
                break
            g = self._stub.RequestGraph(request, timeout=self.timeout, metadata=self._meta(mesh))
        if wait and g.state != pb.GRAPH_STATE_READY:
            raise RuntimeError(f"graph for {mesh} at eps {g.epsilon}: "
                               f"{pb.GraphState.Name(g.state)} {g.error}")
        return g

    def graphs(self):
        return list(self._stub.ListGraphs(pb.ListGraphsRequest(), timeout=self.timeout,
                                          metadata=self._auth).graphs)

    def field(self, mesh, sources, epsilon=0.0, max_distance=0.0, targets=(), method="lc",
              nearest_source=False):
        """Distances as a float64 numpy array (per vertex, or per target)."""
        req = pb.DistanceFieldRequest(mesh=mesh, epsilon=epsilon, max_distance=max_distance,
                                      sources=self._points(mesh, sources), targets=list(targets),
                                      method=method, nearest_source=nearest_source)
        values, labels = None, None
        for chunk in self._stub.DistanceField(req, timeout=self.timeout, metadata=self._meta(mesh)):
            if values is None:
                values = np.empty(chunk.total, dtype=np.float64)
                labels = np.empty(chunk.total, dtype=np.uint32) if nearest_source else None
            end = chunk.offset + len(chunk.values)
            values[chunk.offset:end] = chunk.values
            if nearest_source:
                labels[chunk.offset:end] = chunk.nearest_source
        if values is None:
            values = np.empty(0)
        return (values, labels) if nearest_source else values

    def distances(self, mesh, pairs, epsilon=0.0, with_path=False):
        flat = self._points(mesh, [p for pair in pairs for p in pair])
        req = pb.DistanceRequest(mesh=mesh, epsilon=epsilon, with_path=with_path,
                                 pairs=[pb.PointPair(**{"from": flat[i], "to": flat[i + 1]})
                                        for i in range(0, len(flat), 2)])
        return list(self._stub.Distance(req, timeout=self.timeout,
                                        metadata=self._meta(mesh)).results)

    def distance(self, mesh, a, b, epsilon=0.0):
        """Geodesic distance between two surface points (inf if unreachable)."""
        return self.distances(mesh, [(a, b)], epsilon)[0].distance

    def path(self, mesh, a, b, epsilon=0.0):
        """(length, [(surface point text, (x, y, z)), ...]) from a to b."""
        r = self.distances(mesh, [(a, b)], epsilon, with_path=True)[0]
        return r.path.length, [(format_point(p.point), (p.xyz.x, p.xyz.y, p.xyz.z))
                               for p in r.path.points]

    def matrix(self, mesh, sources, targets, epsilon=0.0):
        r = self._stub.Matrix(pb.MatrixRequest(mesh=mesh, epsilon=epsilon,
                                               sources=self._points(mesh, sources),
                                               targets=self._points(mesh, targets)),
                              timeout=self.timeout, metadata=self._meta(mesh))
        return np.array(r.distances, dtype=np.float64).reshape(r.rows, r.cols)

    def snap(self, mesh, positions):
        r = self._stub.Snap(pb.SnapRequest(mesh=mesh, positions=[pb.Vec3(x=p[0], y=p[1], z=p[2])
                                                                 for p in positions]),
                            timeout=self.timeout, metadata=self._meta(mesh))
        return [format_point(p) for p in r.points]
