#include "pose/opencv_adapter.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <vector>

#include "util/random.h"

namespace hscloc {
namespace {

Rigid3d RandomPose(Random& random) {
  const Eigen::Quaterniond rotation =
      Eigen::Quaterniond(random.Normal(), random.Normal(), random.Normal(), random.Normal())
          .normalized();
  return Rigid3d(rotation,
                 Eigen::Vector3d(random.Normal(0, 10), random.Normal(0, 10), random.Normal(0, 10)));
}

TEST(OpenCvAdapter, PoseRoundTrip) {
  Random random(31);
  for (int trial = 0; trial < 500; ++trial) {
    const Rigid3d cam_from_world = RandomPose(random);
    const OpenCvPose pose = OpenCvPoseFromRigid3d(cam_from_world);
    EXPECT_LE(cv::norm(pose.rvec), M_PI + 1e-12);
    const Rigid3d back = Rigid3dFromOpenCvPose(pose.rvec, pose.tvec);
    EXPECT_LT(RotationErrorDeg(back, cam_from_world), 1e-9) << "trial " << trial;
    EXPECT_LT((back.translation - cam_from_world.translation).norm(), 1e-12) << "trial " << trial;
  }
}

TEST(OpenCvAdapter, IdentityAndHalfTurnRoundTrip) {
  for (const Rigid3d& cam_from_world :
       {Rigid3d(), Rigid3d(Eigen::Quaterniond(0, 1, 0, 0), Eigen::Vector3d(1, 2, 3)),
        Rigid3d(Eigen::Quaterniond(0, 0, 0, -1), Eigen::Vector3d::Zero())}) {
    const OpenCvPose pose = OpenCvPoseFromRigid3d(cam_from_world);
    EXPECT_LT(RotationErrorDeg(Rigid3dFromOpenCvPose(pose.rvec, pose.tvec), cam_from_world), 1e-9);
  }
}

TEST(OpenCvAdapter, RvecIsOpenCvsRodriguesVector) {
  Random random(32);
  for (int trial = 0; trial < 100; ++trial) {
    const Rigid3d cam_from_world = RandomPose(random);
    const OpenCvPose pose = OpenCvPoseFromRigid3d(cam_from_world);
    cv::Matx33d rotation;
    cv::Rodrigues(pose.rvec, rotation);
    const Eigen::Matrix3d expected = cam_from_world.rotation.toRotationMatrix();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(rotation(r, c), expected(r, c), 1e-12);
    }
  }
}

// cv::projectPoints with (rvec, tvec) maps world points as cam_from_world does.
TEST(OpenCvAdapter, ProjectPointsAgreesWithCamFromWorld) {
  Random random(33);
  const Rigid3d cam_from_world = RandomPose(random);
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  std::vector<cv::Point3d> points;
  std::vector<Eigen::Vector2d> expected;
  for (int i = 0; i < 20; ++i) {
    const Eigen::Vector3d point_in_cam(random.Uniform(-2, 2), random.Uniform(-2, 2),
                                       random.Uniform(1, 10));
    const Eigen::Vector3d point_in_world = world_from_cam * point_in_cam;
    points.emplace_back(point_in_world.x(), point_in_world.y(), point_in_world.z());
    expected.push_back(point_in_cam.hnormalized());
  }
  const OpenCvPose pose = OpenCvPoseFromRigid3d(cam_from_world);
  std::vector<cv::Point2d> projected;
  cv::projectPoints(points, pose.rvec, pose.tvec, cv::Matx33d::eye(), cv::noArray(), projected);
  for (size_t i = 0; i < points.size(); ++i) {
    EXPECT_NEAR(projected[i].x, expected[i].x(), 1e-12);
    EXPECT_NEAR(projected[i].y, expected[i].y(), 1e-12);
  }
}

}  // namespace
}  // namespace hscloc
