#include "pose/p3p.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

namespace hscloc {
namespace {

// A real root of x^3 + c2 x^2 + c1 x + c0 (Cardano, or the trigonometric form when all three roots
// are real, where it takes the largest), polished by Newton because the closed forms lose digits
// near a double root. Any real root makes D1 + gamma D2 singular.
double RealCubicRoot(double c2, double c1, double c0) {
  const double p = c1 - c2 * c2 / 3.0;
  const double q = (2.0 * c2 * c2 * c2 - 9.0 * c2 * c1) / 27.0 + c0;
  const double discriminant = q * q / 4.0 + p * p * p / 27.0;
  double t;
  if (discriminant > 0.0) {
    const double root = std::sqrt(discriminant);
    t = std::cbrt(-q / 2.0 + root) + std::cbrt(-q / 2.0 - root);
  } else if (p == 0.0) {
    t = std::cbrt(-q);
  } else {
    const double cosine = std::clamp(1.5 * q / p * std::sqrt(-3.0 / p), -1.0, 1.0);
    t = 2.0 * std::sqrt(-p / 3.0) * std::cos(std::acos(cosine) / 3.0);
  }
  double x = t - c2 / 3.0;
  for (int i = 0; i < 2; ++i) {
    const double value = ((x + c2) * x + c1) * x + c0;
    const double slope = (3.0 * x + 2.0 * c2) * x + c1;
    if (slope == 0.0) break;
    x -= value / slope;
  }
  return x;
}

// Sum of the element-wise product of a and the cofactor matrix of b: the coefficient that
// det(a + g b) takes from one column of a and two of b.
double MixedDeterminant(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  Eigen::Matrix3d cofactor;
  cofactor << b.col(1).cross(b.col(2)), b.col(2).cross(b.col(0)), b.col(0).cross(b.col(1));
  return (a.array() * cofactor.array()).sum();
}

// The null vector of a rank-2 symmetric matrix: the longest cross product of two of its rows is
// the best conditioned.
Eigen::Vector3d NullVector(const Eigen::Matrix3d& m) {
  const Eigen::Vector3d candidates[3] = {m.row(0).cross(m.row(1)), m.row(0).cross(m.row(2)),
                                         m.row(1).cross(m.row(2))};
  int best = 0;
  for (int i = 1; i < 3; ++i) {
    if (candidates[i].squaredNorm() > candidates[best].squaredNorm()) best = i;
  }
  return candidates[best].normalized();
}

struct P3PProblem {
  // Squared distances between the world points and cosines between the rays.
  double a12, a13, a23;
  double b12, b13, b23;

  Eigen::Vector3d Residuals(const Eigen::Vector3d& depth) const {
    return {depth[0] * depth[0] + depth[1] * depth[1] - 2.0 * b12 * depth[0] * depth[1] - a12,
            depth[0] * depth[0] + depth[2] * depth[2] - 2.0 * b13 * depth[0] * depth[2] - a13,
            depth[1] * depth[1] + depth[2] * depth[2] - 2.0 * b23 * depth[1] * depth[2] - a23};
  }

