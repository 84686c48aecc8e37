#include "server/store/disk_budget.h"

#include <fcntl.h>
#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <system_error>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "core/dgg/graph_file.h"
#include "core/mesh/mesh_snapshot.h"
#include "core/query/exact_landmarks_file.h"
#include "server/store/graph_files.h"

namespace geodesic::server {
namespace {

namespace fs = std::filesystem;

struct Candidate {
  std::string name;
  uint64_t bytes;
  fs::file_time_type used;
  FileRole role;
};

// Space held for the catalog's writes, not part of what the directory
// stores.
bool Counted(const fs::directory_entry& entry) {
  return entry.path().filename() != Catalog::kReserveFileName;
}

bool Removable(const std::string& name) {
  return absl::EndsWith(name, ".dgg") || absl::EndsWith(name, ".mesh");
}

// A certified graph's certificate (server/offline/certificate_file.h) goes
// with its graph: kept alone it would certify nothing, and left behind it
// would be refused beside a graph rebuilt under the name. So do the exact
// landmarks kept beside it (core/query/exact_landmarks_file.h): another
// graph of the mesh that read them keeps a copy of its own.
std::vector<std::string> SidecarsOf(const std::string& name) {
  if (!absl::EndsWith(name, ".dgg")) return {};
  return {name + ".certificate.json", ExactLandmarksPathOf(name)};
}

}  // namespace

CatalogFiles FilesOf(const CatalogState& state) {
  CatalogFiles files;
  std::map<std::string, uint64_t> fingerprints;
  for (const CatalogMesh& m : state.meshes) {
    files.catalogued.insert(MeshSnapshotName(m.source_hash));
    if (m.source == "upload") files.uploads.insert(MeshSnapshotName(m.source_hash));
    fingerprints[m.name] = m.fingerprint;
  }
  for (const CatalogGraph& g : state.graphs) {
    if (auto it = fingerprints.find(g.mesh); it != fingerprints.end()) {
      files.catalogued.insert(CachedGraphFileName(it->second, g.params, g.max_error));
    }
  }
  return files;
}

FileRole GraphDirFileRole(const std::string& dir, const std::string& name,
                          const CatalogFiles& files, bool in_use, std::chrono::seconds grace) {
  if (in_use || files.uploads.contains(name)) return FileRole::kInUse;
  // A file the catalog names is finished and known, whatever its age: the
  // grace would otherwise make every young graph unremovable, and a build
  // needing the room fail for a graph nobody is using.
  if (files.catalogued.contains(name)) return FileRole::kCataloged;
  std::error_code ec;
  const auto written = fs::last_write_time(fs::path(dir) / name, ec);
  if (ec || fs::file_time_type::clock::now() - written < grace) return FileRole::kInUse;
  return FileRole::kSpare;
}

absl::StatusOr<uint64_t> DirectoryBytes(const std::string& dir) {
  std::error_code ec;
  uint64_t total = 0;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec)) {
    std::error_code file_ec;
    // A file removed between listing and stat (another replica's cleanup)
    // simply no longer counts.
    if (entry.is_regular_file(file_ec) && Counted(entry)) {
      const uint64_t size = entry.file_size(file_ec);
      if (!file_ec) total += size;
    }
  }
  if (ec) {
    return absl::InternalError(absl::StrFormat("cannot list %s: %s", dir, ec.message()));
  }
  return total;
}

