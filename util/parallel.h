// Data-parallel loops over index ranges on plain threads.
#pragma once

#include <cstddef>
#include <functional>

namespace hscloc {

// The number of threads to use: `requested` when positive, else the hardware concurrency.
int ResolveNumThreads(int requested);

// Calls body(begin, end) on disjoint chunks covering [0, count), on the calling thread and up to
// num_threads - 1 threads kept between calls (<= 0: all cores). Returns once every chunk is done;
// the first exception thrown by any chunk is rethrown then, and the chunks not yet started are
// skipped. Safe to nest and to call from several threads at once.
void ParallelFor(size_t count, int num_threads,
                 const std::function<void(size_t begin, size_t end)>& body);

}  // namespace hscloc
