// Minimal absolute pose: the camera pose from three 2D-3D correspondences (P3P).
#pragma once

#include <Eigen/Core>
#include <array>

#include "geometry/rigid3d.h"

namespace hscloc {

// Up to four poses; a fixed array so that a RANSAC loop calling the solver thousands of times
// allocates nothing.
struct P3PSolutions {
  std::array<Rigid3d, 4> cam_from_world;
  int num_solutions = 0;
};

// Lambda Twist P3P (Persson and Nordberg, "Lambda Twist: An Accurate Fast Robust Perspective Three
// Point (P3P) Solver", ECCV 2018): finds every cam_from_world with
// depth_i * ray_in_cam_i == cam_from_world * point_in_world_i and depth_i > 0.
//
// `rays_in_cam` are unit bearing vectors (normalized (x/z, y/z, 1) of an undistorted observation).
// Returns no solution for degenerate input (collinear or coincident world points, parallel rays);
// every returned pose is finite and has a unit quaternion.
P3PSolutions SolveP3P(const std::array<Eigen::Vector3d, 3>& rays_in_cam,
                      const std::array<Eigen::Vector3d, 3>& points_in_world);

}  // namespace hscloc
