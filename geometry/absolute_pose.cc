#include "geometry/absolute_pose.h"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <utility>

#include "geometry/opencv_adapter.h"
#include "geometry/p3p.h"
#include "util/check.h"
#include "util/random.h"

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

// A RANSAC pose that saw only part of its inliers (the early stop takes the first pose past 100)
// finds the rest when refined, and is refined again on all of them; growth by a few points at the
// threshold is not worth another Ceres run.
constexpr int kMaxRefinementRounds = 3;
constexpr double kInlierGrowthForAnotherRound = 0.05;

// The sequential test's prior: the inlier ratio of a right pose, until a better pose is found, and
// the fraction of correspondences that a wrong pose explains, until measured. The first is low
// because LO-RANSAC needs the rough poses of three noisy points, which explain a few percent, to
// survive until local optimization gathers their inliers: at 10% inliers, a prior of 5% made 1
// query in 40 fail, 2% 1 in 430, 1% 1 in 3000, as without the test (docs/decisions.md).
constexpr double kMinRightInlierRatio = 0.01;
constexpr double kPriorWrongConsistency = 0.01;
// Its cost model, measured on the benchmark queries: a P3P solve costs as much as checking 100
// correspondences (0.53 us against 5 ns) and gives 1.4 poses on average.
constexpr double kSolveCostInChecks = 100.0;
constexpr double kPosesPerSample = 1.4;

// MSAC (Torr and Zisserman, CVIU 2000): sum of min(e^2, threshold^2); lower is better. It ranks
// hypotheses with equal inlier counts by how well they fit them.
struct Score {
  double msac = std::numeric_limits<double>::infinity();
  int num_inliers = 0;
  bool IsBetterThan(const Score& other) const { return msac < other.msac; }
};

template <typename Model>
struct ScoredModel {
  Model model;
  Score score;
};

// Wald's sequential probability ratio test for hypothesis verification (Chum and Matas, "Optimal
// Randomized RANSAC", TPAMI 2008). A wrong pose explains a fraction delta of the correspondences,
// a right one a fraction epsilon; reading correspondences in random order, the test rejects a pose
// once their consistency is `threshold` times likelier under "wrong" than under "right". The
// threshold balances reading more correspondences of wrong poses against rejecting right ones,
// which happens with probability at most 1 / threshold and costs more samples. Below 10% inliers
// it rejects a wrong pose after a few dozen correspondences instead of all of them.
class SequentialTest {
 public:
  SequentialTest() { Update(kMinRightInlierRatio, kPriorWrongConsistency); }

  double consistent_step() const { return consistent_step_; }
  double inconsistent_step() const { return inconsistent_step_; }
  double log_threshold() const { return log_threshold_; }
  double RightPoseAcceptance() const { return 1.0 - std::exp(-log_threshold_); }

  void SetRightInlierRatio(double inlier_ratio) {
    Update(std::max(inlier_ratio, kMinRightInlierRatio), delta_);
  }

  // The consistency of rejected poses estimates delta; the prior weighs as 100 correspondences.
  void RecordWrongPose(int num_consistent, int num_checked) {
    wrong_consistent_ += num_consistent;
    wrong_checked_ += num_checked;
    const double delta =
        (wrong_consistent_ + 100.0 * kPriorWrongConsistency) / (wrong_checked_ + 100.0);
    if (std::abs(delta - delta_) > 0.1 * delta_) Update(epsilon_, delta);
  }

 private:
  void Update(double epsilon, double delta) {
    epsilon_ = epsilon;
    // The test only separates the hypotheses while wrong poses explain less than right ones.
    delta_ = std::min(delta, 0.5 * epsilon);
    consistent_step_ = std::log(delta_ / epsilon_);
    inconsistent_step_ = std::log((1.0 - delta_) / (1.0 - epsilon_));
    // Optimal threshold: the fixed point of A = t_M C / m_S + 1 + ln A, C the Kullback-Leibler
    // divergence of the two Bernoulli distributions (paper, equation 10).
    const double divergence = (1.0 - delta_) * inconsistent_step_ + delta_ * consistent_step_;
    const double base = kSolveCostInChecks * divergence / kPosesPerSample + 1.0;
    double threshold = base;
    for (int i = 0; i < 10; ++i) threshold = base + std::log(threshold);
    log_threshold_ = std::log(threshold);
  }

