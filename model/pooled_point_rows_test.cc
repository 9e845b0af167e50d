// Pooled point rows: the candidate points of a (image, node) against a brute-force walk of the
// tree, and the pooled logits against their definition.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "model/network_module.h"
#include "model/network_test_support.h"
#include "model/point_candidates.h"

namespace hscloc {
namespace {

using testing_support::MakeRandomMap;
using testing_support::RandomMap;

// Whether the label path of `point` passes through `node`.
bool IsUnder(const LabelTree& tree, uint32_t point, uint32_t node) {
  const int depth = tree.NodeLevel(node);
  return tree.NodeOfLabels(tree.LabelsOfPoint(point), depth) == static_cast<int64_t>(node);
}

TEST(PointCandidatesTest, SpansHoldExactlyThePointsUnderTheNodeThatTheImageSees) {
  const RandomMap map = MakeRandomMap(5);
  const std::vector<uint32_t> images = {3, 0, 3, 9};  // 9: the "no image" index
  const PointCandidates candidates(map.tree, &map.visibility, images);
  EXPECT_EQ(candidates.NumRows(), map.tree.NumPoints());
  EXPECT_EQ(candidates.SlotOf(0), candidates.SlotOf(2));
  EXPECT_NE(candidates.SlotOf(0), candidates.SlotOf(1));
  EXPECT_EQ(candidates.SlotOf(3), -1);
  for (uint32_t point = 0; point < map.tree.NumPoints(); ++point) {
    const uint32_t rank = candidates.RankOfPoint(point);
    for (int level = 0; level < map.tree.levels(); ++level) {
      EXPECT_EQ(candidates.LabelOfRow(rank, level), map.tree.LabelsOfPoint(point)[level]);
    }
  }
  for (size_t k = 0; k < images.size(); ++k) {
    for (uint32_t node = 0; node < map.tree.NumNodes(); ++node) {
      std::vector<uint32_t> expected;
      for (uint32_t point = 0; point < map.tree.NumPoints(); ++point) {
        const bool seen =
            images[k] >= map.visibility.NumImages() || map.visibility.IsVisible(images[k], point);
        if (seen && IsUnder(map.tree, point, node)) {
          expected.push_back(candidates.RankOfPoint(point));
        }
      }
      std::sort(expected.begin(), expected.end());
      const CandidateSpan span = candidates.Under(candidates.SlotOf(k), node);
      std::vector<uint32_t> actual;
      for (size_t i = 0; i < span.size; ++i) actual.push_back(span[i]);
      ASSERT_EQ(actual, expected) << "image " << images[k] << ", node " << node;
    }
  }
}

// With several rows per point, a span holds every row of each point it would hold, side by side,
// and each row is labelled as its point.
TEST(PointCandidatesTest, SpansHoldEveryRowOfTheirPoints) {
  const RandomMap map = MakeRandomMap(5);
  const NetworkShape shape = testing_support::WithPrototypeRows(map.shape);
  const std::vector<uint32_t> images = {3, 0, 9};
  const PointCandidates one_row(map.tree, &map.visibility, images);
  const PointCandidates candidates(map.tree, &map.visibility, images, &shape.point_row_offsets);
  EXPECT_EQ(static_cast<int64_t>(candidates.NumRows()), shape.point_row_offsets.back());
  for (uint32_t point = 0; point < map.tree.NumPoints(); ++point) {
    const auto [first, end] = candidates.RowsOfPoint(point);
    const uint32_t rank = candidates.RankOfPoint(point);
    EXPECT_EQ(end - first, 1 + rank % 3);
    for (uint32_t row = first; row < end; ++row) {
      EXPECT_EQ(candidates.LabelOfRow(row, map.tree.levels() - 1),
                map.tree.LabelsOfPoint(point)[map.tree.levels() - 1]);
    }
  }
  for (size_t k = 0; k < images.size(); ++k) {
    for (uint32_t node = 0; node < map.tree.NumNodes(); ++node) {
      const CandidateSpan points = one_row.Under(one_row.SlotOf(k), node);
      std::vector<uint32_t> expected;
      for (size_t i = 0; i < points.size; ++i) {
        const uint32_t first = candidates.FirstRowOfRank(points[i]);
        const uint32_t end = candidates.FirstRowOfRank(points[i] + 1);
        for (uint32_t row = first; row < end; ++row) expected.push_back(row);
      }
      const CandidateSpan span = candidates.Under(candidates.SlotOf(k), node);
      std::vector<uint32_t> actual;
      for (size_t i = 0; i < span.size; ++i) actual.push_back(span[i]);
      ASSERT_EQ(actual, expected) << "image " << images[k] << ", node " << node;
    }
  }
}

// In training the true child scores the observed point alone: with several rows, the log-sum-exp
// of them, and each of its rows gets its share of the gradient.
TEST(PooledPointLogitsTest, TheTruePointScoresTheLogSumExpOfItsRows) {
  torch::manual_seed(6);
  const torch::Tensor table = torch::randn({10, 5}).requires_grad_();
  const torch::Tensor projected = torch::randn({2, 5});
  FlatCandidates candidates{
      torch::tensor({0, 1, 4}, torch::kInt64), torch::tensor({0, 0, 1}, torch::kInt64),
      torch::tensor({0, 1, 2}, torch::kInt64),
      // Row 0's point has rows 2, 3 and 7; row 1's has row 9 alone.
      torch::tensor({2, 3, 7, 9}, torch::kInt64), torch::tensor({1, 0}, torch::kInt64),
      torch::tensor({0, 0, 0, 1}, torch::kInt64)};
  const auto score = [&](int64_t row, int64_t rank) {
    return static_cast<double>((table[rank] * projected[row]).sum().item<float>());
  };
  const torch::Tensor logits =
      PooledPointLogits(projected, table, candidates, 3, Pooling::kLogSumExp);
  const double sum = std::exp(score(0, 2)) + std::exp(score(0, 3)) + std::exp(score(0, 7));
  EXPECT_NEAR(logits[0][1].item<float>(), std::log(sum), 1e-5);
  EXPECT_NEAR(logits[1][0].item<float>(), score(1, 9), 1e-5);
  EXPECT_NEAR(logits[0][0].item<float>(), score(0, 0), 1e-5);
  logits[0][1].backward();
  for (const int64_t rank : {2, 3, 7}) {
    const torch::Tensor expected = projected[0] * (std::exp(score(0, rank)) / sum);
    EXPECT_TRUE(torch::allclose(table.grad()[rank], expected, 1e-4, 1e-5)) << "row " << rank;
  }
}

TEST(PooledPointLogitsTest, PoolEachChildsCandidatesByLogSumExpOrBestPoint) {
  torch::manual_seed(3);
  const int64_t rows = 3, dim = 4, branching = 5;
  const torch::Tensor table = torch::randn({10, dim + 1});
  const torch::Tensor projected = torch::randn({rows, dim + 1});
  // Row 0: children 1 (points 2, 7) and 4 (point 5); row 1: child 0 (point 2, a candidate of
  // row 0 too); row 2: no candidate at all.
  const FlatCandidates candidates{torch::tensor({2, 7, 5, 2}, torch::kInt64),
                                  torch::tensor({0, 0, 0, 1}, torch::kInt64),
                                  torch::tensor({1, 1, 4, 0}, torch::kInt64),
                                  {},
                                  {},
                                  {}};
  const auto score = [&](int64_t row, int64_t rank) {
    return (table[rank] * projected[row]).sum().item<float>();
  };
  const torch::Tensor sum_logits =
      PooledPointLogits(projected, table, candidates, branching, Pooling::kLogSumExp);
  const torch::Tensor max_logits =
      PooledPointLogits(projected, table, candidates, branching, Pooling::kBestPoint);
  const float lowest = -std::numeric_limits<float>::infinity();
  const float s2 = score(0, 2), s7 = score(0, 7);
  EXPECT_NEAR(sum_logits[0][1].item<float>(), std::log(std::exp(s2) + std::exp(s7)), 1e-5);
  EXPECT_NEAR(max_logits[0][1].item<float>(), std::max(s2, s7), 1e-6);
  EXPECT_NEAR(sum_logits[0][4].item<float>(), score(0, 5), 1e-5);
  EXPECT_NEAR(sum_logits[1][0].item<float>(), score(1, 2), 1e-5);
  for (const int64_t child : {0, 2, 3}) EXPECT_EQ(sum_logits[0][child].item<float>(), lowest);
  EXPECT_EQ(max_logits[1][3].item<float>(), lowest);
  EXPECT_TRUE(sum_logits[2].eq(0).all().item<bool>()) << "a row without candidates stays finite";
  EXPECT_TRUE(max_logits[2].eq(0).all().item<bool>());

  // Training: the true child scores the observed point alone, the other children pool.
  FlatCandidates training = candidates;
  training.true_ranks = torch::tensor({7, 2, 3}, torch::kInt64);
  training.true_groups = torch::tensor({1, 0, 2}, torch::kInt64);
  const torch::Tensor trained =
      PooledPointLogits(projected, table, training, branching, Pooling::kLogSumExp);
  EXPECT_NEAR(trained[0][1].item<float>(), s7, 1e-5);
  EXPECT_NEAR(trained[0][4].item<float>(), score(0, 5), 1e-5);
  EXPECT_NEAR(trained[2][2].item<float>(), score(2, 3), 1e-5);
}

// Decoding with several rows per point: a point scores the log-sum-exp of its rows, a child its
// best point.
TEST(PooledPointLogitsTest, TheBestPointPoolsItsOwnRows) {
  torch::manual_seed(4);
  const int64_t dim = 4, branching = 5;
  const torch::Tensor table = torch::randn({10, dim});
  const torch::Tensor projected = torch::randn({2, dim});
  // Row 0: child 1 holds point 0 (rows 2, 3) and point 1 (row 7), child 4 point 2 (row 5); row 1:
  // child 0 holds point 0 (row 2 alone in its image).
  FlatCandidates candidates{torch::tensor({2, 3, 7, 5, 2}, torch::kInt64),
                            torch::tensor({0, 0, 0, 0, 1}, torch::kInt64),
                            torch::tensor({1, 1, 1, 4, 0}, torch::kInt64)};
  candidates.points = torch::tensor({0, 0, 1, 2, 0}, torch::kInt64);
  const auto score = [&](int64_t row, int64_t rank) {
    return static_cast<double>((table[rank] * projected[row]).sum().item<float>());
  };
  const torch::Tensor logits =
      PooledPointLogits(projected, table, candidates, branching, Pooling::kBestPoint);
  const double point_0 = std::log(std::exp(score(0, 2)) + std::exp(score(0, 3)));
  EXPECT_NEAR(logits[0][1].item<float>(), std::max(point_0, score(0, 7)), 1e-5);
  EXPECT_NEAR(logits[0][4].item<float>(), score(0, 5), 1e-5);
  EXPECT_NEAR(logits[1][0].item<float>(), score(1, 2), 1e-5);
  EXPECT_EQ(logits[1][1].item<float>(), -std::numeric_limits<float>::infinity());
}

// Training gathers the candidates of rows that share them (a small map) in a dense form, without
// the flat lists: it pools as the flat lists do, logits and gradients, for rows of several images,
// of no image, under several parents and without any candidate.
TEST(PooledPointLogitsTest, TheDenseFormPoolsAsTheFlatLists) {
  const RandomMap map = MakeRandomMap(5);
  const NetworkShape shape = testing_support::WithPrototypeRows(map.shape);
  const std::vector<uint32_t> images = {3, 0, 9};  // 9: no image, every point
  const PointCandidates candidates(map.tree, &map.visibility, images, &shape.point_row_offsets);
  const int no_image = candidates.SlotOf(2);
  const std::vector<int> slots = {
      no_image, candidates.SlotOf(0), no_image, candidates.SlotOf(1), no_image, no_image};
  const uint32_t first_child = map.tree.NodeOfLabels(map.tree.LabelsOfPoint(0), 1);
  const std::vector<int64_t> parents = {0, 0, 0, first_child, first_child, -1};
  const int64_t rows = static_cast<int64_t>(slots.size());
  const FlatCandidates flat =
      GatherCandidates(candidates, slots.data(), parents.data(), 0, rows, 0);
  const FlatCandidates dense =
      GatherCandidates(candidates, slots.data(), parents.data(), 0, rows, 0, /*allow_dense=*/true);
  ASSERT_TRUE(flat.ranks.defined() && !flat.dense_mask.defined());
  ASSERT_TRUE(dense.dense_mask.defined() && !dense.ranks.defined());
  torch::manual_seed(9);
  const torch::Tensor start_table = torch::randn({shape.point_row_offsets.back(), 4});
  const torch::Tensor start_projected = torch::randn({rows, 4});
  torch::Tensor logits[2], table[2], projected[2];
  for (int pass = 0; pass < 2; ++pass) {
    table[pass] = start_table.clone().requires_grad_(true);
    projected[pass] = start_projected.clone().requires_grad_(true);
    logits[pass] = PooledPointLogits(projected[pass], table[pass], pass == 0 ? flat : dense,
                                     map.tree.branching(), Pooling::kLogSumExp);
    logits[pass].logsumexp(1).sum().backward();
  }
  EXPECT_TRUE(torch::allclose(logits[0], logits[1], 1e-5, 1e-5));
  EXPECT_TRUE(logits[1][rows - 1].eq(0).all().item<bool>()) << "a row without candidates";
  EXPECT_TRUE(logits[1][3].isneginf().any().item<bool>()) << "a child the image does not see";
  EXPECT_TRUE(torch::allclose(table[0].grad(), table[1].grad(), 1e-5, 1e-6));
  EXPECT_TRUE(torch::allclose(projected[0].grad(), projected[1].grad(), 1e-5, 1e-6));
  EXPECT_THROW(PooledPointLogits(start_projected, start_table, dense, map.tree.branching(),
                                 Pooling::kBestPoint),
               std::logic_error);
}

// Logits and gradients against the definition, computed one candidate at a time, for rows that
// share all their candidates (a small map, scored by one matrix product) and rows that share none
// (scored by gathering each candidate's row).
TEST(PooledPointLogitsTest, SharedAndDistinctCandidatesScoreAsTheirDefinition) {
  torch::manual_seed(7);
  const int64_t rows = 6, width = 5, branching = 3;
  std::vector<int64_t> shared_ranks, shared_rows, shared_groups, own_ranks, own_rows, own_groups;
  for (int64_t row = 0; row < rows; ++row) {
    for (const int64_t rank : {4, 9, 11, 17, 30}) {
      shared_ranks.push_back(rank);
      shared_rows.push_back(row);
      shared_groups.push_back(rank % branching);
    }
    for (int64_t i = 0; i < 2; ++i) {
      own_ranks.push_back(40 + 2 * row + i);
      own_rows.push_back(row);
      own_groups.push_back((row + i) % branching);
    }
  }
  const auto as_tensor = [](const std::vector<int64_t>& values) {
    return torch::tensor(values, torch::kInt64);
  };
  const torch::Tensor start_table = torch::randn({60, width});
  const torch::Tensor start_projected = torch::randn({rows, width});
  const torch::Tensor targets = torch::tensor({0, 1, 2, 0, 1, 2}, torch::kInt64);
  for (const bool shared : {true, false}) {
    const FlatCandidates candidates{as_tensor(shared ? shared_ranks : own_ranks),
                                    as_tensor(shared ? shared_rows : own_rows),
                                    as_tensor(shared ? shared_groups : own_groups),
                                    {},
                                    {},
                                    {}};
    torch::Tensor table[2], projected[2], logits[2];
    for (int pass = 0; pass < 2; ++pass) {
      table[pass] = start_table.clone().requires_grad_(true);
      projected[pass] = start_projected.clone().requires_grad_(true);
    }
    logits[0] =
        PooledPointLogits(projected[0], table[0], candidates, branching, Pooling::kLogSumExp);
    std::vector<torch::Tensor> cells(rows * branching);
    for (int64_t i = 0; i < candidates.ranks.size(0); ++i) {
      const int64_t row = candidates.rows[i].item<int64_t>();
      const int64_t cell = row * branching + candidates.groups[i].item<int64_t>();
      const torch::Tensor score =
          (table[1][candidates.ranks[i].item<int64_t>()] * projected[1][row]).sum().unsqueeze(0);
      cells[cell] = cells[cell].defined() ? torch::cat({cells[cell], score}) : score;
    }
    std::vector<torch::Tensor> pooled;
    for (torch::Tensor& cell : cells) {
      pooled.push_back(cell.defined() ? cell.logsumexp(0)
                                      : torch::full({}, -std::numeric_limits<float>::infinity()));
    }
    logits[1] = torch::stack(pooled).view({rows, branching});
    ASSERT_TRUE(torch::allclose(logits[0], logits[1], 1e-5, 1e-5)) << "shared: " << shared;
    for (int pass = 0; pass < 2; ++pass) {
      torch::nn::functional::cross_entropy(logits[pass], targets).backward();
    }
    EXPECT_TRUE(torch::allclose(table[0].grad(), table[1].grad(), 1e-5, 1e-6)) << shared;
    EXPECT_TRUE(torch::allclose(projected[0].grad(), projected[1].grad(), 1e-5, 1e-6)) << shared;
  }
}

TEST(PooledPointLogitsTest, TrainingGradientReachesOnlyTheCandidatesRows) {
  torch::manual_seed(4);
  torch::Tensor table = torch::randn({8, 3}).requires_grad_(true);
  const torch::Tensor projected = torch::randn({2, 3});
  const FlatCandidates candidates{torch::tensor({1, 6, 3}, torch::kInt64),
                                  torch::tensor({0, 0, 1}, torch::kInt64),
                                  torch::tensor({0, 2, 2}, torch::kInt64),
                                  {},
                                  {},
                                  {}};
  const torch::Tensor logits =
      PooledPointLogits(projected, table, candidates, 4, Pooling::kLogSumExp);
  torch::nn::functional::cross_entropy(logits, torch::tensor({0, 2}, torch::kInt64)).backward();
  const torch::Tensor gradient = table.grad();
  EXPECT_TRUE(torch::isfinite(gradient).all().item<bool>());
  const torch::Tensor touched = gradient.abs().sum(1).nonzero().squeeze(1);
  // Row 1 has a single candidate child: nothing to learn, a zero gradient on its point.
  EXPECT_TRUE(touched.equal(torch::tensor({1, 6}, torch::kInt64)));
}

TEST(PooledPointLogitsTest, TheSparseGradientEqualsTheDenseOneAndHoldsOnlyTheGatheredRows) {
  torch::manual_seed(5);
  const torch::Tensor start = torch::randn({1000, 5});
  const torch::Tensor projected = torch::randn({3, 5});
  // Candidates of three rows, with a repeated point and a true point (the training target).
  const FlatCandidates candidates{torch::tensor({10, 20, 30, 20, 999, 5, 6}, torch::kInt64),
                                  torch::tensor({0, 0, 0, 1, 1, 2, 2}, torch::kInt64),
                                  torch::tensor({0, 1, 1, 0, 3, 2, 3}, torch::kInt64),
                                  torch::tensor({10, 999, 6}, torch::kInt64),
                                  torch::tensor({0, 3, 3}, torch::kInt64),
                                  {}};
  const torch::Tensor targets = torch::tensor({0, 3, 3}, torch::kInt64);
  torch::Tensor gradients[2];
  for (const bool sparse : {false, true}) {
    torch::Tensor table = start.clone().requires_grad_(true);
    const torch::Tensor logits =
        PooledPointLogits(projected, table, candidates, 4, Pooling::kLogSumExp, sparse);
    torch::nn::functional::cross_entropy(logits, targets).backward();
    EXPECT_EQ(table.grad().is_sparse(), sparse);
    gradients[sparse] = sparse ? table.grad().coalesce() : table.grad();
  }
  EXPECT_TRUE(torch::allclose(gradients[1].to_dense(), gradients[0], 1e-6, 1e-7));
  // Only the gathered rows are in it: 7 candidates and 3 true points, 6 distinct rows.
  EXPECT_EQ(gradients[1].indices().size(1), 6);
}

}  // namespace
}  // namespace hscloc
