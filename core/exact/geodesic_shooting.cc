#include "core/exact/geodesic_shooting.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"

namespace geodesic {
namespace {

// Places the third corner of face(g) to the left of p0 -> p1, where p0 and
// p1 are the images of tail(g) and head(g): faces are counter-clockwise.
Vec2 PlaceOpposite(const Mesh& mesh, HalfedgeId g, const Vec2& p0, const Vec2& p1) {
  const double L = mesh.length(g);
  const double d0 = mesh.length(Mesh::prev(g));  // opposite -> tail
  const double d1 = mesh.length(Mesh::next(g));  // head -> opposite
  const double x = (L * L + d0 * d0 - d1 * d1) / (2 * L);
  const double y = std::sqrt(std::max(0.0, d0 * d0 - x * x));
  const Vec2 u = (p1 - p0) * (1 / L);
  const Vec2 left{-u.y, u.x};
  return p0 + u * x + left * y;
}

// Barycentric coordinates of q in triangle (a, b, c).
std::array<double, 3> Barycentric(const Vec2& a, const Vec2& b, const Vec2& c, const Vec2& q) {
  const double area = Cross(b - a, c - a);
  if (area == 0) return {1, 0, 0};
  const double wa = Cross(b - q, c - q) / area;
  const double wb = Cross(c - q, a - q) / area;
  return {wa, wb, 1 - wa - wb};
}

// The corner of v whose angle holds `polar_angle`, or kNone.
HalfedgeId CornerContaining(const Mesh& mesh, VertexId v, double polar_angle) {
  HalfedgeId h = mesh.vertex_halfedge(v);
  const HalfedgeId start = h;
  do {
    if (polar_angle >= mesh.polar_angle(h) &&
        polar_angle <= mesh.polar_angle(h) + mesh.corner_angle(h)) {
      return h;
    }
    h = mesh.rotate(h);
  } while (h != kNone && h != start);
  return kNone;
}

// Where a ray from p along dir leaves face f (corner images `pos`): the
// first edge other than `entry` it meets, at distance s along the ray and t
// along the edge. edge kNone: it meets none.
struct FaceExit {
  HalfedgeId edge = kNone;
  double s = std::numeric_limits<double>::infinity();
  double t = 0;
};

FaceExit FirstExit(FaceId f, const std::array<Vec2, 3>& pos, const Vec2& p, const Vec2& dir,
                   HalfedgeId entry) {
  FaceExit exit;
  for (int e = 0; e < 3; ++e) {
    const HalfedgeId g = Mesh::halfedge(f, e);
    if (g == entry) continue;
    const Vec2 q0 = pos[e], q1 = pos[(e + 1) % 3];
    const double den = Cross(q1 - q0, dir);
    if (std::abs(den) < 1e-300) continue;
    const double s = Cross(q0 - p, q1 - q0) / -den;
    const double t = Cross(q0 - p, dir) / -den;
    // The exit the shot stands on is skipped: s is a length, so "zero" is
    // relative to the edge's, as a mesh's units are arbitrary.
    const double zero = 1e-15 * std::max(std::abs(q1.x - q0.x), std::abs(q1.y - q0.y));
    if (s > zero && t >= -1e-12 && t <= 1 + 1e-12 && s < exit.s) {
      exit = {g, s, std::clamp(t, 0.0, 1.0)};
    }
  }
  return exit;
}

}  // namespace

absl::StatusOr<ShotEnd> ShootGeodesic(const Mesh& mesh, VertexId v, double polar_angle,
                                      double length, ShotStrip* strip) {
  if (v >= mesh.num_vertices() || mesh.is_isolated(v)) {
    return absl::InvalidArgumentError(absl::StrFormat("cannot shoot from vertex %u", v));
  }
  if (!std::isfinite(polar_angle) || !(length > 0)) {
    return absl::InvalidArgumentError("shooting needs a finite angle and a positive length");
  }
  const HalfedgeId corner = CornerContaining(mesh, v, polar_angle);
  if (corner == kNone) {
    return absl::InvalidArgumentError(
        absl::StrFormat("angle %g is outside vertex %u's faces", polar_angle, v));
  }
  // Lay out face(corner) with v at the origin and head(corner) on the x axis.
  std::array<Vec2, 3> pos;  // images of the face's corners, in corner order
  FaceId f = Mesh::face(corner);
  const int k = Mesh::corner(corner);
  pos[k] = {0, 0};
  pos[(k + 1) % 3] = {mesh.length(corner), 0};
  pos[(k + 2) % 3] = PlaceOpposite(mesh, corner, pos[k], pos[(k + 1) % 3]);
  const double a = polar_angle - mesh.polar_angle(corner);
  const Vec2 dir{std::cos(a), std::sin(a)};
  Vec2 p{0, 0};
  double travelled = 0;
  HalfedgeId entry = kNone;  // the half-edge of f we came in through
  ShotEnd end;
  if (strip) strip->portals.clear();
  // Where the shot stops, in face f.
  auto finish = [&](const Vec2& q) {
    if (!strip) return;
    for (int e = 0; e < 3; ++e) strip->last_face[e] = mesh.tail(Mesh::halfedge(f, e));
    strip->last_images = pos;
    strip->end = q;
  };
  for (size_t step = 0; step < 4 * mesh.num_faces() + 8; ++step) {
    const auto [exit, best_s, exit_t] = FirstExit(f, pos, p, dir, entry);
    const double remaining = length - travelled;
    if (exit == kNone || best_s >= remaining) {
      const double s = exit == kNone ? 0 : remaining;
      const Vec2 q = p + dir * s;
      auto b = Barycentric(pos[0], pos[1], pos[2], q);
      for (double& x : b) x = std::max(x, 0.0);
      const double sum = b[0] + b[1] + b[2];
      end.point =
          CanonicalizeSurfacePoint(mesh, SurfacePoint::Face(f, b[0] / sum, b[1] / sum, b[2] / sum));
      end.length = travelled + s;
      finish(q);
      return end;
    }
    travelled += best_s;
    p = p + dir * best_s;
    if (exit_t < 1e-12 || exit_t > 1 - 1e-12) {
      // Straight through a vertex: the straightest continuation is ambiguous;
      // stop there.
      const VertexId x = exit_t < 0.5 ? mesh.tail(exit) : mesh.head(exit);
      end.point = SurfacePoint::Vertex(x);
      end.length = travelled;
      end.hit_vertex = true;
      finish(p);
      return end;
    }
    const HalfedgeId twin = mesh.twin(exit);
    if (twin == kNone) {
      end.point = CanonicalizeSurfacePoint(
          mesh,
          SurfacePoint::Edge(mesh.edge(exit),
                             mesh.edge_halfedge(mesh.edge(exit)) == exit ? exit_t : 1 - exit_t));
      end.length = travelled;
      finish(p);
      return end;
    }
    if (strip) {
      strip->portals.push_back({mesh.tail(exit), mesh.head(exit), pos[Mesh::corner(exit)],
                                pos[(Mesh::corner(exit) + 1) % 3]});
    }
    // Unfold the next face across the exit edge.
    const int e = Mesh::corner(exit);
    const Vec2 tail = pos[e], head = pos[(e + 1) % 3];
    f = Mesh::face(twin);
    const int kt = Mesh::corner(twin);
    pos[kt] = head;  // twin runs head(exit) -> tail(exit)
    pos[(kt + 1) % 3] = tail;
    pos[(kt + 2) % 3] = PlaceOpposite(mesh, twin, head, tail);
    entry = twin;
  }
  return absl::InternalError("geodesic shooting did not terminate");
}

double ShotStrip::StraightDistanceToEnd(VertexId w) const {
  constexpr double kNever = std::numeric_limits<double>::infinity();
  // From w's last image on the way: the segment must then cross every later
  // portal, between its ends.
  size_t first = portals.size();
  Vec2 from;
  bool found = false;
  for (size_t i = portals.size(); i-- > 0 && !found;) {
    if (portals[i].a == w || portals[i].b == w) {
      from = portals[i].a == w ? portals[i].image_a : portals[i].image_b;
      first = i + 1;
      found = true;
    }
  }
  if (!found) {
    const auto k = std::find(last_face.begin(), last_face.end(), w) - last_face.begin();
    if (k == 3) return kNever;
    from = last_images[k];
  }
  const Vec2 dir = end - from;
  for (size_t i = first; i < portals.size(); ++i) {
    const Vec2 a = portals[i].image_a, edge = portals[i].image_b - portals[i].image_a;
    const double den = Cross(dir, edge);
    if (den == 0) return kNever;
    const double t = Cross(a - from, edge) / den;  // along the segment
    const double u = Cross(a - from, dir) / den;   // along the portal
    if (t < 0 || t > 1 || u < 0 || u > 1) return kNever;
  }
  return Norm(dir);
}

std::vector<VertexId> ShotStrip::Vertices(VertexId shooter) const {
  std::vector<VertexId> out;
  for (const Portal& p : portals) {
    out.push_back(p.a);
    out.push_back(p.b);
  }
  out.insert(out.end(), last_face.begin(), last_face.end());
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  std::erase(out, shooter);
  return out;
}

}  // namespace geodesic
