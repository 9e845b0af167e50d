#include "geometry/rigid3d.h"

#include <cmath>

#include "util/check.h"

namespace hscloc {

Eigen::Matrix<double, 3, 4> Rigid3d::ToMatrix() const {
  Eigen::Matrix<double, 3, 4> matrix;
  matrix.leftCols<3>() = rotation.toRotationMatrix();
  matrix.col(3) = translation;
  return matrix;
}

Rigid3d Rigid3d::Inverse() const {
  const Eigen::Quaterniond source_from_target = rotation.conjugate();
  return Rigid3d(source_from_target, -(source_from_target * translation));
}

Rigid3d operator*(const Rigid3d& a_from_b, const Rigid3d& b_from_c) {
  // Renormalized so that long chains of compositions do not drift off the unit sphere, which
  // Eigen's quaternion-vector product silently assumes.
  return Rigid3d((a_from_b.rotation * b_from_c.rotation).normalized(),
                 a_from_b.rotation * b_from_c.translation + a_from_b.translation);
}

Eigen::Vector3d CameraCenterInWorld(const Rigid3d& cam_from_world) {
  return -(cam_from_world.rotation.conjugate() * cam_from_world.translation);
}

Rigid3d CamFromWorldFromCenter(const Eigen::Vector3d& center_in_world,
                               const Eigen::Matrix3d& world_from_cam_rotation) {
  constexpr double kTolerance = 1e-6;
  const double orthonormality_error =
      (world_from_cam_rotation.transpose() * world_from_cam_rotation - Eigen::Matrix3d::Identity())
          .cwiseAbs()
          .maxCoeff();
  THROW_CHECK_MSG(orthonormality_error <= kTolerance && world_from_cam_rotation.determinant() > 0,
                  "world_from_cam_rotation is not a rotation (|R^T R - I| = {}, det = {})",
                  orthonormality_error, world_from_cam_rotation.determinant());
  const Eigen::Quaterniond cam_from_world_rotation =
      Eigen::Quaterniond(world_from_cam_rotation.transpose()).normalized();
  return Rigid3d(cam_from_world_rotation, -(cam_from_world_rotation * center_in_world));
}

double RotationErrorDeg(const Rigid3d& a, const Rigid3d& b) {
  const Eigen::Quaterniond a_from_b = a.rotation * b.rotation.conjugate();
  // atan2 of the half-angle's sine and cosine keeps full precision near 0 and 180 degrees, where
  // acos of the trace or of w loses half the digits; |w| folds q and -q onto the same rotation.
  const double half_angle = std::atan2(a_from_b.vec().norm(), std::abs(a_from_b.w()));
  return 2.0 * half_angle * 180.0 / M_PI;
}

double PositionError(const Rigid3d& cam_from_world_a, const Rigid3d& cam_from_world_b) {
  return (CameraCenterInWorld(cam_from_world_a) - CameraCenterInWorld(cam_from_world_b)).norm();
}

}  // namespace hscloc
