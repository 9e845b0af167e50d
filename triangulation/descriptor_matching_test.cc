#include "triangulation/descriptor_matching.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

DescriptorMatrix RandomDescriptors(int64_t count, int64_t dimension, std::mt19937& random) {
  std::normal_distribution<float> normal;
  DescriptorMatrix descriptors(count, dimension);
  for (int64_t i = 0; i < descriptors.size(); ++i) descriptors.data()[i] = normal(random);
  return descriptors;
}

// Image 2 holds image 1's descriptors permuted, scaled and slightly perturbed; for 64-D (XFeat)
// and 128-D (SIFT) descriptors, and across the similarity block boundary (1500 rows).
TEST(DescriptorMatching, FindsAPermutationOfNoisyDescriptors) {
  for (const int64_t dimension : {64, 128}) {
    SCOPED_TRACE(dimension);
    std::mt19937 random(dimension);
    const int64_t count = 1500;
    const DescriptorMatrix descriptors1 = RandomDescriptors(count, dimension, random);
    std::vector<int64_t> permutation(count);
    std::iota(permutation.begin(), permutation.end(), 0);
    std::shuffle(permutation.begin(), permutation.end(), random);
    const DescriptorMatrix noise = RandomDescriptors(count, dimension, random);
    DescriptorMatrix descriptors2(count, dimension);
    for (int64_t i = 0; i < count; ++i) {
      descriptors2.row(permutation[i]) =
          3.0f * (descriptors1.row(i).normalized() + 0.02f * noise.row(i));
    }
    // A strict ratio test keeps them: their second neighbours are far.
    const std::vector<FeatureMatch> matches =
        MatchDescriptors(descriptors1, descriptors2, {.max_ratio = 0.8});
    ASSERT_EQ(matches.size(), static_cast<size_t>(count));
    for (int64_t i = 0; i < count; ++i) {
      EXPECT_EQ(matches[i].point2D_idx1, i);
      EXPECT_EQ(matches[i].point2D_idx2, permutation[i]);
    }
  }
}

TEST(DescriptorMatching, RatioTestDropsAmbiguousMatches) {
  std::mt19937 random(3);
  const DescriptorMatrix base = RandomDescriptors(3, 64, random);
  const DescriptorMatrix noise = RandomDescriptors(4, 64, random);
  DescriptorMatrix descriptors1 = base;
  // Image 2: descriptor 0 twice (nearly equal copies: ambiguous for image 1's 0), 1 and 2 once.
  DescriptorMatrix descriptors2(4, 64);
  descriptors2.row(0) = base.row(0).normalized() + 0.01f * noise.row(0).normalized();
  descriptors2.row(1) = base.row(0).normalized() + 0.01f * noise.row(1).normalized();
  descriptors2.row(2) = base.row(1);
  descriptors2.row(3) = base.row(2);
  const DescriptorMatchingOptions ratio = {.max_ratio = 0.9};
  EXPECT_EQ(MatchDescriptors(descriptors1, descriptors2, ratio),
            (std::vector<FeatureMatch>{{1, 2}, {2, 3}}));
  // Without the ratio test (the default) the nearest copy is matched too.
  EXPECT_EQ(MatchDescriptors(descriptors1, descriptors2).size(), 3u);
  // Ambiguity seen from image 2's side: two near copies in image 1 of one descriptor of image 2.
  descriptors1.row(2) = descriptors2.row(0) + 0.01f * noise.row(2).normalized();
  EXPECT_EQ(MatchDescriptors(descriptors1, descriptors2, ratio),
            (std::vector<FeatureMatch>{{1, 2}}));
}

TEST(DescriptorMatching, KeepsOnlyMutualNearestNeighbours) {
  DescriptorMatrix descriptors1(2, 2);
  descriptors1 << 1, 0, 0.8, 0.6;
  DescriptorMatrix descriptors2(1, 2);
  descriptors2 << 0.9, 0.44;
  // Both of image 1's descriptors are nearest to image 2's only one, which is nearest to the
  // second: one match, without a ratio test for the single descriptor.
  EXPECT_EQ(MatchDescriptors(descriptors1, descriptors2), (std::vector<FeatureMatch>{{1, 0}}));
  EXPECT_TRUE(MatchDescriptors(DescriptorMatrix(0, 2), descriptors2).empty());
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { MatchDescriptors(descriptors1, DescriptorMatrix(3, 4)); }),
              HasSubstr("dimension 2 cannot be matched with dimension 4"));
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { MatchDescriptors(descriptors1, descriptors2, {.max_ratio = 0}); }),
              HasSubstr("max_ratio"));
}

}  // namespace
}  // namespace hscloc
