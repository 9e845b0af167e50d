#include "map/visibility.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <functional>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

struct RandomObservations {
  size_t num_images = 0;
  size_t num_points = 0;
  std::vector<uint32_t> image_indices;
  std::vector<uint32_t> point_indices;
  std::set<std::pair<uint32_t, uint32_t>> pairs;
};

// Observations with many duplicates, in random order; image 0 observes nothing.
RandomObservations MakeRandomObservations(uint64_t seed) {
  Random random(seed);
  RandomObservations observations;
  observations.num_images = 25;
  observations.num_points = 400;
  for (int i = 0; i < 4000; ++i) {
    const auto image = static_cast<uint32_t>(1 + random.UniformInt(observations.num_images - 1));
    const auto point = static_cast<uint32_t>(random.UniformInt(observations.num_points));
    observations.image_indices.push_back(image);
    observations.point_indices.push_back(point);
    observations.pairs.emplace(image, point);
  }
  return observations;
}

Visibility Build(const RandomObservations& observations) {
  return Visibility::FromObservations(observations.num_images, observations.num_points,
                                      observations.image_indices, observations.point_indices);
}

TEST(Visibility, VisibleExactlyWhenObserved) {
  const RandomObservations observations = MakeRandomObservations(1);
  const Visibility visibility = Build(observations);
  ASSERT_LT(observations.pairs.size(), observations.image_indices.size()) << "no duplicates drawn";
  EXPECT_EQ(visibility.NumImages(), observations.num_images);
  EXPECT_EQ(visibility.NumPoints(), observations.num_points);
  EXPECT_EQ(visibility.NumEntries(), observations.pairs.size());
  for (uint32_t image = 0; image < observations.num_images; ++image) {
    for (uint32_t point = 0; point < observations.num_points; ++point) {
      EXPECT_EQ(visibility.IsVisible(image, point), observations.pairs.count({image, point}) == 1)
          << "image " << image << " point " << point;
    }
    // Out-of-range points are simply not visible.
    EXPECT_FALSE(visibility.IsVisible(image, 100000));
  }
  EXPECT_EQ(visibility.NumPointsOfImage(0), 0u);
}

TEST(Visibility, PointsOfAnImageAreSortedAndUnique) {
  const RandomObservations observations = MakeRandomObservations(2);
  const Visibility visibility = Build(observations);
  for (uint32_t image = 0; image < observations.num_images; ++image) {
    std::vector<uint32_t> expected;
    for (const auto& [pair_image, point] : observations.pairs) {
      if (pair_image == image) expected.push_back(point);
    }
    const std::vector<uint32_t> actual(visibility.PointsBegin(image), visibility.PointsEnd(image));
    EXPECT_EQ(actual, expected) << "image " << image;
    EXPECT_EQ(visibility.NumPointsOfImage(image), expected.size());
  }
}

TEST(Visibility, BadObservationsThrowNamingThem) {
  EXPECT_THAT(testing::InvalidArgumentMessage([] {
                Visibility::FromObservations(3, 10, {0, 1, 3}, {0, 0, 0});
              }),
              HasSubstr("observation 2 (image 3, point 0)"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] {
                Visibility::FromObservations(3, 10, {0, 1}, {9, 10});
              }),
              HasSubstr("observation 1 (image 1, point 10)"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] {
                Visibility::FromObservations(3, 10, {0, 1}, {0});
              }),
              HasSubstr("2 image indices but 1 point indices"));
  const Visibility visibility = Visibility::FromObservations(3, 10, {0}, {0});
  EXPECT_THROW(visibility.IsVisible(3, 0), std::invalid_argument);
}

TEST(Visibility, EmptyTables) {
  const Visibility none = Visibility::FromObservations(0, 0, {}, {});
  EXPECT_EQ(none.NumImages(), 0u);
  EXPECT_TRUE(none == Visibility());
  const Visibility blind = Visibility::FromObservations(4, 10, {}, {});
  EXPECT_EQ(blind.NumImages(), 4u);
  EXPECT_FALSE(blind.IsVisible(3, 0));
  EXPECT_FALSE(blind == none);
}

TEST(Visibility, WriteReadRoundTrip) {
  const Visibility visibility = Build(MakeRandomObservations(3));
  std::stringstream stream;
  visibility.Write(stream);
  EXPECT_TRUE(Visibility::Read(stream, "visibility.bin") == visibility);
  EXPECT_FALSE(Build(MakeRandomObservations(4)) == visibility);

  for (const Visibility& empty : {Visibility(), Visibility::FromObservations(4, 10, {}, {})}) {
    std::stringstream empty_stream;
    empty.Write(empty_stream);
    EXPECT_TRUE(Visibility::Read(empty_stream, "empty.bin") == empty);
  }
}

TEST(Visibility, TruncatedOrCorruptDataThrowsNamingTheSource) {
  const Visibility visibility = Visibility::FromObservations(3, 10, {0, 0, 2, 1}, {4, 7, 1, 9});
  std::stringstream stream;
  visibility.Write(stream);
  const std::string bytes = stream.str();
  for (size_t length = 0; length < bytes.size(); ++length) {
    std::istringstream truncated(bytes.substr(0, length));
    EXPECT_THAT(
        testing::InvalidArgumentMessage([&] { Visibility::Read(truncated, "visibility.bin"); }),
        HasSubstr("visibility.bin"))
        << "truncated to " << length << " bytes";
  }

  // Header: magic, version, then image, point and entry counts; the image ends; the points.
  constexpr size_t kPointsOffset = 8 + 3 * 8 + 3 * 8;
  std::string unsorted = bytes;
  std::swap(unsorted[kPointsOffset], unsorted[kPointsOffset + 4]);
  std::istringstream unsorted_stream(unsorted);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { Visibility::Read(unsorted_stream, "visibility.bin"); }),
      HasSubstr("visibility.bin: points of image 0"));

  std::string bad_offset = bytes;
  bad_offset[8 + 3 * 8] = 9;  // image 0 ends past the 4 entries
  std::istringstream bad_offset_stream(bad_offset);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { Visibility::Read(bad_offset_stream, "visibility.bin"); }),
              HasSubstr("visibility.bin: offsets of image 0"));
}

}  // namespace
}  // namespace hscloc
