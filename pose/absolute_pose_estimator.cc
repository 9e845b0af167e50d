#include "pose/absolute_pose_estimator.h"

namespace hscloc {
namespace {

// Local optimization refits to the inliers within a threshold that shrinks to the final one
// (Lebeda, Matas and Chum, "Fixing the Locally Optimized RANSAC", BMVC 2012): the pose of three
// noisy points is often so rough that, at the final threshold, it sees only the inliers around
// them and settles there. On the benchmark queries, refitting at the final threshold only let the
// early stop accept such a pose (2 to 6 m off, just over 100 inliers) for 1 query in 200.
constexpr double kLocalOptimizationThresholdMultipliers[] = {4.0, 2.0, 1.0};
// Levenberg-Marquardt iterations per threshold.
constexpr int kLocalOptimizationIterations = 25;

}  // namespace

P3PSolutions AbsolutePoseEstimator::FitMinimal(const std::array<int, kSampleSize>& sample) const {
  std::array<Eigen::Vector3d, 3> rays_in_cam;
  std::array<Eigen::Vector3d, 3> points_in_world;
  for (int i = 0; i < kSampleSize; ++i) {
    const NormalizedCorrespondence& correspondence = correspondences_[sample[i]];
    rays_in_cam[i] = correspondence.point2D_normalized.homogeneous().normalized();
    points_in_world[i] = correspondence.point3D_in_world;
  }
  return SolveP3P(rays_in_cam, points_in_world);
}

Score AbsolutePoseEstimator::ScorePose(const Rigid3d& cam_from_world, const Score& to_beat,
                                       bool sequential_test) {
  const Eigen::Matrix3d rotation = cam_from_world.rotation.toRotationMatrix();
  double log_likelihood_ratio = 0.0;
  Score score;
  score.msac = 0.0;
  for (int i = 0; i < NumData(); ++i) {
    const double squared_error =
        correspondences_[i].SquaredErrorPx(rotation, cam_from_world.translation);
    if (squared_error <= squared_threshold_) {
      score.msac += squared_error;
      ++score.num_inliers;
      log_likelihood_ratio += test_.consistent_step();
    } else {
      score.msac += squared_threshold_;
      log_likelihood_ratio += test_.inconsistent_step();
    }
    if (score.msac >= to_beat.msac) return Score();
    if (sequential_test && log_likelihood_ratio > test_.log_threshold()) {
      test_.RecordWrongPose(score.num_inliers, i + 1);
      return Score();
    }
  }
  return score;
}

ScoredModel<Rigid3d> AbsolutePoseEstimator::LocalOptimize(const ScoredModel<Rigid3d>& hypothesis) {
  ScoredModel<Rigid3d> optimized;
  optimized.model = hypothesis.model;
  for (const double multiplier : kLocalOptimizationThresholdMultipliers) {
    optimized.model =
        RefinePoseOnNormalizedPlane(correspondences_, optimized.model, multiplier * max_error_px_,
                                    kLocalOptimizationIterations);
  }
  optimized.score = ScorePose(optimized.model, hypothesis.score, /*sequential_test=*/false);
  return optimized.score.IsBetterThan(hypothesis.score) ? optimized : hypothesis;
}

}  // namespace hscloc
