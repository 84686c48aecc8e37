#include "core/query/matrix_files.h"

#include <fcntl.h>
#include <unistd.h>
#include <zip.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/synchronization/mutex.h"
#include "core/base/status.h"
#include "core/query/result_files.h"

namespace geodesic {
namespace {

// What a member of the archive holds: bytes in memory, or a whole scratch
// file.
struct ZipMember {
  const char* name;
  const std::string* bytes = nullptr;
  int fd = -1;
};

absl::Status WriteAt(int fd, const void* data, size_t bytes, uint64_t offset,
                     const std::string& path) {
  const char* p = static_cast<const char*>(data);
  while (bytes > 0) {
    const ssize_t n = ::pwrite(fd, p, bytes, static_cast<off_t>(offset));
    if (n < 0) {
      if (errno == EINTR) continue;
      return ErrnoStatus("cannot write", path);
    }
    p += n;
    bytes -= n;
    offset += n;
  }
  return absl::OkStatus();
}

// `values` as `dtype`'s bytes: the doubles themselves, or their float32
// roundings (to nearest) made in `narrow`.
absl::Span<const char> AsDtype(absl::Span<const double> values, MatrixDtype dtype,
                               std::vector<float>& narrow) {
  if (dtype == MatrixDtype::kFloat64) {
    return {reinterpret_cast<const char*>(values.data()), values.size() * sizeof(double)};
  }
  narrow.assign(values.begin(), values.end());
  return {reinterpret_cast<const char*>(narrow.data()), narrow.size() * sizeof(float)};
}

template <typename T>
void AppendBytes(std::string& out, T value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof value);
}

absl::Status ZipError(zip_t* zip, const std::string& what, const std::string& path) {
  absl::Status s = absl::InternalError(absl::StrFormat("%s %s: %s", what, path, zip_strerror(zip)));
  zip_discard(zip);
  return s;
}

zip_source_t* SourceOf(zip_t* zip, const ZipMember& member) {
  if (member.bytes) return zip_source_buffer(zip, member.bytes->data(), member.bytes->size(), 0);
  // The archive reads the file through its own stream, and closes it. The
  // stream shares the writer's file position, and libzip reads a whole file
  // from wherever that is: back to the start.
  const int copy = ::dup(member.fd);
  if (copy < 0) return nullptr;
  FILE* file = ::fdopen(copy, "rb");
  if (!file) {
    ::close(copy);
    return nullptr;
  }
  std::rewind(file);
  zip_source_t* source = zip_source_filep(zip, file, 0, -1);
  if (!source) std::fclose(file);
  return source;
}

// Writes the archive with libzip, which builds it in a temporary file beside
// `path` and renames it into place on success. Members are stored, not
// deflated: NumPy's own np.savez stores them too, distances' mantissas
// barely compress, and stored members keep the archive a straight copy of
// the scratch files rather than a compression pass over all of them.
absl::Status WriteZip(const std::string& path, std::initializer_list<ZipMember> members) {
  int error = 0;
  zip_t* zip = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &error);
  if (!zip) {
    zip_error_t e;
    zip_error_init_with_code(&e, error);
    absl::Status s =
        absl::InternalError(absl::StrFormat("cannot create %s: %s", path, zip_error_strerror(&e)));
    zip_error_fini(&e);
    return s;
  }
  for (const ZipMember& member : members) {
    zip_source_t* source = SourceOf(zip, member);
    if (!source) return ZipError(zip, absl::StrCat("cannot read ", member.name, " for"), path);
    const zip_int64_t index = zip_file_add(zip, member.name, source, ZIP_FL_OVERWRITE);
    if (index < 0) {
      zip_source_free(source);
      return ZipError(zip, absl::StrCat("cannot add ", member.name, " to"), path);
    }
    if (zip_set_file_compression(zip, index, ZIP_CM_STORE, 0) < 0) {
      return ZipError(zip, "cannot store members in", path);
    }
  }
  if (zip_close(zip) < 0) return ZipError(zip, "cannot write", path);
  return absl::OkStatus();
}

// A 1-D array's preamble is 128 bytes whatever its length (up to 20
// digits), so a member file starts with a placeholder that its final
// preamble overwrites in place once the count is known.
absl::Status FinishMember(AtomicFileWriter& member, const char* dtype, uint64_t count,
                          const std::string& path) {
  const std::string preamble = NpyPreamble(dtype, {count});
  if (preamble.size() != NpyPreamble(dtype, {0}).size()) {
    return absl::InternalError("a .npy preamble changed length with its count");
  }
  return WriteAt(member.fd(), preamble.data(), preamble.size(), 0, path);
}

