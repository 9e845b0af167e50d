#include "retrieval/point_votes.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <stdexcept>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

Visibility RandomVisibility(size_t num_images, size_t num_points, size_t num_observations,
                            uint64_t seed) {
  Random random(seed);
  std::vector<uint32_t> images;
  std::vector<uint32_t> points;
  for (size_t i = 0; i < num_observations; ++i) {
    images.push_back(static_cast<uint32_t>(random.UniformInt(num_images)));
    points.push_back(static_cast<uint32_t>(random.UniformInt(num_points)));
  }
  return Visibility::FromObservations(num_images, num_points, images, points);
}

TEST(PointVoteIndex, IsTheTransposeOfTheVisibilityLists) {
  const Visibility visibility = RandomVisibility(40, 300, 2000, 1);
  const PointVoteIndex index(visibility);
  EXPECT_EQ(index.NumImages(), 40u);
  EXPECT_EQ(index.NumPoints(), 300u);
  size_t entries = 0;
  for (uint32_t point = 0; point < 300; ++point) {
    ASSERT_TRUE(std::is_sorted(index.ImagesBegin(point), index.ImagesEnd(point)));
    for (const uint32_t* image = index.ImagesBegin(point); image != index.ImagesEnd(point);
         ++image) {
      EXPECT_TRUE(visibility.IsVisible(*image, point)) << "image " << *image << " point " << point;
      ++entries;
    }
  }
  // Every (image, point) pair once: the transpose loses and invents nothing.
  EXPECT_EQ(entries, visibility.NumEntries());
}

TEST(PointVoteIndex, ScoresAreTheSummedWeightsOfObservedPoints) {
  // Image 0 sees points 0-3, image 1 points 2-5, image 2 point 9.
  const Visibility visibility =
      Visibility::FromObservations(3, 10, {0, 0, 0, 0, 1, 1, 1, 1, 2}, {0, 1, 2, 3, 2, 3, 4, 5, 9});
  const PointVoteIndex index(visibility);
  const std::vector<RetrievalHit> hits =
      index.Search({0, 2, 4, 5, -1, 7}, {1.0f, 0.5f, 2.0f, 0.25f, 9.0f, 3.0f}, 10);
  ASSERT_EQ(hits.size(), 2u);  // image 2 got no vote and is not returned
  EXPECT_EQ(hits[0].image_index, 1u);
  EXPECT_FLOAT_EQ(hits[0].score, 0.5f + 2.0f + 0.25f);
  EXPECT_EQ(hits[1].image_index, 0u);
  EXPECT_FLOAT_EQ(hits[1].score, 1.0f + 0.5f);

  EXPECT_EQ(index.Search({0, 2, 4, 5}, {1, 1, 1, 1}, 1).size(), 1u);
  EXPECT_TRUE(index.Search({}, {}, 5).empty());
  EXPECT_TRUE(index.Search({2}, {1}, 0).empty());
}

TEST(PointVoteIndex, TiesGoToTheLowerImageIndex) {
  const Visibility visibility = Visibility::FromObservations(4, 2, {3, 1, 2, 0}, {0, 0, 0, 1});
  const std::vector<RetrievalHit> hits = PointVoteIndex(visibility).Search({0}, {1}, 3);
  ASSERT_EQ(hits.size(), 3u);
  EXPECT_EQ(hits[0].image_index, 1u);
  EXPECT_EQ(hits[1].image_index, 2u);
  EXPECT_EQ(hits[2].image_index, 3u);
}

// Noise: a query whose few right points are outnumbered 10 to 1 by votes for random points still
// finds the image that sees its right points, because random votes spread over every image.
TEST(PointVoteIndex, FindsTheObservingImageUnderTenfoldClutter) {
  const size_t num_images = 500;
  const size_t num_points = 20000;
  const Visibility visibility = RandomVisibility(num_images, num_points, 100000, 2);
  const PointVoteIndex index(visibility);
  Random random(3);
  int found = 0;
  const int trials = 50;
  for (int trial = 0; trial < trials; ++trial) {
    const auto image = static_cast<uint32_t>(random.UniformInt(num_images));
    std::vector<int64_t> points;
    std::vector<float> weights;
    const uint32_t* begin = visibility.PointsBegin(image);
    const size_t seen = std::min<size_t>(30, visibility.NumPointsOfImage(image));
    for (size_t i = 0; i < seen; ++i) points.push_back(begin[i]);
    for (size_t i = 0; i < 10 * seen; ++i) points.push_back(random.UniformInt(num_points));
    weights.assign(points.size(), 1.0f);
    found += index.Search(points, weights, 1).front().image_index == image;
  }
  EXPECT_EQ(found, trials);
}

TEST(PointVoteIndex, RejectsBadVotesByName) {
  const PointVoteIndex index(RandomVisibility(5, 10, 30, 4));
  const auto expect_error = [&](const std::vector<int64_t>& points,
                                const std::vector<float>& weights, int top_k,
                                const std::string& message) {
    try {
      index.Search(points, weights, top_k);
      ADD_FAILURE() << "no error for " << message;
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr(message));
    }
  };
  expect_error({1, 2}, {1}, 3, "2 points but 1 weights");
  expect_error({10}, {1}, 3, "point index 10 is out of range");
  expect_error({1}, {-1}, 3, "negative or not finite");
  expect_error({1}, {std::numeric_limits<float>::quiet_NaN()}, 3, "negative or not finite");
  expect_error({1}, {1}, -1, "top_k must be >= 0");
}

TEST(PointVoteIndex, EmptyVisibilityHasNoImages) {
  const PointVoteIndex index{Visibility()};
  EXPECT_EQ(index.NumImages(), 0u);
  EXPECT_TRUE(index.Search({}, {}, 3).empty());
}

}  // namespace
}  // namespace hscloc