absl::StatusOr<DiskReport> EnforceDiskLimit(
    const std::string& dir, uint64_t limit,
    const std::function<FileRole(const std::string&)>& role) {
  DiskReport report;
  std::vector<Candidate> candidates;
  std::error_code ec;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir, ec)) {
    std::error_code file_ec;
    if (!entry.is_regular_file(file_ec) || !Counted(entry)) continue;
    const uint64_t bytes = entry.file_size(file_ec);
    if (file_ec) continue;
    report.bytes_before += bytes;
    const std::string name = entry.path().filename();
    if (!Removable(name)) continue;
    const fs::file_time_type used = entry.last_write_time(file_ec);
    if (file_ec) continue;
    candidates.push_back({name, bytes, used, role(name)});
  }
  if (ec) return absl::InternalError(absl::StrFormat("cannot list %s: %s", dir, ec.message()));
  report.bytes_after = report.bytes_before;
  if (limit == 0 || report.bytes_before <= limit) return report;

  // Spare files before catalogued ones, each group least recently used first.
  std::erase_if(candidates, [](const Candidate& c) { return c.role == FileRole::kInUse; });
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
    const bool a_spare = a.role == FileRole::kSpare, b_spare = b.role == FileRole::kSpare;
    if (a_spare != b_spare) return a_spare;
    if (a.used != b.used) return a.used < b.used;
    return a.name < b.name;
  });
  for (const Candidate& c : candidates) {
    if (report.bytes_after <= limit) break;
    // Asked again just before removing: a file may have come into use since
    // the listing (a graph mapped meanwhile).
    if (role(c.name) == FileRole::kInUse) continue;
    std::error_code remove_ec;
    if (fs::remove(fs::path(dir) / c.name, remove_ec)) {
      report.removed.push_back(c.name);
      report.bytes_after -= c.bytes;
      for (const std::string& sidecar : SidecarsOf(c.name)) {
        std::error_code sidecar_ec;
        const fs::path sidecar_path = fs::path(dir) / sidecar;
        const uint64_t sidecar_bytes = fs::file_size(sidecar_path, sidecar_ec);
        if (!sidecar_ec && fs::remove(sidecar_path, sidecar_ec)) {
          report.removed.push_back(sidecar);
          report.bytes_after -= std::min(sidecar_bytes, report.bytes_after);
        }
      }
    } else if (remove_ec) {
      return absl::InternalError(
          absl::StrFormat("cannot remove %s/%s: %s", dir, c.name, remove_ec.message()));
    }
  }
  report.over_limit = report.bytes_after > limit;
  return report;
}

DiskBudget::DiskBudget(std::string dir, uint64_t limit,
                       std::function<absl::StatusOr<uint64_t>(uint64_t target)> evict)
    : dir_(std::move(dir)), limit_(limit), evict_(std::move(evict)) {}

absl::Status DiskBudget::Scan() {
  auto bytes = DirectoryBytes(dir_);
  if (!bytes.ok()) return bytes.status();
  Set(*bytes);
  return absl::OkStatus();
}

absl::Status DiskBudget::Reserve(uint64_t bytes) {
  absl::MutexLock lock(&mu_);
  auto fits = [&] {
    return limit_ == 0 || (bytes <= limit_ && on_disk_ + pending_ <= limit_ - bytes);
  };
  if (!fits() && evict_ && bytes + pending_ <= limit_) {
    // Under the lock: two writes admitted at once must not both count on
    // the same evicted bytes.
    auto left = evict_(limit_ - pending_ - bytes);
    if (left.ok()) on_disk_ = *left;
  }
  if (!fits()) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "writing %u bytes would take %s past --disk-limit: it holds %u bytes (%u more being "
        "written) of %u, and nothing more may be evicted",
        bytes, dir_, on_disk_, pending_, limit_));
  }
  pending_ += bytes;
  return absl::OkStatus();
}

void DiskBudget::Done(uint64_t reserved, uint64_t written) {
  absl::MutexLock lock(&mu_);
  pending_ -= std::min(pending_, reserved);
  on_disk_ += written;
}

void DiskBudget::Set(uint64_t bytes) {
  absl::MutexLock lock(&mu_);
  on_disk_ = bytes;
}

uint64_t DiskBudget::used() const {
  absl::MutexLock lock(&mu_);
  return on_disk_ + pending_;
}

void MarkFileUsed(const std::string& path) {
  const struct timespec now[2] = {{0, UTIME_NOW}, {0, UTIME_NOW}};
  ::utimensat(AT_FDCWD, path.c_str(), now, 0);
}

}  // namespace geodesic::server
