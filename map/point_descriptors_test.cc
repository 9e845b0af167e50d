#include "map/point_descriptors.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <vector>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using testing::InvalidArgumentMessage;
using testing::NormalFloats;

struct StreamedObservations {
  std::vector<DescriptorMatrix> batches;  // as images arrive
  std::vector<std::vector<uint32_t>> batch_points;
  DescriptorMatrix unit_sums;  // per point, the sum of its rows' unit vectors
};

// Observations of `num_points` points in batches, each row a random scale of its point's direction
// plus noise; point 0 is never observed.
StreamedObservations MakeObservations(int num_points, int dimension, uint64_t seed) {
  Random random(seed);
  const DescriptorMatrix centres = Eigen::Map<const DescriptorMatrix>(
      NormalFloats(int64_t{num_points} * dimension, random).data(), num_points, dimension);
  StreamedObservations observations;
  observations.unit_sums = DescriptorMatrix::Zero(num_points, dimension);
  for (int batch = 0; batch < 6; ++batch) {
    const int rows = 20 + static_cast<int>(random.UniformInt(40));
    DescriptorMatrix descriptors(rows, dimension);
    std::vector<uint32_t> points;
    for (int row = 0; row < rows; ++row) {
      const auto point = static_cast<uint32_t>(1 + random.UniformInt(num_points - 1));
      points.push_back(point);
      const std::vector<float> noise = NormalFloats(dimension, random, 0.3);
      for (int d = 0; d < dimension; ++d) descriptors(row, d) = centres(point, d) + noise[d];
      descriptors.row(row) *= static_cast<float>(1 + 200 * random.Uniform());
      observations.unit_sums.row(point) += descriptors.row(row).normalized();
    }
    observations.batches.push_back(std::move(descriptors));
    observations.batch_points.push_back(std::move(points));
  }
  return observations;
}

PointDescriptors Accumulate(const StreamedObservations& observations, int num_points) {
  PointDescriptorAccumulator accumulator(num_points);
  for (size_t batch = 0; batch < observations.batches.size(); ++batch) {
    accumulator.Add(observations.batches[batch], observations.batch_points[batch].data());
  }
  return accumulator.Finish();
}

std::vector<uint32_t> AllPoints(int num_points) {
  std::vector<uint32_t> points(num_points);
  for (int p = 0; p < num_points; ++p) points[p] = static_cast<uint32_t>(p);
  return points;
}

TEST(PointDescriptors, EachRowIsItsPointsUnitMeanWithinTheCodesRounding) {
  for (const int dimension : {3, 64, 256}) {
    constexpr int kPoints = 50;
    const StreamedObservations observations = MakeObservations(kPoints, dimension, dimension);
    const PointDescriptors descriptors = Accumulate(observations, kPoints);
    ASSERT_EQ(descriptors.NumPoints(), kPoints);
    ASSERT_EQ(descriptors.Dimension(), dimension);
    const std::vector<uint32_t> points = AllPoints(kPoints);
    const DescriptorMatrix rows = descriptors.UnitRows(points.data(), points.size());
    EXPECT_EQ(rows.row(0).norm(), 0) << "an unobserved point matches nothing";
    int observed = 0;
    for (int p = 1; p < kPoints; ++p) {
      if (observations.unit_sums.row(p).norm() == 0) continue;
      ++observed;
      EXPECT_NEAR(rows.row(p).norm(), 1, 1e-5);
      // Rounding to 1/127 of the largest value moves each value by at most 1/254 of it.
      const float cosine = rows.row(p).dot(observations.unit_sums.row(p).normalized());
      EXPECT_GT(cosine, 0.9995f) << "dimension " << dimension << ", point " << p;
    }
    EXPECT_GT(observed, kPoints / 2);
  }
}

TEST(PointDescriptors, UnitRowsFollowTheRequestedOrder) {
  const StreamedObservations observations = MakeObservations(30, 16, 5);
  const PointDescriptors descriptors = Accumulate(observations, 30);
  const std::vector<uint32_t> all = AllPoints(30);
  const DescriptorMatrix rows = descriptors.UnitRows(all.data(), all.size());
  const std::vector<uint32_t> some = {7, 3, 7, 29};
  const DescriptorMatrix picked = descriptors.UnitRows(some.data(), some.size());
  for (size_t i = 0; i < some.size(); ++i) {
    EXPECT_EQ(picked.row(static_cast<Eigen::Index>(i)), rows.row(some[i]));
  }
}