  double epsilon_ = 0.0;
  double delta_ = 0.0;
  double consistent_step_ = 0.0;
  double inconsistent_step_ = 0.0;
  double log_threshold_ = 0.0;
  double wrong_consistent_ = 0.0;
  double wrong_checked_ = 0.0;
};

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

  P3PSolutions FitMinimal(const std::array<int, kSampleSize>& sample) const {
    std::array<Eigen::Vector3d, 3> rays_in_cam;
    std::array<Eigen::Vector3d, 3> points_in_world;
    for (int i = 0; i < kSampleSize; ++i) {
      const NormalizedCorrespondence& correspondence = correspondences_[sample[i]];
      rays_in_cam[i] = correspondence.point2D_normalized.homogeneous().normalized();
      points_in_world[i] = correspondence.point3D_in_world;
    }
    return SolveP3P(rays_in_cam, points_in_world);
  }

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
  ScoredModel<Rigid3d> LocalOptimize(const ScoredModel<Rigid3d>& hypothesis) {
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

 private:
  Score ScorePose(const Rigid3d& cam_from_world, const Score& to_beat, bool sequential_test) {
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

  const std::vector<NormalizedCorrespondence>& correspondences_;
  const double max_error_px_;
  const double squared_threshold_;
  SequentialTest test_;
};

struct RansacOptions {
  int max_iterations = 0;
  int early_stop_inliers = 0;
  double confidence = 0.0;
  bool local_optimization = false;
};

template <typename Model>
struct RansacOutcome {
  bool found = false;
  ScoredModel<Model> best;
  int num_iterations = 0;
};

// Samples needed to draw and accept one all-inlier sample with the given confidence (Fischler and
// Bolles, with the acceptance of the verification as in Chum and Matas).
int RequiredIterations(double good_sample_probability, double confidence, int max_iterations) {
  if (good_sample_probability >= 1.0) return 0;
  if (confidence >= 1.0 || good_sample_probability <= 0.0) return max_iterations;
  const double required = std::log1p(-confidence) / std::log1p(-good_sample_probability);
  return required < max_iterations ? static_cast<int>(std::ceil(required)) : max_iterations;
}

template <int kSampleSize>
std::array<int, kSampleSize> DrawSample(int num_data, Random& random) {
  std::array<int, kSampleSize> sample;
  for (int i = 0; i < kSampleSize; ++i) {
    bool repeated;
    do {
      sample[i] = static_cast<int>(random.UniformInt(num_data));
      repeated = std::find(sample.begin(), sample.begin() + i, sample[i]) != sample.begin() + i;
    } while (repeated);
  }
  return sample;
}

// The LO-RANSAC loop, with the estimator interface of PoseLib's ransac.h: sample, fit, score,
// locally optimize the best.
template <typename Estimator>
RansacOutcome<typename Estimator::Model> RunLoRansac(Estimator& estimator,
                                                     const RansacOptions& options, Random& random) {
  RansacOutcome<typename Estimator::Model> outcome;
  const int num_data = estimator.NumData();
  if (num_data < Estimator::kSampleSize) return outcome;
  int iteration_bound = options.max_iterations;
  while (outcome.num_iterations < iteration_bound) {
    ++outcome.num_iterations;
    const auto sample = DrawSample<Estimator::kSampleSize>(num_data, random);
    const auto models = estimator.FitMinimal(sample);
    for (int i = 0; i < models.num_solutions; ++i) {
      const Score score = estimator.Evaluate(models.cam_from_world[i], outcome.best.score);
      if (!score.IsBetterThan(outcome.best.score)) continue;
      outcome.found = true;
      outcome.best = {models.cam_from_world[i], score};
      if (options.local_optimization) outcome.best = estimator.LocalOptimize(outcome.best);
      estimator.OnNewBest(outcome.best.score);
      const double inlier_ratio = static_cast<double>(outcome.best.score.num_inliers) / num_data;
      iteration_bound = RequiredIterations(
          std::pow(inlier_ratio, Estimator::kSampleSize) * estimator.RightPoseAcceptance(),
          options.confidence, options.max_iterations);
    }
    if (options.early_stop_inliers > 0 &&
        outcome.best.score.num_inliers > options.early_stop_inliers) {
      break;
    }
  }
  return outcome;
}

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
  // every prefix to be a random subset.
  for (int i = static_cast<int>(correspondences.size()) - 1; i > 0; --i) {
    std::swap(correspondences[i], correspondences[random.UniformInt(i + 1)]);
  }
  RansacOptions ransac_options;
  ransac_options.max_iterations = options.max_iterations;
  ransac_options.early_stop_inliers = options.early_stop_inliers;
  ransac_options.confidence = options.confidence;
  ransac_options.local_optimization = options.local_optimization;
  AbsolutePoseEstimator estimator(correspondences, options.max_reprojection_error_px);
  const RansacOutcome<Rigid3d> ransac = RunLoRansac(estimator, ransac_options, random);
  SolverOutcome outcome;
  outcome.found = ransac.found;
  outcome.cam_from_world = ransac.best.model;
  outcome.num_iterations = ransac.num_iterations;
  return outcome;
}

