#include "util/statistics.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "util/random.h"

namespace hscloc {
namespace {

TEST(Percentile, InterpolatesBetweenOrderStatistics) {
  EXPECT_DOUBLE_EQ(Percentile({4, 1, 3, 2}, 0.5), 2.5);
  EXPECT_DOUBLE_EQ(Percentile({4, 1, 3, 2}, 0.0), 1.0);
  EXPECT_DOUBLE_EQ(Percentile({4, 1, 3, 2}, 1.0), 4.0);
  EXPECT_DOUBLE_EQ(Percentile({10, 20}, 0.95), 19.5);
  EXPECT_DOUBLE_EQ(Percentile({7}, 0.3), 7.0);
}

TEST(Percentile, IsMonotoneInTheFractionAndBoundedByTheValues) {
  Random random(3);
  std::vector<double> values(101);
  for (double& value : values) value = random.Uniform();
  double previous = -1;
  for (int i = 0; i <= 20; ++i) {
    const double quantile = Percentile(values, i / 20.0);
    EXPECT_GE(quantile, previous);
    previous = quantile;
  }
  // 101 values: the median is the 51st order statistic exactly.
  std::vector<double> sorted = values;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_DOUBLE_EQ(Percentile(values, 0.5), sorted[50]);
}

TEST(Percentile, NoValuesIsNanAndABadFractionThrows) {
  EXPECT_TRUE(std::isnan(Percentile({}, 0.5)));
  EXPECT_THROW(Percentile({1, 2}, 1.5), std::invalid_argument);
  EXPECT_THROW(Percentile({1, 2}, -0.1), std::invalid_argument);
}

TEST(Mean, AveragesAndIsNanForNoValues) {
  EXPECT_DOUBLE_EQ(Mean({1, 2, 6}), 3.0);
  EXPECT_TRUE(std::isnan(Mean({})));
}

}  // namespace
}  // namespace hscloc
