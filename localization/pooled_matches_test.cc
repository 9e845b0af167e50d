#include "localization/pooled_matches.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <set>
#include <stdexcept>
#include <utility>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;

TEST(PooledMatches, EachPairOnceInKeypointOrderWithItsHighestConfidence) {
  // Pair (2, 7) comes from both parts (0.4 and 0.8); keypoint 2 also goes to point 5 in the second
  // part, and point 7 also has keypoint 1: a keypoint or a point may appear in several pairs.
  const CandidateMatches first{{2, 0, 1}, {7, 3, 7}, {0.4f, 0.9f, 0.6f}};
  const CandidateMatches second{{2, 2, 4}, {7, 5, 3}, {0.8f, 0.3f, 0.7f}};
  const CandidateMatches united = UniteMatches({&first, &second});
  EXPECT_THAT(united.keypoints, ElementsAre(0, 1, 2, 2, 4));
  EXPECT_THAT(united.point_indices, ElementsAre(3, 7, 5, 7, 3));
  EXPECT_THAT(united.confidences, ElementsAre(0.9f, 0.6f, 0.3f, 0.8f, 0.7f));
}

TEST(PooledMatches, MatchesWithoutConfidencesStayWithout) {
  const CandidateMatches first{{3, 1}, {4, 4}, {}};
  const CandidateMatches empty;
  const CandidateMatches united = UniteMatches({&first, &empty, &first});
  EXPECT_THAT(united.keypoints, ElementsAre(1, 3));
  EXPECT_THAT(united.point_indices, ElementsAre(4, 4));
  EXPECT_TRUE(united.confidences.empty());
  EXPECT_EQ(UniteMatches({}).size(), 0u);
}

// Random parts: the union holds exactly the distinct pairs, sorted, whatever the parts' order.
TEST(PooledMatches, UnionOfRandomPartsIsTheSetOfTheirPairs) {
  Random random(7);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<CandidateMatches> parts(1 + static_cast<int>(random.UniformInt(5)));
    std::set<std::pair<int, uint32_t>> expected;
    for (CandidateMatches& part : parts) {
      const int size = static_cast<int>(random.UniformInt(30));
      for (int i = 0; i < size; ++i) {
        part.keypoints.push_back(static_cast<int>(random.UniformInt(20)));
        part.point_indices.push_back(static_cast<uint32_t>(random.UniformInt(10)));
        expected.emplace(part.keypoints.back(), part.point_indices.back());
      }
    }
    std::vector<const CandidateMatches*> forward;
    for (const CandidateMatches& part : parts) forward.push_back(&part);
    std::vector<const CandidateMatches*> backward(forward.rbegin(), forward.rend());
    const CandidateMatches united = UniteMatches(forward);
    std::vector<std::pair<int, uint32_t>> pairs;
    for (size_t i = 0; i < united.size(); ++i) {
      pairs.emplace_back(united.keypoints[i], united.point_indices[i]);
    }
    const std::vector<std::pair<int, uint32_t>> distinct(expected.begin(), expected.end());
    EXPECT_EQ(pairs, distinct);
    const CandidateMatches reversed = UniteMatches(backward);
    EXPECT_EQ(reversed.keypoints, united.keypoints);
    EXPECT_EQ(reversed.point_indices, united.point_indices);
  }
}

// Confident parts over the whole range of point indices: each pair keeps its highest confidence.
TEST(PooledMatches, RandomConfidentPartsKeepEachPairsHighestConfidence) {
  Random random(11);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<CandidateMatches> parts(1 + static_cast<int>(random.UniformInt(6)));
    std::map<std::pair<int, uint32_t>, float> expected;
    for (CandidateMatches& part : parts) {
      const int size = static_cast<int>(random.UniformInt(400));
      for (int i = 0; i < size; ++i) {
        const int keypoint = static_cast<int>(random.UniformInt(3000));
        // Few distinct points per keypoint, some near the top of the index range.
        const uint32_t point = random.Bernoulli(0.5)
                                   ? static_cast<uint32_t>(random.UniformInt(4))
                                   : 0xffffffffu - static_cast<uint32_t>(random.UniformInt(4));
        // Coarse confidences: equal ones are frequent.
        const float confidence = static_cast<float>(random.UniformInt(8)) / 8.0f;
        part.keypoints.push_back(keypoint);
        part.point_indices.push_back(point);
        part.confidences.push_back(confidence);
        const auto [it, inserted] = expected.emplace(std::make_pair(keypoint, point), confidence);
        if (!inserted) it->second = std::max(it->second, confidence);
      }
    }
    std::vector<const CandidateMatches*> pointers;
    for (const CandidateMatches& part : parts) pointers.push_back(&part);
    const CandidateMatches united = UniteMatches(pointers);
    ASSERT_EQ(united.size(), expected.size());
    ASSERT_EQ(united.confidences.size(), expected.size());
    size_t i = 0;
    for (const auto& [pair, confidence] : expected) {
      EXPECT_EQ(united.keypoints[i], pair.first);
      EXPECT_EQ(united.point_indices[i], pair.second);
      EXPECT_EQ(united.confidences[i], confidence);
      ++i;
    }
  }
}

TEST(PooledMatches, MatchesWithoutConfidencesCountAtZeroBesideConfidentOnes) {
  const CandidateMatches confident{{0, 3}, {1, 6}, {0.5f, 0.25f}};
  const CandidateMatches plain{{1, 0}, {2, 1}, {}};
  for (const auto& parts : {std::vector<const CandidateMatches*>{&confident, &plain},
                            std::vector<const CandidateMatches*>{&plain, &confident}}) {
    const CandidateMatches united = UniteMatches(parts);
    EXPECT_THAT(united.keypoints, ElementsAre(0, 1, 3));
    EXPECT_THAT(united.point_indices, ElementsAre(1, 2, 6));
    EXPECT_THAT(united.confidences, ElementsAre(0.5f, 0.0f, 0.25f));
  }
}

TEST(PooledMatches, MalformedPartsThrow) {
  const CandidateMatches short_confidences{{0, 1}, {1, 2}, {0.5f}};
  EXPECT_THROW(UniteMatches({&short_confidences}), std::invalid_argument);
  const CandidateMatches short_points{{0, 1}, {1}, {}};
  EXPECT_THROW(UniteMatches({&short_points}), std::invalid_argument);
  EXPECT_THROW(UniteMatches({nullptr}), std::invalid_argument);
  const CandidateMatches negative_keypoint{{-1}, {2}, {}};
  EXPECT_THROW(UniteMatches({&negative_keypoint}), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
