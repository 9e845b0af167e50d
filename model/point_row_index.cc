#include "model/point_row_index.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>

#include "model/dense_kernels.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "model/point_candidates.h"
#include "util/check.h"
#include "util/parallel.h"

namespace hscloc {

namespace {

constexpr int64_t kAssignBlock = 256;

// The nearest of `centroids` [lists, width] to each of `rows` [count, width] (squared Euclidean
// distance: the largest <x, c> - |c|^2 / 2), on the compute threads.
std::vector<uint32_t> NearestCentroids(const float* rows, int64_t count, int64_t width,
                                       const std::vector<float>& centroids) {
  const int64_t lists = static_cast<int64_t>(centroids.size()) / width;
  std::vector<float> half_norms(lists);
  for (int64_t list = 0; list < lists; ++list) {
    float norm = 0;
    for (int64_t d = 0; d < width; ++d)
      norm += centroids[list * width + d] * centroids[list * width + d];
    half_norms[list] = -0.5f * norm;
  }
  const dense_kernels::PackedMatrix packed =
      dense_kernels::PackMatrix(centroids.data(), lists, width);
  std::vector<uint32_t> nearest(count);
  const int64_t blocks = (count + kAssignBlock - 1) / kAssignBlock;
  ParallelFor(static_cast<size_t>(blocks), ComputeThreads(), [&](size_t first, size_t last) {
    std::vector<float> scores(kAssignBlock * lists);
    for (size_t block = first; block < last; ++block) {
      const int64_t begin = static_cast<int64_t>(block) * kAssignBlock;
      const int64_t rows_in_block = std::min(count, begin + kAssignBlock) - begin;
      dense_kernels::Linear(rows + begin * width, rows_in_block, packed, half_norms.data(), false,
                            scores.data());
      for (int64_t i = 0; i < rows_in_block; ++i) {
        const float* row_scores = scores.data() + i * lists;
        nearest[begin + i] =
            static_cast<uint32_t>(std::max_element(row_scores, row_scores + lists) - row_scores);
      }
    }
  });
  return nearest;
}

// The mean of each list's rows; a list without rows keeps its centroid.
void UpdateCentroids(const float* rows, int64_t width, const std::vector<uint32_t>& assignment,
                     std::vector<float>& centroids) {
  const int64_t lists = static_cast<int64_t>(centroids.size()) / width;
  std::vector<double> sums(centroids.size(), 0.0);
  std::vector<int64_t> counts(lists, 0);
  for (size_t i = 0; i < assignment.size(); ++i) {
    ++counts[assignment[i]];
    for (int64_t d = 0; d < width; ++d) sums[assignment[i] * width + d] += rows[i * width + d];
  }
  for (int64_t list = 0; list < lists; ++list) {
    if (counts[list] == 0) continue;
    for (int64_t d = 0; d < width; ++d) {
      centroids[list * width + d] = static_cast<float>(sums[list * width + d] / counts[list]);
    }
  }
}

// Lloyd's k-means on an evenly spaced sample of the rows, started from evenly spaced sample rows.
std::vector<float> LearnCentroids(const float* rows, int64_t count, int64_t width, int64_t lists,
                                  const PointRowIndexOptions& options) {
  const int64_t sample_size = std::max<int64_t>(lists, std::min(count, options.training_sample));
  std::vector<float> sample(sample_size * width);
  for (int64_t i = 0; i < sample_size; ++i) {
    std::copy_n(rows + (i * count / sample_size) * width, width, sample.data() + i * width);
  }
  std::vector<float> centroids(lists * width);
  for (int64_t list = 0; list < lists; ++list) {
    std::copy_n(sample.data() + (list * sample_size / lists) * width, width,
                centroids.data() + list * width);
  }
  for (int iteration = 0; iteration < options.kmeans_iterations; ++iteration) {
    UpdateCentroids(sample.data(), width,
                    NearestCentroids(sample.data(), sample_size, width, centroids), centroids);
  }
  return centroids;
}

}  // namespace

void PointRowIndexOptions::Check() const {
  THROW_CHECK_MSG(lists >= 0, "PointRowIndexOptions.lists = {}", lists);
  THROW_CHECK_MSG(probes >= 1, "PointRowIndexOptions.probes = {}", probes);
  THROW_CHECK_MSG(kmeans_iterations >= 0, "PointRowIndexOptions.kmeans_iterations = {}",
                  kmeans_iterations);
  THROW_CHECK_MSG(training_sample >= 1, "PointRowIndexOptions.training_sample = {}",
                  training_sample);
}

PointRowIndex PointRowIndex::Build(const Network& network, const LabelTree& tree,
                                   const PointRowIndexOptions& options) {
  options.Check();
  if (!network.options().pooled_point_rows) {
    ThrowInvalidArgument("point row index: the network has no pooled point rows");
  }
  const torch::Tensor table =
      NetworkInternals::Module(network)->point_rows.to(torch::kCPU).contiguous();
  const PointCandidates ranks(tree, nullptr, {}, &network.shape().point_row_offsets);
  if (table.size(0) != static_cast<int64_t>(ranks.NumRows())) {
    ThrowInvalidArgument("point row index: {} point rows where the tree and the network have {}",
                         table.size(0), ranks.NumRows());
  }
  const float* rows = table.data_ptr<float>();
  const int64_t count = table.size(0);
  const int64_t width = table.size(1);
  const int64_t lists = std::clamp<int64_t>(
      options.lists > 0 ? options.lists : std::llround(std::sqrt(static_cast<double>(count))), 1,
      std::max<int64_t>(count, 1));

  PointRowIndex index;
  index.row_width_ = width;
  index.probes_ = static_cast<int>(std::min<int64_t>(options.probes, lists));
  std::vector<float> centroids = LearnCentroids(rows, count, width, lists, options);
  const std::vector<uint32_t> assignment = NearestCentroids(rows, count, width, centroids);
  UpdateCentroids(rows, width, assignment, centroids);
  std::vector<float> centroid_weights(lists * (width - 1));
  index.centroid_biases_.resize(lists);
  for (int64_t list = 0; list < lists; ++list) {
    std::copy_n(centroids.data() + list * width, width - 1,
                centroid_weights.data() + list * (width - 1));
    index.centroid_biases_[list] = centroids[list * width + width - 1];
  }
  index.centroid_weights_ = dense_kernels::PackMatrix(centroid_weights.data(), lists, width - 1);

  // A stable counting sort by list keeps each list's ranks ascending, hence its first-level
  // labels in runs.
  index.offsets_.assign(lists + 1, 0);
  for (const uint32_t list : assignment) ++index.offsets_[list + 1];
  for (int64_t list = 0; list < lists; ++list) index.offsets_[list + 1] += index.offsets_[list];
  std::vector<uint64_t> next(index.offsets_.begin(), index.offsets_.end() - 1);
  index.ranks_.resize(count);
  index.rows_.resize(count * width);
  for (int64_t rank = 0; rank < count; ++rank) {
    const uint64_t slot = next[assignment[rank]]++;
    index.ranks_[slot] = static_cast<uint32_t>(rank);
    std::copy_n(rows + rank * width, width, index.rows_.data() + slot * width);
  }
  index.segment_offsets_.assign(1, 0);
  for (int64_t list = 0; list < lists; ++list) {
    const uint64_t begin = index.offsets_[list];
    for (uint64_t slot = begin; slot < index.offsets_[list + 1]; ++slot) {
      const uint8_t label = ranks.LabelOfRow(index.ranks_[slot], 0);
      if (slot == begin || label != index.segment_labels_.back()) {
        index.segment_starts_.push_back(static_cast<uint32_t>(slot - begin));
        index.segment_labels_.push_back(label);
      }
    }
    index.segment_starts_.push_back(static_cast<uint32_t>(index.offsets_[list + 1] - begin));
    index.segment_offsets_.push_back(index.segment_labels_.size());
  }
  return index;
}

PointRowIndex::Segments PointRowIndex::SegmentsOf(int64_t list) const {
  const uint64_t first = segment_offsets_[list];
  return {segment_starts_.data() + first + list, segment_labels_.data() + first,
          static_cast<int64_t>(segment_offsets_[list + 1] - first)};
}

namespace {

constexpr int64_t kProbeBlock = 128;
using Probe = std::pair<uint32_t, uint32_t>;  // (list, row)

}  // namespace

std::vector<float> PointRowIndex::PooledLogits(const float* projected, int64_t rows,
                                               int64_t branching, int64_t* multiply_adds) const {
  const std::vector<Probe> probes = ProbeLists(projected, rows, multiply_adds);
  const int parts =
      static_cast<int>(std::min<int64_t>(ResolveNumThreads(ComputeThreads()), NumLists()));
  std::vector<std::vector<float>> part_logits(parts);
  std::vector<int64_t> part_multiply_adds(parts, 0);
  ParallelFor(static_cast<size_t>(parts), parts, [&](size_t first, size_t last) {
    for (size_t part = first; part < last; ++part) {
      // Lists [NumLists * part / parts, NumLists * (part + 1) / parts), by their probes.
      const auto list_bound = [&](size_t k) {
        const auto list = static_cast<uint32_t>(NumLists() * k / parts);
        return std::lower_bound(probes.begin(), probes.end(), Probe(list, 0u));
      };
      const Probe* begin = probes.data() + (list_bound(part) - probes.begin());
      const Probe* end = probes.data() + (list_bound(part + 1) - probes.begin());
      part_logits[part].assign(rows * branching, -std::numeric_limits<float>::infinity());
      part_multiply_adds[part] =
          ScanProbedLists(projected, begin, end, branching, part_logits[part].data());
    }
  });
  std::vector<float> logits = std::move(part_logits[0]);
  for (int part = 1; part < parts; ++part) {
    for (int64_t k = 0; k < rows * branching; ++k) {
      logits[k] = std::max(logits[k], part_logits[part][k]);
    }
  }
  *multiply_adds +=
      std::accumulate(part_multiply_adds.begin(), part_multiply_adds.end(), int64_t{0});
  return logits;
}

std::vector<std::pair<uint32_t, uint32_t>> PointRowIndex::ProbeLists(const float* projected,
                                                                     int64_t rows,
                                                                     int64_t* multiply_adds) const {
  const int64_t lists = NumLists();
  const int64_t dim = row_width_ - 1;
  *multiply_adds += rows * lists * dim;
  std::vector<Probe> probed(rows * probes_);
  const int64_t blocks = (rows + kProbeBlock - 1) / kProbeBlock;
  ParallelFor(static_cast<size_t>(blocks), ComputeThreads(), [&](size_t first, size_t last) {
    std::vector<float> scores(kProbeBlock * lists);
    std::vector<uint32_t> order(lists);
    for (size_t block = first; block < last; ++block) {
      const int64_t begin = static_cast<int64_t>(block) * kProbeBlock;
      const int64_t end = std::min(rows, begin + kProbeBlock);
      dense_kernels::Linear(projected + begin * dim, end - begin, centroid_weights_,
                            centroid_biases_.data(), false, scores.data());
      for (int64_t r = begin; r < end; ++r) {
        const float* row_scores = scores.data() + (r - begin) * lists;
        std::iota(order.begin(), order.end(), 0u);
        std::nth_element(order.begin(), order.begin() + probes_ - 1, order.end(),
                         [&](uint32_t a, uint32_t b) { return row_scores[a] > row_scores[b]; });
        for (int64_t p = 0; p < probes_; ++p) {
          probed[r * probes_ + p] = {order[p], static_cast<uint32_t>(r)};
        }
      }
    }
  });
  std::sort(probed.begin(), probed.end());
  return probed;
}

int64_t PointRowIndex::ScanProbedLists(const float* projected, const Probe* first,
                                       const Probe* last, int64_t branching, float* logits) const {
  const int64_t dim = row_width_ - 1;
  int64_t multiply_adds = 0;
  std::vector<float> list_queries, list_logits;
  for (const Probe* p = first; p != last;) {
    const uint32_t list = p->first;
    const Probe* list_end = p;
    while (list_end != last && list_end->first == list) ++list_end;
    const auto count = static_cast<int64_t>(list_end - p);
    list_queries.resize(count * dim);
    list_logits.resize(count * branching);
    for (int64_t k = 0; k < count; ++k) {
      std::copy_n(projected + p[k].second * dim, dim, list_queries.data() + k * dim);
      std::copy_n(logits + p[k].second * branching, branching, list_logits.data() + k * branching);
    }
    const Segments segments = SegmentsOf(list);
    multiply_adds += count * (ListEnd(list) - ListBegin(list)) * dim;
    dense_kernels::PooledMaxLogits(list_queries.data(), count, dim, Rows(list), segments.starts,
                                   segments.labels, segments.count, branching, list_logits.data());
    for (int64_t k = 0; k < count; ++k) {
      std::copy_n(list_logits.data() + k * branching, branching, logits + p[k].second * branching);
    }
    p = list_end;
  }
  return multiply_adds;
}

}  // namespace hscloc
