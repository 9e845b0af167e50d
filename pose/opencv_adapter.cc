#include "pose/opencv_adapter.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>

#include "util/random.h"

namespace hscloc {

OpenCvPose OpenCvPoseFromRigid3d(const Rigid3d& cam_from_world) {
  // AngleAxis picks the angle in [0, pi] for a quaternion of either sign.
  const Eigen::AngleAxisd angle_axis(cam_from_world.rotation.normalized());
  const Eigen::Vector3d rvec = angle_axis.angle() * angle_axis.axis();
  const Eigen::Vector3d& t = cam_from_world.translation;
  return {cv::Vec3d(rvec.x(), rvec.y(), rvec.z()), cv::Vec3d(t.x(), t.y(), t.z())};
}

Rigid3d Rigid3dFromOpenCvPose(const cv::Vec3d& rvec, const cv::Vec3d& tvec) {
  const Eigen::Vector3d axis_angle(rvec[0], rvec[1], rvec[2]);
  const double angle = axis_angle.norm();
  const Eigen::Quaterniond rotation =
      angle > 0.0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis_angle / angle))
                  : Eigen::Quaterniond::Identity();
  return Rigid3d(rotation.normalized(), Eigen::Vector3d(tvec[0], tvec[1], tvec[2]));
}

OpenCvUsacResult EstimatePoseWithOpenCvUsac(
    const std::vector<NormalizedCorrespondence>& correspondences, double focal_length_px,
    const AbsolutePoseOptions& options) {
  const int num_data = static_cast<int>(correspondences.size());
  cv::Mat object_points(num_data, 3, CV_64F);
  cv::Mat image_points(num_data, 2, CV_64F);
  for (int i = 0; i < num_data; ++i) {
    const NormalizedCorrespondence& correspondence = correspondences[i];
    for (int k = 0; k < 3; ++k) object_points.at<double>(i, k) = correspondence.point3D_in_world[k];
    for (int k = 0; k < 2; ++k) {
      image_points.at<double>(i, k) = focal_length_px * correspondence.point2D_normalized[k];
    }
  }
  const cv::Matx33d camera_matrix(focal_length_px, 0, 0, 0, focal_length_px, 0, 0, 0, 1);

  cv::UsacParams params;
  // OpenCV's bound log(1 - confidence) is -inf at 1; the nearest double below 1 means "never".
  params.confidence = std::min(options.confidence, std::nextafter(1.0, 0.0));
  params.isParallel = false;
  params.loIterations = 5;
  params.loMethod = options.local_optimization ? cv::LOCAL_OPTIM_INNER_LO : cv::LOCAL_OPTIM_NULL;
  params.loSampleSize = 14;
  params.maxIterations = options.max_iterations;
  params.neighborsSearch = cv::NEIGH_GRID;
  params.randomGeneratorState = static_cast<int>(MixBits(options.seed) >> 33);
  params.sampler = cv::SAMPLING_UNIFORM;
  params.score = cv::SCORE_METHOD_MSAC;
  params.threshold = options.max_reprojection_error_px;

  OpenCvUsacResult outcome;
  cv::Vec3d rvec, tvec;
  std::vector<int> inliers;
  try {
    outcome.found = cv::solvePnPRansac(object_points, image_points, camera_matrix, cv::noArray(),
                                       rvec, tvec, inliers, params);
  } catch (const cv::Exception& exception) {
    // OpenCV asserts on some degenerate samples; for valid input that is a failed estimate.
    outcome.error = exception.what();
    return outcome;
  }
  if (outcome.found) outcome.cam_from_world = Rigid3dFromOpenCvPose(rvec, tvec);
  outcome.found = outcome.found && outcome.cam_from_world.translation.allFinite() &&
                  outcome.cam_from_world.rotation.coeffs().allFinite();
  return outcome;
}

}  // namespace hscloc
