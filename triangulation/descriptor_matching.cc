#include "triangulation/descriptor_matching.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "util/check.h"

namespace hscloc {
namespace {

// Rows of descriptors1 compared at once: bounds the similarity block's memory (here 32 MiB for
// 8192 columns) whatever the keypoint counts.
constexpr int64_t kBlockRows = 1024;

// The two largest similarities seen for one descriptor, and the index of the largest.
struct BestTwo {
  float best = -std::numeric_limits<float>::infinity();
  float second = -std::numeric_limits<float>::infinity();
  int64_t index = -1;
  void Add(float similarity, int64_t candidate) {
    if (similarity > best) {
      second = best;
      best = similarity;
      index = candidate;
    } else if (similarity > second) {
      second = similarity;
    }
  }
  // ||a - b||^2 = 2 - 2 a.b for unit vectors; the ratio is compared on squared distances.
  bool PassesRatio(double max_ratio) const {
    if (max_ratio >= 1 || !std::isfinite(second)) return true;
    const double best_distance_sq = std::max(0.0, 2.0 - 2.0 * best);
    const double second_distance_sq = std::max(0.0, 2.0 - 2.0 * second);
    return best_distance_sq <= max_ratio * max_ratio * second_distance_sq;
  }
};

}  // namespace

void DescriptorMatchingOptions::Check() const {
  THROW_CHECK_MSG(max_ratio > 0 && max_ratio <= 1, "max_ratio must lie in (0, 1], not {}",
                  max_ratio);
}

std::vector<FeatureMatch> MatchDescriptors(const DescriptorMatrix& descriptors1,
                                           const DescriptorMatrix& descriptors2,
                                           const DescriptorMatchingOptions& options) {
  options.Check();
  if (descriptors1.cols() != descriptors2.cols()) {
    ThrowInvalidArgument("descriptors of dimension {} cannot be matched with dimension {}",
                         descriptors1.cols(), descriptors2.cols());
  }
  const int64_t num1 = descriptors1.rows();
  const int64_t num2 = descriptors2.rows();
  if (num1 == 0 || num2 == 0) return {};
  const DescriptorMatrix unit1 = UnitRows(descriptors1);
  const DescriptorMatrix unit2 = UnitRows(descriptors2);

  std::vector<BestTwo> best_of1(num1);
  std::vector<BestTwo> best_of2(num2);
  Eigen::MatrixXf similarity;
  for (int64_t begin = 0; begin < num1; begin += kBlockRows) {
    const int64_t rows = std::min(kBlockRows, num1 - begin);
    similarity.noalias() = unit1.middleRows(begin, rows) * unit2.transpose();
    for (int64_t j = 0; j < num2; ++j) {
      for (int64_t i = 0; i < rows; ++i) {
        best_of1[begin + i].Add(similarity(i, j), j);
        best_of2[j].Add(similarity(i, j), begin + i);
      }
    }
  }

  std::vector<FeatureMatch> matches;
  for (int64_t i = 0; i < num1; ++i) {
    const BestTwo& forward = best_of1[i];
    if (forward.index < 0 || best_of2[forward.index].index != i) continue;
    if (!forward.PassesRatio(options.max_ratio) ||
        !best_of2[forward.index].PassesRatio(options.max_ratio)) {
      continue;
    }
    matches.push_back({static_cast<point2D_t>(i), static_cast<point2D_t>(forward.index)});
  }
  return matches;
}

}  // namespace hscloc
