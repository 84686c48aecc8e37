#include "core/query/result_files.h"

#include <bit>
#include <cmath>
#include <string_view>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"
#include "core/mesh/gifti_files.h"

namespace geodesic {
namespace {

static_assert(std::endian::native == std::endian::little,
              "raw and .npy outputs are written as little-endian memory images");

// The extension of `path`, lower case, with its dot ("" if none). GIFTI
// names its kind before ".gii", so a metric's extension is ".func.gii".
std::string ExtensionOf(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  const size_t dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  const std::string lower = absl::AsciiStrToLower(path);
  constexpr std::string_view kMetric = ".func.gii";
  if (lower.ends_with(kMetric) && lower.size() - kMetric.size() > slash + 1) {
    return std::string(kMetric);
  }
  return lower.substr(dot);
}

absl::Status CheckExtension(const std::string& path, std::string_view what,
                            std::initializer_list<const char*> accepted) {
  const std::string ext = ExtensionOf(path);
  for (const char* a : accepted) {
    if (ext == a) return absl::OkStatus();
  }
  return absl::InvalidArgumentError(
      absl::StrFormat("%s: cannot write %s as '%s'; use one of %s", path, what,
                      ext.empty() ? "(no extension)" : ext, absl::StrJoin(accepted, ", ")));
}

absl::Status WriteText(const std::string& path, const std::string& text) {
  ASSIGN_OR_RETURN(AtomicFileWriter out, AtomicFileWriter::Create(path));
  RETURN_IF_ERROR(out.Append(text.data(), text.size()));
  return std::move(out).Commit();
}

template <typename T>
absl::Status WriteNpy(const std::string& path, std::string_view dtype, absl::Span<const T> values) {
  const std::string preamble = NpyPreamble(dtype, {values.size()});
  ASSIGN_OR_RETURN(AtomicFileWriter out, AtomicFileWriter::Create(path));
  RETURN_IF_ERROR(out.Append(preamble.data(), preamble.size()));
  RETURN_IF_ERROR(out.Append(values.data(), values.size() * sizeof(T)));
  return std::move(out).Commit();
}

template <typename T>
absl::Status WriteRaw(const std::string& path, absl::Span<const T> values) {
  ASSIGN_OR_RETURN(AtomicFileWriter out, AtomicFileWriter::Create(path));
  RETURN_IF_ERROR(out.Append(values.data(), values.size() * sizeof(T)));
  return std::move(out).Commit();
}

// Blue (near) to red (far), black isolines every twentieth of the largest
// distance, grey where unreached.
std::array<int, 3> DistanceColour(double d, double largest) {
  if (!std::isfinite(d) || !(largest > 0)) return {128, 128, 128};
  const double t = std::clamp(d / largest, 0.0, 1.0);
  if (std::fmod(t * 20, 1.0) < 0.08) return {0, 0, 0};
  return {static_cast<int>(255 * t), static_cast<int>(255 * (1 - std::abs(2 * t - 1))),
          static_cast<int>(255 * (1 - t))};
}

absl::Status WriteColouredPly(const std::string& path, absl::Span<const double> values,
                              const TriangleSoup& geometry) {
  if (geometry.positions.size() != values.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the mesh has %u vertices but the field has %u values", path,
                        geometry.positions.size(), values.size()));
  }
  double largest = 0;
  for (double v : values) {
    if (std::isfinite(v)) largest = std::max(largest, v);
  }
  std::string text = absl::StrFormat(
      "ply\nformat ascii 1.0\nelement vertex %u\nproperty double x\nproperty double y\n"
      "property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
      "property double distance\nelement face %u\nproperty list uchar int vertex_indices\n"
      "end_header\n",
      values.size(), geometry.triangles.size());
  for (size_t i = 0; i < values.size(); ++i) {
    const Vec3& p = geometry.positions[i];
    const auto [r, g, b] = DistanceColour(values[i], largest);
    // PLY has no infinity: unreached vertices carry -1.
    absl::StrAppendFormat(&text, "%.17g %.17g %.17g %d %d %d %.17g\n", p.x, p.y, p.z, r, g, b,
                          std::isfinite(values[i]) ? values[i] : -1.0);
  }
  for (const auto& t : geometry.triangles)
    absl::StrAppend(&text, "3 ", t[0], " ", t[1], " ", t[2], "\n");
  return WriteText(path, text);
}

}  // namespace

