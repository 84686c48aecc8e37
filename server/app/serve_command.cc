// geodesicd serve: the daemon.
#include <malloc.h>

#include <optional>
#include <utility>

#include "server/app/daemon.h"
#include "server/app/serve.h"
#include "server/app/serve_options.h"

namespace geodesic::server {

int RunServe(int argc, char** argv) {
  // Buffers of a megabyte or more (a field's distances, a long query's
  // records, a mesh being loaded) get mappings of their own, returned to the
  // system when freed. By default glibc raises this threshold after the first
  // such free, then serves them from per-thread arenas that keep the memory,
  // which --memory-limit does not count (BENCHMARKS.md, "Memory-bounded build
  // and serving").
  mallopt(M_MMAP_THRESHOLD, 1 << 20);
  ServeOptions options;
  if (std::optional<int> rc = ParseServeOptions(argc, argv, &options)) return *rc;
  Daemon daemon(std::move(options));
  if (int rc = daemon.Start(); rc != 0) return rc;
  if (int rc = daemon.Restore(); rc != 0) return rc;
  daemon.Serve();
  daemon.Drain();
  return 0;
}

}  // namespace geodesic::server
