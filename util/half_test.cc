#include "util/half.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace hscloc {
namespace {

TEST(Half, EveryHalfRoundTripsExactly) {
  for (uint32_t bits = 0; bits < 0x10000u; ++bits) {
    const float value = HalfBitsToFloat(static_cast<uint16_t>(bits));
    if (std::isnan(value)) {
      EXPECT_TRUE(std::isnan(HalfBitsToFloat(FloatToHalfBits(value))));
      continue;
    }
    ASSERT_EQ(FloatToHalfBits(value), bits) << bits;
  }
}

TEST(Half, KnownValues) {
  EXPECT_EQ(FloatToHalfBits(1.0f), 0x3c00u);
  EXPECT_EQ(FloatToHalfBits(-2.0f), 0xc000u);
  EXPECT_EQ(FloatToHalfBits(65504.0f), 0x7bffu);
  EXPECT_EQ(FloatToHalfBits(65520.0f), 0x7c00u);  // overflows to inf
  EXPECT_EQ(HalfBitsToFloat(0x0001u), std::ldexp(1.0f, -24));
  EXPECT_EQ(HalfBitsToFloat(0x7c00u), std::numeric_limits<float>::infinity());
}

TEST(Half, RoundsToNearestWithinHalfAnUlp) {
  std::mt19937 random(5);
  std::uniform_real_distribution<float> uniform(-1000.0f, 1000.0f);
  for (int i = 0; i < 100000; ++i) {
    const float value = uniform(random);
    const float rounded = HalfBitsToFloat(FloatToHalfBits(value));
    // Half has 11 significant bits: relative error at most 2^-11.
    ASSERT_LE(std::abs(rounded - value), std::abs(value) * std::ldexp(1.0f, -11)) << value;
  }
}

}  // namespace
}  // namespace hscloc
