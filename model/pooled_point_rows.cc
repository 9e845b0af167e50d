// Pooled point rows through libtorch operators: the trainer's loss and the libtorch inference path
// (model/network_module.h).
#include <algorithm>
#include <limits>
#include <stdexcept>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "model/network_module.h"

namespace hscloc {

namespace {

// Bytes of one piece of the scores' gathers: each [piece, r + 1] buffer and its gradient stays
// under glibc's largest mmap threshold (32 MiB, model/trainer.cc), so that it is reused from the
// heap rather than mapped and page-faulted in anew at every step.
constexpr int64_t kPieceBytes = int64_t{16} << 20;

// Candidate scores computes the dense [rows, distinct candidates] product where it holds at most
// this many cells per candidate it needs.
constexpr int64_t kDenseScoresPerCandidate = 4;

// DenseLogSumExp's bounds: cells per candidate, and cells in all (64 MiB per float table).
constexpr int64_t kDenseCellsPerCandidate = 8;
constexpr int64_t kMaxDenseCells = int64_t{1} << 24;

// A copy of `values` as a tensor.
torch::Tensor Int64Tensor(std::vector<int64_t>& values) {
  return torch::from_blob(values.data(), {static_cast<int64_t>(values.size())}, torch::kInt64)
      .clone();
}

// point_rows[ranks]; with a sparse gradient (embedding's) the backward pass touches only those
// rows, where index_select's allocates and fills the whole table's gradient at every step.
torch::Tensor GatherRows(const torch::Tensor& point_rows, const torch::Tensor& ranks,
                         bool sparse_gradient) {
  if (!sparse_gradient || !point_rows.requires_grad()) return point_rows.index_select(0, ranks);
  return torch::embedding(point_rows, ranks, /*padding_idx=*/-1, /*scale_grad_by_freq=*/false,
                          /*sparse=*/true);
}

// <point_rows[rank_i], projected[row_i]> for every candidate i, [T].
torch::Tensor CandidateScores(const torch::Tensor& projected, const torch::Tensor& point_rows,
                              const torch::Tensor& ranks, const torch::Tensor& rows,
                              bool sparse_gradient) {
  // Where the rows share most of their candidates (a small map, whose images each see a large
  // part of it), every row is scored against every distinct candidate by one matrix product:
  // gathering a row and a point row per candidate instead moved up to a gigabyte per step.
  torch::Tensor distinct, position;
  std::tie(distinct, position, std::ignore) =
      torch::_unique2(ranks, /*sorted=*/false, /*return_inverse=*/true);
  if (projected.size(0) * distinct.size(0) <= kDenseScoresPerCandidate * ranks.size(0)) {
    const torch::Tensor all_scores =
        torch::matmul(projected, GatherRows(point_rows, distinct, sparse_gradient).t());
    return all_scores.view({-1}).index_select(0, rows * distinct.size(0) + position);
  }
  const int64_t per_piece = std::max<int64_t>(
      1024, kPieceBytes / (point_rows.size(1) * static_cast<int64_t>(sizeof(float))));
  std::vector<torch::Tensor> pieces;
  for (int64_t begin = 0; begin < ranks.size(0); begin += per_piece) {
    const int64_t size = std::min(per_piece, ranks.size(0) - begin);
    const torch::Tensor gathered =
        GatherRows(point_rows, ranks.narrow(0, begin, size), sparse_gradient);
    pieces.push_back((gathered * projected.index_select(0, rows.narrow(0, begin, size))).sum(1));
  }
  if (pieces.empty()) return torch::empty({0}, projected.options());
  return torch::cat(pieces);
}

// The largest score of each cell (row * branching + child) of `num_cells`; -inf where none.
torch::Tensor CellMaxima(const torch::Tensor& cells, const torch::Tensor& scores,
                         int64_t num_cells) {
  const torch::Tensor cpu_cells = cells.to(torch::kCPU).contiguous();
  const torch::Tensor cpu_scores = scores.detach().to(torch::kCPU).contiguous();
  torch::Tensor maxima = torch::full({num_cells}, -std::numeric_limits<float>::infinity());
  float* best = maxima.data_ptr<float>();
  const int64_t* cell = cpu_cells.data_ptr<int64_t>();
  const float* score = cpu_scores.data_ptr<float>();
  for (int64_t i = 0; i < cpu_cells.numel(); ++i) best[cell[i]] = std::max(best[cell[i]], score[i]);
  return maxima.to(scores.device());
}

// The score of each row's observed point [R]: its row's, or with several rows per point the
// log-sum-exp of them, as decoding scores a point (Pooling::kBestPoint); the gradient reaches each
// of the point's rows by its share of the sum.
torch::Tensor TrueScores(const torch::Tensor& projected, const torch::Tensor& point_rows,
                         const torch::Tensor& true_ranks, const torch::Tensor& true_rows,
                         bool sparse_gradient) {
  const int64_t num_rows = projected.size(0);
  if (!true_rows.defined() || true_rows.size(0) == num_rows) {
    return (GatherRows(point_rows, true_ranks, sparse_gradient) * projected).sum(1);
  }
  const torch::Tensor rows = true_rows.to(projected.device());
  const torch::Tensor scores =
      CandidateScores(projected, point_rows, true_ranks, rows, sparse_gradient);
  // Each row's best score stabilizes the exponentials (a constant for the gradient).
  const torch::Tensor best = CellMaxima(rows, scores, num_rows);
  const torch::Tensor sums = torch::zeros({num_rows}, projected.options())
                                 .index_add(0, rows, (scores - best.index_select(0, rows)).exp());
  return sums.log() + best;
}

// Each (row, point) pair's log-sum-exp over its candidates, the pairs being the runs of equal
// rows[i] and points[i] (GatherCandidates' order): the pairs' scores [P] and each pair's index of
// its first candidate.
std::pair<torch::Tensor, torch::Tensor> PointLogSumExps(const torch::Tensor& scores,
                                                        const torch::Tensor& rows,
                                                        const torch::Tensor& points) {
  const int64_t count = scores.size(0);
  const torch::Tensor starts =
      torch::cat({torch::ones({1}, rows.options().dtype(torch::kBool)),
                  rows.narrow(0, 1, count - 1).ne(rows.narrow(0, 0, count - 1)) |
                      points.narrow(0, 1, count - 1).ne(points.narrow(0, 0, count - 1))});
  const torch::Tensor pair = starts.to(torch::kInt64).cumsum(0) - 1;
  const int64_t num_pairs = pair[count - 1].item<int64_t>() + 1;
  const torch::Tensor best = CellMaxima(pair, scores, num_pairs);
  const torch::Tensor sums = torch::zeros({num_pairs}, scores.options())
                                 .index_add(0, pair, (scores - best.index_select(0, pair)).exp());
  return {sums.log() + best, starts.nonzero().view({-1})};
}

// Log-sum-exp or best point per cell (row * branching + child) over the candidates one at a time:
// [R, branching], -inf where a cell has none.
torch::Tensor SparsePooling(const torch::Tensor& projected, const torch::Tensor& point_rows,
                            const FlatCandidates& candidates, int64_t branching, Pooling pooling,
                            bool sparse_gradient) {
  const torch::Device device = projected.device();
  const torch::Tensor rows = candidates.rows.to(device);
  const int64_t num_rows = projected.size(0);
  const torch::Tensor cells = rows * branching + candidates.groups.to(device);
  const torch::Tensor scores =
      CandidateScores(projected, point_rows, candidates.ranks.to(device), rows, sparse_gradient);
  if (pooling == Pooling::kBestPoint) {
    // Without the points' ranks each candidate stands for a point of its own.
    if (!candidates.points.defined() || scores.size(0) == 0) {
      return CellMaxima(cells, scores, num_rows * branching).view({num_rows, branching});
    }
    const auto [point_scores, first_of_point] =
        PointLogSumExps(scores.detach(), rows, candidates.points.to(device));
    return CellMaxima(cells.index_select(0, first_of_point), point_scores, num_rows * branching)
        .view({num_rows, branching});
  }
  // The maximum per cell stabilizes the exponentials (a constant for the gradient).
  const torch::Tensor best = CellMaxima(cells, scores, num_rows * branching);
  const torch::Tensor stable = best.clamp_min(-1e30);
  const torch::Tensor sums =
      torch::zeros({num_rows * branching}, projected.options())
          .index_add(0, cells, (scores - stable.index_select(0, cells)).exp());
  // Only cells without candidates sum to 0; they are set to -inf below.
  return (sums.clamp_min(1e-30).log() + stable)
      .masked_fill(best.isneginf(), -std::numeric_limits<float>::infinity())
      .view({num_rows, branching});
}

// Whether GatherCandidates gives the dense form: on a small table (every row against every table
// row stays under kMaxDenseCells) where the dense cells are at most kDenseCellsPerCandidate per
// candidate. A dense cell costs a multiply-add per width in a matrix product and a few passes of
// plain memory; a candidate of SparsePooling gathers a table row and goes through a chain of
// gathers and scatters, far more.
bool IsDense(int64_t num_rows, int64_t table_rows, int64_t num_candidates) {
  return num_candidates > 0 && num_rows * table_rows <= kMaxDenseCells &&
         num_rows * table_rows <= kDenseCellsPerCandidate * num_candidates;
}

// SparsePooling's log-sum-exp on the dense form: one matrix product scores every row against
// every table row in it, the mask keeps each row's own candidates and a sum over table rows pools
// each child's, so that no per-candidate gather, scatter or loop is left (with a row per view
// these were most of a small map's training step). Each row's largest candidate score stabilizes
// its exponentials: a child more than ~69 below it gets log(1e-30) above that maximum rather than
// its exact logit, a probability of 0 either way.
torch::Tensor DenseLogSumExp(const torch::Tensor& projected, const torch::Tensor& point_rows,
                             const FlatCandidates& dense, int64_t branching, bool sparse_gradient) {
  const torch::Device device = projected.device();
  const int64_t num_rows = projected.size(0);
  const torch::Tensor is_candidate = dense.dense_mask.to(device);
  const torch::Tensor children = dense.dense_children.to(device);
  // Table rows by row: pooling a child adds whole rows of these tables, in memory order.
  const torch::Tensor scores =
      torch::matmul(GatherRows(point_rows, dense.dense_table_rows.to(device), sparse_gradient),
                    projected.t())
          .masked_fill(is_candidate.logical_not(), -std::numeric_limits<float>::infinity());
  const torch::Tensor stable =
      std::get<0>(scores.detach().max(0, /*keepdim=*/true)).clamp_min(-1e30);
  const torch::Tensor sums = torch::zeros({branching, num_rows}, projected.options())
                                 .index_add(0, children, (scores - stable).exp());
  const torch::Tensor has_candidates =
      torch::zeros({branching, num_rows}, projected.options())
          .index_add(0, children, is_candidate.to(projected.scalar_type()))
          .gt(0);
  return (sums.clamp_min(1e-30).log() + stable)
      .masked_fill(has_candidates.logical_not(), -std::numeric_limits<float>::infinity())
      .t();
}

// The dense form straight from the spans, without the flat lists: the rows of one image under one
// parent share their candidates (all of a batch's rows at the coarsest level share the root), so
// each such list is marked once and every row takes its list's column.
FlatCandidates DenseCandidates(const PointCandidates& candidates,
                               const std::vector<CandidateSpan>& spans,
                               const std::vector<int64_t>& list_of_row, int level) {
  const int64_t table_rows = static_cast<int64_t>(candidates.NumRows());
  std::vector<int64_t> position(table_rows, -1), distinct, children;
  for (const CandidateSpan& span : spans) {
    for (size_t i = 0; i < span.size; ++i) {
      if (position[span[i]] >= 0) continue;
      position[span[i]] = static_cast<int64_t>(distinct.size());
      distinct.push_back(span[i]);
      children.push_back(candidates.LabelOfRow(span[i], level));
    }
  }
  const int64_t num_distinct = static_cast<int64_t>(distinct.size());
  const int64_t num_lists = static_cast<int64_t>(spans.size());
  // One more list, empty, for the rows without candidates.
  torch::Tensor list_masks = torch::zeros({num_lists + 1, num_distinct}, torch::kBool);
  bool* mask = list_masks.data_ptr<bool>();
  for (int64_t list = 0; list < num_lists; ++list) {
    for (size_t i = 0; i < spans[list].size; ++i) {
      mask[list * num_distinct + position[spans[list][i]]] = true;
    }
  }
  std::vector<int64_t> lists(list_of_row);
  for (int64_t& list : lists) list = list < 0 ? num_lists : list;
  FlatCandidates dense;
  dense.dense_table_rows = Int64Tensor(distinct);
  dense.dense_children = Int64Tensor(children);
  dense.dense_mask = list_masks.index_select(0, Int64Tensor(lists)).t().contiguous();
  return dense;
}

// The flat lists of the spans: each row's candidates one after another.
FlatCandidates FlatCandidatesOf(const PointCandidates& candidates,
                                const std::vector<CandidateSpan>& spans,
                                const std::vector<int64_t>& list_of_row, int level) {
  std::vector<int64_t> ranks, rows, groups, points;
  for (size_t row = 0; row < list_of_row.size(); ++row) {
    if (list_of_row[row] < 0) continue;
    const CandidateSpan& span = spans[list_of_row[row]];
    rows.insert(rows.end(), span.size, static_cast<int64_t>(row));
    // A span's table rows ascend and a point's rows are adjacent: its label is looked up once.
    uint32_t end_of_point = 0;
    int64_t group = 0, point = 0;
    for (size_t i = 0; i < span.size; ++i) {
      if (i == 0 || span[i] >= end_of_point) {
        point = candidates.RankOfRow(span[i]);
        end_of_point = candidates.FirstRowOfRank(static_cast<uint32_t>(point) + 1);
        group = candidates.LabelOfRow(span[i], level);
      }
      ranks.push_back(span[i]);
      groups.push_back(group);
      points.push_back(point);
    }
  }
  FlatCandidates flat{Int64Tensor(ranks), Int64Tensor(rows), Int64Tensor(groups)};
  flat.points = Int64Tensor(points);
  return flat;
}

}  // namespace

FlatCandidates GatherCandidates(const PointCandidates& candidates, const int* slots,
                                const int64_t* parent_nodes, int64_t begin, int64_t end, int level,
                                bool allow_dense) {
  // Each distinct (slot, parent) is a list of candidates, looked up once.
  std::unordered_map<uint64_t, int64_t> list_of_key;
  std::vector<CandidateSpan> spans;
  std::vector<int64_t> list_of_row(end - begin, -1);
  int64_t num_candidates = 0;
  for (int64_t r = begin; r < end; ++r) {
    if (parent_nodes[r] < 0) continue;
    const uint64_t key =
        (static_cast<uint64_t>(slots[r] + 1) << 32) | static_cast<uint32_t>(parent_nodes[r]);
    const auto [it, inserted] = list_of_key.emplace(key, static_cast<int64_t>(spans.size()));
    if (inserted) {
      spans.push_back(candidates.Under(slots[r], static_cast<uint32_t>(parent_nodes[r])));
    }
    list_of_row[r - begin] = it->second;
    num_candidates += static_cast<int64_t>(spans[it->second].size);
  }
  if (allow_dense &&
      IsDense(end - begin, static_cast<int64_t>(candidates.NumRows()), num_candidates)) {
    return DenseCandidates(candidates, spans, list_of_row, level);
  }
  return FlatCandidatesOf(candidates, spans, list_of_row, level);
}

torch::Tensor PooledPointLogits(const torch::Tensor& projected, const torch::Tensor& point_rows,
                                const FlatCandidates& candidates, int64_t branching,
                                Pooling pooling, bool sparse_gradient) {
  const torch::Device device = projected.device();
  torch::Tensor logits;
  if (candidates.dense_mask.defined()) {
    if (pooling != Pooling::kLogSumExp) {
      throw std::logic_error("PooledPointLogits: dense candidates pool by log-sum-exp only");
    }
    logits = DenseLogSumExp(projected, point_rows, candidates, branching, sparse_gradient);
  } else {
    logits = SparsePooling(projected, point_rows, candidates, branching, pooling, sparse_gradient);
  }
  if (candidates.true_ranks.defined()) {
    const torch::Tensor true_scores =
        TrueScores(projected, point_rows, candidates.true_ranks.to(device), candidates.true_rows,
                   sparse_gradient);
    logits =
        logits.scatter(1, candidates.true_groups.to(device).unsqueeze(1), true_scores.unsqueeze(1));
  }
  // A row without any candidate keeps finite logits, as a path that left the tree does.
  const torch::Tensor empty = logits.isneginf().all(1, /*keepdim=*/true);
  return logits.masked_fill(empty, 0.0f);
}

}  // namespace hscloc
