#include "triangulation/epipolar_verification.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// Lund's camera: an iPhone 4S with its radial distortion.
Camera LundCamera() {
  return Camera::FromModelName(1, "SIMPLE_RADIAL", 1024, 768, {995, 512, 384, 0.13});
}

// Two views a step apart along a street, turned 10 degrees, and points 5 to 20 m in front.
struct TwoViews {
  Camera camera = LundCamera();
  Rigid3d cam1_from_world;
  Rigid3d cam2_from_world{Eigen::Quaterniond(Eigen::AngleAxisd(0.17, Eigen::Vector3d::UnitY())),
                          Eigen::Vector3d(-1.0, 0.1, 0.3)};
  std::vector<Eigen::Vector3d> points_in_world;
  KeypointMatrix keypoints1;
  KeypointMatrix keypoints2;

  explicit TwoViews(int count) {
    std::mt19937 random(11);
    std::uniform_real_distribution<double> lateral(-4, 4);
    std::uniform_real_distribution<double> depth(5, 20);
    while (static_cast<int>(points_in_world.size()) < count) {
      const Eigen::Vector3d point(lateral(random), 0.5 * lateral(random), depth(random));
      const Eigen::Vector2d pixel1 = camera.ImgFromPointInCam(cam1_from_world * point);
      const Eigen::Vector2d pixel2 = camera.ImgFromPointInCam(cam2_from_world * point);
      if (camera.IsInside(pixel1) && camera.IsInside(pixel2)) points_in_world.push_back(point);
    }
    keypoints1.resize(count, 2);
    keypoints2.resize(count, 2);
    for (int i = 0; i < count; ++i) Project(i, points_in_world[i], points_in_world[i]);
  }

  void Project(int i, const Eigen::Vector3d& point1, const Eigen::Vector3d& point2) {
    keypoints1.row(i) = camera.ImgFromPointInCam(cam1_from_world * point1).cast<float>();
    keypoints2.row(i) = camera.ImgFromPointInCam(cam2_from_world * point2).cast<float>();
  }

  // The unit normal of the epipolar plane through both centres and `point`.
  Eigen::Vector3d EpipolarPlaneNormal(const Eigen::Vector3d& point) const {
    const Eigen::Vector3d center1 = CameraCenterInWorld(cam1_from_world);
    const Eigen::Vector3d center2 = CameraCenterInWorld(cam2_from_world);
    return (center2 - center1).cross(point - center1).normalized();
  }
};

std::vector<FeatureMatch> Diagonal(int count) {
  std::vector<FeatureMatch> matches;
  for (int i = 0; i < count; ++i) matches.push_back({point2D_t(i), point2D_t(i)});
  return matches;
}

TEST(EpipolarVerification, KeepsExactCorrespondencesAndDropsOffLineOnes) {
  const int count = 60;
  TwoViews views(count);
  // Every third correspondence: image 2 sees its point moved off the epipolar plane by 0.05 m per
  // metre of depth, about 50 px in either image (distortion changes it by some 10 %).
  for (int i = 0; i < count; i += 3) {
    const Eigen::Vector3d& point = views.points_in_world[i];
    const double depth = (views.cam2_from_world * point).z();
    views.Project(i, point, point + 0.05 * depth * views.EpipolarPlaneNormal(point));
  }
  const PosedKeypoints image1 =
      UndistortKeypoints(views.camera, views.cam1_from_world, views.keypoints1);
  const PosedKeypoints image2 =
      UndistortKeypoints(views.camera, views.cam2_from_world, views.keypoints2);
  EXPECT_EQ(image1.focal_length_px, 995);
  const std::vector<double> errors = EpipolarErrorsPx(image1, image2, Diagonal(count));
  for (int i = 0; i < count; ++i) {
    SCOPED_TRACE(i);
    if (i % 3 == 0) {
      EXPECT_GT(errors[i], 35);
      EXPECT_LT(errors[i], 70);
    } else {
      // float32 keypoints: a few thousandths of a pixel.
      EXPECT_LT(errors[i], 0.01);
    }
  }
  const VerifiedMatches verified = VerifyWithKnownPoses(image1, image2, Diagonal(count));
  EXPECT_TRUE(verified.accepted);
  ASSERT_EQ(verified.inliers.size(), 40u);
  for (const FeatureMatch& match : verified.inliers) EXPECT_NE(match.point2D_idx1 % 3, 0u);
  // The errors are symmetric in the two images.
  const std::vector<double> swapped = EpipolarErrorsPx(image2, image1, {{1, 1}, {3, 3}});
  EXPECT_NEAR(swapped[0], errors[1], 1e-9);
  EXPECT_NEAR(swapped[1], errors[3], 1e-9);
}

TEST(EpipolarVerification, DropsPairsWithTooFewInliers) {
  TwoViews views(20);
  const PosedKeypoints image1 =
      UndistortKeypoints(views.camera, views.cam1_from_world, views.keypoints1);
  const PosedKeypoints image2 =
      UndistortKeypoints(views.camera, views.cam2_from_world, views.keypoints2);
  const std::vector<FeatureMatch> matches = Diagonal(14);
  const VerifiedMatches few = VerifyWithKnownPoses(image1, image2, matches);
  EXPECT_EQ(few.inliers.size(), 14u);
  EXPECT_FALSE(few.accepted);
  EXPECT_TRUE(VerifyWithKnownPoses(image1, image2, matches, {.min_num_inliers = 14}).accepted);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                VerifyWithKnownPoses(image1, image2, matches, {.max_epipolar_error_px = 0});
              }),
              HasSubstr("max_epipolar_error_px"));
}

TEST(EpipolarVerification, KeypointsWithoutUndistortionAreOutliers) {
  TwoViews views(2);
  PosedKeypoints image1 = UndistortKeypoints(views.camera, views.cam1_from_world, views.keypoints1);
  const PosedKeypoints image2 =
      UndistortKeypoints(views.camera, views.cam2_from_world, views.keypoints2);
  image1.normalized(0, 0) = std::nan("");
  const std::vector<double> errors = EpipolarErrorsPx(image1, image2, Diagonal(2));
  EXPECT_TRUE(std::isinf(errors[0]));
  EXPECT_LT(errors[1], 0.01);
  // Coinciding centres have no epipolar geometry: nothing is an inlier.
  const std::vector<double> same = EpipolarErrorsPx(image1, image1, Diagonal(2));
  EXPECT_TRUE(std::isinf(same[1]));
}

}  // namespace
}  // namespace hscloc
