#include "pose/pose_refinement.h"

#include <ceres/ceres.h>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <cmath>
#include <memory>

#include "util/check.h"

namespace hscloc {
namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

// Large enough that the rounding of ImgFromCam (about 1e-13 px at 1000 px) stays far below the
// difference, small enough that the truncation error (h^2 times the third derivative) does too.
constexpr double kDifferenceStep = 1e-6;

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d skew;
  skew << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return skew;
}

// d(x/z, y/z) / d(x, y, z).
Eigen::Matrix<double, 2, 3> NormalizedFromCamJacobian(const Eigen::Vector3d& point_in_cam) {
  const double inverse_z = 1.0 / point_in_cam.z();
  Eigen::Matrix<double, 2, 3> jacobian;
  jacobian << inverse_z, 0.0, -point_in_cam.x() * inverse_z * inverse_z,  //
      0.0, inverse_z, -point_in_cam.y() * inverse_z * inverse_z;
  return jacobian;
}

struct NormalEquations {
  Matrix6d hessian = Matrix6d::Zero();
  Vector6d gradient = Vector6d::Zero();
  double cost = 0.0;
};

// Gauss-Newton normal equations of the truncated cost in the left-multiplied tangent
// (omega, delta_t): R <- exp(omega) R, t <- t + delta_t. Correspondences beyond the threshold add
// the constant threshold^2 and no gradient.
NormalEquations Accumulate(const std::vector<NormalizedCorrespondence>& correspondences,
                           const Rigid3d& cam_from_world, double squared_threshold) {
  const Eigen::Matrix3d rotation = cam_from_world.rotation.toRotationMatrix();
  NormalEquations equations;
  for (const NormalizedCorrespondence& correspondence : correspondences) {
    const Eigen::Vector3d rotated = rotation * correspondence.point3D_in_world;
    const Eigen::Vector3d point_in_cam = rotated + cam_from_world.translation;
    if (!(point_in_cam.z() > 0.0)) {
      equations.cost += squared_threshold;
      continue;
    }
    const Eigen::Vector2d residual = point_in_cam.hnormalized() - correspondence.point2D_normalized;
    const double squared_error = residual.dot(correspondence.pixel_metric * residual);
    if (!(squared_error <= squared_threshold)) {
      equations.cost += squared_threshold;
      continue;
    }
    equations.cost += squared_error;
    const Eigen::Matrix<double, 2, 3> d_normalized = NormalizedFromCamJacobian(point_in_cam);
    Eigen::Matrix<double, 2, 6> jacobian;
    jacobian.leftCols<3>() = -d_normalized * Skew(rotated);
    jacobian.rightCols<3>() = d_normalized;
    const Eigen::Matrix<double, 6, 2> weighted = jacobian.transpose() * correspondence.pixel_metric;
    equations.hessian.noalias() += weighted * jacobian;
    equations.gradient.noalias() += weighted * residual;
  }
  return equations;
}

Rigid3d ApplyStep(const Rigid3d& cam_from_world, const Vector6d& step) {
  const Eigen::Vector3d omega = step.head<3>();
  const double angle = omega.norm();
  const Eigen::Quaterniond delta = angle > 0.0
                                       ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, omega / angle))
                                       : Eigen::Quaterniond::Identity();
  return Rigid3d((delta * cam_from_world.rotation).normalized(),
                 cam_from_world.translation + step.tail<3>());
}

// Reprojection error in pixels through the real camera model. Analytic in the pose, with the
// camera's 2x2 Jacobian by differences (Camera is not templated for automatic differentiation).
class PixelReprojectionCost final : public ceres::SizedCostFunction<2, 4, 3> {
 public:
  PixelReprojectionCost(const Camera& camera, const Eigen::Vector2d& keypoint_px,
                        const Eigen::Vector3d& point_in_world)
      : camera_(camera), keypoint_px_(keypoint_px), point_in_world_(point_in_world) {}

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    // Eigen stores the quaternion x, y, z, w, which is the order EigenQuaternionManifold expects.
    const Eigen::Map<const Eigen::Quaterniond> rotation(parameters[0]);
    const Eigen::Map<const Eigen::Vector3d> translation(parameters[1]);
    const Eigen::Vector3d point_in_cam = rotation * point_in_world_ + translation;
    // Returning false makes Ceres reject a step that moves a point behind the camera.
    if (!(point_in_cam.z() > 0.0)) return false;
    const Eigen::Vector2d normalized = point_in_cam.hnormalized();
    const Eigen::Vector2d pixel = camera_.ImgFromCam(normalized);
    if (!pixel.allFinite()) return false;
    Eigen::Map<Eigen::Vector2d> residual(residuals);
    residual = pixel - keypoint_px_;
    if (jacobians == nullptr) return true;

