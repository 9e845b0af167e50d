#include "util/radix_sort.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <stdexcept>

#include "util/random.h"

namespace hscloc {
namespace {

using Items = std::vector<std::pair<int64_t, int64_t>>;

// Keys below `bound`, values their position: the pairs' own order is the stable order by key.
Items RandomItems(size_t count, int64_t bound, Random& random) {
  Items items(count);
  for (size_t i = 0; i < count; ++i) {
    items[i] = {static_cast<int64_t>(random.UniformInt(static_cast<uint64_t>(bound))),
                static_cast<int64_t>(i)};
  }
  return items;
}

TEST(RadixSortTest, GivesThePairsOrderForKeysOfAnyWidth) {
  Random random(3);
  Items scratch;
  // One digit, a digit's edge, several digits with many ties, and keys past 40 bits.
  for (const int64_t bound : {int64_t{1}, int64_t{2}, int64_t{2047}, int64_t{2049}, int64_t{100},
                              int64_t{4000} * 100 * 100, int64_t{1} << 41}) {
    for (const size_t count : {size_t{0}, size_t{1}, size_t{5000}}) {
      SCOPED_TRACE(testing::Message() << count << " keys below " << bound);
      Items items = RandomItems(count, bound, random);
      Items expected = items;
      std::sort(expected.begin(), expected.end());
      StableSortByKey(items, scratch);
      EXPECT_EQ(items, expected);
    }
  }
}

TEST(RadixSortTest, EqualKeysKeepTheirOrderWhateverTheValues) {
  Random random(4);
  Items items = RandomItems(3000, 300000, random);
  for (auto& item : items) item.second = static_cast<int64_t>(random.UniformInt(1000));
  Items expected = items;
  std::stable_sort(expected.begin(), expected.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  Items scratch;
  StableSortByKey(items, scratch);
  EXPECT_EQ(items, expected);
}

TEST(RadixSortTest, ANegativeKeyIsRefused) {
  Items items = {{3, 0}, {-1, 1}};
  Items scratch;
  EXPECT_THROW(StableSortByKey(items, scratch), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
