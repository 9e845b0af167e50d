#include "util/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <numeric>
#include <stdexcept>
#include <vector>

namespace hscloc {
namespace {

TEST(ParallelFor, CoversEveryIndexExactlyOnce) {
  for (const size_t count : {0u, 1u, 7u, 1000u, 12345u}) {
    for (const int threads : {1, 2, 3, 8}) {
      std::vector<std::atomic<int>> visits(count);
      ParallelFor(count, threads, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) visits[i]++;
      });
      for (size_t i = 0; i < count; ++i) ASSERT_EQ(visits[i].load(), 1) << i;
    }
  }
}

TEST(ParallelFor, RethrowsTheWorkersException) {
  EXPECT_THROW(ParallelFor(1000, 4,
                           [](size_t begin, size_t end) {
                             for (size_t i = begin; i < end; ++i) {
                               if (i == 500) throw std::invalid_argument("item 500");
                             }
                           }),
               std::invalid_argument);
}

TEST(ParallelFor, ResolvesThreadCount) {
  EXPECT_EQ(ResolveNumThreads(3), 3);
  EXPECT_GE(ResolveNumThreads(0), 1);
  EXPECT_GE(ResolveNumThreads(-1), 1);
}

}  // namespace
}  // namespace hscloc
