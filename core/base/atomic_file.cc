#include "core/base/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <random>

#include "absl/status/statusor.h"
#include "absl/strings/str_format.h"

namespace geodesic {

absl::Status ErrnoStatus(const std::string& what, const std::string& path) {
  int e = errno;
  std::string message = absl::StrFormat("%s %s: %s", what, path, std::strerror(e));
  if (e == ENOENT) return absl::NotFoundError(message);
  if (e == EACCES || e == EPERM || e == EROFS) return absl::PermissionDeniedError(message);
  if (e == ENOSPC || e == EDQUOT) return absl::ResourceExhaustedError(message);
  return absl::InternalError(message);
}

bool IsAtomicTemporaryName(const std::string& file_name) {
  // Matches the name Create() makes, from the end: ".tmp." digits "." hex.
  const size_t dot = file_name.rfind('.');
  if (dot == std::string::npos || dot + 1 == file_name.size()) return false;
  for (size_t i = dot + 1; i < file_name.size(); ++i) {
    if (!std::isxdigit(static_cast<unsigned char>(file_name[i]))) return false;
  }
  const size_t pid_dot = file_name.rfind('.', dot - 1);
  if (pid_dot == std::string::npos || pid_dot + 1 == dot || pid_dot < 4) return false;
  for (size_t i = pid_dot + 1; i < dot; ++i) {
    if (!std::isdigit(static_cast<unsigned char>(file_name[i]))) return false;
  }
  return file_name.compare(pid_dot - 4, 4, ".tmp") == 0 && pid_dot > 4;
}

void ForEachFileOlderThan(
    const std::string& dir, std::chrono::seconds min_age,
    const std::function<void(const std::string& name, const std::filesystem::path& path)>& visit) {
  std::error_code ec;
  const auto now = std::filesystem::file_time_type::clock::now();
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    std::error_code file_ec;
    if (!entry.is_regular_file(file_ec)) continue;
    const auto written = entry.last_write_time(file_ec);
    if (file_ec || now - written < min_age) continue;
    visit(entry.path().filename().string(), entry.path());
  }
}

std::vector<std::string> RemoveStaleTemporaries(const std::string& dir,
                                                std::chrono::seconds min_age) {
  std::vector<std::string> removed;
  ForEachFileOlderThan(dir, min_age, [&](const std::string& name, const auto& path) {
    std::error_code ec;
    if (IsAtomicTemporaryName(name) && std::filesystem::remove(path, ec)) removed.push_back(name);
  });
  return removed;
}

absl::StatusOr<AtomicFileWriter> AtomicFileWriter::Create(const std::string& path) {
  // The temporary name carries pid and a random tag so that concurrent
  // writers of one destination never share a temporary file.
  std::string tmp = absl::StrFormat("%s.tmp.%d.%x", path, getpid(), std::random_device{}());
  int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return ErrnoStatus("cannot create", tmp);
  return AtomicFileWriter(path, std::move(tmp), fd);
}

AtomicFileWriter::AtomicFileWriter(AtomicFileWriter&& other) noexcept
    : path_(std::move(other.path_)),
      tmp_(std::move(other.tmp_)),
      fd_(std::exchange(other.fd_, -1)),
      written_(other.written_) {}

AtomicFileWriter::~AtomicFileWriter() { Abandon(); }

void AtomicFileWriter::Abandon() {
  if (fd_ < 0) return;
  ::close(fd_);
  ::unlink(tmp_.c_str());
  fd_ = -1;
}

absl::Status AtomicFileWriter::Append(const void* data, size_t bytes) {
  if (fd_ < 0) return absl::FailedPreconditionError("write to a closed file " + path_);
  const char* p = static_cast<const char*>(data);
  while (bytes > 0) {
    ssize_t n = ::write(fd_, p, bytes);
    if (n < 0) {
      if (errno == EINTR) continue;
      absl::Status s = ErrnoStatus("cannot write", tmp_);
      Abandon();
      return s;
    }
    p += n;
    bytes -= n;
    written_ += n;
  }
  return absl::OkStatus();
}

absl::Status AtomicFileWriter::PadTo(size_t alignment) {
  static const char kZeros[4096] = {};
  size_t pad = (alignment - written_ % alignment) % alignment;
  while (pad > 0) {
    const size_t n = std::min(pad, sizeof(kZeros));
    if (absl::Status s = Append(kZeros, n); !s.ok()) return s;
    pad -= n;
  }
  return absl::OkStatus();
}

absl::Status AtomicFileWriter::SkipTo(uint64_t offset) {
  if (fd_ < 0) return absl::FailedPreconditionError("write to a closed file " + path_);
  if (::lseek(fd_, static_cast<off_t>(offset), SEEK_SET) < 0) {
    absl::Status s = ErrnoStatus("cannot seek in", tmp_);
    Abandon();
    return s;
  }
  written_ = offset;
  return absl::OkStatus();
}

absl::Status AtomicFileWriter::Commit() && {
  if (fd_ < 0) return absl::FailedPreconditionError("commit of a closed file " + path_);
  // A region mapped and grown past what was finally kept ends the file early.
  if (::ftruncate(fd_, static_cast<off_t>(written_)) != 0) {
    absl::Status s = ErrnoStatus("cannot size", tmp_);
    Abandon();
    return s;
  }
  if (::fsync(fd_) != 0) {
    absl::Status s = ErrnoStatus("cannot fsync", tmp_);
    Abandon();
    return s;
  }
  const int fd = std::exchange(fd_, -1);
  if (::close(fd) != 0) {
    absl::Status s = ErrnoStatus("cannot close", tmp_);
    ::unlink(tmp_.c_str());
    return s;
  }
  if (::rename(tmp_.c_str(), path_.c_str()) != 0) {
    absl::Status s = ErrnoStatus("cannot rename into", path_);
    ::unlink(tmp_.c_str());
    return s;
  }
  // The rename is durable only once the directory entry is.
  std::filesystem::path target(path_);
  std::filesystem::path dir = target.has_parent_path() ? target.parent_path() : ".";
  int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
  return absl::OkStatus();
}

}  // namespace geodesic
