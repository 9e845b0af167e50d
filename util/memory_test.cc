#include "util/memory.h"

#include <gtest/gtest.h>
#include <sys/resource.h>

#include <algorithm>
#include <cstring>
#include <memory>

namespace hscloc {
namespace {

long MinorFaults() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_minflt;
}

// Page faults while a block of `bytes` is allocated, written through and freed.
long FaultsOfOneUse(size_t bytes) {
  const long before = MinorFaults();
  {
    const std::unique_ptr<char[]> block(new char[bytes]);
    std::memset(block.get(), 1, bytes);
    // Keeps the writes: the compiler may not drop a buffer that is read afterwards.
    volatile char sink = block[bytes / 2];
    (void)sink;
  }
  return MinorFaults() - before;
}

// Three uses of a block of `bytes`: the first may fault every page in (huge pages: fewer); the
// later ones find them resident.
void ExpectReusedWithoutFaults(size_t bytes) {
  const long first = FaultsOfOneUse(bytes);
  const long second = FaultsOfOneUse(bytes);
  const long third = FaultsOfOneUse(bytes);
  EXPECT_GT(first, 0);
  EXPECT_LT(second, 64) << "first use " << first << " faults";
  EXPECT_LT(third, 64) << "first use " << first << " faults";
}

TEST(MemoryTest, AFreedBlockIsReusedWithoutFaultingItsPagesInAgain) {
  KeepFreedMemoryForReuse();
  ExpectReusedWithoutFaults(8 << 20);  // 2,048 pages of 4 KiB
}

TEST(MemoryTest, AFreedBlockPastMmapsLargestThresholdIsReusedToo) {
  KeepLargeFreedMemoryForReuse();
  ExpectReusedWithoutFaults(64 << 20);  // twice glibc's largest mmap threshold
}

// Values given are kept; growing keeps what was there; only the new tail is left unset.
TEST(MemoryTest, UninitializedVectorKeepsEveryValueItIsGiven) {
  UninitializedVector<float> values(1000, 2.5f);
  EXPECT_EQ(std::count(values.begin(), values.end(), 2.5f), 1000);
  values.resize(5000);
  EXPECT_EQ(std::count(values.begin(), values.begin() + 1000, 2.5f), 1000);
  std::fill(values.begin() + 1000, values.end(), -1.0f);
  values.resize(9000, 7.0f);
  EXPECT_EQ(std::count(values.begin() + 1000, values.begin() + 5000, -1.0f), 4000);
  EXPECT_EQ(std::count(values.begin() + 5000, values.end(), 7.0f), 4000);
  values.push_back(3.0f);
  EXPECT_EQ(values.back(), 3.0f);
}

}  // namespace
}  // namespace hscloc