std::string NpyPreamble(std::string_view dtype, std::initializer_list<uint64_t> shape) {
  // The shape as Python writes a tuple: (), (n,) or (a, b).
  std::string dims = absl::StrJoin(shape, ", ");
  if (shape.size() == 1) dims += ",";
  std::string header =
      absl::StrFormat("{'descr': '%s', 'fortran_order': False, 'shape': (%s), }", dtype, dims);
  const size_t fixed = 10;  // magic (6), version (2), header length (2)
  header.append(63 - (fixed + header.size()) % 64, ' ');
  header.push_back('\n');
  std::string bytes = "\x93NUMPY";
  bytes.push_back(1);
  bytes.push_back(0);
  bytes.push_back(static_cast<char>(header.size() & 0xff));
  bytes.push_back(static_cast<char>(header.size() >> 8));
  return bytes + header;
}

absl::Status CheckFieldPath(const std::string& path, bool have_geometry) {
  RETURN_IF_ERROR(
      CheckExtension(path, "a distance field", {".f64", ".npy", ".csv", ".ply", ".func.gii"}));
  if (ExtensionOf(path) == ".ply" && !have_geometry) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: a .ply field needs the mesh's geometry", path));
  }
  return absl::OkStatus();
}

absl::Status CheckLabelPath(const std::string& path) {
  return CheckExtension(path, "labels", {".npy", ".csv", ".u32"});
}

absl::Status CheckPolylinePath(const std::string& path) {
  return CheckExtension(path, "a path", {".csv", ".ply", ".obj"});
}

absl::Status CheckMatrixPath(const std::string& path, bool sparse) {
  return sparse ? CheckExtension(path, "a sparse matrix", {".npz"})
                : CheckExtension(path, "a dense matrix", {".npy"});
}

absl::Status WriteField(const std::string& path, absl::Span<const double> values,
                        const TriangleSoup* geometry) {
  RETURN_IF_ERROR(CheckFieldPath(path, geometry != nullptr));
  const std::string ext = ExtensionOf(path);
  if (ext == ".f64") return WriteRaw(path, values);
  if (ext == ".npy") return WriteNpy(path, "<f8", values);
  if (ext == ".ply") return WriteColouredPly(path, values, *geometry);
  if (ext == ".func.gii") {
    ASSIGN_OR_RETURN(const std::string bytes, GiftiMetricBytes(values));
    return WriteText(path, bytes);
  }
  std::string text = "vertex,distance\n";
  for (size_t i = 0; i < values.size(); ++i)
    absl::StrAppendFormat(&text, "%u,%.17g\n", i, values[i]);
  return WriteText(path, text);
}

absl::Status WriteLabels(const std::string& path, absl::Span<const uint32_t> labels) {
  RETURN_IF_ERROR(CheckLabelPath(path));
  const std::string ext = ExtensionOf(path);
  if (ext == ".u32") return WriteRaw(path, labels);
  if (ext == ".npy") return WriteNpy(path, "<u4", labels);
  std::string text = "vertex,label\n";
  for (size_t i = 0; i < labels.size(); ++i) absl::StrAppend(&text, i, ",", labels[i], "\n");
  return WriteText(path, text);
}

absl::Status WritePolyline(const std::string& path, absl::Span<const Vec3> points) {
  RETURN_IF_ERROR(CheckPolylinePath(path));
  const std::string ext = ExtensionOf(path);
  std::string text;
  if (ext == ".csv") {
    text = "x,y,z\n";
    for (const Vec3& p : points) absl::StrAppendFormat(&text, "%.17g,%.17g,%.17g\n", p.x, p.y, p.z);
  } else if (ext == ".obj") {
    for (const Vec3& p : points)
      absl::StrAppendFormat(&text, "v %.17g %.17g %.17g\n", p.x, p.y, p.z);
    if (points.size() >= 2) {
      text += "l";
      for (size_t i = 1; i <= points.size(); ++i) absl::StrAppend(&text, " ", i);
      text += "\n";
    }
  } else {
    const size_t edges = points.empty() ? 0 : points.size() - 1;
    text = absl::StrFormat(
        "ply\nformat ascii 1.0\nelement vertex %u\nproperty double x\nproperty double y\n"
        "property double z\nelement edge %u\nproperty int vertex1\nproperty int vertex2\n"
        "end_header\n",
        points.size(), edges);
    for (const Vec3& p : points) absl::StrAppendFormat(&text, "%.17g %.17g %.17g\n", p.x, p.y, p.z);
    for (size_t i = 0; i < edges; ++i) absl::StrAppend(&text, i, " ", i + 1, "\n");
  }
  return WriteText(path, text);
}

}  // namespace geodesic
