#include "model/point_prototypes.h"

#include <torch/torch.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>

#include "model/network_module.h"
#include "model/point_candidates.h"
#include "scene/features.h"

namespace hscloc {
namespace {

// Training observations grouped by point: point p's are order[first[p] .. first[p + 1]).
struct ObservationsByPoint {
  std::vector<size_t> first;
  std::vector<size_t> order;  // positions in `training`
};

ObservationsByPoint GroupByPoint(const Scene& scene, const std::vector<uint32_t>& training) {
  ObservationsByPoint groups;
  groups.first.assign(scene.NumPoints() + 1, 0);
  for (const uint32_t observation : training) {
    ++groups.first[scene.observation_point_indices[observation] + 1];
  }
  for (size_t p = 1; p < groups.first.size(); ++p) groups.first[p] += groups.first[p - 1];
  groups.order.resize(training.size());
  std::vector<size_t> next(groups.first.begin(), groups.first.end() - 1);
  for (size_t i = 0; i < training.size(); ++i) {
    groups.order[next[scene.observation_point_indices[training[i]]]++] = i;
  }
  return groups;
}

// Of `unit` (one observation per row), the index of the prototype each row joins: `count` seeds
// chosen farthest-first from the row nearest to the mean, each row to its most similar seed.
std::vector<int> AssignToPrototypes(const DescriptorMatrix& unit, int count) {
  const Eigen::VectorXf mean = unit.colwise().sum().transpose();
  std::vector<int64_t> seeds;
  Eigen::VectorXf(unit * mean).maxCoeff(&seeds.emplace_back());
  Eigen::VectorXf nearest_seed = unit * unit.row(seeds[0]).transpose();
  while (static_cast<int>(seeds.size()) < count) {
    nearest_seed.minCoeff(&seeds.emplace_back());
    nearest_seed = nearest_seed.cwiseMax(unit * unit.row(seeds.back()).transpose());
  }
  std::vector<int> prototype(unit.rows());
  for (int64_t i = 0; i < unit.rows(); ++i) {
    float best = -std::numeric_limits<float>::infinity();
    for (int s = 0; s < count; ++s) {
      const float similarity = unit.row(i).dot(unit.row(seeds[s]));
      if (similarity > best) {
        best = similarity;
        prototype[i] = s;
      }
    }
  }
  return prototype;
}

}  // namespace

std::vector<int64_t> PointRowOffsets(const Scene& scene, const std::vector<uint32_t>& training,
                                     const LabelTree& tree, int max_rows_per_point) {
  if (max_rows_per_point <= 1) return {};
  const PointCandidates ranks(tree, nullptr, {});
  std::vector<int64_t> rows_of_rank(ranks.NumRows(), 0);
  for (const uint32_t observation : training) {
    ++rows_of_rank[ranks.RankOfPoint(scene.observation_point_indices[observation])];
  }
  std::vector<int64_t> offsets(rows_of_rank.size() + 1, 0);
  for (size_t rank = 0; rank < rows_of_rank.size(); ++rank) {
    offsets[rank + 1] =
        offsets[rank] + std::clamp<int64_t>(rows_of_rank[rank], 1, max_rows_per_point);
  }
  return offsets;
}

std::vector<int64_t> StartingRowOfObservations(const Scene& scene,
                                               const std::vector<uint32_t>& training,
                                               const PointCandidates& candidates) {
  std::vector<int64_t> rows(training.size());
  const ObservationsByPoint groups = GroupByPoint(scene, training);
  DescriptorMatrix unit;
  for (size_t point = 0; point + 1 < groups.first.size(); ++point) {
    const size_t begin = groups.first[point];
    const size_t count = groups.first[point + 1] - begin;
    if (count == 0) continue;
    const auto [first_row, end_row] = candidates.RowsOfPoint(static_cast<uint32_t>(point));
    const auto prototypes = static_cast<int>(end_row - first_row);
    if (prototypes == 1 || static_cast<size_t>(prototypes) == count) {
      for (size_t i = 0; i < count; ++i) {
        rows[groups.order[begin + i]] = first_row + (prototypes == 1 ? 0 : static_cast<int64_t>(i));
      }
      continue;
    }
    unit.resize(static_cast<int64_t>(count), scene.Dimension());
    for (size_t i = 0; i < count; ++i) {
      unit.row(static_cast<int64_t>(i)) =
          scene.observation_descriptors.row(training[groups.order[begin + i]]);
    }
    NormalizeRows(unit);
    const std::vector<int> prototype = AssignToPrototypes(unit, prototypes);
    for (size_t i = 0; i < count; ++i) rows[groups.order[begin + i]] = first_row + prototype[i];
  }
  return rows;
}

void InitializePointRowsFromDescriptors(const Scene& scene, const std::vector<uint32_t>& training,
                                        const PointCandidates& candidates, bool identity,
                                        torch::Tensor& point_rows) {
  torch::NoGradGuard no_grad;
  const int64_t dim = scene.Dimension();
  const int64_t rows_dim = point_rows.size(1) - 1;
  const torch::Tensor projection = identity ? torch::eye(dim) : torch::randn({dim, rows_dim});
  const std::vector<int64_t> starting_rows = StartingRowOfObservations(scene, training, candidates);
  torch::Tensor sums = torch::zeros({point_rows.size(0), rows_dim});
  const torch::Tensor all =
      torch::from_blob(const_cast<float*>(scene.observation_descriptors.data()),
                       {static_cast<int64_t>(scene.NumObservations()), dim}, torch::kFloat32);
  constexpr size_t kBlock = 1 << 15;
  for (size_t begin = 0; begin < training.size(); begin += kBlock) {
    const size_t end = std::min(training.size(), begin + kBlock);
    const std::vector<int64_t> observations(training.begin() + begin, training.begin() + end);
    const std::vector<int64_t> rows(starting_rows.begin() + begin, starting_rows.begin() + end);
    const torch::Tensor block =
        NormalizeRows(all.index_select(0, torch::tensor(observations, torch::kInt64)));
    sums.index_add_(0, torch::tensor(rows, torch::kInt64), block.mm(projection));
  }
  point_rows.narrow(1, 0, rows_dim).copy_(NormalizeRows(sums).to(point_rows.device()));
  // Each bias starts at -log of its point's rows, so that a point's log-sum-exp starts as the log
  // of its rows' mean exponential and a point seen often is not favoured for its count.
  torch::Tensor biases = torch::zeros({point_rows.size(0)});
  float* bias = biases.data_ptr<float>();
  for (uint32_t rank = 0; candidates.FirstRowOfRank(rank) < candidates.NumRows(); ++rank) {
    const uint32_t first = candidates.FirstRowOfRank(rank);
    const uint32_t end = candidates.FirstRowOfRank(rank + 1);
    std::fill(bias + first, bias + end, -std::log(static_cast<float>(end - first)));
  }
  point_rows.select(1, rows_dim).copy_(biases.to(point_rows.device()));
}

}  // namespace hscloc
