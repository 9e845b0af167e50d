#include "geometry/rigid3d.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

namespace hscloc {
namespace {

constexpr int kNumTrials = 200;

Eigen::Quaterniond RandomRotation(std::mt19937& rng) {
  std::normal_distribution<double> normal;
  // A normalized 4D Gaussian is uniform on the sphere of unit quaternions.
  return Eigen::Quaterniond(normal(rng), normal(rng), normal(rng), normal(rng)).normalized();
}

Eigen::Vector3d RandomVector(std::mt19937& rng, double scale) {
  std::normal_distribution<double> normal(0.0, scale);
  return Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
}

Rigid3d RandomRigid3d(std::mt19937& rng) {
  return Rigid3d(RandomRotation(rng), RandomVector(rng, 10.0));
}

Eigen::Vector3d RandomAxis(std::mt19937& rng) { return RandomVector(rng, 1.0).normalized(); }

::testing::AssertionResult TransformsNear(const Rigid3d& actual, const Rigid3d& expected,
                                          double tolerance) {
  const double difference = (actual.ToMatrix() - expected.ToMatrix()).cwiseAbs().maxCoeff();
  if (difference <= tolerance) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << "max |difference| " << difference << " > " << tolerance << "\nactual:\n"
         << actual.ToMatrix() << "\nexpected:\n"
         << expected.ToMatrix();
}

::testing::AssertionResult PointsNear(const Eigen::Vector3d& actual,
                                      const Eigen::Vector3d& expected, double tolerance) {
  const double distance = (actual - expected).norm();
  if (distance <= tolerance) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << "(" << actual.transpose() << ") is " << distance << " from (" << expected.transpose()
         << "), tolerance " << tolerance;
}

TEST(Rigid3d, ToMatrixActsLikeTheTransform) {
  std::mt19937 rng(1);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d b_from_a = RandomRigid3d(rng);
    const Eigen::Vector3d point_in_a = RandomVector(rng, 5.0);
    EXPECT_TRUE(
        PointsNear(b_from_a.ToMatrix() * point_in_a.homogeneous(), b_from_a * point_in_a, 1e-12));
  }
}

TEST(Rigid3d, ComposingWithTheInverseGivesIdentity) {
  std::mt19937 rng(2);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d b_from_a = RandomRigid3d(rng);
    EXPECT_TRUE(TransformsNear(b_from_a * b_from_a.Inverse(), Rigid3d(), 1e-12));
    EXPECT_TRUE(TransformsNear(b_from_a.Inverse() * b_from_a, Rigid3d(), 1e-12));
    EXPECT_TRUE(TransformsNear(b_from_a.Inverse().Inverse(), b_from_a, 1e-12));
  }
}

TEST(Rigid3d, CompositionIsAssociative) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d a = RandomRigid3d(rng);
    const Rigid3d b = RandomRigid3d(rng);
    const Rigid3d c = RandomRigid3d(rng);
    EXPECT_TRUE(TransformsNear((a * b) * c, a * (b * c), 1e-11));
  }
}

TEST(Rigid3d, ComposedTransformEqualsApplyingInSequence) {
  std::mt19937 rng(4);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d c_from_b = RandomRigid3d(rng);
    const Rigid3d b_from_a = RandomRigid3d(rng);
    const Eigen::Vector3d point_in_a = RandomVector(rng, 5.0);
    EXPECT_TRUE(
        PointsNear((c_from_b * b_from_a) * point_in_a, c_from_b * (b_from_a * point_in_a), 1e-11));
  }
}

TEST(Rigid3d, InverseMapsBack) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d b_from_a = RandomRigid3d(rng);
    const Eigen::Vector3d point_in_a = RandomVector(rng, 5.0);
    EXPECT_TRUE(PointsNear(b_from_a.Inverse() * (b_from_a * point_in_a), point_in_a, 1e-12));
  }
}

TEST(Rigid3d, CameraCenterMapsToTheCameraOrigin) {
  std::mt19937 rng(6);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d cam_from_world = RandomRigid3d(rng);
    const Eigen::Vector3d center_in_world = CameraCenterInWorld(cam_from_world);
    EXPECT_TRUE(PointsNear(cam_from_world * center_in_world, Eigen::Vector3d::Zero(), 1e-12));
    EXPECT_TRUE(PointsNear(center_in_world, cam_from_world.Inverse().translation, 1e-12));
  }
}

