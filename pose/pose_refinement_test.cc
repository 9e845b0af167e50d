#include "pose/pose_refinement.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <utility>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

Camera OpenCvCamera() {
  return Camera::FromModelName(1, "OPENCV", 1024, 768,
                               {900.0, 910.0, 515.0, 380.0, -0.12, 0.03, 0.001, -0.0005});
}

Camera FisheyeCamera() {
  return Camera::FromModelName(2, "OPENCV_FISHEYE", 1024, 768,
                               {500.0, 500.0, 512.0, 384.0, 0.05, -0.01, 0.002, 0.0});
}

// Noise-free correspondences seen by `camera` from `cam_from_world`.
struct Scene {
  std::vector<Eigen::Vector2d> keypoints_px;
  std::vector<Eigen::Vector3d> points_in_world;
};

Scene MakeScene(const Camera& camera, const Rigid3d& cam_from_world, int num_points,
                Random& random) {
  Scene scene;
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  while (static_cast<int>(scene.keypoints_px.size()) < num_points) {
    const Eigen::Vector2d pixel(random.Uniform(0, camera.width), random.Uniform(0, camera.height));
    const Eigen::Vector2d normalized = camera.CamFromImg(pixel);
    if (!normalized.allFinite()) continue;
    scene.keypoints_px.push_back(pixel);
    scene.points_in_world.push_back(world_from_cam *
                                    (random.Uniform(2, 30) * normalized.homogeneous()));
  }
  return scene;
}

Rigid3d Perturb(const Rigid3d& pose, double angle_rad, double offset_m, Random& random) {
  const Eigen::Vector3d axis =
      Eigen::Vector3d(random.Normal(), random.Normal(), random.Normal()).normalized();
  const Eigen::Vector3d offset(random.Normal(), random.Normal(), random.Normal());
  return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(angle_rad, axis)) * pose.rotation,
                 pose.translation + offset_m * offset.normalized());
}

std::vector<int> AllIndices(int count) {
  std::vector<int> indices(count);
  std::iota(indices.begin(), indices.end(), 0);
  return indices;
}

const Rigid3d kTruePose(
    Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized())),
    Eigen::Vector3d(0.5, -1.0, 2.0));

TEST(PoseRefinement, CeresConvergesToTheTruePoseThroughDistortion) {
  Random random(21);
  for (const Camera& camera : {OpenCvCamera(), FisheyeCamera()}) {
    const Scene scene = MakeScene(camera, kTruePose, 60, random);
    const Rigid3d start = Perturb(kTruePose, 0.05, 0.3, random);
    const PoseRefinementResult result =
        RefineAbsolutePose(camera, scene.keypoints_px, scene.points_in_world, AllIndices(60), start,
                           PoseRefinementOptions());
    ASSERT_TRUE(result.usable) << CameraModelName(camera.model_id);
    EXPECT_LT(RotationErrorDeg(result.cam_from_world, kTruePose), 1e-7)
        << CameraModelName(camera.model_id);
    EXPECT_LT(PositionError(result.cam_from_world, kTruePose), 1e-7)
        << CameraModelName(camera.model_id);
    EXPECT_LT(result.final_cost, 1e-12 * result.initial_cost);
  }
}

TEST(PoseRefinement, CauchyLossIgnoresAGrossOutlier) {
  Random random(22);
  const Camera camera = OpenCvCamera();
  Scene scene = MakeScene(camera, kTruePose, 60, random);
  scene.keypoints_px[7] += Eigen::Vector2d(9.0, -6.0);
  const PoseRefinementResult result =
      RefineAbsolutePose(camera, scene.keypoints_px, scene.points_in_world, AllIndices(60),
                         Perturb(kTruePose, 0.01, 0.05, random), PoseRefinementOptions());
  ASSERT_TRUE(result.usable);
  EXPECT_LT(RotationErrorDeg(result.cam_from_world, kTruePose), 0.01);
  EXPECT_LT(PositionError(result.cam_from_world, kTruePose), 0.005);
}

TEST(PoseRefinement, TooFewCorrespondencesAreNotUsable) {
  Random random(23);
  const Camera camera = OpenCvCamera();
  const Scene scene = MakeScene(camera, kTruePose, 2, random);
  const PoseRefinementResult result =
      RefineAbsolutePose(camera, scene.keypoints_px, scene.points_in_world, {0, 1}, kTruePose,
                         PoseRefinementOptions());
  EXPECT_FALSE(result.usable);
}

