#include "localization/nearest_neighbor_matcher.h"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>

#include "util/check.h"

namespace hscloc {

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

CandidateMatches MatchNearestRows(const DescriptorMatrix& unit_query,
                                  const Eigen::Ref<const DescriptorMatrix>& rows,
                                  const uint32_t* row_points,
                                  const NearestNeighborOptions& options) {
  CandidateMatches matches;
  const int64_t count = rows.rows();
  if (unit_query.rows() == 0 || count == 0) return matches;
  // Row-major, so that both scans below read it in memory order: a query's row here, and every
  // column's running best query in the mutual check.
  const Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> similarity =
      unit_query * rows.transpose();
  std::vector<int> best_query_of_row;
  if (options.mutual) {
    // The first query of the largest similarity, as maxCoeff would find it column by column.
    best_query_of_row.assign(count, 0);
    std::vector<float> best_of_row(similarity.row(0).begin(), similarity.row(0).end());
    for (int64_t query_row = 1; query_row < similarity.rows(); ++query_row) {
      const float* values = similarity.row(query_row).data();
      for (int64_t j = 0; j < count; ++j) {
        if (values[j] > best_of_row[j]) {
          best_of_row[j] = values[j];
          best_query_of_row[j] = static_cast<int>(query_row);
        }
      }
    }
  }
  // For unit vectors, squared distance = 2 - 2 cos.
  const auto squared_distance = [](float cosine) { return std::max(0.0f, 2 - 2 * cosine); };
  const double squared_ratio = options.ratio * options.ratio;
  for (int64_t query_row = 0; query_row < similarity.rows(); ++query_row) {
    // The best row, and the best row of any other point.
    float best = -std::numeric_limits<float>::infinity();
    float second = -std::numeric_limits<float>::infinity();
    int64_t best_row = -1;
    const float* values = similarity.row(query_row).data();
    for (int64_t j = 0; j < count; ++j) {
      const float cosine = values[j];
      const bool same_point = best_row >= 0 && row_points[j] == row_points[best_row];
      if (cosine > best) {
        if (!same_point) second = best;
        best = cosine;
        best_row = j;
      } else if (cosine > second && !same_point) {
        second = cosine;
      }
    }
    if (best_row < 0) continue;
    if (std::isfinite(second) &&
        squared_distance(best) >= squared_ratio * squared_distance(second)) {
      continue;
    }
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