// cv::solvePnPRansac with USAC on the undistorted points, shown to OpenCV as a pinhole camera
// with the mean focal length so that its threshold is in (approximate) pixels. Every UsacParams
// field is set, so no OpenCV default or global state (its RNG, its thread pool) leaks in.
SolverOutcome RunOpenCvUsac(const std::vector<NormalizedCorrespondence>& correspondences,
                            double focal_length_px, const AbsolutePoseOptions& options) {
  const int num_data = static_cast<int>(correspondences.size());
  cv::Mat object_points(num_data, 3, CV_64F);
  cv::Mat image_points(num_data, 2, CV_64F);
  for (int i = 0; i < num_data; ++i) {
    const NormalizedCorrespondence& correspondence = correspondences[i];
    for (int k = 0; k < 3; ++k) object_points.at<double>(i, k) = correspondence.point3D_in_world[k];
    for (int k = 0; k < 2; ++k) {
      image_points.at<double>(i, k) = focal_length_px * correspondence.point2D_normalized[k];
    }
  }
  const cv::Matx33d camera_matrix(focal_length_px, 0, 0, 0, focal_length_px, 0, 0, 0, 1);

  cv::UsacParams params;
  // OpenCV's bound log(1 - confidence) is -inf at 1; the nearest double below 1 means "never".
  params.confidence = std::min(options.confidence, std::nextafter(1.0, 0.0));
  params.isParallel = false;
  params.loIterations = 5;
  params.loMethod = options.local_optimization ? cv::LOCAL_OPTIM_INNER_LO : cv::LOCAL_OPTIM_NULL;
  params.loSampleSize = 14;
  params.maxIterations = options.max_iterations;
  params.neighborsSearch = cv::NEIGH_GRID;
  params.randomGeneratorState = static_cast<int>(MixBits(options.seed) >> 33);
  params.sampler = cv::SAMPLING_UNIFORM;
  params.score = cv::SCORE_METHOD_MSAC;
  params.threshold = options.max_reprojection_error_px;

  SolverOutcome outcome;
  // USAC does not report how many samples it drew.
  outcome.num_iterations = -1;
  cv::Vec3d rvec, tvec;
  std::vector<int> inliers;
  try {
    outcome.found = cv::solvePnPRansac(object_points, image_points, camera_matrix, cv::noArray(),
                                       rvec, tvec, inliers, params);
  } catch (const cv::Exception& exception) {
    // OpenCV asserts on some degenerate samples; for valid input that is a failed estimate.
    outcome.error = exception.what();
    return outcome;
  }
  if (outcome.found) outcome.cam_from_world = Rigid3dFromOpenCvPose(rvec, tvec);
  outcome.found = outcome.found && outcome.cam_from_world.translation.allFinite() &&
                  outcome.cam_from_world.rotation.coeffs().allFinite();
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
  if (early_stop_inliers < 0) {
    ThrowInvalidArgument("AbsolutePoseOptions.early_stop_inliers is {}, must be >= 0 (0: off)",
                         early_stop_inliers);
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
          : RunOpenCvUsac(correspondences, camera.MeanFocalLength(), options);
  result.num_iterations = outcome.num_iterations;
  if (!outcome.error.empty()) {
    return Fail(std::move(result), "OpenCV USAC failed: " + outcome.error);
  }
  if (!outcome.found) {
    return Fail(std::move(result),
                "no hypothesis: no sample gave a pose that passed verification (no consistent "
                "matches, or degenerate geometry such as collinear points)");
  }

  RefinedPose pose;
  pose.cam_from_world = outcome.cam_from_world;
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

}  // namespace hscloc
