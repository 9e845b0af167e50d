// The LO-RANSAC loop (Chum et al., DAGM 2003) over any estimator with PoseLib's interface
// (ransac.h there): NumData(), FitMinimal(sample), Evaluate(model, to_beat), LocalOptimize(best),
// OnNewBest(score) and RightPoseAcceptance(). The estimator owns the data and the scoring; this
// loop owns the sampling, the adaptive iteration bound and the early stop on an inlier count.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <vector>

#include "util/check.h"
#include "util/random.h"

namespace hscloc {

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

struct RansacOptions {
  int max_iterations = 0;
  // Stop sampling once the best hypothesis has more than this many inliers; 0 disables.
  int stop_past_inliers = 0;
  double confidence = 0.0;
  bool local_optimization = false;
  // Only a hypothesis with more inliers than this is of use; the adaptive bound assumes at least
  // that inlier ratio from the start. 0: none.
  int inliers_to_beat = 0;
  // PROSAC's sampling where not empty: the data's indices, best first (ProgressiveSampler), and
  // the samples over which the drawn prefix grows to all of them. Empty: uniform sampling.
  std::vector<int> data_best_first;
  int progressive_growth_samples = 0;
};

template <typename Model>
struct RansacOutcome {
  bool found = false;
  ScoredModel<Model> best;
  int num_iterations = 0;
};

// Samples needed to draw and accept one all-inlier sample with the given confidence (Fischler and
// Bolles, with the acceptance of the verification as in Chum and Matas).
inline int RequiredIterations(double good_sample_probability, double confidence,
                              int max_iterations) {
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

// PROSAC's sampling (Chum and Matas, "Matching with PROSAC - progressive sample consensus", CVPR
// 2005). With the data ranked best first, the t-th sample is drawn from the best n(t), and holds
// the n-th of them until n grows: n grows so that the prefix of n is sampled about as often as
// uniform sampling over `growth_samples` draws would sample it, and past them the draw is
// uniform. Where the best-ranked data are more often inliers, an all-inlier sample comes far
// sooner; where the ranking says nothing, the first draws are merely less varied.
template <int kSampleSize>
class ProgressiveSampler {
 public:
  // Reads `data_best_first` on every draw: it must outlive the sampler.
  ProgressiveSampler(const std::vector<int>& data_best_first, int growth_samples)
      : data_best_first_(data_best_first) {
    const auto num_data = static_cast<double>(data_best_first_.size());
    // T_n of the paper for n = kSampleSize: the uniform draws among growth_samples that fall
    // wholly within the best kSampleSize.
    expected_draws_ = growth_samples;
    for (int i = 0; i < kSampleSize; ++i) {
      expected_draws_ *= static_cast<double>(kSampleSize - i) / (num_data - i);
    }
  }

  std::array<int, kSampleSize> Draw(Random& random) {
    ++num_drawn_;
    const auto num_data = static_cast<int>(data_best_first_.size());
    while (prefix_ < num_data && num_drawn_ > prefix_draws_) {
      const double next = expected_draws_ * (prefix_ + 1) / (prefix_ + 1 - kSampleSize);
      prefix_draws_ += static_cast<int64_t>(std::ceil(next - expected_draws_));
      expected_draws_ = next;
      ++prefix_;
    }
    std::array<int, kSampleSize> ranks;
    if (num_drawn_ > prefix_draws_) {
      ranks = DrawSample<kSampleSize>(prefix_, random);
    } else {
      // The newest of the prefix and the rest from before it: the samples that uniform draws
      // over the prefix have and those over the previous prefix had not.
      const auto earlier = DrawSample<kSampleSize - 1>(prefix_ - 1, random);
      std::copy(earlier.begin(), earlier.end(), ranks.begin());
      ranks.back() = prefix_ - 1;
    }
    std::array<int, kSampleSize> sample;
    for (int i = 0; i < kSampleSize; ++i) sample[i] = data_best_first_[ranks[i]];
    return sample;
  }

  // The best-ranked data the draws come from so far.
  int prefix() const { return prefix_; }

 private:
  const std::vector<int>& data_best_first_;
  int64_t num_drawn_ = 0;
  int prefix_ = kSampleSize;
  double expected_draws_ = 0.0;  // T_n
  int64_t prefix_draws_ = 1;     // T'_n: the last draw that holds the prefix's newest
};

// The LO-RANSAC loop, with the estimator interface of PoseLib's ransac.h: sample, fit, score,
// locally optimize the best.
template <typename Estimator>
RansacOutcome<typename Estimator::Model> RunLoRansac(Estimator& estimator,
                                                     const RansacOptions& options, Random& random) {
  RansacOutcome<typename Estimator::Model> outcome;
  const int num_data = estimator.NumData();
  if (num_data < Estimator::kSampleSize) return outcome;
  // The inlier ratio a useful hypothesis has at least, and the samples that find one with the
  // options' confidence.
  const double useful_ratio = static_cast<double>(options.inliers_to_beat + 1) / num_data;
  const auto iterations_for = [&](double inlier_ratio) {
    if (options.inliers_to_beat > 0) inlier_ratio = std::max(inlier_ratio, useful_ratio);
    return RequiredIterations(std::pow(std::min(inlier_ratio, 1.0), Estimator::kSampleSize) *
                                  estimator.RightPoseAcceptance(),
                              options.confidence, options.max_iterations);
  };
  int iteration_bound = options.inliers_to_beat > 0 ? iterations_for(0.0) : options.max_iterations;
  std::optional<ProgressiveSampler<Estimator::kSampleSize>> progressive_sampler;
  if (!options.data_best_first.empty()) {
    THROW_CHECK_MSG(static_cast<int>(options.data_best_first.size()) == num_data,
                    "PROSAC's ranking holds {} indices for {} data", options.data_best_first.size(),
                    num_data);
    progressive_sampler.emplace(options.data_best_first,
                                std::max(options.progressive_growth_samples, 1));
  }
  while (outcome.num_iterations < iteration_bound) {
    ++outcome.num_iterations;
    const auto sample = progressive_sampler ? progressive_sampler->Draw(random)
                                            : DrawSample<Estimator::kSampleSize>(num_data, random);
    const auto models = estimator.FitMinimal(sample);
    for (int i = 0; i < models.num_solutions; ++i) {
      const Score score = estimator.Evaluate(models.cam_from_world[i], outcome.best.score);
      if (!score.IsBetterThan(outcome.best.score)) continue;
      outcome.found = true;
      outcome.best = {models.cam_from_world[i], score};
      if (options.local_optimization) outcome.best = estimator.LocalOptimize(outcome.best);
      estimator.OnNewBest(outcome.best.score);
      iteration_bound =
          iterations_for(static_cast<double>(outcome.best.score.num_inliers) / num_data);
    }
    if (options.stop_past_inliers > 0 &&
        outcome.best.score.num_inliers > options.stop_past_inliers) {
      break;
    }
  }
  return outcome;
}

}  // namespace hscloc
