// The essential matrix of two calibrated views with a known relative pose.
#pragma once

#include <Eigen/Core>

#include "geometry/rigid3d.h"

namespace hscloc {

// E = [t]x R of cam2_from_cam1 = (R, t): x2^T E x1 = 0 for the normalized homogeneous coordinates
// x1, x2 of one point seen by both cameras (Hartley and Zisserman, eq. 9.12).
Eigen::Matrix3d EssentialMatrix(const Rigid3d& cam2_from_cam1);

}  // namespace hscloc
