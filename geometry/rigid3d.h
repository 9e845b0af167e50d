// Rigid transforms named target_from_source: `cam_from_world * point_in_world == point_in_cam`.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace hscloc {

struct Rigid3d {
  // Unit quaternion; files store it w first (COLMAP: QW QX QY QZ).
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3d() = default;
  Rigid3d(const Eigen::Quaterniond& rotation, const Eigen::Vector3d& translation)
      : rotation(rotation), translation(translation) {}

  // The 3x4 matrix [R | t].
  Eigen::Matrix<double, 3, 4> ToMatrix() const;
  // source_from_target.
  Rigid3d Inverse() const;
  Eigen::Vector3d operator*(const Eigen::Vector3d& point_in_source) const {
    return rotation * point_in_source + translation;
  }
};

// a_from_c = a_from_b * b_from_c.
Rigid3d operator*(const Rigid3d& a_from_b, const Rigid3d& b_from_c);

// The camera centre in world coordinates: -R^T t.
Eigen::Vector3d CameraCenterInWorld(const Rigid3d& cam_from_world);

// Builds cam_from_world from a camera centre in world and a world_from_cam rotation.
Rigid3d CamFromWorldFromCenter(const Eigen::Vector3d& center_in_world,
                               const Eigen::Matrix3d& world_from_cam_rotation);

// Angle of the relative rotation between two transforms, in degrees, in [0, 180].
double RotationErrorDeg(const Rigid3d& a, const Rigid3d& b);

// Distance between the camera centres of two cam_from_world transforms, in world units.
double PositionError(const Rigid3d& cam_from_world_a, const Rigid3d& cam_from_world_b);

}  // namespace hscloc
