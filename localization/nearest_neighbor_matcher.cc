#include "localization/nearest_neighbor_matcher.h"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>

#include "model/dense_kernels.h"
#include "util/check.h"

namespace hscloc {

CandidateMatches SelectMatches(const CandidateMatches& matches, const std::vector<size_t>& chosen) {
  const bool with_confidences = !matches.confidences.empty();
  CandidateMatches selected;
  selected.keypoints.reserve(chosen.size());
  selected.point_indices.reserve(chosen.size());
  if (with_confidences) selected.confidences.reserve(chosen.size());
  for (const size_t i : chosen) {
    selected.keypoints.push_back(matches.keypoints[i]);
    selected.point_indices.push_back(matches.point_indices[i]);
    if (with_confidences) selected.confidences.push_back(matches.confidences[i]);
  }
  return selected;
}

void NearestNeighborOptions::Check() const {
  THROW_CHECK_MSG(ratio > 0 && ratio <= 1, "NearestNeighborOptions.ratio = {} (0 .. 1]", ratio);
}

NearestNeighborMatcher::NearestNeighborMatcher(const Scene& scene) {
  if (scene.NumObservations() == 0) return;
  offsets_.assign(scene.NumImages() + 1, 0);
  for (const uint32_t image : scene.observation_image_indices) ++offsets_[image + 1];
  for (size_t i = 1; i < offsets_.size(); ++i) offsets_[i] += offsets_[i - 1];
  unit_descriptors_.resize(static_cast<int64_t>(scene.NumObservations()), scene.Dimension());
  point_indices_.resize(scene.NumObservations());
  std::vector<uint32_t> next(offsets_.begin(), offsets_.end() - 1);
  for (uint32_t observation = 0; observation < scene.NumObservations(); ++observation) {
    const uint32_t row = next[scene.observation_image_indices[observation]]++;
    unit_descriptors_.row(row) = scene.observation_descriptors.row(observation);
    point_indices_[row] = scene.observation_point_indices[observation];
  }
  NormalizeRows(unit_descriptors_);
}

namespace {

// Query rows per block of similarities: a block of about a megabyte stays in cache between the
// product that writes it and the scans that read it, where the whole matrix (thousands of
// keypoints by thousands of rows) would go out to memory and back.
int64_t QueryRowsPerBlock(int64_t rows) {
  constexpr int64_t kBlockFloats = int64_t{1} << 18;
  constexpr int64_t kTileRows = 12;
  return std::max(kTileRows, kBlockFloats / std::max<int64_t>(rows, 1) / kTileRows * kTileRows);
}

// The best row of one query row's similarities and the best row of any other point: the row, or
// -1 where the ratio test rejects it.
int64_t BestRowPassingRatio(const float* similarities, int64_t count, const uint32_t* row_points,
                            double squared_ratio) {
  float best = -std::numeric_limits<float>::infinity();
  float second = -std::numeric_limits<float>::infinity();
  int64_t best_row = -1;
  for (int64_t j = 0; j < count; ++j) {
    const float cosine = similarities[j];
    const bool same_point = best_row >= 0 && row_points[j] == row_points[best_row];
    if (cosine > best) {
      if (!same_point) second = best;
      best = cosine;
      best_row = j;
    } else if (cosine > second && !same_point) {
      second = cosine;
    }
  }
  // For unit vectors, squared distance = 2 - 2 cos.
  const auto squared_distance = [](float cosine) { return std::max(0.0f, 2 - 2 * cosine); };
  if (best_row >= 0 && std::isfinite(second) &&
      squared_distance(best) >= squared_ratio * squared_distance(second)) {
    return -1;
  }
  return best_row;
}

}  // namespace

CandidateMatches MatchNearestRows(const DescriptorMatrix& unit_query,
                                  const Eigen::Ref<const DescriptorMatrix>& rows,
                                  const uint32_t* row_points,
                                  const NearestNeighborOptions& options) {
  CandidateMatches matches;
  const int64_t count = rows.rows();
  const int64_t num_queries = unit_query.rows();
  if (num_queries == 0 || count == 0) return matches;
  THROW_CHECK_EQ(unit_query.cols(), rows.cols());
  // The similarities come from the network's matrix-product kernel, at the machine's vector width:
  // the rows packed once, the queries block by block.
  // Rows side by side already (an image's observations, a gathered set of point rows) are packed
  // where they lie; only a strided view is copied first.
  DescriptorMatrix strided_copy;
  const float* row_data = rows.data();
  if (rows.outerStride() != rows.cols()) {
    strided_copy = rows;
    row_data = strided_copy.data();
  }
  const dense_kernels::PackedMatrix packed_rows =
      dense_kernels::PackMatrix(row_data, count, rows.cols());
  const std::vector<float> no_bias(count, 0.0f);
  const int64_t block_rows = std::min(num_queries, QueryRowsPerBlock(count));
  std::vector<float> block(block_rows * count);
  std::vector<int64_t> best_row_of_query(num_queries, -1);
  // Every row's best query, the first of the largest similarity, as a scan in query order finds it.
  std::vector<float> best_of_row(options.mutual ? count : 0,
                                 -std::numeric_limits<float>::infinity());
  std::vector<int> best_query_of_row(options.mutual ? count : 0, 0);
  const double squared_ratio = options.ratio * options.ratio;
  for (int64_t first = 0; first < num_queries; first += block_rows) {
    const int64_t size = std::min(block_rows, num_queries - first);
    dense_kernels::Linear(unit_query.row(first).data(), size, packed_rows, no_bias.data(), false,
                          block.data());
    for (int64_t i = 0; i < size; ++i) {
      const float* values = block.data() + i * count;
      best_row_of_query[first + i] = BestRowPassingRatio(values, count, row_points, squared_ratio);
      if (!options.mutual) continue;
      for (int64_t j = 0; j < count; ++j) {
        if (values[j] > best_of_row[j]) {
          best_of_row[j] = values[j];
          best_query_of_row[j] = static_cast<int>(first + i);
        }
      }
    }
  }
  for (int64_t query_row = 0; query_row < num_queries; ++query_row) {
    const int64_t best_row = best_row_of_query[query_row];
    if (best_row < 0) continue;
    if (options.mutual && best_query_of_row[best_row] != query_row) continue;
    matches.keypoints.push_back(static_cast<int>(query_row));
    matches.point_indices.push_back(row_points[best_row]);
  }
  return matches;
}

CandidateMatches NearestNeighborMatcher::Match(const DescriptorMatrix& unit_query,
                                               uint32_t image_index,
                                               const NearestNeighborOptions& options) const {
  THROW_CHECK_MSG(image_index + 1 < offsets_.size(),
                  "NearestNeighborMatcher: image index {} of {} images", image_index,
                  offsets_.empty() ? 0 : offsets_.size() - 1);
  const int64_t first = offsets_[image_index];
  const int64_t count = offsets_[image_index + 1] - first;
  return MatchNearestRows(unit_query, unit_descriptors_.middleRows(first, count),
                          point_indices_.data() + first, options);
}

}  // namespace hscloc
