// The CPU inference kernels against libtorch's operators, which the CUDA path runs: the same
// weights must give the same labels and confidences.
#include <gtest/gtest.h>

#include <numeric>

#include "model/network.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "model/network_test_support.h"
#include "model/point_candidates.h"
#include "util/random.h"

namespace hscloc {
namespace {

using testing_support::MakeRandomMap;
using testing_support::RandomDescriptors;
using testing_support::RandomMap;

// Rows whose label paths agree; a near tie between two children may flip under a different
// summation order, so a handful of disagreements is allowed, but the confidences of agreeing rows
// must match to float precision.
void ExpectSamePredictions(const PointPredictions& kernels, const PointPredictions& torch_ops) {
  ASSERT_EQ(kernels.labels.rows(), torch_ops.labels.rows());
  int64_t agreeing = 0;
  for (int64_t r = 0; r < kernels.labels.rows(); ++r) {
    if (kernels.labels.row(r) != torch_ops.labels.row(r)) continue;
    ++agreeing;
    EXPECT_NEAR(kernels.confidences.data()[r], torch_ops.confidences.data()[r],
                1e-4f * torch_ops.confidences.data()[r] + 1e-7f)
        << "row " << r;
    EXPECT_EQ(kernels.point_indices.data()[r], torch_ops.point_indices.data()[r]);
  }
  EXPECT_GE(agreeing, kernels.labels.rows() * 995 / 1000) << "of " << kernels.labels.rows();
}

// A level's FLOPs are those of its descriptors, of the deciding rows and of one generator pass
// per run of rows sharing their modulation: the runs they leave must be a whole number between 1
// and the deciding rows. A row that did work it need not have breaks the count.
void ExpectWorkOfDecidingRowsOnly(double level_flops, int64_t descriptor_dim,
                                  const NetworkOptions& options, int64_t descriptors,
                                  double deciding, double children_scored) {
  const double d = static_cast<double>(descriptor_dim), c = options.channels;
  const double e = options.embedding_dim, h = options.trunk_channels;
  const double layers = options.conditioned_layers, out = options.node_output_dim;
  const double per_descriptor = static_cast<double>(descriptors) * (d * h + h * c + c * c);
  const double per_row = deciding * ((layers - 1) * c * c + c * out) + children_scored * out;
  const double generator = 2 * (e * e + 2 * layers * e * c);
  const double runs = (level_flops - 2 * (per_descriptor + per_row)) / generator;
  EXPECT_DOUBLE_EQ(runs, std::round(runs));
  EXPECT_GE(runs, 1);
  EXPECT_LE(runs, deciding);
}

TEST(NetworkCpuInferenceTest, KernelsMatchTorchOperators) {
  const RandomMap fixture = MakeRandomMap(11);
  const DescriptorMatrix descriptors = RandomDescriptors(333, fixture.shape.descriptor_dim, 5);
  const std::vector<uint32_t> images = {4, 0, 8, 4, 9, 7};  // 9: no image
  for (int layers = 1; layers <= 3; ++layers) {
    NetworkOptions base;
    base.channels = 48;
    base.embedding_dim = 24;
    base.conditioned_layers = layers;
    base.trunk_channels = 40 + 16 * layers;  // differs from the channels
    for (const NetworkOptions& options :
         testing_support::HeadVariants(base, fixture.shape.descriptor_dim)) {
      const Network network = testing_support::WithRandomProjections(
          Network(fixture.shape, options, 100 + layers), 200 + layers);
      for (const Visibility* mask :
           {static_cast<const Visibility*>(nullptr), &fixture.visibility}) {
        SCOPED_TRACE(testing::Message()
                     << layers << " conditioned layers, node conditioning "
                     << options.node_conditioning << ", node output rows "
                     << options.node_output_dim << ", pooled " << options.pooled_point_rows
                     << ", shortcut " << options.descriptor_shortcut << ", shared trunk "
                     << options.shared_trunk << ", mask " << (mask != nullptr));
        ExpectSamePredictions(
            network.Predict(descriptors, images, fixture.tree, mask),
            NetworkInternals::PredictWithTorch(network, descriptors, images, fixture.tree, mask));
      }
    }
  }
}

// Pooled point rows at the descriptors' width with the descriptor shortcut, `channels` wide.
NetworkOptions ShortcutRowOptions(int descriptor_dim, int channels) {
  NetworkOptions options;
  options.channels = channels;
  options.embedding_dim = channels / 2;
  options.trunk_channels = 40;
  options.node_conditioning = false;
  options.pooled_point_rows = true;
  options.node_output_dim = descriptor_dim;
  options.descriptor_shortcut = true;
  return options;
}

// With several rows per point, both paths pool a point's rows, and a prediction is a point.
TEST(NetworkCpuInferenceTest, KernelsMatchTorchOperatorsWithSeveralRowsPerPoint) {
  const RandomMap fixture = MakeRandomMap(11);
  const NetworkShape shape = testing_support::WithPrototypeRows(fixture.shape);
  const DescriptorMatrix descriptors = RandomDescriptors(333, shape.descriptor_dim, 5);
  const std::vector<uint32_t> images = {4, 0, 8, 4, 9, 7};  // 9: no image
  const Network network = testing_support::WithRandomProjections(
      Network(shape, ShortcutRowOptions(shape.descriptor_dim, 48), 101), 201);
  EXPECT_EQ(NetworkInternals::Module(network)->point_rows.size(0), shape.point_row_offsets.back());
  for (const Visibility* mask : {static_cast<const Visibility*>(nullptr), &fixture.visibility}) {
    ExpectSamePredictions(
        network.Predict(descriptors, images, fixture.tree, mask),
        NetworkInternals::PredictWithTorch(network, descriptors, images, fixture.tree, mask));
  }
}

// With several rows per point a child pools its rows by log-sum-exp on both paths: a point whose
// three rows each score 15.2 (their sum e^16.3) beats one whose single row scores 16, which the
// maximum would choose.
TEST(NetworkCpuInferenceTest, SeveralRowsPerPointPoolByLogSumExp) {
  const RandomMap fixture = MakeRandomMap(12);
  const NetworkShape shape = testing_support::WithPrototypeRows(fixture.shape);
  // The projections start at zero: a row's score is <row, s x> + bias, x the unit descriptor.
  Network network(shape, ShortcutRowOptions(shape.descriptor_dim, 16), 3);
  const DescriptorMatrix descriptor = RandomDescriptors(1, shape.descriptor_dim, 4);
  const PointCandidates candidates(fixture.tree, nullptr, {}, &shape.point_row_offsets);
  // A point of one row and a point of three under different first-level children.
  uint32_t single = 0, triple = 0;
  while (candidates.RowsOfPoint(single).second - candidates.RowsOfPoint(single).first != 1) {
    ++single;
  }
  const LabelTree::Label single_child = fixture.tree.LabelsOfPoint(single)[0];
  while (candidates.RowsOfPoint(triple).second - candidates.RowsOfPoint(triple).first != 3 ||
         fixture.tree.LabelsOfPoint(triple)[0] == single_child) {
    ++triple;
  }
  {
    torch::NoGradGuard no_grad;
    torch::Tensor rows = NetworkInternals::Module(network)->point_rows;
    const int64_t dim = shape.descriptor_dim;
    rows.zero_();
    rows.select(1, dim).fill_(-100);
    const torch::Tensor unit =
        torch::from_blob(const_cast<float*>(descriptor.data()), {dim}, torch::kFloat32);
    const torch::Tensor direction = unit / unit.norm();
    const auto give_score = [&](uint32_t point, float score) {
      const auto [first, end] = candidates.RowsOfPoint(point);
      for (uint32_t row = first; row < end; ++row) {
        rows[row].narrow(0, 0, dim).copy_(direction * (score / kInitialShortcutScale));
        rows[row][dim] = 0;
      }
    };
    give_score(single, 16.0f);
    give_score(triple, 15.2f);
  }
  const std::vector<uint32_t> no_image = {9};
  EXPECT_EQ(network.Predict(descriptor, no_image, fixture.tree).point_indices(0, 0), triple);
  EXPECT_EQ(NetworkInternals::PredictWithTorch(network, descriptor, no_image, fixture.tree, nullptr)
                .point_indices(0, 0),
            triple);
}

TEST(NetworkCpuInferenceTest, NodeOutputRowsGiveNoProbabilityToMissingChildren) {
  const RandomMap fixture = MakeRandomMap(13);
  NetworkOptions options = testing_support::SmallOptions();
  options.node_output_dim = 6;
  const Network network(fixture.shape, options, 4);
  const DescriptorMatrix descriptors = RandomDescriptors(120, fixture.shape.descriptor_dim, 7);
  const PointPredictions predictions = network.Predict(descriptors, {0, 3, 9}, fixture.tree);
  // Every path stays in the tree: no level can pick a label its parent does not have.
  EXPECT_TRUE((predictions.point_indices.array() >= 0).all());
  // Trained-for-nothing rows still give probabilities: the confidence is a product of them.
  EXPECT_TRUE((predictions.confidences.array() > 0).all());
  EXPECT_TRUE((predictions.confidences.array() <= 1).all());
}

TEST(NetworkCpuInferenceTest, LevelsWithoutChoiceTakeTheOnlyChildWithCertainty) {
  const LabelTree tree = testing_support::SixtyPointTree();
  ASSERT_FALSE(tree.LevelHasChoice(2));
  const NetworkShape shape = NetworkShape::ForTree(16, tree, 4);
  const Network network(shape, testing_support::SmallOptions(), 5);
  const DescriptorMatrix descriptors = RandomDescriptors(200, shape.descriptor_dim, 6);
  const std::vector<uint32_t> images = {0, 3, 4};
  Random random(22);
  const uint32_t num_points = 60;
  std::vector<uint32_t> seen_images, seen_points;
  for (uint32_t image = 0; image < 4; ++image) {
    for (uint32_t point = 0; point < num_points; ++point) {
      if (random.Bernoulli(0.3)) {
        seen_images.push_back(image);
        seen_points.push_back(point);
      }
    }
  }
  const Visibility visibility =
      Visibility::FromObservations(4, num_points, seen_images, seen_points);
  for (const Visibility* mask : {static_cast<const Visibility*>(nullptr), &visibility}) {
    SCOPED_TRACE(testing::Message() << "mask " << (mask != nullptr));
    const PointPredictions masked_or_not = network.Predict(descriptors, images, tree, mask);
    ExpectSamePredictions(masked_or_not, NetworkInternals::PredictWithTorch(network, descriptors,
                                                                            images, tree, mask));
    EXPECT_TRUE((masked_or_not.labels.col(2).array() == 0).all());
  }
  const PointPredictions kernels = network.Predict(descriptors, images, tree);
  EXPECT_EQ(kernels.level_milliseconds.size(), 3u);
  // The skipped level costs no FLOPs: two thirds of a pass whose three levels all decide.
  const RandomMap full = MakeRandomMap(1);
  ASSERT_TRUE(full.tree.LevelHasChoice(2));
  EXPECT_NEAR(network.PredictFlops(200, 3, tree),
              2.0 / 3.0 * network.PredictFlops(200, 3, full.tree), 1.0);
}

TEST(NetworkCpuInferenceTest, CountsTheWorkItDidNeverMoreThanTheShapesCount) {
  const RandomMap fixture = MakeRandomMap(11);
  const int64_t n = 700;
  const std::vector<uint32_t> images = {1, 2, 3, 5, 8};
  const DescriptorMatrix descriptors = RandomDescriptors(n, fixture.shape.descriptor_dim, 6);
  NetworkOptions shared_output = testing_support::SmallOptions();
  shared_output.node_output_dim = 0;
  const Network network(fixture.shape, shared_output, 7);
  const PointPredictions predictions = network.Predict(descriptors, images, fixture.tree);
  ASSERT_EQ(predictions.level_flops.size(), static_cast<size_t>(fixture.shape.levels));
  const double d = fixture.shape.descriptor_dim, c = shared_output.channels;
  const double e = shared_output.embedding_dim, h = shared_output.trunk_channels;
  const double layers = shared_output.conditioned_layers;
  const double rows = static_cast<double>(n * images.size());
  // Everything but the modulation's generator is done per descriptor or per row, as counted from
  // the shapes; the generator runs once per run of rows sharing an image and label prefix: at
  // least once per image, and (rows sorted by that prefix) far fewer times than there are rows.
  const double per_pass = 2 * (n * (d * h + h * c + c * c) + rows * (layers - 1) * c * c +
                               rows * c * fixture.shape.branching);
  const double generator = 2 * (e * e + 2 * layers * e * c);
  double total = 0;
  for (int level = 0; level < fixture.shape.levels; ++level) {
    SCOPED_TRACE(testing::Message() << "level " << level);
    const double flops = predictions.level_flops[level];
    if (!fixture.tree.LevelHasChoice(level)) {
      EXPECT_EQ(flops, 0);
      continue;
    }
    const double runs = (flops - per_pass) / generator;
    EXPECT_DOUBLE_EQ(runs, std::round(runs));
    EXPECT_GE(runs, static_cast<double>(images.size()));
    EXPECT_LT(runs, rows / 4);
    total += flops;
  }
  const int64_t k = static_cast<int64_t>(images.size());
  EXPECT_LT(total, network.PredictFlops(n, k, fixture.tree));
  // Node output rows score a row against its parent's children only, fewer than the branching
  // the shapes count.
  const Network node_rows(fixture.shape, testing_support::SmallOptions(), 7);
  const std::vector<double> node_flops =
      node_rows.Predict(descriptors, images, fixture.tree).level_flops;
  EXPECT_LT(std::accumulate(node_flops.begin(), node_flops.end(), 0.0),
            node_rows.PredictFlops(n, k, fixture.tree));
}

// Where missing children get no probability (node rows here), a row whose parent has one child
// takes it with certainty and runs no layer: the finest level's work is that of the rows whose
// parent offers a choice, and nothing more.
TEST(NetworkCpuInferenceTest, RowsWhoseParentHasOneChildTakeItWithoutWork) {
  const RandomMap fixture = MakeRandomMap(11);
  const int64_t n = 500;
  const std::vector<uint32_t> images = {1, 2, 3, 5, 8};
  const DescriptorMatrix descriptors = RandomDescriptors(n, fixture.shape.descriptor_dim, 6);
  NetworkOptions options = testing_support::SmallOptions();
  options.node_output_dim = 8;
  const Network network(fixture.shape, options, 7);
  const PointPredictions predictions = network.Predict(descriptors, images, fixture.tree);
  const int last = fixture.shape.levels - 1;
  ASSERT_TRUE(fixture.tree.LevelHasChoice(last));
  // The rows whose parent at the last level offers a choice, and the children they score.
  double deciding = 0, children_scored = 0, forced = 0;
  for (int64_t row = 0; row < predictions.labels.rows(); ++row) {
    const int64_t parent = fixture.tree.NodeOfLabels(predictions.labels.row(row).data(), last);
    ASSERT_GE(parent, 0);
    const uint32_t children = fixture.tree.NumChildren(static_cast<uint32_t>(parent));
    if (children == 1) {
      ++forced;
      EXPECT_EQ(predictions.labels(row, last), 0);
    } else {
      ++deciding;
      children_scored += children;
    }
  }
  ASSERT_GT(forced, 50) << "the fixture must have such parents";
  ASSERT_GT(deciding, 0);
  ExpectWorkOfDecidingRowsOnly(predictions.level_flops[last], fixture.shape.descriptor_dim, options,
                               n, deciding, children_scored);
  // Their confidence is that of the levels above: the torch operators, which run every row,
  // give the only child a probability of 1 too.
  ExpectSamePredictions(predictions, NetworkInternals::PredictWithTorch(
                                         network, descriptors, images, fixture.tree, nullptr));
}

// Pooled point rows under a visibility mask give the children an image does not see no
// probability, so a row whose image sees one child of its parent takes it with certainty and no
// work, as a parent with one child does.
TEST(NetworkCpuInferenceTest, RowsWhoseImageSeesOneChildTakeItWithoutWork) {
  const RandomMap fixture = MakeRandomMap(11);
  const int64_t n = 500;
  const std::vector<uint32_t> images = {1, 2, 3, 5, 8};
  const DescriptorMatrix descriptors = RandomDescriptors(n, fixture.shape.descriptor_dim, 6);
  NetworkOptions options = testing_support::SmallOptions();
  options.node_output_dim = 8;
  options.pooled_point_rows = true;
  const Network network(fixture.shape, options, 7);
  const PointPredictions predictions =
      network.Predict(descriptors, images, fixture.tree, &fixture.visibility);
  const NodeVisibilityMasks masks(images, fixture.tree, fixture.visibility);
  const int last = fixture.shape.levels - 1;
  ASSERT_TRUE(fixture.tree.LevelHasChoice(last));
  // At the last level the children are points: a deciding row scores those its image sees.
  double deciding = 0, children_scored = 0, forced = 0;
  for (int64_t row = 0; row < predictions.labels.rows(); ++row) {
    const int slot = masks.SlotOfK(static_cast<size_t>(row / n));
    ASSERT_GE(slot, 0);
    const int64_t parent = fixture.tree.NodeOfLabels(predictions.labels.row(row).data(), last);
    ASSERT_GE(parent, 0);
    const uint32_t first = fixture.tree.FirstChild(static_cast<uint32_t>(parent));
    std::vector<int> seen;
    for (uint32_t c = 0; c < fixture.tree.NumChildren(static_cast<uint32_t>(parent)); ++c) {
      if (masks.Contains(slot, first + c)) seen.push_back(static_cast<int>(c));
    }
    ASSERT_FALSE(seen.empty()) << "the masked path reached a parent its image does not see";
    if (seen.size() == 1) {
      ++forced;
      EXPECT_EQ(predictions.labels(row, last), seen.front()) << "row " << row;
    } else {
      ++deciding;
      children_scored += static_cast<double>(seen.size());
    }
  }
  ASSERT_GT(forced, 100) << "the fixture must have such rows";
  ASSERT_GT(deciding, 100);
  ExpectWorkOfDecidingRowsOnly(predictions.level_flops[last], fixture.shape.descriptor_dim, options,
                               n, deciding, children_scored);
  ExpectSamePredictions(
      predictions, NetworkInternals::PredictWithTorch(network, descriptors, images, fixture.tree,
                                                      &fixture.visibility));
}

TEST(NetworkCpuInferenceTest, ThreadCountDoesNotChangeResults) {
  const RandomMap fixture = MakeRandomMap(11);
  const DescriptorMatrix descriptors = RandomDescriptors(700, fixture.shape.descriptor_dim, 6);
  const std::vector<uint32_t> images = {1, 2, 3, 5, 8};
  const Network network(fixture.shape, NetworkOptions{32, 16, 2}, 7);
  SetComputeThreads(1);
  const PointPredictions one = network.Predict(descriptors, images, fixture.tree);
  SetComputeThreads(3);
  const PointPredictions three = network.Predict(descriptors, images, fixture.tree);
  SetComputeThreads(0);
  EXPECT_EQ(one.labels, three.labels);
  EXPECT_EQ(one.confidences, three.confidences);
}

// One query's calls (its candidates, the votes without an image id, the votes' candidates) share
// the descriptor-only layers: the same predictions as without the cache, less work after the
// first call, and a cache of other descriptors refused.
TEST(NetworkCpuInferenceTest, DescriptorLayerCacheGivesTheSamePredictionsWithLessWork) {
  const RandomMap fixture = MakeRandomMap(11);
  const DescriptorMatrix descriptors = RandomDescriptors(300, fixture.shape.descriptor_dim, 6);
  for (const NetworkOptions& options : testing_support::HeadVariants(
           testing_support::SmallOptions(), fixture.shape.descriptor_dim)) {
    const Network network =
        testing_support::WithRandomProjections(Network(fixture.shape, options, 12), 13);
    DescriptorLayerCache cache;
    const auto total = [](const PointPredictions& predictions) {
      return std::accumulate(predictions.level_flops.begin(), predictions.level_flops.end(), 0.0);
    };
    for (const std::vector<uint32_t>& images :
         {std::vector<uint32_t>{1, 2, 3}, {network.NoImageIndex()}, {4, 5}}) {
      const PointPredictions plain = network.Predict(descriptors, images, fixture.tree);
      const bool first = cache.levels.empty();
      const PointPredictions cached =
          network.Predict(descriptors, images, fixture.tree, nullptr, &cache);
      EXPECT_EQ(cached.labels, plain.labels);
      EXPECT_EQ(cached.confidences, plain.confidences);
      if (first) {
        EXPECT_EQ(total(cached), total(plain));
      } else {
        EXPECT_LT(total(cached), total(plain)) << "the descriptor layers ran again";
      }
    }
    const DescriptorMatrix others = RandomDescriptors(300, fixture.shape.descriptor_dim, 7);
    EXPECT_THROW(network.Predict(others, {1}, fixture.tree, nullptr, &cache),
                 std::invalid_argument);
  }
}

// The kernels read the weights packed once and kept; an in-place update (an optimizer step
// between held-out evaluations) must reach the next Predict.
TEST(NetworkCpuInferenceTest, WeightsUpdatedInPlaceReachTheNextPrediction) {
  const RandomMap fixture = MakeRandomMap(11);
  NetworkOptions options;
  options.channels = 48;
  options.embedding_dim = 24;
  options.conditioned_layers = 2;
  Network network(fixture.shape, options, 12);
  const DescriptorMatrix descriptors = RandomDescriptors(200, fixture.shape.descriptor_dim, 13);
  const std::vector<uint32_t> images = {3, 6};
  const PointPredictions before = network.Predict(descriptors, images, fixture.tree);
  {
    torch::NoGradGuard no_grad;
    for (torch::Tensor& parameter : NetworkInternals::Module(network)->parameters()) {
      parameter.add_(torch::randn_like(parameter) * 0.5);
    }
  }
  const PointPredictions after = network.Predict(descriptors, images, fixture.tree);
  EXPECT_NE(before.labels, after.labels);
  ExpectSamePredictions(after, NetworkInternals::PredictWithTorch(network, descriptors, images,
                                                                  fixture.tree, nullptr));
}

// The masked choice against its definition, on a tree of branching 100 (a parent's children span
// two or three mask words): the most probable child the image sees, the first of equals, and the
// plain argmax when it sees none; and the only kept child where there is one.
TEST(NetworkCpuInferenceTest, MaskedChoiceIsTheFirstMostProbableKeptChild) {
  Random random(31);
  const std::vector<Eigen::Vector3d> points = testing_support::RandomPoints(4000, random);
  const LabelTree tree = testing_support::RandomPointTree(points, 2, 100);
  std::vector<uint32_t> seen_images, seen_points;
  for (uint32_t image = 0; image < 3; ++image) {
    const double share = 0.002 * (image + 1);  // parents with none, a few and many kept children
    for (uint32_t point = 0; point < points.size(); ++point) {
      if (random.Bernoulli(share * (point % 7 + 1))) {
        seen_images.push_back(image);
        seen_points.push_back(point);
      }
    }
  }
  const Visibility visibility =
      Visibility::FromObservations(3, points.size(), seen_images, seen_points);
  const NodeVisibilityMasks masks({0, 1, 2, 3}, tree, visibility);  // 3: no image, no mask
  ASSERT_EQ(masks.SlotOfK(3), -1);
  for (int slot = 0; slot < 3; ++slot) {
    for (uint32_t first = 0; first + 64 <= tree.NumNodes(); ++first) {
      for (const int count : {1, 7, 63, 64}) {
        const uint64_t bits = masks.Bits(slot, first, count);
        for (int i = 0; i < 64; ++i) {
          ASSERT_EQ((bits >> i) & 1, i < count && masks.Contains(slot, first + i))
              << "slot " << slot << ", nodes " << first << " + " << i << " of " << count;
        }
      }
    }
  }
  int kept_none = 0;
  int kept_some = 0;
  int kept_one = 0;
  for (int64_t parent = 0; parent <= 100; ++parent) {
    if (tree.NumChildren(static_cast<uint32_t>(parent)) == 0) continue;
    const uint32_t first_child = tree.FirstChild(static_cast<uint32_t>(parent));
    const int64_t children = tree.NumChildren(static_cast<uint32_t>(parent));
    for (int k = 0; k < 4; ++k) {
      std::vector<float> probabilities(100);
      // Few distinct values, so that ties between kept children are common.
      for (float& p : probabilities) p = static_cast<float>(random.UniformInt(8)) / 8.0f;
      const int slot = masks.SlotOfK(k);
      int64_t expected = -1;
      for (int64_t c = 0; slot >= 0 && c < children; ++c) {
        if (masks.Contains(slot, first_child + static_cast<uint32_t>(c)) &&
            (expected < 0 || probabilities[c] > probabilities[expected])) {
          expected = c;
        }
      }
      if (slot >= 0) {
        int64_t only_kept = -1;
        int kept = 0;
        for (int64_t c = 0; c < children; ++c) {
          if (masks.Contains(slot, first_child + static_cast<uint32_t>(c))) {
            ++kept;
            only_kept = c;
          }
        }
        EXPECT_EQ(masks.OnlyKeptChild(slot, first_child, children), kept == 1 ? only_kept : -1)
            << "parent " << parent << ", image " << k << ", " << kept << " kept";
        kept_one += kept == 1;
      }
      (expected < 0 ? kept_none : kept_some) += 1;
      if (expected < 0) {
        expected =
            std::max_element(probabilities.begin(), probabilities.end()) - probabilities.begin();
      }
      EXPECT_EQ(ChooseLabel(probabilities.data(), 100, &masks, slot, parent, tree), expected)
          << "parent " << parent << ", image " << k;
    }
  }
  EXPECT_GT(kept_none, 0);
  EXPECT_GT(kept_some, 100);
  EXPECT_GT(kept_one, 0);
}

TEST(NetworkCpuInferenceTest, EmptyQueriesGiveEmptyPredictions) {
  const RandomMap fixture = MakeRandomMap(11);
  const Network network(fixture.shape, NetworkOptions{32, 16, 1}, 8);
  const PointPredictions no_keypoints =
      network.Predict(DescriptorMatrix(0, fixture.shape.descriptor_dim), {1, 2}, fixture.tree);
  EXPECT_EQ(no_keypoints.point_indices.size(), 0);
  const PointPredictions no_images =
      network.Predict(RandomDescriptors(5, fixture.shape.descriptor_dim, 9), {}, fixture.tree);
  EXPECT_EQ(no_images.point_indices.size(), 0);
}

}  // namespace
}  // namespace hscloc
