#include "util/memory.h"

#include <gtest/gtest.h>
#include <sys/resource.h>

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

TEST(MemoryTest, AFreedBlockIsReusedWithoutFaultingItsPagesInAgain) {
  KeepFreedMemoryForReuse();
  constexpr size_t kBytes = 8 << 20;  // 2,048 pages of 4 KiB
  const long first = FaultsOfOneUse(kBytes);
  const long second = FaultsOfOneUse(kBytes);
  const long third = FaultsOfOneUse(kBytes);
  // The first use may fault every page in (huge pages: fewer); the later ones find them resident.
  EXPECT_GT(first, 0);
  EXPECT_LT(second, 64) << "first use " << first << " faults";
  EXPECT_LT(third, 64) << "first use " << first << " faults";
}

}  // namespace
}  // namespace hscloc