TEST(Rigid3d, CamFromWorldFromCenterRoundTrips) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Eigen::Vector3d center_in_world = RandomVector(rng, 10.0);
    const Eigen::Matrix3d world_from_cam_rotation = RandomRotation(rng).toRotationMatrix();
    const Rigid3d cam_from_world = CamFromWorldFromCenter(center_in_world, world_from_cam_rotation);
    EXPECT_TRUE(PointsNear(CameraCenterInWorld(cam_from_world), center_in_world, 1e-12));
    EXPECT_LT((cam_from_world.rotation.toRotationMatrix().transpose() - world_from_cam_rotation)
                  .cwiseAbs()
                  .maxCoeff(),
              1e-12);

    const Rigid3d original = RandomRigid3d(rng);
    const Rigid3d rebuilt = CamFromWorldFromCenter(
        CameraCenterInWorld(original), original.rotation.toRotationMatrix().transpose());
    EXPECT_TRUE(TransformsNear(rebuilt, original, 1e-12));
  }
}

TEST(Rigid3d, CamFromWorldFromCenterRejectsNonRotations) {
  const Eigen::Vector3d center = Eigen::Vector3d::Zero();
  const Eigen::Matrix3d scaled = 2.0 * Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d reflection = Eigen::Vector3d(1.0, 1.0, -1.0).asDiagonal();
  EXPECT_THROW(CamFromWorldFromCenter(center, scaled), std::invalid_argument);
  try {
    CamFromWorldFromCenter(center, reflection);
    FAIL() << "a reflection was accepted as a rotation";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), ::testing::HasSubstr("world_from_cam_rotation"));
  }
}

TEST(Rigid3d, RotationErrorOfKnownRotations) {
  std::mt19937 rng(8);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d a = RandomRigid3d(rng);
    for (const double angle_deg : {0.0, 1e-7, 1e-3, 30.0, 90.0, 179.999, 180.0}) {
      const Eigen::Quaterniond delta(Eigen::AngleAxisd(angle_deg * M_PI / 180.0, RandomAxis(rng)));
      // The translation must not matter.
      const Rigid3d b(delta * a.rotation, RandomVector(rng, 10.0));
      EXPECT_NEAR(RotationErrorDeg(a, b), angle_deg, 1e-9 * std::max(1.0, angle_deg));
      EXPECT_NEAR(RotationErrorDeg(b, a), angle_deg, 1e-9 * std::max(1.0, angle_deg));
    }
  }
}

TEST(Rigid3d, RotationErrorIgnoresTheQuaternionSign) {
  std::mt19937 rng(9);
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const Rigid3d a = RandomRigid3d(rng);
    Rigid3d negated = a;
    negated.rotation.coeffs() = -a.rotation.coeffs();
    EXPECT_NEAR(RotationErrorDeg(a, negated), 0.0, 1e-9);
  }
}

TEST(Rigid3d, RotationErrorOfThirtyDegreesAboutZ) {
  const Rigid3d a;
  const Rigid3d b(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 6.0, Eigen::Vector3d::UnitZ())),
                  Eigen::Vector3d::Zero());
  EXPECT_NEAR(RotationErrorDeg(a, b), 30.0, 1e-12);
}

TEST(Rigid3d, PositionErrorOfKnownCentres) {
  std::mt19937 rng(10);
  const Rigid3d a = CamFromWorldFromCenter(Eigen::Vector3d(1.0, 2.0, 3.0),
                                           RandomRotation(rng).toRotationMatrix());
  const Rigid3d b = CamFromWorldFromCenter(Eigen::Vector3d(4.0, 6.0, 3.0),
                                           RandomRotation(rng).toRotationMatrix());
  EXPECT_NEAR(PositionError(a, b), 5.0, 1e-12);
  EXPECT_NEAR(PositionError(b, a), 5.0, 1e-12);
  EXPECT_NEAR(PositionError(a, a), 0.0, 1e-12);
  // Same centre, different orientation: no position error.
  const Rigid3d c = CamFromWorldFromCenter(Eigen::Vector3d(1.0, 2.0, 3.0),
                                           RandomRotation(rng).toRotationMatrix());
  EXPECT_NEAR(PositionError(a, c), 0.0, 1e-12);
}

}  // namespace
}  // namespace hscloc
