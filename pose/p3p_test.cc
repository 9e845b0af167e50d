#include "pose/p3p.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>

#include "util/random.h"

namespace hscloc {
namespace {

constexpr int kNumTrials = 2000;

Eigen::Quaterniond RandomRotation(Random& random) {
  // A normalized 4D Gaussian is uniform on the unit quaternions.
  return Eigen::Quaterniond(random.Normal(), random.Normal(), random.Normal(), random.Normal())
      .normalized();
}

struct P3PInstance {
  Rigid3d cam_from_world;
  std::array<Eigen::Vector3d, 3> rays_in_cam;
  std::array<Eigen::Vector3d, 3> points_in_world;
};

// Three points in front of the camera within a 90 degree field of view, 1 to 20 units away.
P3PInstance RandomInstance(Random& random) {
  P3PInstance instance;
  instance.cam_from_world =
      Rigid3d(RandomRotation(random),
              Eigen::Vector3d(random.Normal(0, 5), random.Normal(0, 5), random.Normal(0, 5)));
  const Rigid3d world_from_cam = instance.cam_from_world.Inverse();
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d direction(random.Uniform(-1, 1), random.Uniform(-1, 1), 1.0);
    instance.rays_in_cam[i] = direction.normalized();
    instance.points_in_world[i] =
        world_from_cam * (random.Uniform(1, 20) * instance.rays_in_cam[i]);
  }
  return instance;
}

double PoseDistance(const Rigid3d& a, const Rigid3d& b) {
  return (a.ToMatrix() - b.ToMatrix()).cwiseAbs().maxCoeff();
}

TEST(P3P, FindsTheTruePoseAmongItsSolutions) {
  Random random(11);
  int num_found = 0;
  double worst_found_distance = 0.0;
  for (int trial = 0; trial < kNumTrials; ++trial) {
    const P3PInstance instance = RandomInstance(random);
    const P3PSolutions solutions = SolveP3P(instance.rays_in_cam, instance.points_in_world);
    ASSERT_LE(solutions.num_solutions, 4);
    double best = std::numeric_limits<double>::infinity();
    for (int i = 0; i < solutions.num_solutions; ++i) {
      best = std::min(best, PoseDistance(solutions.cam_from_world[i], instance.cam_from_world));
    }
    if (best < 1e-6) {
      ++num_found;
      worst_found_distance = std::max(worst_found_distance, best);
    }
  }
  // Lambda Twist misses the true pose only in near-degenerate configurations.
  EXPECT_GE(num_found, kNumTrials * 999 / 1000) << "of " << kNumTrials << " random instances";
  EXPECT_LT(worst_found_distance, 1e-8);
}

TEST(P3P, EverySolutionExplainsTheThreeRays) {
  Random random(12);
  for (int trial = 0; trial < 200; ++trial) {
    const P3PInstance instance = RandomInstance(random);
    const P3PSolutions solutions = SolveP3P(instance.rays_in_cam, instance.points_in_world);
    for (int i = 0; i < solutions.num_solutions; ++i) {
      const Rigid3d& cam_from_world = solutions.cam_from_world[i];
      EXPECT_NEAR(cam_from_world.rotation.norm(), 1.0, 1e-12);
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d point_in_cam = cam_from_world * instance.points_in_world[k];
        EXPECT_GT(point_in_cam.z(), 0.0);
        EXPECT_LT((point_in_cam.normalized() - instance.rays_in_cam[k]).norm(), 1e-8)
            << "trial " << trial << ", solution " << i << ", point " << k;
      }
    }
  }
}

TEST(P3P, DegenerateWorldPointsGiveNoSolution) {
  Random random(13);
  P3PInstance instance = RandomInstance(random);
  // Collinear world points.
  instance.points_in_world[2] = 2.0 * instance.points_in_world[1] - instance.points_in_world[0];
  EXPECT_EQ(SolveP3P(instance.rays_in_cam, instance.points_in_world).num_solutions, 0);
  // Coincident world points.
  instance.points_in_world[1] = instance.points_in_world[0];
  EXPECT_EQ(SolveP3P(instance.rays_in_cam, instance.points_in_world).num_solutions, 0);
}

}  // namespace
}  // namespace hscloc
