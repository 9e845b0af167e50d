// Conversions between hscloc's conventions and OpenCV's, kept in this one file.
//
// OpenCV's calib3d writes a pose as (rvec, tvec): the Rodrigues vector (axis times angle in
// radians) of the world-to-camera rotation and the world-to-camera translation. That is exactly
// cam_from_world, so the conversion only changes the rotation's parametrization.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "geometry/rigid3d.h"
#include "pose/absolute_pose.h"
#include "pose/pose_refinement.h"

namespace hscloc {

struct OpenCvPose {
  cv::Vec3d rvec;
  cv::Vec3d tvec;
};

// The rotation angle of rvec is in [0, pi].
OpenCvPose OpenCvPoseFromRigid3d(const Rigid3d& cam_from_world);
// Accepts any rvec (its angle is taken modulo 2 pi); returns a unit quaternion.
Rigid3d Rigid3dFromOpenCvPose(const cv::Vec3d& rvec, const cv::Vec3d& tvec);

struct OpenCvUsacResult {
  bool found = false;
  Rigid3d cam_from_world;
  // Set where OpenCV threw (it asserts on some degenerate samples).
  std::string error;
};

// cv::solvePnPRansac with USAC on undistorted points, shown to OpenCV as a pinhole camera with the
// mean focal length so that its threshold is in (approximate) pixels. Every UsacParams field is
// set, so no OpenCV default or global state (its RNG, its thread pool) leaks in.
OpenCvUsacResult EstimatePoseWithOpenCvUsac(
    const std::vector<NormalizedCorrespondence>& correspondences, double focal_length_px,
    const AbsolutePoseOptions& options);

}  // namespace hscloc
