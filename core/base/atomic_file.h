// Files that appear whole or not at all.
//
// AtomicFileWriter writes to a temporary file beside the destination, and
// Commit() fsyncs it, renames it over the destination and fsyncs the
// directory. A reader (or a daemon restarted after kill -9) sees the old file
// or the complete new one, never a partial one; an existing file is replaced
// by a new inode, never rewritten in place, so mappings of it stay valid.
#ifndef GEODESIC_CORE_BASE_ATOMIC_FILE_H_
#define GEODESIC_CORE_BASE_ATOMIC_FILE_H_

#include <chrono>
#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace geodesic {

class AtomicFileWriter {
 public:
  // Creates the temporary file. Errors name the path and the errno text;
  // a full disk is RESOURCE_EXHAUSTED, a missing directory NOT_FOUND.
  static absl::StatusOr<AtomicFileWriter> Create(const std::string& path);

  AtomicFileWriter(AtomicFileWriter&& other) noexcept;
  AtomicFileWriter& operator=(AtomicFileWriter&&) = delete;
  // Without Commit(), the temporary file is removed.
  ~AtomicFileWriter();

  absl::Status Append(const void* data, size_t bytes);
  // Pads with zero bytes up to a multiple of `alignment`.
  absl::Status PadTo(size_t alignment);
  // Appends from `offset` on, leaving the bytes before it as they are: for a
  // region already written through a mapping of fd().
  absl::Status SkipTo(uint64_t offset);
  uint64_t bytes_written() const { return written_; }
  // Open for reading and writing, so that a part of the file may be mapped
  // shared and written in place. Commit() cuts the file at bytes_written().
  int fd() const { return fd_; }
  absl::Status Commit() &&;

 private:
  AtomicFileWriter(std::string path, std::string tmp, int fd)
      : path_(std::move(path)), tmp_(std::move(tmp)), fd_(fd) {}
  void Abandon();

  std::string path_, tmp_;
  int fd_ = -1;
  uint64_t written_ = 0;
};

// Whether `file_name` is an AtomicFileWriter's temporary name
// ("<destination>.tmp.<pid>.<hex tag>"), of any destination.
bool IsAtomicTemporaryName(const std::string& file_name);

// Removes the temporary files in `dir` (not recursively) that writers
// killed mid-write left behind, those last modified at least `min_age` ago:
// a younger one may belong to a live writer (another process sharing the
// directory). Returns the names removed; best effort.
// Calls visit(name, path) for every file directly in `dir` last written at
// least `min_age` ago (start-up clean-ups of what killed writers left).
void ForEachFileOlderThan(
    const std::string& dir, std::chrono::seconds min_age,
    const std::function<void(const std::string& name, const std::filesystem::path& path)>& visit);
std::vector<std::string> RemoveStaleTemporaries(const std::string& dir,
                                                std::chrono::seconds min_age);

// The errno of the last failed call as a status naming `what` and `path`.
absl::Status ErrnoStatus(const std::string& what, const std::string& path);

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_ATOMIC_FILE_H_
