#include "pose/absolute_pose.h"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>

#include "pose/absolute_pose_estimator.h"
#include "pose/opencv_adapter.h"
#include "pose/ransac.h"
#include "util/check.h"
#include "util/random.h"

namespace hscloc {
namespace {

// A RANSAC pose that saw only part of its inliers (the early stop takes the first pose past 100)
// finds the rest when refined, and is refined again on all of them; growth by a few points at the
// threshold is not worth another Ceres run.
constexpr int kMaxRefinementRounds = 3;
constexpr double kInlierGrowthForAnotherRound = 0.05;

struct SolverOutcome {
  bool found = false;
  Rigid3d cam_from_world;
  int num_iterations = 0;
  // Set where the solver failed in a way that says more than "not found".
  std::string error;
};

SolverOutcome RunLoRansacSolver(std::vector<NormalizedCorrespondence> correspondences,
                                const AbsolutePoseOptions& options) {
  Random random(options.seed);
  // Keypoints often arrive in order (by image row, by retrieved image); the sequential test needs
  // every prefix to be a random subset. PROSAC samples by the order they came in, so it follows
  // each correspondence's rank to its shuffled position.
  const bool progressive = options.progressive_sampling;
  std::vector<int> rank_at_position;
  if (progressive) {
    rank_at_position.resize(correspondences.size());
    std::iota(rank_at_position.begin(), rank_at_position.end(), 0);
  }
  for (int i = static_cast<int>(correspondences.size()) - 1; i > 0; --i) {
    const auto j = static_cast<int>(random.UniformInt(i + 1));
    std::swap(correspondences[i], correspondences[j]);
    if (progressive) std::swap(rank_at_position[i], rank_at_position[j]);
  }
  RansacOptions ransac_options;
  if (progressive) {
    ransac_options.data_best_first.resize(rank_at_position.size());
    for (size_t position = 0; position < rank_at_position.size(); ++position) {
      ransac_options.data_best_first[rank_at_position[position]] = static_cast<int>(position);
    }
    ransac_options.progressive_growth_samples = options.max_iterations;
  }
  ransac_options.max_iterations = options.max_iterations;
  ransac_options.stop_past_inliers = options.stop_sampling_past_inliers;
  ransac_options.confidence = options.confidence;
  ransac_options.local_optimization = options.local_optimization;
  ransac_options.inliers_to_beat = options.inliers_to_beat;
  AbsolutePoseEstimator estimator(correspondences, options.max_reprojection_error_px);
  const RansacOutcome<Rigid3d> ransac = RunLoRansac(estimator, ransac_options, random);
  SolverOutcome outcome;
  outcome.found = ransac.found;
  outcome.cam_from_world = ransac.best.model;
  outcome.num_iterations = ransac.num_iterations;
  return outcome;
}

SolverOutcome RunOpenCvUsacSolver(const std::vector<NormalizedCorrespondence>& correspondences,
                                  double focal_length_px, const AbsolutePoseOptions& options) {
  const OpenCvUsacResult usac =
      EstimatePoseWithOpenCvUsac(correspondences, focal_length_px, options);
  SolverOutcome outcome;
  outcome.found = usac.found;
  outcome.cam_from_world = usac.cam_from_world;
  // USAC does not report how many samples it drew.
  outcome.num_iterations = -1;
  outcome.error = usac.error;
  return outcome;
}

struct PixelInliers {
  std::vector<char> mask;
  std::vector<int> indices;
  double mean_error_px = 0.0;
};

// The exact test, through the camera model in pixels.
PixelInliers FindPixelInliers(const Camera& camera,
                              const std::vector<Eigen::Vector2d>& keypoints_px,
                              const std::vector<Eigen::Vector3d>& points_in_world,
                              const Rigid3d& cam_from_world, double max_error_px) {
  PixelInliers inliers;
  inliers.mask.assign(keypoints_px.size(), 0);
  double error_sum = 0.0;
  for (size_t i = 0; i < keypoints_px.size(); ++i) {
    const Eigen::Vector3d point_in_cam = cam_from_world * points_in_world[i];
    if (!(point_in_cam.z() > 0.0)) continue;
    const double error = (camera.ImgFromPointInCam(point_in_cam) - keypoints_px[i]).norm();
    if (!(error <= max_error_px)) continue;
    inliers.mask[i] = 1;
    inliers.indices.push_back(static_cast<int>(i));
    error_sum += error;
  }
  if (!inliers.indices.empty()) inliers.mean_error_px = error_sum / inliers.indices.size();
  return inliers;
}

void CheckCorrespondences(const std::vector<Eigen::Vector2d>& keypoints_px,
                          const std::vector<Eigen::Vector3d>& points_in_world) {
  if (keypoints_px.size() != points_in_world.size()) {
    ThrowInvalidArgument("keypoints_px has {} entries but points_in_world has {}",
                         keypoints_px.size(), points_in_world.size());
  }
  for (size_t i = 0; i < keypoints_px.size(); ++i) {
    if (!keypoints_px[i].allFinite()) {
      ThrowInvalidArgument("keypoints_px[{}] = ({}, {}) is not finite", i, keypoints_px[i].x(),
                           keypoints_px[i].y());
    }
    if (!points_in_world[i].allFinite()) {
      ThrowInvalidArgument("points_in_world[{}] = ({}, {}, {}) is not finite", i,
                           points_in_world[i].x(), points_in_world[i].y(), points_in_world[i].z());
    }
  }
}

std::vector<NormalizedCorrespondence> NormalizeCorrespondences(
    const Camera& camera, const std::vector<Eigen::Vector2d>& keypoints_px,
    const std::vector<Eigen::Vector3d>& points_in_world) {
  std::vector<NormalizedCorrespondence> correspondences;
  correspondences.reserve(keypoints_px.size());
  for (size_t i = 0; i < keypoints_px.size(); ++i) {
    NormalizedCorrespondence correspondence;
    correspondence.point2D_normalized = camera.CamFromImg(keypoints_px[i]);
    if (!correspondence.point2D_normalized.allFinite()) continue;
    correspondence.point3D_in_world = points_in_world[i];
    const Eigen::Matrix2d jacobian =
        PixelFromNormalizedJacobian(camera, correspondence.point2D_normalized);
    correspondence.pixel_metric = jacobian.transpose() * jacobian;
    correspondences.push_back(correspondence);
  }
  return correspondences;
}

struct RefinedPose {
  Rigid3d cam_from_world;
  PixelInliers inliers;
  bool refined = false;
};

// Ceres on the inliers, then the inliers again; once more while they grow markedly.
RefinedPose RefineWhileInliersGrow(const Camera& camera,
                                   const std::vector<Eigen::Vector2d>& keypoints_px,
                                   const std::vector<Eigen::Vector3d>& points_in_world,
                                   RefinedPose pose, const AbsolutePoseOptions& options) {
  for (int round = 0; round < kMaxRefinementRounds &&
                      static_cast<int>(pose.inliers.indices.size()) >= options.min_inliers;
       ++round) {
    const PoseRefinementResult refinement =
        RefineAbsolutePose(camera, keypoints_px, points_in_world, pose.inliers.indices,
                           pose.cam_from_world, options.refinement);
    if (!refinement.usable) break;
    PixelInliers inliers =
        FindPixelInliers(camera, keypoints_px, points_in_world, refinement.cam_from_world,
                         options.max_reprojection_error_px);
    const bool grew =
        inliers.indices.size() > (1.0 + kInlierGrowthForAnotherRound) * pose.inliers.indices.size();
    pose = {refinement.cam_from_world, std::move(inliers), true};
    if (!grew) break;
  }
  return pose;
}

AbsolutePoseResult Fail(AbsolutePoseResult result, std::string reason) {
  result.success = false;
  result.failure_reason = std::move(reason);
  return result;
}

// What follows a pose hypothesis: its exact inliers, the refinement, and the verdict.
AbsolutePoseResult FinishFromPose(const Camera& camera,
                                  const std::vector<Eigen::Vector2d>& keypoints_px,
                                  const std::vector<Eigen::Vector3d>& points_in_world,
                                  const Rigid3d& cam_from_world, const AbsolutePoseOptions& options,
                                  AbsolutePoseResult result) {
  RefinedPose pose;
  pose.cam_from_world = cam_from_world;
  pose.inliers = FindPixelInliers(camera, keypoints_px, points_in_world, pose.cam_from_world,
                                  options.max_reprojection_error_px);
  result.ransac_num_inliers = static_cast<int>(pose.inliers.indices.size());
  if (options.refine) {
    pose = RefineWhileInliersGrow(camera, keypoints_px, points_in_world, std::move(pose), options);
  }
  result.cam_from_world = pose.cam_from_world;
  result.refined = pose.refined;
  result.inlier_mask = std::move(pose.inliers.mask);
  result.num_inliers = static_cast<int>(pose.inliers.indices.size());
  result.mean_inlier_error_px = pose.inliers.mean_error_px;
  if (result.num_inliers < options.min_inliers) {
    return Fail(
        std::move(result),
        fmt::format("the best pose has {} inliers within {} px, fewer than "
                    "min_inliers = {}",
                    result.num_inliers, options.max_reprojection_error_px, options.min_inliers));
  }
  result.success = true;
  return result;
}

}  // namespace

void AbsolutePoseOptions::Check() const {
  if (!(max_reprojection_error_px > 0.0) || !std::isfinite(max_reprojection_error_px)) {
    ThrowInvalidArgument("AbsolutePoseOptions.max_reprojection_error_px is {}, must be positive",
                         max_reprojection_error_px);
  }
  if (max_iterations < 1) {
    ThrowInvalidArgument("AbsolutePoseOptions.max_iterations is {}, must be at least 1",
                         max_iterations);
  }
  if (inliers_to_beat < 0) {
    ThrowInvalidArgument("AbsolutePoseOptions.inliers_to_beat is {}, must be >= 0 (0: none)",
                         inliers_to_beat);
  }
  if (stop_sampling_past_inliers < 0) {
    ThrowInvalidArgument(
        "AbsolutePoseOptions.stop_sampling_past_inliers is {}, must be >= 0 (0: off)",
        stop_sampling_past_inliers);
  }
  if (!(confidence > 0.0 && confidence <= 1.0)) {
    ThrowInvalidArgument("AbsolutePoseOptions.confidence is {}, must be in (0, 1]", confidence);
  }
  if (min_inliers < 4) {
    ThrowInvalidArgument("AbsolutePoseOptions.min_inliers is {}, must be at least 4", min_inliers);
  }
  if (solver != Solver::kLoRansac && solver != Solver::kOpenCvUsac) {
    ThrowInvalidArgument("AbsolutePoseOptions.solver is {}, not a known solver",
                         static_cast<int>(solver));
  }
  refinement.Check();
}

AbsolutePoseResult EstimateAbsolutePose(const Camera& camera,
                                        const std::vector<Eigen::Vector2d>& keypoints_px,
                                        const std::vector<Eigen::Vector3d>& points_in_world,
                                        const AbsolutePoseOptions& options) {
  options.Check();
  camera.Check();
  CheckCorrespondences(keypoints_px, points_in_world);

  AbsolutePoseResult result;
  const int num_correspondences = static_cast<int>(keypoints_px.size());
  result.inlier_mask.assign(num_correspondences, 0);
  if (num_correspondences < options.min_inliers) {
    return Fail(std::move(result), fmt::format("{} correspondences, fewer than min_inliers = {}",
                                               num_correspondences, options.min_inliers));
  }

  std::vector<NormalizedCorrespondence> correspondences =
      NormalizeCorrespondences(camera, keypoints_px, points_in_world);
  if (static_cast<int>(correspondences.size()) < options.min_inliers) {
    return Fail(std::move(result),
                fmt::format("only {} of {} keypoints can be undistorted by the camera, fewer "
                            "than min_inliers = {}",
                            correspondences.size(), num_correspondences, options.min_inliers));
  }

  const SolverOutcome outcome =
      options.solver == AbsolutePoseOptions::Solver::kLoRansac
          ? RunLoRansacSolver(std::move(correspondences), options)
          : RunOpenCvUsacSolver(correspondences, camera.MeanFocalLength(), options);
  result.num_iterations = outcome.num_iterations;
  if (!outcome.error.empty()) {
    return Fail(std::move(result), "OpenCV USAC failed: " + outcome.error);
  }
  if (!outcome.found) {
    return Fail(std::move(result),
                "no hypothesis: no sample gave a pose that passed verification (no consistent "
                "matches, or degenerate geometry such as collinear points)");
  }

  return FinishFromPose(camera, keypoints_px, points_in_world, outcome.cam_from_world, options,
                        std::move(result));
}

AbsolutePoseResult RefineAbsolutePoseFrom(const Camera& camera,
                                          const std::vector<Eigen::Vector2d>& keypoints_px,
                                          const std::vector<Eigen::Vector3d>& points_in_world,
                                          const Rigid3d& initial_cam_from_world,
                                          const AbsolutePoseOptions& options) {
  options.Check();
  camera.Check();
  CheckCorrespondences(keypoints_px, points_in_world);
  if (!initial_cam_from_world.rotation.coeffs().allFinite() ||
      !initial_cam_from_world.translation.allFinite()) {
    ThrowInvalidArgument("RefineAbsolutePoseFrom: the initial pose is not finite");
  }
  AbsolutePoseResult result;
  result.inlier_mask.assign(keypoints_px.size(), 0);
  return FinishFromPose(camera, keypoints_px, points_in_world, initial_cam_from_world, options,
                        std::move(result));
}

}  // namespace hscloc
