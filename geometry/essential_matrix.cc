#include "geometry/essential_matrix.h"

namespace hscloc {

Eigen::Matrix3d EssentialMatrix(const Rigid3d& cam2_from_cam1) {
  const Eigen::Vector3d& t = cam2_from_cam1.translation;
  Eigen::Matrix3d t_cross;
  t_cross << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  return t_cross * cam2_from_cam1.rotation.toRotationMatrix();
}

}  // namespace hscloc
