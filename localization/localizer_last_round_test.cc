// The Localizer's last round (LocalizerOptions::nearest_point_candidates): where the network
// places nothing, the global ranking's images matched against the mean descriptors of the points
// they see, on the trained `small` synthetic city with an untrained network.
#include <gtest/gtest.h>

#include <algorithm>
#include <iostream>
#include <memory>
#include <set>
#include <vector>

#include "localization/localizer.h"
#include "localization/localizer_test_support.h"
#include "model/network.h"

namespace hscloc {
namespace {

// A localizer whose network is untrained (its labels random): it places nothing, so every query
// reaches the last round.
Localizer WithUntrainedNetwork(const std::shared_ptr<const LocalizationMap>& map) {
  return Localizer(map, std::make_shared<const Network>(
                            NetworkShape::ForTree(map->descriptor_dim(), map->label_tree(),
                                                  static_cast<int>(map->scene().NumImages())),
                            NetworkOptions(), /*seed=*/7));
}

// Where the network places nothing (here an untrained one, whose labels are random), the last
// round matches the global ranking's images against the mean descriptors of the points they see,
// and poses the top_k with the most matches. The deeper global round does not run before it: the
// last round ranks those images too. The earlier candidates draw the rest of RANSAC's budget after
// the last round's first looks, and only as far as they could still beat its pose: each draws at
// most what it draws before a last round (as a localizer without one does), and in all fewer.
TEST_F(SmallCityLocalizerTest, PointDescriptorsPlaceQueriesTheNetworkCannot) {
  const auto map = LocalizationMap::Load(localizer().map().dir());
  ASSERT_FALSE(map->point_descriptors().empty()) << "the map builder writes them";
  ASSERT_EQ(map->point_descriptors().NumPoints(), map->scene().NumPoints());
  const Localizer localizer = WithUntrainedNetwork(map);
  const LocalizerOptions options;
  ASSERT_GT(options.deeper_global_candidates, 0);
  LocalizerOptions deeper_without = options;
  deeper_without.nearest_point_candidates = 0;
  // The rounds that run before the last one.
  LocalizerOptions without = deeper_without;
  without.deeper_global_candidates = 0;
  const QuerySet& set = Set("day");
  const size_t count = std::min<size_t>(set.queries.size(), 6);
  int placed = 0;
  int64_t earlier_samples_without = 0;
  int64_t earlier_samples_with = 0;
  for (size_t q = 0; q < count; ++q) {
    SCOPED_TRACE(set.queries[q].name);
    const PoseResult network_alone = localizer.Localize(set.queries[q], without);
    EXPECT_FALSE(WithinQuarterMetreAndTwoDegrees(set.ground_truth[q], network_alone))
        << "an untrained network must not place the query for the test to mean anything";
    if (network_alone.success) continue;  // the last round runs only without any pose
    EXPECT_GT(localizer.Localize(set.queries[q], deeper_without).candidates.size(),
              network_alone.candidates.size())
        << "without a last round, the deeper global round poses more images";
    const PoseResult result = localizer.Localize(set.queries[q], options);
    const size_t earlier = network_alone.candidates.size();
    ASSERT_GT(result.candidates.size(), earlier);
    EXPECT_LE(result.candidates.size(), earlier + options.top_k);
    std::set<uint32_t> last_round_images;
    for (size_t k = 0; k < result.candidates.size(); ++k) {
      const LocalizationCandidate& candidate = result.candidates[k];
      EXPECT_EQ(candidate.source == CandidateSource::kNearestPoints, k >= earlier) << k;
      if (k < earlier) {
        EXPECT_EQ(candidate.image_index, network_alone.candidates[k].image_index) << k;
        EXPECT_LE(candidate.ransac_samples, network_alone.candidates[k].ransac_samples) << k;
        earlier_samples_without += network_alone.candidates[k].ransac_samples;
        earlier_samples_with += candidate.ransac_samples;
        continue;
      }
      // Ranked by their matches, and only those with enough of them to be posed.
      EXPECT_TRUE(candidate.evaluated) << k;
      EXPECT_GE(candidate.num_matches, options.pose.min_inliers) << k;
      if (k > earlier) {
        EXPECT_LE(candidate.num_matches, result.candidates[k - 1].num_matches) << k;
      }
      last_round_images.insert(candidate.image_index);
    }
    EXPECT_EQ(last_round_images.size(), result.candidates.size() - earlier);
    ASSERT_TRUE(result.success) << result.failure_reason;
    EXPECT_EQ(result.candidates[result.best_candidate].source, CandidateSource::kNearestPoints);
    placed += WithinQuarterMetreAndTwoDegrees(set.ground_truth[q], result);
  }
  EXPECT_GE(placed, static_cast<int>(count) - 1);
  std::cout << "the earlier rounds' candidates drew " << earlier_samples_without
            << " RANSAC samples without the last round and " << earlier_samples_with
            << " with it\n";
  EXPECT_LT(earlier_samples_with, earlier_samples_without)
      << "the earlier candidates drew their whole budgets before the last round's pose";
}

// The last round's shortlist (the images with the most matches of a sample of the keypoints) holds
// the images that counting every image on every keypoint poses: the same candidates in the same
// order, the same pose.
TEST_F(SmallCityLocalizerTest, TheLastRoundsShortlistPosesWhatCountingEveryImagePoses) {
  const auto map = LocalizationMap::Load(localizer().map().dir());
  const Localizer localizer = WithUntrainedNetwork(map);
  const LocalizerOptions shortlisted;
  LocalizerOptions every_image = shortlisted;
  every_image.nearest_point_shortlist = 0;
  ASSERT_GT(map->scene().NumImages(), static_cast<size_t>(shortlisted.nearest_point_shortlist))
      << "the shortlist must leave images out for the test to mean anything";
  const QuerySet& set = Set("night");
  const size_t count = std::min<size_t>(set.queries.size(), 6);
  int compared = 0;
  for (size_t q = 0; q < count; ++q) {
    SCOPED_TRACE(set.queries[q].name);
    ASSERT_GT(set.queries[q].descriptors.rows(), kNearestPointSampleKeypoints);
    const PoseResult expected = localizer.Localize(set.queries[q], every_image);
    const PoseResult result = localizer.Localize(set.queries[q], shortlisted);
    ASSERT_EQ(result.candidates.size(), expected.candidates.size());
    for (size_t k = 0; k < result.candidates.size(); ++k) {
      EXPECT_EQ(result.candidates[k].image_index, expected.candidates[k].image_index) << k;
      EXPECT_EQ(result.candidates[k].source, expected.candidates[k].source) << k;
      compared += result.candidates[k].source == CandidateSource::kNearestPoints;
    }
    EXPECT_EQ(result.success, expected.success);
    EXPECT_TRUE(result.cam_from_world.rotation.isApprox(expected.cam_from_world.rotation, 1e-9));
    EXPECT_TRUE(
        result.cam_from_world.translation.isApprox(expected.cam_from_world.translation, 1e-9));
  }
  EXPECT_GT(compared, 10) << "the last round must run for the test to mean anything";
}

// Where the last round's first images give no pose, its second pass ranks the global ranking's
// next ones, and only then: a query placed by the first pass is left as it was. Each query is
// also sent with another query's global descriptor, whose first images show another street.
TEST_F(SmallCityLocalizerTest, TheLastRoundWidensOnlyWhereItsFirstImagesGiveNoPose) {
  const auto map = LocalizationMap::Load(localizer().map().dir());
  const Localizer localizer = WithUntrainedNetwork(map);
  LocalizerOptions narrow;
  narrow.nearest_point_candidates = 2;
  narrow.nearest_point_widened_candidates = 0;
  LocalizerOptions widened = narrow;
  widened.nearest_point_widened_candidates = 1000;
  ASSERT_LE(map->scene().NumImages(), 1000u) << "the second pass ranks every other image";
  const QuerySet& set = Set("day");
  const size_t count = std::min<size_t>(set.queries.size(), 6);
  int recovered = 0;
  int kept = 0;
  for (size_t q = 0; q < count; ++q) {
    for (const bool misled : {false, true}) {
      SCOPED_TRACE(set.queries[q].name + (misled ? ", misled" : ""));
      LocalizationQuery query = set.queries[q];
      if (misled) {
        query.global_descriptor =
            map->vlad()->Encode(set.queries[(q + count / 2) % count].descriptors);
      }
      const PoseResult first_pass = localizer.Localize(query, narrow);
      const PoseResult result = localizer.Localize(query, widened);
      ASSERT_GE(result.candidates.size(), first_pass.candidates.size());
      for (size_t k = 0; k < first_pass.candidates.size(); ++k) {
        EXPECT_EQ(result.candidates[k].image_index, first_pass.candidates[k].image_index) << k;
      }
      if (first_pass.success) {
        EXPECT_EQ(result.candidates.size(), first_pass.candidates.size());
        kept += WithinQuarterMetreAndTwoDegrees(set.ground_truth[q], first_pass);
        continue;
      }
      // The later passes' images come from past the first pass's ranks, each pass's from ranks
      // up to kNearestPointWideningFactor times as deep as the pass before: 2-10, 10-50,
      // 50-250, 250-1000, in that order.
      const std::vector<RetrievalHit> ranking =
          map->global_index().Search(*query.global_descriptor, 1000);
      const auto pass_of = [&](uint32_t image) {
        const auto rank =
            std::find_if(ranking.begin(), ranking.end(),
                         [&](const RetrievalHit& hit) { return hit.image_index == image; }) -
            ranking.begin();
        int pass = 0;
        for (int64_t end = narrow.nearest_point_candidates; rank >= end;
             end *= kNearestPointWideningFactor) {
          ++pass;
        }
        return pass;
      };
      int previous_pass = 1;
      for (size_t k = first_pass.candidates.size(); k < result.candidates.size(); ++k) {
        EXPECT_EQ(result.candidates[k].source, CandidateSource::kNearestPoints) << k;
        const int pass = pass_of(result.candidates[k].image_index);
        EXPECT_GE(pass, previous_pass) << k;
        previous_pass = pass;
      }
      recovered += WithinQuarterMetreAndTwoDegrees(set.ground_truth[q], result);
    }
  }
  EXPECT_GE(recovered, 3) << "the first pass must miss queries that the second places";
  EXPECT_GE(kept, 3) << "the first pass must place queries for the test to mean anything";
}

}  // namespace
}  // namespace hscloc
