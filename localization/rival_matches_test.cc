#include "localization/rival_matches.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <stdexcept>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;

CandidateMatches Predictions(const std::vector<int>& keypoints, const std::vector<uint32_t>& points,
                             const std::vector<float>& confidences) {
  return {keypoints, points, confidences};
}

TEST(RivalMatches, MostConfidentKeypointStandsForItsPoint) {
  // Point 7 has rivals 0, 2 and 4 (4 the most confident); point 3 rivals 1 and 5 with equal
  // confidence (the first wins); point 9 has keypoint 3 alone.
  const CandidateMatches predictions =
      Predictions({0, 1, 2, 3, 4, 5}, {7, 3, 7, 9, 7, 3}, {0.5f, 0.9f, 0.8f, 0.2f, 0.99f, 0.9f});
  const CandidateMatches chosen = MostConfidentKeypointPerPoint(predictions);
  EXPECT_THAT(chosen.keypoints, ElementsAre(1, 3, 4));
  EXPECT_THAT(chosen.point_indices, ElementsAre(3, 9, 7));
  EXPECT_THAT(chosen.confidences, ElementsAre(0.9f, 0.2f, 0.99f));
  EXPECT_EQ(MostConfidentKeypointPerPoint({}).size(), 0u);
  EXPECT_THROW(MostConfidentKeypointPerPoint(Predictions({0, 1}, {7, 7}, {})),
               std::invalid_argument);
  EXPECT_THROW(MostConfidentKeypointPerPoint(Predictions({0, -1}, {7, 7}, {0.5f, 0.6f})),
               std::invalid_argument);
}

// Against a brute-force reference on many rivals: for each point, the first of its most
// confident keypoints, the survivors in keypoint order (keypoints repeat: a keypoint predicts a
// point per level of rivals).
TEST(RivalMatches, MostConfidentKeypointMatchesABruteForceReference) {
  Random random(3);
  for (int trial = 0; trial < 20; ++trial) {
    CandidateMatches predictions;
    for (int i = 0; i < 300; ++i) {
      predictions.keypoints.push_back(static_cast<int>(random.UniformInt(100)));
      predictions.point_indices.push_back(static_cast<uint32_t>(random.UniformInt(40)));
      // Few distinct confidences, so that ties are common.
      predictions.confidences.push_back(static_cast<float>(random.UniformInt(5)) / 4);
    }
    std::vector<size_t> expected;
    for (size_t i = 0; i < predictions.size(); ++i) {
      bool best = true;
      for (size_t j = 0; j < predictions.size() && best; ++j) {
        if (predictions.point_indices[j] != predictions.point_indices[i]) continue;
        best = predictions.confidences[j] < predictions.confidences[i] ||
               (predictions.confidences[j] == predictions.confidences[i] && j >= i);
      }
      if (best) expected.push_back(i);
    }
    std::stable_sort(expected.begin(), expected.end(), [&](size_t a, size_t b) {
      return predictions.keypoints[a] < predictions.keypoints[b];
    });
    const CandidateMatches chosen = MostConfidentKeypointPerPoint(predictions);
    ASSERT_EQ(chosen.size(), expected.size());
    for (size_t k = 0; k < expected.size(); ++k) {
      EXPECT_EQ(chosen.keypoints[k], predictions.keypoints[expected[k]]);
      EXPECT_EQ(chosen.point_indices[k], predictions.point_indices[expected[k]]);
    }
  }
}

// A pinhole camera at the origin looking down +z: point i at depth 10 m reprojects on the pixel
// it was made from.
struct RivalScene {
  Camera camera = Camera::FromModelName(1, "PINHOLE", 640, 480, {500, 500, 320, 240});
  std::vector<Eigen::Vector3d> points;
  KeypointMatrix keypoints;
};

TEST(RivalMatches, NearestKeypointToThePosesReprojectionWins) {
  Random random(3);
  RivalScene scene;
  const int num_points = 50;
  // Keypoint 2i: the point's true pixel plus 1 px noise; keypoint 2i + 1: a rival 4 to 9 px off,
  // more confident.
  scene.keypoints.resize(2 * num_points, 2);
  CandidateMatches predictions;
  for (int i = 0; i < num_points; ++i) {
    const Eigen::Vector2d pixel(random.Uniform(20, 620), random.Uniform(20, 460));
    scene.points.push_back(10.0 * scene.camera.CamFromImg(pixel).homogeneous());
    const double angle = random.Uniform(0, 2 * M_PI);
    const Eigen::Vector2d noise(random.Normal(0, 0.5), random.Normal(0, 0.5));
    const Eigen::Vector2d offset =
        random.Uniform(4, 9) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
    scene.keypoints.row(2 * i) = (pixel + noise).cast<float>().transpose();
    scene.keypoints.row(2 * i + 1) = (pixel + offset).cast<float>().transpose();
    for (const int keypoint : {2 * i, 2 * i + 1}) {
      predictions.keypoints.push_back(keypoint);
      predictions.point_indices.push_back(i);
      predictions.confidences.push_back(keypoint % 2 == 1 ? 0.99f : 0.6f);
    }
  }
  const CandidateMatches by_confidence = MostConfidentKeypointPerPoint(predictions);
  const CandidateMatches by_pose =
      NearestKeypointPerPoint(predictions, scene.keypoints, scene.camera, Rigid3d(), scene.points);
  ASSERT_EQ(by_confidence.size(), static_cast<size_t>(num_points));
  ASSERT_EQ(by_pose.size(), static_cast<size_t>(num_points));
  for (int i = 0; i < num_points; ++i) {
    EXPECT_EQ(by_confidence.keypoints[i], 2 * i + 1);
    EXPECT_EQ(by_pose.keypoints[i], 2 * i);
    EXPECT_EQ(by_pose.point_indices[i], static_cast<uint32_t>(i));
  }
  // Behind the camera no keypoint is nearer than another: confidence decides.
  const Rigid3d turned_around(Eigen::Quaterniond(0, 1, 0, 0), Eigen::Vector3d::Zero());
  const CandidateMatches behind = NearestKeypointPerPoint(
      predictions, scene.keypoints, scene.camera, turned_around, scene.points);
  EXPECT_EQ(behind.keypoints, by_confidence.keypoints);
  EXPECT_THROW(NearestKeypointPerPoint(Predictions({0}, {0}, {}), scene.keypoints, scene.camera,
                                       Rigid3d(), scene.points),
               std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