std::vector<NormalizedCorrespondence> Normalize(const Camera& camera, const Scene& scene) {
  std::vector<NormalizedCorrespondence> correspondences;
  for (size_t i = 0; i < scene.keypoints_px.size(); ++i) {
    NormalizedCorrespondence correspondence;
    correspondence.point2D_normalized = camera.CamFromImg(scene.keypoints_px[i]);
    correspondence.point3D_in_world = scene.points_in_world[i];
    const Eigen::Matrix2d jacobian =
        PixelFromNormalizedJacobian(camera, correspondence.point2D_normalized);
    correspondence.pixel_metric = jacobian.transpose() * jacobian;
    correspondences.push_back(correspondence);
  }
  return correspondences;
}

TEST(PoseRefinement, NormalizedPlaneRefinementConvergesToTheTruePose) {
  Random random(24);
  const Camera camera = FisheyeCamera();
  const Scene scene = MakeScene(camera, kTruePose, 50, random);
  // A threshold beyond every residual of the start: plain least squares.
  const Rigid3d refined = RefinePoseOnNormalizedPlane(
      Normalize(camera, scene), Perturb(kTruePose, 0.05, 0.3, random), 1e4, 20);
  EXPECT_LT(RotationErrorDeg(refined, kTruePose), 1e-7);
  EXPECT_LT(PositionError(refined, kTruePose), 1e-7);
}

TEST(PoseRefinement, NormalizedPlaneRefinementIgnoresMatchesBeyondTheThreshold) {
  Random random(26);
  const Camera camera = OpenCvCamera();
  Scene scene = MakeScene(camera, kTruePose, 200, random);
  // Half of the matches are wrong: their keypoints moved 30 to 300 px.
  for (size_t i = 0; i < scene.keypoints_px.size(); i += 2) {
    const double angle = random.Uniform(0, 2 * M_PI);
    scene.keypoints_px[i] +=
        random.Uniform(30, 300) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
  }
  const Rigid3d start = Perturb(kTruePose, 0.002, 0.02, random);
  const Rigid3d refined = RefinePoseOnNormalizedPlane(Normalize(camera, scene), start, 10.0, 25);
  EXPECT_LT(RotationErrorDeg(refined, kTruePose), 1e-7);
  EXPECT_LT(PositionError(refined, kTruePose), 1e-7);
}

TEST(PoseRefinement, PixelMetricGivesThePixelErrorOfSmallOffsets) {
  Random random(25);
  // The first-order error grows with the curvature of the projection: up to 4% at the corners of
  // the fisheye, 73 degrees off its axis.
  const std::pair<Camera, double> cameras_and_tolerances_px[] = {{OpenCvCamera(), 0.2},
                                                                 {FisheyeCamera(), 0.5}};
  for (const auto& [camera, tolerance_px] : cameras_and_tolerances_px) {
    const Scene scene = MakeScene(camera, kTruePose, 200, random);
    const std::vector<NormalizedCorrespondence> correspondences = Normalize(camera, scene);
    const Eigen::Matrix3d rotation = kTruePose.rotation.toRotationMatrix();
    for (size_t i = 0; i < correspondences.size(); ++i) {
      // Move the keypoint 10 px (the default threshold) in a random direction.
      const double angle = random.Uniform(0, 2 * M_PI);
      NormalizedCorrespondence moved = correspondences[i];
      moved.point2D_normalized = camera.CamFromImg(
          scene.keypoints_px[i] + 10.0 * Eigen::Vector2d(std::cos(angle), std::sin(angle)));
      if (!moved.point2D_normalized.allFinite()) continue;
      const double error_px = std::sqrt(moved.SquaredErrorPx(rotation, kTruePose.translation));
      EXPECT_NEAR(error_px, 10.0, tolerance_px)
          << CameraModelName(camera.model_id) << " at " << scene.keypoints_px[i].transpose();
    }
  }
}

TEST(PoseRefinement, SquaredErrorIsInfiniteBehindTheCamera) {
  NormalizedCorrespondence correspondence;
  correspondence.point3D_in_world = Eigen::Vector3d(0, 0, -1);
  EXPECT_TRUE(std::isinf(
      correspondence.SquaredErrorPx(Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero())));
}

TEST(PoseRefinement, CheckNamesTheBadField) {
  PoseRefinementOptions options;
  options.loss_scale_px = 0.0;
  EXPECT_THAT([&] { options.Check(); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("loss_scale_px")));
  options = PoseRefinementOptions();
  options.max_num_iterations = 0;
  EXPECT_THAT([&] { options.Check(); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("max_num_iterations")));
}

}  // namespace
}  // namespace hscloc
