// Process-wide allocator settings, and buffers that are not zeroed before they are written.
#pragma once

#include <memory>
#include <new>
#include <utility>
#include <vector>

namespace hscloc {

// Keeps freed blocks of up to 32 MB in the process for reuse instead of handing them back to the
// kernel. Training steps and queries allocate and free the same few-megabyte buffers again and
// again; with glibc's defaults every one of them came back as fresh pages, and each first touch
// of a page was a fault the kernel had to zero (half of a training step's CPU time, a tenth of a
// query's network; docs/decisions.md). Idempotent; affects the whole process.
void KeepFreedMemoryForReuse();

// KeepFreedMemoryForReuse, and no block mapped apart, whatever its size: every block comes from
// the heap and goes back to it. A training step on a small map with a row per view allocates and
// frees score tables of 50 to 60 MB, past the largest threshold glibc allows, and faulted every
// page of each in anew (fountain-P11 SIFT: 2.9 times the time per step; docs/decisions.md). For
// batch work such as training: the process keeps up to a gigabyte of freed heap.
void KeepLargeFreedMemoryForReuse();

// An allocator whose default construction leaves a trivial value as it finds it: `resize` on a
// buffer that is written in full next does not zero it first. The network's per-query
// activations are such buffers, several megabytes a level.
template <typename T>
class UninitializedAllocator : public std::allocator<T> {
 public:
  template <typename U>
  struct rebind {
    using other = UninitializedAllocator<U>;
  };
  UninitializedAllocator() = default;
  template <typename U>
  UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}

  template <typename U>
  void construct(U* place) {
    ::new (static_cast<void*>(place)) U;
  }
  template <typename U, typename... Args>
  void construct(U* place, Args&&... args) {
    ::new (static_cast<void*>(place)) U(std::forward<Args>(args)...);
  }
};

template <typename T>
using UninitializedVector = std::vector<T, UninitializedAllocator<T>>;

}  // namespace hscloc