  // The closed form leaves errors of a few ulps amplified by the conditioning of the eigen
  // decomposition; Newton on the three distance equations removes them (paper, section 3.5).
  Eigen::Vector3d RefineDepths(Eigen::Vector3d depth) const {
    const double tolerance = 1e-14 * (a12 + a13 + a23);
    for (int i = 0; i < 5; ++i) {
      const Eigen::Vector3d residuals = Residuals(depth);
      if (residuals.cwiseAbs().sum() < tolerance) break;
      Eigen::Matrix3d jacobian;
      jacobian << depth[0] - b12 * depth[1], depth[1] - b12 * depth[0], 0.0,  //
          depth[0] - b13 * depth[2], 0.0, depth[2] - b13 * depth[0],          //
          0.0, depth[1] - b23 * depth[2], depth[2] - b23 * depth[1];
      const double determinant = jacobian.determinant();
      if (!(std::abs(determinant) > 0.0)) break;
      depth -= 0.5 * (jacobian.inverse() * residuals);
    }
    return depth;
  }
};

// The positive depths on one plane of the degenerate conic (at most two) that satisfy
// depth^T constraint depth = 0 and the distance equations.
std::vector<Eigen::Vector3d> DepthsOnPlane(const P3PProblem& problem, const Eigen::Vector3d& plane,
                                           const Eigen::Matrix3d& constraint) {
  // Eliminate the depth with the largest coefficient: depth = scale * (p + tau q).
  const bool eliminate_first = std::abs(plane[0]) >= std::abs(plane[1]);
  Eigen::Vector3d p, q;
  if (eliminate_first) {
    p << -plane[1] / plane[0], 1.0, 0.0;
    q << -plane[2] / plane[0], 0.0, 1.0;
  } else {
    p << 1.0, -plane[0] / plane[1], 0.0;
    q << 0.0, -plane[2] / plane[1], 1.0;
  }
  const double qa = q.dot(constraint * q);
  const double qb = 2.0 * p.dot(constraint * q);
  const double qc = p.dot(constraint * p);
  std::vector<double> taus;
  if (std::abs(qa) <= 1e-14 * (std::abs(qb) + std::abs(qc))) {
    if (qb != 0.0) taus.push_back(-qc / qb);
  } else {
    const double discriminant = qb * qb - 4.0 * qa * qc;
    if (discriminant < -1e-12 * qb * qb) return {};
    const double root = std::sqrt(std::max(0.0, discriminant));
    // The numerically stable pair of roots.
    const double w = -0.5 * (qb + std::copysign(root, qb));
    taus.push_back(w / qa);
    if (w != 0.0) taus.push_back(qc / w);
  }
  std::vector<Eigen::Vector3d> depths;
  for (const double tau : taus) {
    if (!(tau > 0.0)) continue;
    // The scale from the distance equation between the two depths that p + tau q keeps free.
    const double cosine = eliminate_first ? problem.b23 : problem.b13;
    const double squared_distance = eliminate_first ? problem.a23 : problem.a13;
    const double scale = std::sqrt(squared_distance / (tau * (tau - 2.0 * cosine) + 1.0));
    const Eigen::Vector3d depth = scale * (p + tau * q);
    if (depth.minCoeff() > 0.0) depths.push_back(depth);
  }
  return depths;
}

// The rigid transform that puts the world points at `depth` along their rays; none when the
// numbers are not finite.
std::optional<Rigid3d> PoseFromDepths(const Eigen::Vector3d& depth,
                                      const std::array<Eigen::Vector3d, 3>& rays_in_cam,
                                      const std::array<Eigen::Vector3d, 3>& points_in_world,
                                      const Eigen::Matrix3d& world_basis_inverse) {
  std::array<Eigen::Vector3d, 3> points_in_cam;
  for (int k = 0; k < 3; ++k) points_in_cam[k] = depth[k] * rays_in_cam[k];
  const Eigen::Vector3d c12 = points_in_cam[0] - points_in_cam[1];
  const Eigen::Vector3d c13 = points_in_cam[0] - points_in_cam[2];
  Eigen::Matrix3d cam_basis;
  cam_basis << c12, c13, c12.cross(c13);
  Eigen::Quaterniond rotation(Eigen::Matrix3d(cam_basis * world_basis_inverse));
  rotation.normalize();
  const Eigen::Vector3d translation = points_in_cam[0] - rotation * points_in_world[0];
  if (!rotation.coeffs().allFinite() || !translation.allFinite()) return std::nullopt;
  return Rigid3d(rotation, translation);
}

}  // namespace

P3PSolutions SolveP3P(const std::array<Eigen::Vector3d, 3>& rays_in_cam,
                      const std::array<Eigen::Vector3d, 3>& points_in_world) {
  P3PSolutions solutions;
  const Eigen::Vector3d d12 = points_in_world[0] - points_in_world[1];
  const Eigen::Vector3d d13 = points_in_world[0] - points_in_world[2];
  const Eigen::Vector3d normal = d12.cross(d13);
  // Collinear or coincident points leave the rotation about their line undetermined.
  if (!(normal.norm() > 1e-10 * d12.norm() * d13.norm())) return solutions;

  P3PProblem problem;
  problem.a12 = d12.squaredNorm();
  problem.a13 = d13.squaredNorm();
  problem.a23 = (points_in_world[1] - points_in_world[2]).squaredNorm();
  problem.b12 = rays_in_cam[0].dot(rays_in_cam[1]);
  problem.b13 = rays_in_cam[0].dot(rays_in_cam[2]);
  problem.b23 = rays_in_cam[1].dot(rays_in_cam[2]);
  const double a12 = problem.a12, a13 = problem.a13, a23 = problem.a23;
  const double b12 = problem.b12, b13 = problem.b13, b23 = problem.b23;

  // depth^T D depth = 0 for both homogeneous combinations of the three distance equations.
  Eigen::Matrix3d d1;
  d1 << a23, -a23 * b12, 0.0,            //
      -a23 * b12, a23 - a12, a12 * b23,  //
      0.0, a12 * b23, -a12;
  Eigen::Matrix3d d2;
  d2 << a23, 0.0, -a23 * b13,  //
      0.0, -a13, a13 * b23,    //
      -a23 * b13, a13 * b23, a23 - a13;

  const double c3 = d2.determinant();
  if (!(std::abs(c3) > 0.0)) return solutions;
  const double gamma = RealCubicRoot(MixedDeterminant(d1, d2) / c3, MixedDeterminant(d2, d1) / c3,
                                     d1.determinant() / c3);
  const Eigen::Matrix3d d0 = d1 + gamma * d2;

  // d0 is a degenerate conic: a pair of planes through the origin of depth space,
  // sigma1 (e1 . depth)^2 + sigma2 (e2 . depth)^2 = 0 with sigma1 and sigma2 of opposite signs.
  const double trace = d0.trace();
  const double minors = d0(0, 0) * d0(1, 1) - d0(0, 1) * d0(0, 1) + d0(0, 0) * d0(2, 2) -
                        d0(0, 2) * d0(0, 2) + d0(1, 1) * d0(2, 2) - d0(1, 2) * d0(1, 2);
  const double spread = std::sqrt(std::max(0.0, trace * trace / 4.0 - minors));
  double sigma1 = trace / 2.0 + spread;
  double sigma2 = trace / 2.0 - spread;
  if (std::abs(sigma1) < std::abs(sigma2)) std::swap(sigma1, sigma2);
  const double ratio = -sigma2 / sigma1;
  if (!(ratio >= 0.0)) return solutions;
  const double s = std::sqrt(ratio);
  const Eigen::Vector3d e1 = NullVector(d0 - sigma1 * Eigen::Matrix3d::Identity());
  const Eigen::Vector3d e2 = NullVector(d0 - sigma2 * Eigen::Matrix3d::Identity());

  // On each plane, d1 and d2 restrict to multiples of each other (their combination d0 vanishes
  // there); the one not scaled down by gamma is the better conditioned.
  const Eigen::Matrix3d& constraint = std::abs(gamma) < 1.0 ? d2 : d1;
  Eigen::Matrix3d world_basis;
  world_basis << d12, d13, normal;
  const Eigen::Matrix3d world_basis_inverse = world_basis.inverse();

  for (const double sign : {1.0, -1.0}) {
    for (const Eigen::Vector3d& depth : DepthsOnPlane(problem, e1 - sign * s * e2, constraint)) {
      const std::optional<Rigid3d> pose = PoseFromDepths(problem.RefineDepths(depth), rays_in_cam,
                                                         points_in_world, world_basis_inverse);
      if (pose) solutions.cam_from_world[solutions.num_solutions++] = *pose;
    }
  }
  return solutions;
}

}  // namespace hscloc