// The codes are the rows' directions: normalized, they give UnitRows in the same order.
TEST(PointDescriptors, CodeRowsAreTheUnitRowsDirections) {
  const StreamedObservations observations = MakeObservations(30, 16, 5);
  const PointDescriptors descriptors = Accumulate(observations, 30);
  const std::vector<uint32_t> some = {7, 3, 7, 29, 0};
  const DescriptorMatrix rows = descriptors.UnitRows(some.data(), some.size());
  const std::vector<int8_t> codes = descriptors.CodeRows(some.data(), some.size());
  ASSERT_EQ(codes.size(), some.size() * 16);
  for (size_t i = 0; i < some.size(); ++i) {
    Eigen::VectorXf direction(16);
    for (int d = 0; d < 16; ++d) direction[d] = codes[i * 16 + d];
    if (direction.norm() > 0) direction.normalize();
    EXPECT_TRUE(direction.transpose().isApprox(rows.row(static_cast<Eigen::Index>(i)), 1e-6f)) << i;
  }
}

TEST(PointDescriptors, WriteReadRoundTrip) {
  const PointDescriptors descriptors = Accumulate(MakeObservations(40, 32, 9), 40);
  std::stringstream stream;
  descriptors.Write(stream);
  const std::string bytes = stream.str();
  EXPECT_EQ(bytes.size(), 4 + 4 + 8 + 8 + 40 * 4 + 40 * 32);
  std::istringstream input(bytes);
  EXPECT_EQ(PointDescriptors::Read(input, "points.bin"), descriptors);

  std::istringstream truncated(bytes.substr(0, bytes.size() - 1));
  EXPECT_THAT(InvalidArgumentMessage([&] { PointDescriptors::Read(truncated, "points.bin"); }),
              HasSubstr("points.bin"));
  std::string wrong_magic = bytes;
  wrong_magic[0] = 'X';
  std::istringstream not_ours(wrong_magic);
  EXPECT_THAT(InvalidArgumentMessage([&] { PointDescriptors::Read(not_ours, "points.bin"); }),
              HasSubstr("wrong magic"));
  std::string nan_scale = bytes;
  for (int byte = 24; byte < 28; ++byte) nan_scale[byte] = static_cast<char>(0xff);  // point 0's
  std::istringstream bad_scale(nan_scale);
  EXPECT_THAT(InvalidArgumentMessage([&] { PointDescriptors::Read(bad_scale, "points.bin"); }),
              HasSubstr("scale"));
}

TEST(PointDescriptors, AMapWithoutDescriptorsRoundTripsEmpty) {
  PointDescriptorAccumulator accumulator(12);
  const PointDescriptors descriptors = accumulator.Finish();
  EXPECT_TRUE(descriptors.empty());
  std::stringstream stream;
  descriptors.Write(stream);
  EXPECT_EQ(PointDescriptors::Read(stream, "points.bin"), descriptors);
}

TEST(PointDescriptors, RejectsPointsOutOfRangeAndAChangeOfDimension) {
  PointDescriptorAccumulator accumulator(5);
  const DescriptorMatrix row = DescriptorMatrix::Ones(1, 8);
  const uint32_t past_the_end = 5;
  EXPECT_THAT(InvalidArgumentMessage([&] { accumulator.Add(row, &past_the_end); }),
              HasSubstr("point 5 of 5"));
  const uint32_t point = 4;
  accumulator.Add(row, &point);
  EXPECT_THAT(
      InvalidArgumentMessage([&] { accumulator.Add(DescriptorMatrix::Ones(1, 9), &point); }),
      HasSubstr("dimension 9"));
  const PointDescriptors descriptors = accumulator.Finish();
  EXPECT_THAT(InvalidArgumentMessage([&] { descriptors.UnitRows(&past_the_end, 1); }),
              HasSubstr("point 5 of 5"));
  EXPECT_THAT(InvalidArgumentMessage([&] { descriptors.CodeRows(&past_the_end, 1); }),
              HasSubstr("point 5 of 5"));
}

}  // namespace
}  // namespace hscloc
