// Distance matrices as NumPy files, written while the rows are computed, so
// that a matrix larger than memory never has to be held:
//
//  - dense: a .npy of float32 or float64 (+inf where unreached), sized up
//    front, each row written at its own offset by the thread that computed
//    it, in any order;
//  - sparse: a .npz in the layout scipy.sparse.save_npz writes for a CSR
//    matrix (indices, indptr, format, shape and data members), rows appended
//    in order, its entries staged in scratch files beside the output.
//
// Both appear whole at the end or not at all: a failed or abandoned write
// leaves no output and no scratch file.
#ifndef GEODESIC_CORE_QUERY_MATRIX_FILES_H_
#define GEODESIC_CORE_QUERY_MATRIX_FILES_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/base/atomic_file.h"

namespace geodesic {

enum class MatrixDtype { kFloat32, kFloat64 };

// The NumPy descr of a dtype: '<f4' or '<f8'.
const char* NpyDescr(MatrixDtype dtype);
size_t BytesPerEntry(MatrixDtype dtype);

class BackgroundWriteOut;

class DenseMatrixFile {
 public:
  DenseMatrixFile(DenseMatrixFile&&) noexcept;
  ~DenseMatrixFile();

  // Creates the temporary file beside `path` (.npy) and sizes it for
  // rows x cols entries.
  static absl::StatusOr<DenseMatrixFile> Create(const std::string& path, uint64_t rows,
                                                uint64_t cols, MatrixDtype dtype);

  // Writes row i (cols values, float32 ones rounded to nearest). Safe from
  // several threads at once, each writing its own rows.
  absl::Status WriteRow(uint64_t i, absl::Span<const double> row) const;
  // The same for a row already rounded to float32: a float32 file only.
  absl::Status WriteRow(uint64_t i, absl::Span<const float> row) const;

  // Renames the file into place; returns its size in bytes.
  absl::StatusOr<uint64_t> Commit() &&;

 private:
  DenseMatrixFile(std::string path, AtomicFileWriter file, uint64_t data_offset, uint64_t cols,
                  MatrixDtype dtype);
  absl::Status CheckColumns(size_t values) const;
  absl::Status WriteRowBytes(uint64_t i, absl::Span<const char> bytes) const;

  std::string path_;
  AtomicFileWriter file_;
  uint64_t data_offset_, cols_;
  MatrixDtype dtype_;
  // Starts the disk writes of the rows while later rows are computed, so
  // that Commit's fsync does not wait for all of them after the last.
  std::unique_ptr<BackgroundWriteOut> write_out_;
};

class SparseMatrixFile {
 public:
  // Creates the scratch files for the entries beside `path` (.npz).
  static absl::StatusOr<SparseMatrixFile> Create(const std::string& path, uint64_t rows,
                                                 uint64_t cols, MatrixDtype dtype);

  // Appends the next row's entries: their columns, increasing, and values.
  absl::Status AppendRow(absl::Span<const int32_t> columns, absl::Span<const double> values);
  uint64_t nonzeros() const { return row_starts_.back(); }

  // Writes the archive once every row has been appended; returns its size
  // in bytes.
  absl::StatusOr<uint64_t> Commit() &&;

 private:
  SparseMatrixFile(std::string path, uint64_t rows, uint64_t cols, MatrixDtype dtype,
                   AtomicFileWriter indices, AtomicFileWriter data);

  std::string path_;
  uint64_t rows_, cols_;
  MatrixDtype dtype_;
  // Each member file holds its .npy preamble (rewritten once the count is
  // known) and then the entries.
  AtomicFileWriter indices_, data_;
  std::vector<uint64_t> row_starts_;  // CSR indptr: one per row appended, and a 0
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_MATRIX_FILES_H_
