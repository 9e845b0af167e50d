#include "localization/nearest_neighbor_matcher.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;
using ::testing::IsEmpty;

// Random unit rows: distinct directions in 32-D are nearly orthogonal.
DescriptorMatrix RandomUnitRows(int rows, int dim, uint64_t seed) {
  Random random(seed);
  DescriptorMatrix descriptors(rows, dim);
  for (int i = 0; i < rows; ++i) {
    for (int d = 0; d < dim; ++d) descriptors(i, d) = static_cast<float>(random.Normal());
  }
  return UnitRows(descriptors);
}

// Two images: image 0 observes points 10..13 (descriptors 0..3), image 1 points 20..21
// (descriptors 4..5), with the observations interleaved as a map builder might join them.
Scene TwoImageScene(const DescriptorMatrix& descriptors) {
  Scene scene;
  scene.images.resize(2);
  scene.points.resize(22, Eigen::Vector3d::Zero());
  const std::vector<uint32_t> images = {0, 1, 0, 0, 1, 0};
  const std::vector<uint32_t> points = {10, 20, 11, 12, 21, 13};
  const std::vector<int> rows = {0, 4, 1, 2, 5, 3};
  scene.observation_descriptors.resize(6, descriptors.cols());
  for (size_t i = 0; i < images.size(); ++i) {
    scene.observation_image_indices.push_back(images[i]);
    scene.observation_point_indices.push_back(points[i]);
    // Any norm: the matcher normalizes once.
    scene.observation_descriptors.row(i) = 3.0f * descriptors.row(rows[i]);
  }
  return scene;
}

TEST(NearestNeighborMatcher, MatchesEachQueryToItsObservationInTheRightImage) {
  const DescriptorMatrix descriptors = RandomUnitRows(6, 32, 1);
  const NearestNeighborMatcher matcher(TwoImageScene(descriptors));
  ASSERT_FALSE(matcher.empty());
  // Query rows: descriptor 2 (point 12), descriptor 5 (point 21), descriptor 0 (point 10).
  DescriptorMatrix query(3, 32);
  query << descriptors.row(2), descriptors.row(5), descriptors.row(0);
  const CandidateMatches in_image0 = matcher.Match(query, 0, {});
  EXPECT_THAT(in_image0.keypoints, ElementsAre(0, 2));
  EXPECT_THAT(in_image0.point_indices, ElementsAre(12, 10));
  const CandidateMatches in_image1 = matcher.Match(query, 1, {});
  EXPECT_THAT(in_image1.keypoints, ElementsAre(1));
  EXPECT_THAT(in_image1.point_indices, ElementsAre(21));
}

TEST(NearestNeighborMatcher, RatioTestRejectsAQueryBetweenTwoObservations) {
  const DescriptorMatrix descriptors = RandomUnitRows(6, 32, 2);
  const NearestNeighborMatcher matcher(TwoImageScene(descriptors));
  // Halfway between points 10 and 11: the best and second distances are equal.
  DescriptorMatrix query = UnitRows(descriptors.row(0) + descriptors.row(1));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 0.9, .mutual = false}).keypoints, IsEmpty());
  // Slightly closer to point 11: accepted only without the ratio test's margin.
  query = UnitRows(0.49f * descriptors.row(0) + 0.51f * descriptors.row(1));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 0.9, .mutual = false}).keypoints, IsEmpty());
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 1.0, .mutual = false}).point_indices,
              ElementsAre(11));
}

TEST(NearestNeighborMatcher, MutualCheckKeepsOnlyTheObservationsBestQuery) {
  const DescriptorMatrix descriptors = RandomUnitRows(6, 32, 3);
  const NearestNeighborMatcher matcher(TwoImageScene(descriptors));
  // Two queries near point 13; the second is nearer, so only it is mutual.
  DescriptorMatrix query(2, 32);
  query.row(0) = UnitRows(descriptors.row(3) + 0.3f * descriptors.row(0));
  query.row(1) = UnitRows(descriptors.row(3) + 0.1f * descriptors.row(0));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 1.0, .mutual = true}).keypoints, ElementsAre(1));
  EXPECT_THAT(matcher.Match(query, 0, {.ratio = 1.0, .mutual = false}).keypoints,
              ElementsAre(0, 1));
}

// Rows standing for points, several per point: the ratio test weighs the best row against the
// best row of another point, so a query near two rows of one point (two views of it) is not
// rejected as ambiguous.
TEST(NearestNeighborMatcher, RatioTestComparesOtherPointsNotOtherRowsOfOnePoint) {
  const DescriptorMatrix descriptors = RandomUnitRows(3, 32, 8);
  DescriptorMatrix rows(3, 32);
  rows << UnitRows(descriptors.row(0) + 0.05f * descriptors.row(2)),
      UnitRows(descriptors.row(0) - 0.05f * descriptors.row(2)), descriptors.row(1);
  const DescriptorMatrix query = descriptors.row(0);
  const NearestNeighborOptions options{.ratio = 0.8, .mutual = true};
  const std::vector<uint32_t> one_point_two_rows = {7, 7, 9};
  EXPECT_THAT(MatchNearestRows(query, rows, one_point_two_rows.data(), options).point_indices,
              ElementsAre(7));
  // Two points with those rows: now the query is ambiguous.
  const std::vector<uint32_t> two_points = {7, 8, 9};
  EXPECT_THAT(MatchNearestRows(query, rows, two_points.data(), options).keypoints, IsEmpty());
  // The best row of another point may come before or after the best row.
  const DescriptorMatrix reversed = rows.colwise().reverse();
  const std::vector<uint32_t> reversed_points = {9, 7, 7};
  EXPECT_THAT(MatchNearestRows(query, reversed, reversed_points.data(), options).point_indices,
              ElementsAre(7));
}

TEST(NearestNeighborMatcher, EmptySceneAndBadImageIndex) {
  EXPECT_TRUE(NearestNeighborMatcher(Scene()).empty());
  const NearestNeighborMatcher matcher(TwoImageScene(RandomUnitRows(6, 8, 4)));
  EXPECT_THROW(matcher.Match(RandomUnitRows(1, 8, 5), 2, {}), std::invalid_argument);
  EXPECT_THROW(NearestNeighborOptions{.ratio = 0}.Check(), std::invalid_argument);
  EXPECT_THROW(NearestNeighborOptions{.ratio = 1.5}.Check(), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
