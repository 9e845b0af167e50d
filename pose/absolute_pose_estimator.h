// The estimator layer of hscloc's LO-RANSAC (PoseLib's layering): the minimal fit (Lambda Twist
// P3P), MSAC scoring with the sequential test, and local optimization of an absolute pose on
// undistorted correspondences.
#pragma once

#include <array>
#include <vector>

#include "geometry/rigid3d.h"
#include "pose/p3p.h"
#include "pose/pose_refinement.h"
#include "pose/ransac.h"
#include "pose/sequential_test.h"

namespace hscloc {

// The estimator layer: minimal fit, scoring, and local optimization of an absolute pose on
// undistorted correspondences.
class AbsolutePoseEstimator {
 public:
  using Model = Rigid3d;
  static constexpr int kSampleSize = 3;

  AbsolutePoseEstimator(const std::vector<NormalizedCorrespondence>& correspondences,
                        double max_error_px)
      : correspondences_(correspondences),
        max_error_px_(max_error_px),
        squared_threshold_(max_error_px * max_error_px) {}

  int NumData() const { return static_cast<int>(correspondences_.size()); }

  P3PSolutions FitMinimal(const std::array<int, kSampleSize>& sample) const;

  // The score of a sampled pose; stops early (returning the worst score) once the pose cannot
  // beat `to_beat` or the sequential test rejects it.
  Score Evaluate(const Rigid3d& cam_from_world, const Score& to_beat) {
    return ScorePose(cam_from_world, to_beat, /*sequential_test=*/true);
  }

  void OnNewBest(const Score& best) {
    test_.SetRightInlierRatio(static_cast<double>(best.num_inliers) / NumData());
  }

  // Probability that a right pose survives verification.
  double RightPoseAcceptance() const { return test_.RightPoseAcceptance(); }

  // A minimal-sample pose fits its own three points exactly and the rest only roughly; refitting
  // to the inliers is the LO of LO-RANSAC.
  ScoredModel<Rigid3d> LocalOptimize(const ScoredModel<Rigid3d>& hypothesis);

 private:
  Score ScorePose(const Rigid3d& cam_from_world, const Score& to_beat, bool sequential_test);

  const std::vector<NormalizedCorrespondence>& correspondences_;
  const double max_error_px_;
  const double squared_threshold_;
  SequentialTest test_;
};

}  // namespace hscloc
