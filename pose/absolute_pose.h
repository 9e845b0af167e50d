// Absolute pose estimation: the cam_from_world of a calibrated camera from 2D keypoints matched to
// 3D points, robust to a large share of wrong matches.
//
// Structured as PoseLib's robust estimators are: a minimal solver (Lambda Twist P3P, p3p.h); an
// estimator that fits, scores (MSAC, with Wald's sequential test of Chum and Matas, TPAMI 2008,
// to reject wrong poses early) and locally optimizes (Lebeda et al., BMVC 2012); a short
// LO-RANSAC loop (Chum et al., DAGM 2003); and this top-level function, which undistorts the
// keypoints, runs RANSAC and refines the pose on its inliers with Ceres (pose_refinement.h). The
// defaults are the Aachen setting of Li et al., "Hierarchical Scene Coordinate Classification and
// Regression for Visual Localization", CVPR 2020: a 10 px threshold, at most 5000 hypotheses, and
// an early stop once a hypothesis has more than 100 inliers.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "pose/pose_refinement.h"

namespace hscloc {

struct AbsolutePoseOptions {
  enum class Solver {
    // hscloc's LO-RANSAC with Lambda Twist P3P, the early stop, and errors measured in pixels of
    // the real camera (to first order). As accurate as kOpenCvUsac and 1.5 to 10 times faster,
    // the more so the fewer the inliers (docs/decisions.md).
    kLoRansac,
    // OpenCV's USAC (cv::solvePnPRansac with cv::UsacParams: P3P, MSAC score, inner LO). It sees
    // a pinhole camera with the mean focal length, so its threshold is in pixels only where the
    // distortion is mild, and it cannot stop early on an inlier count.
    kOpenCvUsac,
  };

  // Inlier threshold on the reprojection error, in pixels of the real (distorted) image. RANSAC
  // compares it with the error mapped to pixels through the camera's local Jacobian at the
  // keypoint; the final inlier set uses the exact reprojection through the camera model.
  double max_reprojection_error_px = 10.0;
  // Most minimal samples drawn (hypotheses; one sample gives up to four P3P poses).
  int max_iterations = 5000;
  // Stop sampling once the best hypothesis has more than this many inliers; 0 disables.
  int stop_sampling_past_inliers = 100;
  // Stop sampling once a hypothesis with more inliers than the best is at most this unlikely to
  // have been missed (the standard adaptive bound); 1 never stops on it.
  double confidence = 0.9999;
  // Fewest inliers of an accepted pose; at least 4, since any 3 correspondences fit some pose.
  int min_inliers = 12;
  // Inliers that a pose must exceed to be of use (another candidate's pose has them); 0: none.
  // The adaptive bound then assumes at least that inlier ratio: sampling stops once a pose with
  // more inliers would have been found with `confidence`, as it stops once one better than the
  // best so far would have (a candidate that cannot win is not sampled 5000 times). The LO-RANSAC
  // solver only.
  int inliers_to_beat = 0;
  // PROSAC (Chum and Matas, CVPR 2005): the correspondences come best first (by a matcher's
  // confidence), and samples are drawn from the best ones first, from a share that grows to all of
  // them over max_iterations samples. False: uniform sampling. The LO-RANSAC solver only.
  bool progressive_sampling = false;
  Solver solver = Solver::kLoRansac;
  // Refit each new best hypothesis to its inliers during RANSAC (LO-RANSAC).
  bool local_optimization = true;
  // Refine the RANSAC pose on its inliers with Ceres, then recompute the inliers.
  bool refine = true;
  PoseRefinementOptions refinement;
  // Seeds the sampling; equal inputs and seeds give equal results.
  uint64_t seed = 0;

  // Throws std::invalid_argument naming the field.
  void Check() const;
};

struct AbsolutePoseResult {
  bool success = false;
  // Why no pose was accepted; empty on success.
  std::string failure_reason;
  // The estimate; on failure the best hypothesis found, or the identity when there was none.
  Rigid3d cam_from_world;
  // One entry per correspondence: 1 where cam_from_world reprojects the point in front of the
  // camera within max_reprojection_error_px of its keypoint (exact, through the camera model).
  std::vector<char> inlier_mask;
  int num_inliers = 0;
  // Inliers of the RANSAC pose (RefineAbsolutePoseFrom: the initial pose) before refinement (same
  // exact test).
  int ransac_num_inliers = 0;
  // Minimal samples drawn; -1 for kOpenCvUsac, which does not report it.
  int num_iterations = 0;
  // Mean reprojection error of the inliers, in pixels.
  double mean_inlier_error_px = 0.0;
  // Whether the Ceres refinement ran and its pose was kept.
  bool refined = false;
};

// Estimates cam_from_world from keypoints (pixels, COLMAP convention: the centre of the top-left
// pixel is (0.5, 0.5)) matched one to one with points in world coordinates, for any COLMAP camera
// model. Keypoints that the camera cannot undistort (beyond the fold of its distortion) never
// count as inliers.
//
// Throws std::invalid_argument for bad input: invalid options or camera, keypoints_px and
// points_in_world of different sizes, non-finite coordinates. Too few correspondences, no
// hypothesis with min_inliers inliers, or degenerate geometry give success = false with a reason.
// Deterministic for a seed; thread-safe (no shared state; OpenCV runs single-threaded with its
// random state taken from the seed).
AbsolutePoseResult EstimateAbsolutePose(const Camera& camera,
                                        const std::vector<Eigen::Vector2d>& keypoints_px,
                                        const std::vector<Eigen::Vector3d>& points_in_world,
                                        const AbsolutePoseOptions& options);

// The end of EstimateAbsolutePose from a known pose instead of RANSAC's: the inliers of
// `initial_cam_from_world`, refined as options.refine says, and the same verdict (success with
// min_inliers inliers). For correspondences chosen once a pose is known, e.g. among rival matches.
// Throws std::invalid_argument as EstimateAbsolutePose does, and for a non-finite initial pose.
AbsolutePoseResult RefineAbsolutePoseFrom(const Camera& camera,
                                          const std::vector<Eigen::Vector2d>& keypoints_px,
                                          const std::vector<Eigen::Vector3d>& points_in_world,
                                          const Rigid3d& initial_cam_from_world,
                                          const AbsolutePoseOptions& options);

}  // namespace hscloc
