// Data-parallel loops over index ranges on plain threads.
#pragma once

#include <cstddef>
#include <functional>

namespace hscloc {

// The number of threads to use: `requested` when positive, else the hardware concurrency.
int ResolveNumThreads(int requested);

// Calls body(begin, end) on disjoint chunks covering [0, count), on up to num_threads threads
// (<= 0: all cores). The first exception thrown by any chunk is rethrown after all threads joined.
void ParallelFor(size_t count, int num_threads,
                 const std::function<void(size_t begin, size_t end)>& body);

}  // namespace hscloc
