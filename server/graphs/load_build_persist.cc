// The steps of an operation that touch --graph-dir, each outside the lock:
// Load maps a graph's file (and moves aside one that fails validation),
// Build builds it (a plain graph into a draft of its file, a certified one in
// memory), Persist commits or writes the file. The disk a build takes is
// admitted to --disk-limit as it grows (BuildAdmission), not after.
#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "server/base/log.h"
#include "server/graphs/graph_cache.h"
#include "server/offline/certificate_file.h"

namespace geodesic::server {

std::shared_ptr<const DggGraph> GraphCache::Load(const GraphKey& key, Entry& e, std::string* note,
                                                 std::optional<GraphCertificate>* certificate) {
  absl::StatusOr<std::shared_ptr<const DggGraph>> opened;
  if (key.max_error > 0) {
    auto certified = options_.maker->OpenCertified(e.path, *e.mesh->mesh, key.params, key.max_error,
                                                   GraphFile::Check::kFull);
    if (certified.ok()) {
      *certificate = certified->certificate;
      opened = std::move(certified->graph);
    } else {
      opened = certified.status();
    }
  } else {
    opened = options_.maker->Open(e.path, *e.mesh->mesh, key.params, GraphFile::Check::kFull);
  }
  if (opened.ok()) {
    if (options_.on_file_used) options_.on_file_used(e.path);
    Log(LogLevel::kInfo, "graph_loaded", {{"mesh", e.status.mesh}, {"path", e.path}});
    return *std::move(opened);
  }
  if (absl::IsNotFound(opened.status())) return nullptr;
  // Never serve a file that fails validation or was built otherwise: move
  // it aside (for a post-mortem), rebuild.
  const std::string aside =
      absl::StrFormat("%s.rejected-%d", e.path, absl::ToUnixSeconds(absl::Now()));
  std::error_code ec;
  std::filesystem::rename(e.path, aside, ec);
  // Nor a certificate that was not the file's (or that a rebuild would
  // not replace, were its write to fail).
  if (key.max_error > 0) offline::RemoveCertificate(e.path).IgnoreError();
  *note = absl::StrFormat("rejected %s (%s), rebuilt", e.path, opened.status().message());
  Log(LogLevel::kWarning, "graph_file_rejected",
      {{"mesh", e.status.mesh}, {"path", e.path}, {"error", opened.status().ToString()}});
  return nullptr;
}

namespace {

// The file a plain build keeps its edges in as it makes them
// (GraphFileDraft), so that they take page cache, which the kernel writes
// back and reclaims, instead of the daemon's memory; Persist commits it.
// None without a graph directory; none with pseudo vertices, whose node
// count, which lays the file out, the build decides; none for a certified
// graph, whose builds are several, at epsilons it picks as it goes: it
// stays built in memory and is written whole.
absl::StatusOr<std::optional<GraphFileDraft>> DraftFor(const GraphKey& key, const std::string& path,
                                                       const Mesh& mesh, DggBuildOptions& options) {
  if (path.empty() || key.params.pseudo_vertices || key.max_error > 0) return std::nullopt;
  auto draft = GraphFileDraft::Create(path, mesh.num_vertices());
  if (!draft.ok()) return draft.status();
  draft->AttachTo(options);
  return std::optional<GraphFileDraft>(*std::move(draft));
}

// The disk a build writes while it runs, its draft's edges and the spill
// file of --build-memory-limit: the budget admits each growth before it
// happens, so the directory stays within --disk-limit during the build
// instead of passing it until the file is admitted afterwards. The spill's
// admission is given back when the spill is read back, the edges' when the
// build ends; Persist then admits the file, with the draft counted as on
// disk (BytesToAdmit).
class BuildAdmission {
 public:
  BuildAdmission(DiskBudget* disk, DggBuildOptions& options) : disk_(disk) {
    if (!disk_) return;
    if (options.edge_file.fd >= 0) {
      options.edge_file.admit_growth = [this](uint64_t bytes) -> absl::Status {
        absl::Status room = Admit(edges_, bytes);
        if (room.ok()) return room;
        refused_ = bytes;
        return absl::ResourceExhaustedError(absl::StrFormat(
            "its edges need %u bytes on disk: %s; use a larger epsilon or raise --disk-limit",
            bytes, room.message()));
      };
    }
    options.admit_spill = [this](uint64_t bytes) -> absl::Status {
      absl::Status room = Admit(spill_, bytes);
      if (room.ok()) return room;
      spill_refused_ = bytes;
      return absl::ResourceExhaustedError(absl::StrFormat(
          "its candidate edges past --build-memory-limit need %u bytes of spill file on disk: %s; "
          "raise --build-memory-limit or --disk-limit",
          bytes, room.message()));
    };
  }
  ~BuildAdmission() {
    Admit(edges_, 0).IgnoreError();
    Admit(spill_, 0).IgnoreError();
  }
  BuildAdmission(const BuildAdmission&) = delete;
  BuildAdmission& operator=(const BuildAdmission&) = delete;

