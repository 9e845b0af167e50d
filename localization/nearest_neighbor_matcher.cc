#include "localization/nearest_neighbor_matcher.h"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>

#include "model/code_kernels.h"
#include "model/dense_kernels.h"
#include "util/check.h"
#include "util/parallel.h"

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

// Rows per block of similarities against `columns` others: a block of about a megabyte stays in
// cache between the product that writes it and the scans that read it, where the whole matrix
// (thousands of keypoints by thousands of rows) would go out to memory and back.
int64_t RowsPerBlock(int64_t columns) {
  constexpr int64_t kBlockFloats = int64_t{1} << 18;
  constexpr int64_t kTileRows = 12;
  return std::max(kTileRows, kBlockFloats / std::max<int64_t>(columns, 1) / kTileRows * kTileRows);
}

// Lowe's test on the similarities of a query's best row and of the best row of any other point
// (-infinity: there is none, and the best row passes). For unit vectors, squared distance =
// 2 - 2 cos.
bool PassesRatioTest(float best, float second, double squared_ratio) {
  const auto squared_distance = [](float cosine) { return std::max(0.0f, 2 - 2 * cosine); };
  return !std::isfinite(second) ||
         squared_distance(best) < squared_ratio * squared_distance(second);
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
  if (best_row >= 0 && !PassesRatioTest(best, second, squared_ratio)) return -1;
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
  const int64_t block_rows = std::min(num_queries, RowsPerBlock(count));
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

namespace {

// The sets that hold each row: sets[first_set[r] .. first_set[r + 1]) for row r.
struct SetsOfRows {
  std::vector<int64_t> first_set;
  std::vector<uint32_t> sets;
};

SetsOfRows InvertSets(const std::vector<std::vector<uint32_t>>& sets, int64_t num_rows) {
  SetsOfRows inverse;
  inverse.first_set.assign(num_rows + 1, 0);
  for (size_t set = 0; set < sets.size(); ++set) {
    for (size_t i = 0; i < sets[set].size(); ++i) {
      const uint32_t row = sets[set][i];
      THROW_CHECK_MSG(row < num_rows, "CountNearestRowMatches: set {} holds row {} of {}", set, row,
                      num_rows);
      THROW_CHECK_MSG(i == 0 || sets[set][i - 1] < row,
                      "CountNearestRowMatches: set {} is not in increasing order at position {}",
                      set, i);
      ++inverse.first_set[row + 1];
    }
  }
  for (int64_t row = 0; row < num_rows; ++row) inverse.first_set[row + 1] += inverse.first_set[row];
  inverse.sets.resize(inverse.first_set.back());
  std::vector<int64_t> next(inverse.first_set.begin(), inverse.first_set.end() - 1);
  for (size_t set = 0; set < sets.size(); ++set) {
    for (const uint32_t row : sets[set]) inverse.sets[next[row]++] = static_cast<uint32_t>(set);
  }
  return inverse;
}

// What one slice of the queries found against every row: per set and query of the slice
// ([set][query]), the best and second similarity over the set's rows and the best row; per row,
// its best query of the slice (a query index of the whole) and that similarity.
struct QuerySliceScan {
  int64_t first_query = 0;
  int64_t num_queries = 0;
  std::vector<float> best;
  std::vector<float> second;
  std::vector<int32_t> best_row;
  std::vector<float> row_best_similarity;
  std::vector<int32_t> row_best_query;
};

QuerySliceScan ScanQuerySlice(const DescriptorMatrix& unit_query, int64_t first_query,
                              int64_t num_queries, int64_t num_rows, const RowCodeReader& read_rows,
                              const SetsOfRows& inverse, size_t num_sets) {
  constexpr float kNone = -std::numeric_limits<float>::infinity();
  QuerySliceScan scan{first_query,
                      num_queries,
                      std::vector<float>(num_sets * num_queries, kNone),
                      std::vector<float>(num_sets * num_queries, kNone),
                      std::vector<int32_t>(num_sets * num_queries, -1),
                      std::vector<float>(num_rows),
                      std::vector<int32_t>(num_rows)};
  // The queries are the product's packed side: a row's similarities to them lie side by side, as
  // UpdateBestTwo reads them for every set that holds the row.
  const int64_t dimension = unit_query.cols();
  const code_kernels::PackedQueryCodes packed_queries =
      code_kernels::PackQueryCodes(unit_query.row(first_query).data(), num_queries, dimension);
  const int64_t stride = packed_queries.padded_count;
  const int64_t block_rows = std::min(num_rows, RowsPerBlock(stride));
  std::vector<float> block(block_rows * stride);
  std::vector<float> inverse_norms(block_rows);
  for (int64_t first_row = 0; first_row < num_rows; first_row += block_rows) {
    const int64_t size = std::min(block_rows, num_rows - first_row);
    const std::vector<int8_t> codes = read_rows(first_row, size);
    THROW_CHECK_MSG(static_cast<int64_t>(codes.size()) == size * dimension,
                    "CountNearestRowMatches: asked for {} rows of dimension {}, read {} codes",
                    size, dimension, codes.size());
    code_kernels::InverseCodeNorms(codes.data(), size, dimension, inverse_norms.data());
    code_kernels::CodeSimilarities(codes.data(), inverse_norms.data(), size, packed_queries,
                                   block.data());
    for (int64_t i = 0; i < size; ++i) {
      const int64_t row = first_row + i;
      const float* similarities = block.data() + i * stride;
      const int64_t best_query = dense_kernels::FirstArgMax(similarities, num_queries);
      scan.row_best_similarity[row] = similarities[best_query];
      scan.row_best_query[row] = static_cast<int32_t>(first_query + best_query);
      // BestRowPassingRatio's scan, a row at a time over every query, for each set of the row.
      for (int64_t k = inverse.first_set[row]; k < inverse.first_set[row + 1]; ++k) {
        const int64_t offset = int64_t{inverse.sets[k]} * num_queries;
        dense_kernels::UpdateBestTwo(similarities, num_queries, static_cast<int32_t>(row),
                                     scan.best.data() + offset, scan.second.data() + offset,
                                     scan.best_row.data() + offset);
      }
    }
  }
  return scan;
}

// Each row's best query over all slices, the first of equals as a scan in query order finds it.
std::vector<int32_t> BestQueryOfEachRow(const std::vector<QuerySliceScan>& slices) {
  std::vector<int32_t> best_query = slices.front().row_best_query;
  std::vector<float> best_similarity = slices.front().row_best_similarity;
  for (size_t k = 1; k < slices.size(); ++k) {
    for (size_t row = 0; row < best_query.size(); ++row) {
      if (slices[k].row_best_similarity[row] > best_similarity[row]) {
        best_similarity[row] = slices[k].row_best_similarity[row];
        best_query[row] = slices[k].row_best_query[row];
      }
    }
  }
  return best_query;
}

}  // namespace

std::vector<int> CountNearestRowMatches(const DescriptorMatrix& unit_query, int64_t num_rows,
                                        const RowCodeReader& read_rows,
                                        const std::vector<std::vector<uint32_t>>& sets,
                                        const NearestNeighborOptions& options, int num_threads) {
  // Fewer queries per thread than this would spend more on each slice's pass over the rows than
  // the threads save.
  constexpr int64_t kMinQueriesPerSlice = 64;
  const SetsOfRows inverse = InvertSets(sets, num_rows);
  std::vector<int> counts(sets.size(), 0);
  const int64_t num_queries = unit_query.rows();
  if (num_queries == 0 || num_rows == 0 || sets.empty()) return counts;
  const int threads = ResolveNumThreads(num_threads);
  const int64_t num_slices =
      std::clamp<int64_t>(num_queries / kMinQueriesPerSlice, 1, std::max(threads, 1));
  std::vector<QuerySliceScan> slices(num_slices);
  ParallelFor(num_slices, threads, [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      const int64_t first = num_queries * static_cast<int64_t>(k) / num_slices;
      const int64_t last = num_queries * static_cast<int64_t>(k + 1) / num_slices;
      slices[k] = ScanQuerySlice(unit_query, first, last - first, num_rows, read_rows, inverse,
                                 sets.size());
    }
  });
  const std::vector<int32_t> best_query_of_row =
      options.mutual ? BestQueryOfEachRow(slices) : std::vector<int32_t>();
  const double squared_ratio = options.ratio * options.ratio;
  for (const QuerySliceScan& slice : slices) {
    for (size_t set = 0; set < sets.size(); ++set) {
      const int64_t offset = static_cast<int64_t>(set) * slice.num_queries;
      for (int64_t i = 0; i < slice.num_queries; ++i) {
        const int32_t best_row = slice.best_row[offset + i];
        if (best_row < 0 ||
            !PassesRatioTest(slice.best[offset + i], slice.second[offset + i], squared_ratio)) {
          continue;
        }
        if (options.mutual && best_query_of_row[best_row] != slice.first_query + i) continue;
        ++counts[set];
      }
    }
  }
  return counts;
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