// CSR's indptr as scipy holds it: int32 while the entries fit, else int64.
std::string IndptrNpy(const std::vector<uint64_t>& row_starts) {
  const bool wide = row_starts.back() > uint64_t{std::numeric_limits<int32_t>::max()};
  std::string bytes = NpyPreamble(wide ? "<i8" : "<i4", {row_starts.size()});
  for (uint64_t start : row_starts) {
    if (wide) {
      AppendBytes(bytes, static_cast<int64_t>(start));
    } else {
      AppendBytes(bytes, static_cast<int32_t>(start));
    }
  }
  return bytes;
}

}  // namespace

const char* NpyDescr(MatrixDtype dtype) { return dtype == MatrixDtype::kFloat32 ? "<f4" : "<f8"; }

size_t BytesPerEntry(MatrixDtype dtype) {
  return dtype == MatrixDtype::kFloat32 ? sizeof(float) : sizeof(double);
}

// Asks the kernel, from a thread of its own, to start writing a file's dirty
// pages out each time another kEvery bytes have been written to it: the
// writers never wait on the disk, and a large file's fsync finds most of it
// written. (The kernel alone starts only at a share of memory, or after half
// a minute.) Errors are left to the fsync.
class BackgroundWriteOut {
 public:
  explicit BackgroundWriteOut(int fd) : fd_(fd), thread_([this] { Run(); }) {}
  ~BackgroundWriteOut() {
    {
      absl::MutexLock lock(&mu_);
      stop_ = true;
    }
    thread_.join();
  }

  void Wrote(uint64_t bytes) {
    absl::MutexLock lock(&mu_);
    pending_ += bytes;
  }

 private:
  static constexpr uint64_t kEvery = uint64_t{64} << 20;

  void Run() {
    mu_.Lock();
    while (true) {
      mu_.Await(absl::Condition(
          +[](BackgroundWriteOut* w) { return w->stop_ || w->pending_ >= kEvery; }, this));
      if (stop_) break;
      pending_ = 0;
      mu_.Unlock();
      ::sync_file_range(fd_, 0, 0, SYNC_FILE_RANGE_WRITE);
      mu_.Lock();
    }
    mu_.Unlock();
  }

  const int fd_;
  absl::Mutex mu_;
  uint64_t pending_ ABSL_GUARDED_BY(mu_) = 0;
  bool stop_ ABSL_GUARDED_BY(mu_) = false;
  std::thread thread_;
};

DenseMatrixFile::DenseMatrixFile(std::string path, AtomicFileWriter file, uint64_t data_offset,
                                 uint64_t cols, MatrixDtype dtype)
    : path_(std::move(path)),
      file_(std::move(file)),
      data_offset_(data_offset),
      cols_(cols),
      dtype_(dtype),
      write_out_(std::make_unique<BackgroundWriteOut>(file_.fd())) {}
DenseMatrixFile::DenseMatrixFile(DenseMatrixFile&&) noexcept = default;
DenseMatrixFile::~DenseMatrixFile() = default;

absl::StatusOr<DenseMatrixFile> DenseMatrixFile::Create(const std::string& path, uint64_t rows,
                                                        uint64_t cols, MatrixDtype dtype) {
  RETURN_IF_ERROR(CheckMatrixPath(path, false));
  const uint64_t row_bytes = cols * BytesPerEntry(dtype);
  if (cols > 0 && rows > std::numeric_limits<int64_t>::max() / 2 / row_bytes) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: a %u x %u matrix is too large for a file", path, rows, cols));
  }
  ASSIGN_OR_RETURN(AtomicFileWriter file, AtomicFileWriter::Create(path));
  const std::string preamble = NpyPreamble(NpyDescr(dtype), {rows, cols});
  RETURN_IF_ERROR(file.Append(preamble.data(), preamble.size()));
  // The whole size at once: rows then land at their offsets in any order.
  const uint64_t size = preamble.size() + rows * row_bytes;
  if (::ftruncate(file.fd(), static_cast<off_t>(size)) != 0) {
    return ErrnoStatus("cannot size", path);
  }
  RETURN_IF_ERROR(file.SkipTo(size));
  return DenseMatrixFile(path, std::move(file), preamble.size(), cols, dtype);
}

absl::Status DenseMatrixFile::CheckColumns(size_t values) const {
  if (values == cols_) return absl::OkStatus();
  return absl::InternalError(
      absl::StrFormat("matrix row of %u values for %u columns", values, cols_));
}

absl::Status DenseMatrixFile::WriteRowBytes(uint64_t i, absl::Span<const char> bytes) const {
  RETURN_IF_ERROR(WriteAt(file_.fd(), bytes.data(), bytes.size(),
                          data_offset_ + i * cols_ * BytesPerEntry(dtype_), path_));
  write_out_->Wrote(bytes.size());
  return absl::OkStatus();
}

