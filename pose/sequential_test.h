// Wald's sequential probability ratio test for RANSAC's hypothesis verification.
#pragma once

#include <cmath>

namespace hscloc {

// Wald's sequential probability ratio test for hypothesis verification (Chum and Matas, "Optimal
// Randomized RANSAC", TPAMI 2008). A wrong pose explains a fraction delta of the correspondences,
// a right one a fraction epsilon; reading correspondences in random order, the test rejects a pose
// once their consistency is `threshold` times likelier under "wrong" than under "right". The
// threshold balances reading more correspondences of wrong poses against rejecting right ones,
// which happens with probability at most 1 / threshold and costs more samples. Below 10% inliers
// it rejects a wrong pose after a few dozen correspondences instead of all of them.
class SequentialTest {
 public:
  SequentialTest();

  double consistent_step() const { return consistent_step_; }
  double inconsistent_step() const { return inconsistent_step_; }
  double log_threshold() const { return log_threshold_; }
  double RightPoseAcceptance() const { return 1.0 - std::exp(-log_threshold_); }

  void SetRightInlierRatio(double inlier_ratio);

  // The consistency of rejected poses estimates delta; the prior weighs as 100 correspondences.
  void RecordWrongPose(int num_consistent, int num_checked);

 private:
  void Update(double epsilon, double delta);

  double epsilon_ = 0.0;
  double delta_ = 0.0;
  double consistent_step_ = 0.0;
  double inconsistent_step_ = 0.0;
  double log_threshold_ = 0.0;
  double wrong_consistent_ = 0.0;
  double wrong_checked_ = 0.0;
};

}  // namespace hscloc
