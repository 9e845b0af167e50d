#include "util/random.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace hscloc {
namespace {

TEST(Random, SameSeedAndKeysGiveSameStream) {
  Random a(42, {3, 7});
  Random b(42, {3, 7});
  for (int i = 0; i < 100; ++i) ASSERT_EQ(a.NextU64(), b.NextU64());
}

TEST(Random, DifferentKeysGiveDifferentStreams) {
  Random a(42, {3, 7});
  Random b(42, {7, 3});
  Random c(43, {3, 7});
  int equal_ab = 0, equal_ac = 0;
  for (int i = 0; i < 100; ++i) {
    const uint64_t x = a.NextU64();
    equal_ab += x == b.NextU64();
    equal_ac += x == c.NextU64();
  }
  EXPECT_EQ(equal_ab, 0);
  EXPECT_EQ(equal_ac, 0);
}

TEST(Random, UniformMomentsAndRange) {
  Random random(1);
  const int n = 200000;
  double sum = 0, sum_sq = 0;
  for (int i = 0; i < n; ++i) {
    const double x = random.Uniform();
    ASSERT_GE(x, 0.0);
    ASSERT_LT(x, 1.0);
    sum += x;
    sum_sq += x * x;
  }
  EXPECT_NEAR(sum / n, 0.5, 0.005);
  EXPECT_NEAR(sum_sq / n - std::pow(sum / n, 2), 1.0 / 12, 0.002);
}

TEST(Random, NormalMoments) {
  Random random(2);
  const int n = 200000;
  double sum = 0, sum_sq = 0, sum_4 = 0;
  for (int i = 0; i < n; ++i) {
    const double x = random.Normal();
    sum += x;
    sum_sq += x * x;
    sum_4 += x * x * x * x;
  }
  EXPECT_NEAR(sum / n, 0.0, 0.01);
  EXPECT_NEAR(sum_sq / n, 1.0, 0.02);
  EXPECT_NEAR(sum_4 / n, 3.0, 0.1);  // kurtosis of a Gaussian
}

TEST(Random, UniformIntCoversRangeEvenly) {
  Random random(3);
  std::vector<int> counts(7, 0);
  for (int i = 0; i < 70000; ++i) {
    const uint64_t x = random.UniformInt(7);
    ASSERT_LT(x, 7u);
    counts[x]++;
  }
  for (const int count : counts) EXPECT_NEAR(count, 10000, 400);
}

}  // namespace
}  // namespace hscloc
