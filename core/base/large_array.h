// An array of trivially copyable values in an anonymous mapping of its own.
//
// The graph build keeps its edges in one of these and turns it, in place, into
// the graph's edge array, so that the edges never exist twice in memory. A
// mapping of its own is what makes that cheap: pages are committed only when
// first written, growing moves no bytes (mremap), and shrinking or dying
// returns the pages to the system at once, where a std::vector would copy on
// growth and leave freed memory to the allocator.
//
// BackWithFile keeps the array in a file instead (the graph file being
// written): its pages are then the page cache's, which the kernel writes back
// and drops under memory pressure, so an array larger than the memory left
// beside the rest of a build still fits.
#ifndef GEODESIC_CORE_BASE_LARGE_ARRAY_H_
#define GEODESIC_CORE_BASE_LARGE_ARRAY_H_

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <new>
#include <type_traits>
#include <utility>

namespace geodesic {

template <typename T>
class LargeArray {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  LargeArray() = default;
  explicit LargeArray(size_t n) { resize(n); }
  LargeArray(LargeArray&& other) noexcept { *this = std::move(other); }
  LargeArray& operator=(LargeArray&& other) noexcept {
    if (this != &other) {
      Unmap();
      data_ = std::exchange(other.data_, nullptr);
      size_ = std::exchange(other.size_, 0);
      mapped_ = std::exchange(other.mapped_, 0);
      fd_ = std::exchange(other.fd_, -1);
      offset_ = std::exchange(other.offset_, 0);
    }
    return *this;
  }
  ~LargeArray() { Unmap(); }

  // Keeps the array in file `fd` from byte `offset` (a multiple of the page
  // size) on, growing the file with it; call while the array is empty. The
  // file stays the caller's: it must outlive the array's growth, not its
  // mapping (a mapping outlives its descriptor).
  void BackWithFile(int fd, uint64_t offset) {
    Unmap();
    fd_ = fd;
    offset_ = offset;
  }
  // BackWithFile's file, or -1.
  int backing_fd() const { return fd_; }

  // New elements are zero. Throws std::bad_alloc when the system has no
  // memory to map, as std::vector does (or, backed by a file, no disk).
  void resize(size_t n) {
    const size_t old = size_;
    Reserve(n * sizeof(T), /*exact=*/true);
    size_ = n;
    // The mapping beyond size_ stays zero (fresh pages are), so that growing
    // again yields zeros.
    if (n < old && mapped_ > 0) {
      std::memset(static_cast<void*>(data_ + n), 0,
                  std::min(mapped_, old * sizeof(T)) - n * sizeof(T));
    }
  }
  void push_back(const T& value) {
    if ((size_ + 1) * sizeof(T) > mapped_) Reserve(std::max<size_t>(2 * mapped_, 1 << 16), false);
    data_[size_++] = value;
  }

  // Reuses the mapping for values of another type of the same size, each
  // made from the value in its place by `convert`.
  template <typename U, typename Convert>
  LargeArray<U> TransformInPlace(Convert convert) && {
    static_assert(sizeof(U) == sizeof(T) && alignof(U) <= alignof(T));
    static_assert(std::is_trivially_copyable_v<U>);
    for (size_t i = 0; i < size_; ++i) {
      const U u = convert(static_cast<const T&>(data_[i]));
      std::memcpy(static_cast<void*>(data_ + i), &u, sizeof(U));
    }
    LargeArray<U> out;
    out.data_ = std::launder(reinterpret_cast<U*>(std::exchange(data_, nullptr)));
    out.size_ = std::exchange(size_, 0);
    out.mapped_ = std::exchange(mapped_, 0);
    out.fd_ = std::exchange(fd_, -1);
    out.offset_ = std::exchange(offset_, 0);
    return out;
  }

  T* data() { return data_; }
  const T* data() const { return data_; }
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  T& operator[](size_t i) { return data_[i]; }
  const T& operator[](size_t i) const { return data_[i]; }
  T* begin() { return data_; }
  T* end() { return data_ + size_; }
  const T* begin() const { return data_; }
  const T* end() const { return data_ + size_; }
  // Bytes mapped, and so at most committed.
  size_t mapped_bytes() const { return mapped_; }

 private:
  template <typename>
  friend class LargeArray;

  static size_t PageRound(size_t bytes) {
    static const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
    return (bytes + page - 1) / page * page;
  }

  // Maps `bytes` (exact: no more, page-rounded; else at least).
  void Reserve(size_t bytes, bool exact) {
    const size_t want = PageRound(bytes);
    if (want == mapped_ || (!exact && want <= mapped_)) return;
    if (want == 0) return Unmap();
    // Blocks are allocated before they are mapped, so that a full disk is
    // an error here rather than a SIGBUS at the first write to a page.
    if (fd_ >= 0 && want > mapped_ &&
        ::posix_fallocate(fd_, static_cast<off_t>(offset_ + mapped_),
                          static_cast<off_t>(want - mapped_)) != 0) {
      throw std::bad_alloc();
    }
    void* p = mapped_ != 0 ? ::mremap(data_, mapped_, want, MREMAP_MAYMOVE)
              : fd_ >= 0   ? ::mmap(nullptr, want, PROT_READ | PROT_WRITE, MAP_SHARED, fd_,
                                    static_cast<off_t>(offset_))
                           : ::mmap(nullptr, want, PROT_READ | PROT_WRITE,
                                    MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
    data_ = static_cast<T*>(p);
    mapped_ = want;
    if (size_ * sizeof(T) > mapped_) size_ = mapped_ / sizeof(T);
  }
  void Unmap() {
    if (mapped_ != 0) ::munmap(data_, mapped_);
    data_ = nullptr;
    size_ = mapped_ = 0;
  }

  T* data_ = nullptr;
  size_t size_ = 0;
  size_t mapped_ = 0;  // bytes
  int fd_ = -1;        // BackWithFile's file, or anonymous memory
  uint64_t offset_ = 0;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_LARGE_ARRAY_H_
