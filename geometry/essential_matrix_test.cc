#include "geometry/essential_matrix.h"

#include <gtest/gtest.h>

#include <random>

namespace hscloc {
namespace {

TEST(EssentialMatrix, HoldsTheEpipolarConstraintOfRandomPosesAndPoints) {
  std::mt19937 random(7);
  std::uniform_real_distribution<double> uniform(-1, 1);
  for (int trial = 0; trial < 20; ++trial) {
    const Rigid3d cam2_from_cam1(
        Eigen::Quaterniond(
            Eigen::Vector4d(uniform(random), uniform(random), uniform(random), uniform(random))
                .normalized()),
        Eigen::Vector3d(uniform(random), uniform(random), uniform(random)));
    const Eigen::Matrix3d essential = EssentialMatrix(cam2_from_cam1);
    EXPECT_NEAR(essential.determinant(), 0, 1e-12);
    for (int point = 0; point < 10; ++point) {
      const Eigen::Vector3d in_cam1(uniform(random), uniform(random), 3 + uniform(random));
      const Eigen::Vector3d in_cam2 = cam2_from_cam1 * in_cam1;
      EXPECT_NEAR(in_cam2.normalized().dot(essential * in_cam1.normalized()), 0, 1e-12);
      // A point off the ray does not satisfy it.
      const Eigen::Vector3d off = in_cam2 + in_cam2.cross(cam2_from_cam1.translation).normalized();
      EXPECT_GT(std::abs(off.normalized().dot(essential * in_cam1.normalized())), 1e-3);
    }
  }
}

}  // namespace
}  // namespace hscloc
