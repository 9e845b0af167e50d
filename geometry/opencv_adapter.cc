#include "geometry/opencv_adapter.h"

#include <Eigen/Geometry>

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

}  // namespace hscloc
