#include "util/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
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

TEST(ParallelFor, ReusesItsThreadsAcrossCalls) {
  // A thread new to the loops finds its thread_local flag unset (thread ids cannot tell: the
  // system hands a finished thread's id to the next one).
  std::atomic<int> fresh_threads{0};
  for (int call = 0; call < 200; ++call) {
    ParallelFor(64, 3, [&](size_t, size_t) {
      thread_local bool seen = false;
      if (!seen) {
        seen = true;
        ++fresh_threads;
      }
    });
  }
  // The caller and the pool's threads, however many loops ran; a thread per loop would count up
  // to 400.
  EXPECT_LE(fresh_threads.load(), 8);
}

TEST(ParallelFor, NestedLoopsFinishWhenEveryThreadIsBusy) {
  std::atomic<int> inner_items{0};
  ParallelFor(16, 4, [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      ParallelFor(100, 4, [&](size_t b, size_t e) { inner_items += static_cast<int>(e - b); });
    }
  });
  EXPECT_EQ(inner_items.load(), 1600);
}

TEST(ParallelFor, CallersOnSeveralThreadsEachGetTheirOwnLoop) {
  constexpr int kCallers = 4;
  std::vector<long> sums(kCallers, 0);
  std::vector<std::thread> callers;
  for (int c = 0; c < kCallers; ++c) {
    callers.emplace_back([&sums, c] {
      for (int round = 0; round < 50; ++round) {
        std::atomic<long> sum{0};
        ParallelFor(1000, 2, [&](size_t begin, size_t end) {
          for (size_t i = begin; i < end; ++i) sum += static_cast<long>(i) * (c + 1);
        });
        sums[c] += sum.load();
      }
    });
  }
  for (std::thread& caller : callers) caller.join();
  for (int c = 0; c < kCallers; ++c) EXPECT_EQ(sums[c], 50L * 499500L * (c + 1)) << c;
}

TEST(ParallelFor, AFailedLoopLeavesThePoolWorking) {
  for (int round = 0; round < 20; ++round) {
    EXPECT_THROW(ParallelFor(100, 3, [](size_t, size_t) { throw std::runtime_error("chunk"); }),
                 std::runtime_error);
    std::atomic<int> items{0};
    ParallelFor(100, 3, [&](size_t begin, size_t end) { items += static_cast<int>(end - begin); });
    ASSERT_EQ(items.load(), 100);
  }
}

TEST(ParallelFor, ResolvesThreadCount) {
  EXPECT_EQ(ResolveNumThreads(3), 3);
  EXPECT_GE(ResolveNumThreads(0), 1);
  EXPECT_GE(ResolveNumThreads(-1), 1);
}

}  // namespace
}  // namespace hscloc