    const Eigen::Matrix<double, 2, 3> d_pixel_d_cam =
        PixelFromNormalizedJacobian(camera_, normalized) * NormalizedFromCamJacobian(point_in_cam);
    if (jacobians[0] != nullptr) {
      // Eigen rotates by X + 2w (v x X) + 2 v x (v x X) with q = (v, w); these are its partial
      // derivatives, which the manifold restricts to the unit sphere.
      const Eigen::Vector3d v = rotation.vec();
      const double w = rotation.w();
      const Eigen::Vector3d& x = point_in_world_;
      Eigen::Matrix<double, 3, 4> d_cam_d_quaternion;
      d_cam_d_quaternion.leftCols<3>() =
          -2.0 * w * Skew(x) + 2.0 * (v.dot(x) * Eigen::Matrix3d::Identity() + v * x.transpose() -
                                      2.0 * x * v.transpose());
      d_cam_d_quaternion.col(3) = 2.0 * v.cross(x);
      Eigen::Map<Eigen::Matrix<double, 2, 4, Eigen::RowMajor>> d_residual_d_quaternion(
          jacobians[0]);
      d_residual_d_quaternion = d_pixel_d_cam * d_cam_d_quaternion;
    }
    if (jacobians[1] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>> d_residual_d_translation(
          jacobians[1]);
      d_residual_d_translation = d_pixel_d_cam;
    }
    return true;
  }

 private:
  const Camera& camera_;
  const Eigen::Vector2d keypoint_px_;
  const Eigen::Vector3d point_in_world_;
};

}  // namespace

Eigen::Matrix2d PixelFromNormalizedJacobian(const Camera& camera,
                                            const Eigen::Vector2d& normalized) {
  Eigen::Matrix2d jacobian;
  for (int axis = 0; axis < 2; ++axis) {
    Eigen::Vector2d offset = Eigen::Vector2d::Zero();
    offset[axis] = kDifferenceStep;
    jacobian.col(axis) =
        (camera.ImgFromCam(normalized + offset) - camera.ImgFromCam(normalized - offset)) /
        (2.0 * kDifferenceStep);
  }
  return jacobian;
}

Rigid3d RefinePoseOnNormalizedPlane(const std::vector<NormalizedCorrespondence>& correspondences,
                                    const Rigid3d& initial_cam_from_world, double max_error_px,
                                    int max_iterations) {
  const double squared_threshold = max_error_px * max_error_px;
  Rigid3d cam_from_world = initial_cam_from_world;
  NormalEquations equations = Accumulate(correspondences, cam_from_world, squared_threshold);
  double damping = 1e-4;
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    Matrix6d damped = equations.hessian;
    damped.diagonal() *= 1.0 + damping;
    const Vector6d step = damped.ldlt().solve(-equations.gradient);
    if (!step.allFinite()) break;
    const Rigid3d candidate = ApplyStep(cam_from_world, step);
    const NormalEquations candidate_equations =
        Accumulate(correspondences, candidate, squared_threshold);
    if (candidate_equations.cost < equations.cost) {
      const double decrease = equations.cost - candidate_equations.cost;
      cam_from_world = candidate;
      equations = candidate_equations;
      damping = std::max(damping * 0.1, 1e-10);
      // Converged once a step gains less than rounding noise of the cost.
      if (decrease <= 1e-12 * equations.cost) break;
    } else {
      damping *= 10.0;
      if (damping > 1e6) break;
    }
  }
  return cam_from_world;
}

void PoseRefinementOptions::Check() const {
  if (!(loss_scale_px > 0.0) || !std::isfinite(loss_scale_px)) {
    ThrowInvalidArgument("PoseRefinementOptions.loss_scale_px is {}, must be positive",
                         loss_scale_px);
  }
  if (max_num_iterations < 1) {
    ThrowInvalidArgument("PoseRefinementOptions.max_num_iterations is {}, must be at least 1",
                         max_num_iterations);
  }
}

PoseRefinementResult RefineAbsolutePose(const Camera& camera,
                                        const std::vector<Eigen::Vector2d>& keypoints_px,
                                        const std::vector<Eigen::Vector3d>& points_in_world,
                                        const std::vector<int>& indices,
                                        const Rigid3d& initial_cam_from_world,
                                        const PoseRefinementOptions& options) {
  options.Check();
  THROW_CHECK_EQ(keypoints_px.size(), points_in_world.size());
  PoseRefinementResult result;
  result.cam_from_world = initial_cam_from_world;
  if (indices.size() < 3) return result;

  Eigen::Quaterniond rotation = initial_cam_from_world.rotation.normalized();
  Eigen::Vector3d translation = initial_cam_from_world.translation;
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  ceres::CauchyLoss loss(options.loss_scale_px);
  for (const int index : indices) {
    THROW_CHECK(index >= 0 && static_cast<size_t>(index) < keypoints_px.size());
    problem.AddResidualBlock(
        new PixelReprojectionCost(camera, keypoints_px[index], points_in_world[index]), &loss,
        rotation.coeffs().data(), translation.data());
  }
  problem.SetManifold(rotation.coeffs().data(), new ceres::EigenQuaternionManifold);

  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::DENSE_QR;
  // Eigen, not LAPACK: Debian's Ceres would hand a 6-column QR to a multi-threaded BLAS whose
  // threads spin (sched_yield) and contend with the concurrent queries of the server.
  solver_options.dense_linear_algebra_library_type = ceres::EIGEN;
  solver_options.max_num_iterations = options.max_num_iterations;
  solver_options.num_threads = 1;
  solver_options.logging_type = ceres::SILENT;
  solver_options.minimizer_progress_to_stdout = false;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &problem, &summary);

  result.num_iterations = static_cast<int>(summary.iterations.size());
  result.initial_cost = summary.initial_cost;
  result.final_cost = summary.final_cost;
  result.usable =
      summary.IsSolutionUsable() && rotation.coeffs().allFinite() && translation.allFinite();
  if (result.usable) result.cam_from_world = Rigid3d(rotation.normalized(), translation);
  return result;
}

}  // namespace hscloc