absl::Status DenseMatrixFile::WriteRow(uint64_t i, absl::Span<const double> row) const {
  RETURN_IF_ERROR(CheckColumns(row.size()));
  std::vector<float> narrow;
  return WriteRowBytes(i, AsDtype(row, dtype_, narrow));
}

absl::Status DenseMatrixFile::WriteRow(uint64_t i, absl::Span<const float> row) const {
  RETURN_IF_ERROR(CheckColumns(row.size()));
  if (dtype_ != MatrixDtype::kFloat32) {
    return absl::InternalError(absl::StrFormat("%s: a float32 row for a float64 matrix", path_));
  }
  return WriteRowBytes(i, {reinterpret_cast<const char*>(row.data()), row.size() * sizeof(float)});
}

absl::StatusOr<uint64_t> DenseMatrixFile::Commit() && {
  write_out_.reset();  // before the file closes
  const uint64_t size = file_.bytes_written();
  RETURN_IF_ERROR(std::move(file_).Commit());
  return size;
}

SparseMatrixFile::SparseMatrixFile(std::string path, uint64_t rows, uint64_t cols,
                                   MatrixDtype dtype, AtomicFileWriter indices,
                                   AtomicFileWriter data)
    : path_(std::move(path)),
      rows_(rows),
      cols_(cols),
      dtype_(dtype),
      indices_(std::move(indices)),
      data_(std::move(data)),
      row_starts_{0} {}

absl::StatusOr<SparseMatrixFile> SparseMatrixFile::Create(const std::string& path, uint64_t rows,
                                                          uint64_t cols, MatrixDtype dtype) {
  RETURN_IF_ERROR(CheckMatrixPath(path, true));
  if (cols > uint64_t{std::numeric_limits<int32_t>::max()}) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: %u columns do not fit scipy's int32 indices", path, cols));
  }
  // Scratch files, never committed: their destructors remove them.
  ASSIGN_OR_RETURN(AtomicFileWriter indices, AtomicFileWriter::Create(path + ".indices"));
  ASSIGN_OR_RETURN(AtomicFileWriter data, AtomicFileWriter::Create(path + ".data"));
  const std::string indices_preamble = NpyPreamble("<i4", {0});
  const std::string data_preamble = NpyPreamble(NpyDescr(dtype), {0});
  RETURN_IF_ERROR(indices.Append(indices_preamble.data(), indices_preamble.size()));
  RETURN_IF_ERROR(data.Append(data_preamble.data(), data_preamble.size()));
  return SparseMatrixFile(path, rows, cols, dtype, std::move(indices), std::move(data));
}

absl::Status SparseMatrixFile::AppendRow(absl::Span<const int32_t> columns,
                                         absl::Span<const double> values) {
  if (columns.size() != values.size() || row_starts_.size() > rows_) {
    return absl::InternalError("sparse matrix row does not fit the matrix");
  }
  RETURN_IF_ERROR(indices_.Append(columns.data(), columns.size() * sizeof(int32_t)));
  std::vector<float> narrow;
  const absl::Span<const char> bytes = AsDtype(values, dtype_, narrow);
  RETURN_IF_ERROR(data_.Append(bytes.data(), bytes.size()));
  row_starts_.push_back(row_starts_.back() + columns.size());
  return absl::OkStatus();
}

absl::StatusOr<uint64_t> SparseMatrixFile::Commit() && {
  if (row_starts_.size() != rows_ + 1) {
    return absl::InternalError(
        absl::StrFormat("%s: %u of %u rows written", path_, row_starts_.size() - 1, rows_));
  }
  RETURN_IF_ERROR(FinishMember(indices_, "<i4", nonzeros(), path_));
  RETURN_IF_ERROR(FinishMember(data_, NpyDescr(dtype_), nonzeros(), path_));
  const std::string indptr = IndptrNpy(row_starts_);
  const std::string format = NpyPreamble("|S3", {}) + "csr";
  std::string shape = NpyPreamble("<i8", {2});
  for (uint64_t extent : {rows_, cols_}) AppendBytes(shape, static_cast<int64_t>(extent));
  // The members in the order scipy.sparse.save_npz writes them.
  RETURN_IF_ERROR(WriteZip(path_, {{"indices.npy", nullptr, indices_.fd()},
                                   {"indptr.npy", &indptr},
                                   {"format.npy", &format},
                                   {"shape.npy", &shape},
                                   {"data.npy", nullptr, data_.fd()}}));
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path_, ec);
  if (ec) return absl::InternalError(absl::StrFormat("cannot stat %s: %s", path_, ec.message()));
  return size;
}

}  // namespace geodesic
