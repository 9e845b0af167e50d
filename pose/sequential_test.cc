#include "pose/sequential_test.h"

#include <algorithm>

namespace hscloc {
namespace {

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

}  // namespace

SequentialTest::SequentialTest() { Update(kMinRightInlierRatio, kPriorWrongConsistency); }

void SequentialTest::SetRightInlierRatio(double inlier_ratio) {
  Update(std::max(inlier_ratio, kMinRightInlierRatio), delta_);
}

void SequentialTest::RecordWrongPose(int num_consistent, int num_checked) {
  wrong_consistent_ += num_consistent;
  wrong_checked_ += num_checked;
  const double delta =
      (wrong_consistent_ + 100.0 * kPriorWrongConsistency) / (wrong_checked_ + 100.0);
  if (std::abs(delta - delta_) > 0.1 * delta_) Update(epsilon_, delta);
}

void SequentialTest::Update(double epsilon, double delta) {
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

}  // namespace hscloc
