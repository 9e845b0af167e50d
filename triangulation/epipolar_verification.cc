#include "triangulation/epipolar_verification.h"

#include <cmath>
#include <limits>

#include "geometry/essential_matrix.h"
#include "util/check.h"

namespace hscloc {

void EpipolarVerificationOptions::Check() const {
  THROW_CHECK_MSG(max_epipolar_error_px > 0, "max_epipolar_error_px must be positive, not {}",
                  max_epipolar_error_px);
  THROW_CHECK_MSG(min_num_inliers >= 0, "min_num_inliers must not be negative, not {}",
                  min_num_inliers);
}

PosedKeypoints UndistortKeypoints(const Camera& camera, const Rigid3d& cam_from_world,
                                  const KeypointMatrix& keypoints) {
  PosedKeypoints posed;
  posed.cam_from_world = cam_from_world;
  posed.focal_length_px = camera.MeanFocalLength();
  posed.normalized.resize(keypoints.rows(), 2);
  for (int64_t i = 0; i < keypoints.rows(); ++i) {
    posed.normalized.row(i) = camera.CamFromImg(keypoints.row(i).cast<double>().transpose());
  }
  return posed;
}

std::vector<double> EpipolarErrorsPx(const PosedKeypoints& image1, const PosedKeypoints& image2,
                                     const std::vector<FeatureMatch>& matches) {
  const Rigid3d cam2_from_cam1 = image2.cam_from_world * image1.cam_from_world.Inverse();
  const Eigen::Matrix3d essential = EssentialMatrix(cam2_from_cam1);

  std::vector<double> errors;
  errors.reserve(matches.size());
  for (const FeatureMatch& match : matches) {
    const Eigen::Vector3d x1 = image1.normalized.row(match.point2D_idx1).transpose().homogeneous();
    const Eigen::Vector3d x2 = image2.normalized.row(match.point2D_idx2).transpose().homogeneous();
    const Eigen::Vector3d line_in2 = essential * x1;
    const Eigen::Vector3d line_in1 = essential.transpose() * x2;
    const double residual = std::abs(x2.dot(line_in2));
    const double error2 = image2.focal_length_px * residual / line_in2.head<2>().norm();
    const double error1 = image1.focal_length_px * residual / line_in1.head<2>().norm();
    const double error = std::max(error1, error2);
    // NaN from a keypoint without undistortion or a zero line compares false everywhere.
    errors.push_back(std::isnan(error) ? std::numeric_limits<double>::infinity() : error);
  }
  return errors;
}

VerifiedMatches VerifyWithKnownPoses(const PosedKeypoints& image1, const PosedKeypoints& image2,
                                     const std::vector<FeatureMatch>& matches,
                                     const EpipolarVerificationOptions& options) {
  options.Check();
  const std::vector<double> errors = EpipolarErrorsPx(image1, image2, matches);
  VerifiedMatches verified;
  for (size_t i = 0; i < matches.size(); ++i) {
    if (errors[i] <= options.max_epipolar_error_px) verified.inliers.push_back(matches[i]);
  }
  verified.accepted = static_cast<int>(verified.inliers.size()) >= options.min_num_inliers;
  return verified;
}

}  // namespace hscloc
