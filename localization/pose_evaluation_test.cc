#include "localization/pose_evaluation.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// A pose whose camera centre lies `position_error` from the truth's and whose rotation differs by
// `rotation_error_deg`, about a random axis.
Rigid3d Perturbed(const Rigid3d& truth, double position_error, double rotation_error_deg,
                  Random& random) {
  const Eigen::Vector3d axis =
      Eigen::Vector3d(random.Normal(), random.Normal(), random.Normal()).normalized();
  const Eigen::Vector3d direction =
      Eigen::Vector3d(random.Normal(), random.Normal(), random.Normal()).normalized();
  const Eigen::Quaterniond rotation =
      Eigen::Quaterniond(Eigen::AngleAxisd(rotation_error_deg * M_PI / 180, axis)) * truth.rotation;
  const Eigen::Vector3d center = CameraCenterInWorld(truth) + position_error * direction;
  return Rigid3d(rotation, -(rotation * center));
}

std::vector<NamedPose> RandomTruth(int count, Random& random) {
  std::vector<NamedPose> truth;
  for (int i = 0; i < count; ++i) {
    Eigen::Quaterniond rotation(random.Normal(), random.Normal(), random.Normal(), random.Normal());
    truth.push_back({"query/day/" + std::to_string(i) + ".jpg",
                     Rigid3d(rotation.normalized(),
                             Eigen::Vector3d(random.Normal(0, 50), random.Normal(0, 50), 3))});
  }
  return truth;
}

TEST(PoseEvaluationTest, KnownErrorsAreRecovered) {
  Random random(3);
  const std::vector<NamedPose> truth = RandomTruth(6, random);
  const double positions[] = {0.1, 0.3, 0.1, 2.0, 20.0};
  const double rotations[] = {1.0, 1.0, 4.0, 9.0, 1.0};
  std::vector<NamedPose> results;
  for (int i = 0; i < 5; ++i) {
    // Submissions carry basenames; the sixth query has no result.
    results.push_back({ImageBasename(truth[i].name),
                       Perturbed(truth[i].cam_from_world, positions[i], rotations[i], random)});
  }
  const std::vector<QueryPoseError> errors = ComputePoseErrors(truth, results);
  ASSERT_EQ(errors.size(), 6u);
  for (int i = 0; i < 5; ++i) {
    EXPECT_TRUE(errors[i].estimated);
    EXPECT_NEAR(errors[i].position, positions[i], 1e-9);
    EXPECT_NEAR(errors[i].rotation_deg, rotations[i], 1e-6);
  }
  EXPECT_FALSE(errors[5].estimated);
  EXPECT_TRUE(std::isinf(errors[5].position));

  const ConditionAccuracy accuracy = SummarizeAccuracy("day", errors, AachenThresholds());
  EXPECT_EQ(accuracy.num_queries, 6u);
  EXPECT_EQ(accuracy.num_estimated, 5u);
  // (0.25 m, 2 deg): query 0; (0.5 m, 5 deg): 0, 1, 2; (5 m, 10 deg): 0 .. 3.
  EXPECT_DOUBLE_EQ(accuracy.localized_fraction[0], 1.0 / 6);
  EXPECT_DOUBLE_EQ(accuracy.localized_fraction[1], 3.0 / 6);
  EXPECT_DOUBLE_EQ(accuracy.localized_fraction[2], 4.0 / 6);
  // Sorted positions 0.1 0.1 0.3 2 20 inf: the median is (0.3 + 2) / 2.
  EXPECT_NEAR(accuracy.median_position, 1.15, 1e-9);
  EXPECT_NEAR(accuracy.median_rotation_deg, 2.5, 1e-6);

  const std::string table = FormatAccuracyTable({accuracy});
  EXPECT_THAT(table, HasSubstr("(0.25 m, 2 deg)"));
  EXPECT_THAT(table, HasSubstr("16.7%"));
  EXPECT_THAT(table, HasSubstr("66.7%"));
}

TEST(PoseEvaluationTest, PerfectResultsScoreFullMarks) {
  Random random(4);
  const std::vector<NamedPose> truth = RandomTruth(10, random);
  const ConditionAccuracy accuracy =
      SummarizeAccuracy("all", ComputePoseErrors(truth, truth), AachenThresholds());
  for (const double fraction : accuracy.localized_fraction) EXPECT_DOUBLE_EQ(fraction, 1.0);
  EXPECT_LT(accuracy.median_position, 1e-9);
  const ConditionAccuracy none =
      SummarizeAccuracy("all", ComputePoseErrors(truth, {}), AachenThresholds());
  for (const double fraction : none.localized_fraction) EXPECT_DOUBLE_EQ(fraction, 0.0);
  EXPECT_TRUE(std::isinf(none.median_position));
  EXPECT_THAT(FormatAccuracyTable({none}), HasSubstr(" - "));
}

TEST(PoseEvaluationTest, RejectsResultsThatDoNotMatchTheQueries) {
  Random random(5);
  const std::vector<NamedPose> truth = RandomTruth(3, random);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                ComputePoseErrors(truth, {{"other.jpg", truth[0].cam_from_world}});
              }),
              HasSubstr("'other.jpg' is not a query"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                ComputePoseErrors(truth, {truth[1], {"1.jpg", truth[1].cam_from_world}});
              }),
              HasSubstr("two poses"));
  std::vector<NamedPose> clashing = truth;
  clashing[2].name = "query/night/0.jpg";
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ComputePoseErrors(clashing, {}); }),
              HasSubstr("share the basename"));
}

}  // namespace
}  // namespace hscloc
