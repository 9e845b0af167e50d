// Conversions between hscloc's conventions and OpenCV's, kept in this one file.
//
// OpenCV's calib3d writes a pose as (rvec, tvec): the Rodrigues vector (axis times angle in
// radians) of the world-to-camera rotation and the world-to-camera translation. That is exactly
// cam_from_world, so the conversion only changes the rotation's parametrization.
#pragma once

#include <opencv2/core.hpp>

#include "geometry/rigid3d.h"

namespace hscloc {

struct OpenCvPose {
  cv::Vec3d rvec;
  cv::Vec3d tvec;
};

// The rotation angle of rvec is in [0, pi].
OpenCvPose OpenCvPoseFromRigid3d(const Rigid3d& cam_from_world);
// Accepts any rvec (its angle is taken modulo 2 pi); returns a unit quaternion.
Rigid3d Rigid3dFromOpenCvPose(const cv::Vec3d& rvec, const cv::Vec3d& tvec);

}  // namespace hscloc