  // The edge bytes a refused growth asked for (0: none refused): at least
  // the graph's file size.
  uint64_t refused() const { return refused_; }
  // The same for the spill file.
  uint64_t spill_refused() const { return spill_refused_; }

 private:
  // Makes what is admitted for one file `bytes`: reserves its growth, or
  // gives everything back at 0. Each file's hook is called by one build
  // thread at a time.
  absl::Status Admit(uint64_t& reserved, uint64_t bytes) {
    if (bytes == 0) {
      if (reserved > 0) disk_->Done(reserved, 0);
      reserved = 0;
      return absl::OkStatus();
    }
    if (bytes <= reserved) return absl::OkStatus();
    RETURN_IF_ERROR(disk_->Reserve(bytes - reserved));
    reserved = bytes;
    return absl::OkStatus();
  }

  DiskBudget* const disk_;
  uint64_t edges_ = 0, spill_ = 0;  // bytes reserved for each
  uint64_t refused_ = 0;            // set by the thread that grows the edges, read after
  uint64_t spill_refused_ = 0;      // set by the thread that writes the spill, read after
};

// What the disk budget must admit for a graph file of `bytes`. A draft's
// edges are on disk since its build made them, under a temporary name, which
// the budget's last count of the directory may or may not have seen: it
// counts the directory now, draft included, and admits what the file adds.
uint64_t BytesToAdmit(DiskBudget& disk, uint64_t bytes,
                      const std::optional<GraphFileDraft>& draft) {
  struct stat st;
  if (!draft || !disk.Scan().ok() || ::fstat(draft->edge_file().fd, &st) != 0) return bytes;
  return bytes - std::min<uint64_t>(bytes, st.st_size);
}

}  // namespace

DggBuildOptions GraphCache::BuildOptions(const GraphKey& key, Entry& e) {
  DggBuildOptions options;
  options.params = key.params;
  options.threads = options_.build_threads;
  options.pseudo_vertex_limit = options_.pseudo_vertex_limit;
  options.candidate_memory_limit = options_.build_memory_limit;
  options.spill_dir = options_.graph_dir.empty() ? std::filesystem::temp_directory_path().string()
                                                 : options_.graph_dir;
  auto logged_quarter = std::make_shared<int>(0);  // under mu_
  options.progress = [this, &e, key, logged_quarter](std::string_view phase, double fraction) {
    absl::MutexLock lock(&mu_);
    if (e.status.phase != phase || fraction - e.status.progress >= 0.01 || fraction >= 1) {
      e.status.phase = std::string(phase);
      e.status.progress = fraction;
      ++e.status.version;
    }
    if (static_cast<int>(4 * fraction) > *logged_quarter && fraction < 1) {
      *logged_quarter = static_cast<int>(4 * fraction);
      Log(LogLevel::kInfo, "graph_build_progress",
          {{"mesh", key.mesh},
           {"eps", key.params.epsilon},
           {"percent", 25 * *logged_quarter},
           {"phase", std::string(phase)}});
    }
    return !e.cancel.load();
  };
  return options;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphCache::BuildCertified(
    const GraphKey& key, Entry& e, const DggBuildOptions& options,
    std::optional<GraphCertificate>* certificate) {
  // Build, check against the exact engine, rebuild tighter if it missed:
  // the phases of each build and then "check", the fraction of each
  // build-and-check; later builds say which they are.
  CertifyOptions certify;
  certify.build = options;
  certify.build.progress = nullptr;
  certify.progress = [&](uint32_t build, std::string_view phase, double fraction) {
    const std::string name =
        build <= 1 ? std::string(phase) : absl::StrFormat("%s (build %u)", phase, build);
    return options.progress(name, fraction);
  };
  certify.cancelled = [&e] { return e.cancel.load(); };
  auto certified = options_.maker->BuildCertified(e.mesh->mesh, key.max_error, certify);
  if (!certified.ok()) return certified.status();
  *certificate = certified->certificate;
  Log(LogLevel::kInfo, "graph_certified",
      {{"mesh", key.mesh},
       {"max_error", key.max_error},
       {"eps", certified->certificate.epsilon},
       {"measured_max_error", certified->certificate.measured_max_error},
       {"measured_mean_error", certified->certificate.measured_mean_error},
       {"sources", certified->certificate.sources},
       {"builds", certified->certificate.builds}});
  return std::move(certified->graph);
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphCache::Build(
    const GraphKey& key, Entry& e, std::optional<GraphFileDraft>* draft,
    std::optional<GraphCertificate>* certificate) {
  Log(LogLevel::kInfo, "graph_build_started",
      {{"mesh", key.mesh}, {"params", DescribeParams(key.params)}, {"max_error", key.max_error}});
  DggBuildOptions options = BuildOptions(key, e);
  // A directory that cannot take the file fails the graph before its build.
  auto drafted = DraftFor(key, e.path, *e.mesh->mesh, options);
  if (!drafted.ok()) return drafted.status();
  if (drafted->has_value()) draft->emplace(*std::move(*drafted));
  BuildAdmission admission(options_.disk, options);
  ++builds_started_;
  ++builds_running_;
  const auto start = std::chrono::steady_clock::now();
  absl::StatusOr<std::shared_ptr<const DggGraph>> built;
  if (key.max_error > 0) {
    built = BuildCertified(key, e, options, certificate);
  } else {
    built = options_.maker->Build(*e.mesh->mesh, options);
    if (*draft && absl::IsResourceExhausted(built.status())) {
      built = absl::ResourceExhaustedError(
          absl::StrFormat("building %s: %s", e.path, built.status().message()));
    }
  }
  if (admission.refused() > 0 || admission.spill_refused() > 0) {
    // Asked again, the graph is refused at once for those sizes (Admit).
    absl::MutexLock lock(&mu_);
    KnownBytes& known = known_bytes_[KnownBytesOf(*e.mesh, key.params, key.max_error)];
    if (admission.refused() > 0) known.file = admission.refused();
    if (admission.spill_refused() > 0) known.spill = admission.spill_refused();
  }
  --builds_running_;
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (built.ok()) {
    Log(LogLevel::kInfo, "graph_build_finished",
        {{"mesh", key.mesh},
         {"eps", key.params.epsilon},
         {"seconds", seconds},
         {"edges", (*built)->num_directed_edges() / 2},
         {"bytes", (*built)->byte_size()}});
  }
  return built;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphCache::Persist(
    const GraphKey& key, Entry& e, std::shared_ptr<const DggGraph> graph,
    std::optional<GraphFileDraft> draft, const std::optional<GraphCertificate>& certificate,
    std::string* note) {
  // The arrays are the file but for its header and alignment.
  const uint64_t bytes = graph->byte_size();
  {
    absl::MutexLock lock(&mu_);
    known_bytes_[KnownBytesOf(*e.mesh, key.params, key.max_error)].file = bytes;
  }
  const bool drafted = draft.has_value();
  const uint64_t admitted = options_.disk ? BytesToAdmit(*options_.disk, bytes, draft) : bytes;
  if (options_.disk) {
    if (absl::Status room = options_.disk->Reserve(admitted); !room.ok()) {
      Log(LogLevel::kWarning, "graph_write_refused",
          {{"mesh", key.mesh}, {"path", e.path}, {"error", room.ToString()}});
      draft.reset();
      if (drafted) options_.disk->Scan().IgnoreError();  // without the draft now
      return absl::ResourceExhaustedError(absl::StrFormat(
          "the graph was built but its file %s was not kept: %s; use a larger epsilon or raise "
          "--disk-limit",
          e.path, room.message()));
    }
  }
  absl::Status written = drafted ? options_.maker->Finish(*std::move(draft), *graph)
                                 : options_.maker->Write(*graph, e.path);
  if (options_.disk && drafted) {
    // The draft became the file or went: the directory says which.
    const bool scanned = options_.disk->Scan().ok();
    options_.disk->Done(admitted, scanned || !written.ok() ? 0 : admitted);
  } else if (options_.disk) {
    std::error_code ec;
    const uint64_t on_disk = written.ok() ? std::filesystem::file_size(e.path, ec) : 0;
    options_.disk->Done(bytes, ec ? bytes : on_disk);
  }
  if (!written.ok()) {
    Log(LogLevel::kWarning, "graph_write_failed",
        {{"mesh", key.mesh}, {"path", e.path}, {"error", written.ToString()}});
    // A graph built into its file is served from that file or not at all:
    // the directory could not hold it.
    if (drafted) {
      return absl::Status(written.code(),
                          absl::StrFormat("the graph was built but its file %s was not kept: %s",
                                          e.path, written.message()));
    }
    *note = absl::StrFormat("graph kept in memory only: %s", written.message());
    return graph;
  }
  if (certificate) {
    // Without its sidecar the file would be rebuilt after a restart, not
    // believed: the graph is still served, from memory or its file.
    if (absl::Status c = options_.maker->WriteCertificate(*graph, e.path, *certificate); !c.ok()) {
      *note = absl::StrFormat("certificate not written beside the file: %s", c.message());
      Log(LogLevel::kWarning, "graph_certificate_write_failed",
          {{"mesh", key.mesh}, {"path", e.path}, {"error", c.ToString()}});
    }
  }
  if (options_.on_file_used) options_.on_file_used(e.path);
  // Serve the file mapped as a restart would map it, not the graph the
  // build returned: read-only, its pages the page cache's, and counted the
  // same (mapped, the file's bytes) whether built here or loaded. A draft's
  // graph has only its edges in the file (a writable mapping of it) and
  // the rest in memory, which goes with it. A certified graph's epsilon is
  // its build's, not its key's.
  auto mapped =
      options_.maker->Open(e.path, *e.mesh->mesh, graph->params(), GraphFile::Check::kHeader);
  return mapped.ok() ? *std::move(mapped) : graph;
}

}  // namespace geodesic::server
