// Non-linear refinement of an absolute pose from 2D-3D correspondences with known intrinsics.
//
// Two refiners: a Gauss-Newton one on undistorted image coordinates that LO-RANSAC runs many
// times, and a robust Ceres one on the reprojection error in pixels through the real camera model
// that runs once on the final inliers (as COLMAP refines registered poses).
#pragma once

#include <Eigen/Core>
#include <limits>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"

namespace hscloc {

// A correspondence prepared for fast scoring: the keypoint undistorted to normalized coordinates
// and the local metric that turns an offset there into pixels of the real image.
struct NormalizedCorrespondence {
  Eigen::Vector2d point2D_normalized = Eigen::Vector2d::Zero();
  Eigen::Vector3d point3D_in_world = Eigen::Vector3d::Zero();
  // J^T J, with J the Jacobian of Camera::ImgFromCam at point2D_normalized: e^T M e is the squared
  // pixel length of a small offset e in normalized coordinates. Exact for the pinhole models, a
  // first-order approximation within the inlier threshold for the distorted ones.
  Eigen::Matrix2d pixel_metric = Eigen::Matrix2d::Identity();

  // Squared reprojection error in pixels (to first order), or +infinity behind the camera.
  // Inline: RANSAC calls it for every correspondence of every hypothesis.
  double SquaredErrorPx(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation) const {
    const Eigen::Vector3d point_in_cam = rotation * point3D_in_world + translation;
    if (!(point_in_cam.z() > 0.0)) return std::numeric_limits<double>::infinity();
    const Eigen::Vector2d error = point_in_cam.hnormalized() - point2D_normalized;
    return error.dot(pixel_metric * error);
  }
};

// The Jacobian of Camera::ImgFromCam at `normalized` (pixels per normalized unit), by central
// differences: Camera exposes no analytic derivatives, and differences of its double-precision
// projection are accurate to about 1e-9 relative.
Eigen::Matrix2d PixelFromNormalizedJacobian(const Camera& camera,
                                            const Eigen::Vector2d& normalized);

// Levenberg-Marquardt on the MSAC cost sum_i min(e_i^T M_i e_i, max_error_px^2) over all
// correspondences: a least-squares fit to the inliers that re-selects them at every iteration, so
// a rough pose gathers inliers as it improves (PoseLib's local optimization with a truncated
// loss). Returns the initial pose when no step lowers the cost.
Rigid3d RefinePoseOnNormalizedPlane(const std::vector<NormalizedCorrespondence>& correspondences,
                                    const Rigid3d& initial_cam_from_world, double max_error_px,
                                    int max_iterations);

struct PoseRefinementOptions {
  // Scale of the Cauchy loss on the pixel reprojection error, in pixels. A wrong match 10 px off
  // weighs 1 / (1 + 10^2 / 2^2) = 4% of its least-squares weight, while 1-2 px keypoint noise
  // keeps most of its weight: at 1 px noise, COLMAP's 1 px gave an 11% larger mean position
  // error (docs/decisions.md).
  double loss_scale_px = 2.0;
  // Levenberg-Marquardt iterations of Ceres.
  int max_num_iterations = 50;

  // Throws std::invalid_argument naming the field.
  void Check() const;
};

struct PoseRefinementResult {
  Rigid3d cam_from_world;
  // False where Ceres reports no usable solution (e.g. a point left the front of the camera at
  // the start); cam_from_world is then the initial pose.
  bool usable = false;
  // Ceres iterations, the evaluation at the start included.
  int num_iterations = 0;
  // Ceres costs: 1/2 sum of the robustified squared pixel errors.
  double initial_cost = 0.0;
  double final_cost = 0.0;
};

// Minimizes the Cauchy-robustified reprojection error in pixels, through `camera` with its
// intrinsics fixed, of the correspondences `indices`; the rotation lives on the unit quaternion
// manifold. `keypoints_px` use COLMAP's pixel convention. Thread-safe (one Ceres problem per call,
// one thread).
PoseRefinementResult RefineAbsolutePose(const Camera& camera,
                                        const std::vector<Eigen::Vector2d>& keypoints_px,
                                        const std::vector<Eigen::Vector3d>& points_in_world,
                                        const std::vector<int>& indices,
                                        const Rigid3d& initial_cam_from_world,
                                        const PoseRefinementOptions& options);

}  // namespace hscloc
