#include "model/trainer.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <numeric>

#include "map/map_bundle.h"
#include "model/network_module.h"
#include "model/network_test_support.h"
#include "model/point_candidates.h"
#include "model/point_prototypes.h"
#include "model/trainer_test_support.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "scene/scene_io.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using trainer_testing::CityMap;
using trainer_testing::MakeCityMap;
using trainer_testing::QuickOptions;
using trainer_testing::ShortcutOptions;
using trainer_testing::TinyCityTrainerTest;
using trainer_testing::TrainingObservations;

TEST(TrainerOptionsTest, ChecksNameTheField) {
  TrainerOptions options;
  EXPECT_NO_THROW(options.Check());  // no budget: automatic epochs
  options.max_minutes = 1;
  EXPECT_NO_THROW(options.Check());
  options.halving_fractions = {0.5, 1.5};
  EXPECT_THROW(options.Check(), std::invalid_argument);
  options = TrainerOptions();
  options.augmentation.dimension_dropout = 1;
  EXPECT_THROW(options.Check(), std::invalid_argument);
  const auto expect_named = [](const std::function<void(TrainerOptions&)>& change,
                               const std::string& field) {
    TrainerOptions changed;
    change(changed);
    try {
      changed.Check();
      ADD_FAILURE() << field << " passed the check";
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), ::testing::HasSubstr(field));
    }
  };
  expect_named([](TrainerOptions& o) { o.epochs = -1; }, "epochs");
  expect_named([](TrainerOptions& o) { o.warmup_fraction = 1; }, "warmup_fraction");
  expect_named([](TrainerOptions& o) { o.final_rate_fraction = 0; }, "final_rate_fraction");
  expect_named([](TrainerOptions& o) { o.evaluations = -1; }, "evaluations");
  expect_named([](TrainerOptions& o) { o.evaluation_observations = 0; }, "evaluation_observations");
  expect_named([](TrainerOptions& o) { o.network.node_output_dim = -2; }, "node_output_dim");
  // Larger maps get fewer passes, and narrower point rows.
  const NetworkOptions pooled = DefaultNetworkOptions(kMinPointsForNodeOutputRows, 256);
  EXPECT_TRUE(pooled.pooled_point_rows);
  EXPECT_FALSE(pooled.descriptor_shortcut);
  EXPECT_EQ(pooled.channels, NetworkOptions().channels);
  EXPECT_TRUE(pooled.shared_trunk);
  EXPECT_GT(DefaultEpochs(20000, NetworkOptions{}), DefaultEpochs(2000000, NetworkOptions{}));
  EXPECT_LT(DefaultEpochs(600000, pooled), DefaultEpochs(600000, NetworkOptions{}));
  EXPECT_GE(DefaultNetworkOptions(100000, 256).node_output_dim,
            DefaultNetworkOptions(2000000, 256).node_output_dim);
  EXPECT_LT(DefaultNetworkOptions(100000, 256).node_output_dim, 256);
  // Small maps start from their points' mean descriptors: the shortcut at the descriptor's width,
  // on a narrow network.
  for (const int dim : {64, 128, 256}) {
    const NetworkOptions small = DefaultNetworkOptions(kMinPointsForNodeOutputRows - 1, dim);
    EXPECT_TRUE(small.descriptor_shortcut);
    EXPECT_TRUE(small.pooled_point_rows);
    EXPECT_EQ(small.node_output_dim, dim);
    EXPECT_LT(small.channels, NetworkOptions().channels);
    EXPECT_LT(small.trunk_channels, NetworkOptions().trunk_channels);
    EXPECT_FALSE(small.shared_trunk);
    small.Check();
  }
}

// Converged unless the last quarter of the budget gained 5 % or more over every earlier check; a
// start that later checks only fall below is converged, not "still improving".
TEST(TrainerTest, HeldOutSplitIsDeterministicAndNearTheFraction) {
  size_t held_out = 0;
  for (uint64_t i = 0; i < 100000; ++i) {
    const bool first = IsHeldOutObservation(i, 0.05, 3);
    EXPECT_EQ(first, IsHeldOutObservation(i, 0.05, 3));
    held_out += first;
    if (first) {
      EXPECT_TRUE(IsHeldOutObservation(i, 0.1, 3)) << "a larger fraction keeps the smaller";
    }
  }
  EXPECT_NEAR(held_out / 100000.0, 0.05, 0.005);
  EXPECT_FALSE(IsHeldOutObservation(17, 0, 3));
}

// The nearest-class-mean yardstick: the tiny city's points are a prototype each plus noise, so the
// class means of the training observations place most held-out ones; a label path right at a level
// is right at every coarser one; with a point's own observations all evaluated, nothing is left to
// place it, and its observations are never right.
TEST_F(TinyCityTrainerTest, NearestClassMeanPlacesHeldOutObservationsByTheirPointsMeans) {
  const Scene& scene = Map().scene;
  const std::vector<uint32_t> held_out = HeldOutObservations(scene, 0.05, 0);
  const NetworkEvaluation evaluation =
      EvaluateNearestClassMean(scene, Map().tree, Map().visibility, held_out);
  EXPECT_EQ(evaluation.num_observations, held_out.size());
  ASSERT_EQ(evaluation.level_accuracies.size(), static_cast<size_t>(Map().tree.levels()));
  EXPECT_GE(evaluation.leaf_accuracy, 0.9);
  for (size_t level = 1; level < evaluation.level_accuracies.size(); ++level) {
    EXPECT_LE(evaluation.level_accuracies[level], evaluation.level_accuracies[level - 1]);
  }
  EXPECT_EQ(evaluation.level_accuracies.back(), evaluation.leaf_accuracy);

  std::vector<uint32_t> every_observation(scene.NumObservations());
  std::iota(every_observation.begin(), every_observation.end(), 0u);
  const NetworkEvaluation without_means =
      EvaluateNearestClassMean(scene, Map().tree, Map().visibility, every_observation);
  EXPECT_EQ(without_means.leaf_accuracy, 0.0);
  EXPECT_THROW(EvaluateNearestClassMean(scene, Map().tree, Map().visibility,
                                        {static_cast<uint32_t>(scene.NumObservations())}),
               std::invalid_argument);
}

// The descriptor shortcut starts as the nearest-class-mean matcher among the points each image
// sees (the rows at the class means, the projections at zero), checks that before its first step,
// and keeps the best check: it ends no worse than the class means, short of sampling noise.
TEST_F(TinyCityTrainerTest, DescriptorShortcutStartsAsTheClassMeansAndEndsNoWorse) {
  TrainerOptions options = ShortcutOptions(60, Map().scene);
  options.point_prototypes = 1;
  options.evaluations = 3;
  const std::vector<uint32_t> held_out =
      HeldOutObservations(Map().scene, options.holdout_fraction, options.holdout_seed);
  options.evaluation_observations = static_cast<int64_t>(held_out.size());
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  const NetworkEvaluation class_means =
      EvaluateNearestClassMean(Map().scene, Map().tree, Map().visibility, held_out);
  ASSERT_GE(result.held_out_checks.size(), 2u);
  EXPECT_EQ(result.held_out_checks.front().iteration, 0);
  // Ties between two rows may fall either way under another summation order: one observation.
  const double one = 1.0 / static_cast<double>(held_out.size());
  EXPECT_NEAR(result.held_out_checks.front().point_accuracy, class_means.leaf_accuracy, one + 1e-9);
  // Checks after the start keep their schedule (a third and two thirds of the budget, the end).
  EXPECT_EQ(result.held_out_checks.size(), 4u);
  const NetworkEvaluation trained =
      EvaluateNetwork(result.network, Map().scene, Map().tree, held_out, &Map().visibility);
  const double p = class_means.leaf_accuracy;
  const double standard_error = std::sqrt(p * (1 - p) * one);
  EXPECT_GE(trained.leaf_accuracy, p - 2 * standard_error - one);
  EXPECT_TRUE(result.network.options().descriptor_shortcut);
  EXPECT_TRUE(result.network.options().masked_decoding);
}

// The held-out accuracy of what a shortcut network with a row per training view starts as: the
// point, among those the image sees, of the largest mean(exp(s <x, v>)) over its training views v
// (1 for a point without any: a zero row), x the unit descriptor and s the shortcut's starting
// scale. Each level takes the child of the best point, so the levels together take the best.
double SoftVoteOfTrainingViewsAccuracy(const CityMap& map, const std::vector<uint32_t>& training,
                                       const std::vector<uint32_t>& held_out) {
  const Scene& scene = map.scene;
  DescriptorMatrix unit = scene.observation_descriptors;
  NormalizeRows(unit);
  std::vector<std::vector<uint32_t>> views_of_point(scene.NumPoints());
  for (const uint32_t view : training) {
    views_of_point[scene.observation_point_indices[view]].push_back(view);
  }
  size_t right = 0;
  for (const uint32_t observation : held_out) {
    const uint32_t image = scene.observation_image_indices[observation];
    double best = -1;
    uint32_t best_point = 0;
    for (const uint32_t* point = map.visibility.PointsBegin(image);
         point != map.visibility.PointsEnd(image); ++point) {
      double sum = 0;
      for (const uint32_t view : views_of_point[*point]) {
        sum += std::exp(kInitialShortcutScale * unit.row(observation).dot(unit.row(view)));
      }
      const auto views = static_cast<double>(views_of_point[*point].size());
      const double vote = views == 0 ? 1.0 : sum / views;
      if (vote > best) {
        best = vote;
        best_point = *point;
      }
    }
    right += best_point == scene.observation_point_indices[observation];
  }
  return static_cast<double>(right) / static_cast<double>(held_out.size());
}

// With as many rows per point as it has training views, the shortcut starts as a soft vote of
// each point's training views among the points each image sees (SoftVoteOfTrainingViewsAccuracy);
// with fewer, a point's rows are spread over its views.
TEST_F(TinyCityTrainerTest, PointPrototypesStartAsThePointsOwnViews) {
  TrainerOptions options = ShortcutOptions(30, Map().scene);
  options.evaluations = 1;
  const std::vector<uint32_t> held_out =
      HeldOutObservations(Map().scene, options.holdout_fraction, options.holdout_seed);
  const std::vector<uint32_t> training = TrainingObservations(Map().scene, options);
  options.evaluation_observations = static_cast<int64_t>(held_out.size());
  const double one = 1.0 / static_cast<double>(held_out.size());
  const std::vector<int64_t> views_per_point =
      PointRowOffsets(Map().scene, training, Map().tree, 64);
  ASSERT_EQ(views_per_point.size(), Map().tree.NumPoints() + 1);
  EXPECT_GE(views_per_point.back(), static_cast<int64_t>(training.size()));

  options.point_prototypes = 64;
  const TrainingResult every_view = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_EQ(every_view.network.shape().point_row_offsets, views_per_point);
  ASSERT_FALSE(every_view.held_out_checks.empty());
  EXPECT_EQ(every_view.held_out_checks.front().iteration, 0);
  EXPECT_NEAR(every_view.held_out_checks.front().point_accuracy,
              SoftVoteOfTrainingViewsAccuracy(Map(), training, held_out), one + 1e-9);

  // Two rows: each starting row is the mean of a part of its point's views, the parts disjoint
  // and both used, so a point of several views gets two distinct rows.
  const std::vector<int64_t> two_rows = PointRowOffsets(Map().scene, training, Map().tree, 2);
  const PointCandidates candidates(Map().tree, nullptr, {}, &two_rows);
  const std::vector<int64_t> starts = StartingRowOfObservations(Map().scene, training, candidates);
  std::vector<int> views_of_row(two_rows.back(), 0);
  std::vector<int> views_of_point(Map().scene.NumPoints(), 0);
  for (const uint32_t view : training)
    ++views_of_point[Map().scene.observation_point_indices[view]];
  for (size_t i = 0; i < training.size(); ++i) {
    const auto [first, end] =
        candidates.RowsOfPoint(Map().scene.observation_point_indices[training[i]]);
    ASSERT_GE(starts[i], first);
    ASSERT_LT(starts[i], end);
    ++views_of_row[starts[i]];
  }
  EXPECT_EQ(std::count(views_of_row.begin(), views_of_row.end(), 0),
            std::count(views_of_point.begin(), views_of_point.end(), 0))
      << "every row of a point with views starts from at least one";
  // Each bias starts at -log of its point's rows: a point's pooled score is its rows' mean.
  torch::Tensor table = torch::full({two_rows.back(), Map().scene.Dimension() + 1}, 7.0f);
  InitializePointRowsFromDescriptors(Map().scene, training, candidates, true, table);
  for (uint32_t point = 0; point < Map().scene.NumPoints(); ++point) {
    const auto [first, end] = candidates.RowsOfPoint(point);
    for (uint32_t row = first; row < end; ++row) {
      EXPECT_FLOAT_EQ(table[row][Map().scene.Dimension()].item<float>(),
                      -std::log(static_cast<float>(end - first)));
    }
  }
}

TEST_F(TinyCityTrainerTest, ReachesNinetyNinePercentOnItsTrainingObservations) {
  TrainerOptions options = QuickOptions(400);
  options.visibility_softmax = true;
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_EQ(result.iterations, 400);
  EXPECT_EQ(result.num_training_observations + result.num_held_out_observations,
            Map().scene.NumObservations());
  // Trained with the visibility softmax, the network is decoded with the visibility mask.
  const NetworkEvaluation training =
      EvaluateNetwork(result.network, Map().scene, Map().tree,
                      TrainingObservations(Map().scene, options), &Map().visibility);
  const NetworkEvaluation held_out =
      EvaluateNetwork(result.network, Map().scene, Map().tree,
                      HeldOutObservations(Map().scene, options.holdout_fraction, 0));
  std::cout << fmt::format(
      "tiny city, {} iterations in {:.1f} s: training leaf accuracy {:.4f} ({} observations), "
      "held-out {:.4f} ({}), final loss {:.4f}\n",
      result.iterations, result.seconds, training.leaf_accuracy, training.num_observations,
      held_out.leaf_accuracy, held_out.num_observations, result.final_loss);
  EXPECT_GE(training.leaf_accuracy, 0.99);
  EXPECT_GE(training.level_accuracies.front(), training.leaf_accuracy);
  EXPECT_LT(result.final_loss, result.log.front().loss);
  // The one-cycle ends near its final rate.
  EXPECT_NEAR(result.log.back().learning_rate, options.learning_rate * options.final_rate_fraction,
              0.01 * options.learning_rate);
}

TEST_F(TinyCityTrainerTest, DefaultsAndThePapersConfigurationDecodePlainly) {
  for (const bool paper : {false, true}) {
    TrainerOptions options = QuickOptions(400);
    if (paper) {
      options.network.node_conditioning = false;
      options.network.node_output_dim = 0;
      options.schedule = LearningRateSchedule::kHalving;
    }
    const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
    const NetworkEvaluation training = EvaluateNetwork(result.network, Map().scene, Map().tree,
                                                       TrainingObservations(Map().scene, options));
    std::cout << fmt::format("tiny city, {}: plain decoding, training leaf accuracy {:.4f}\n",
                             paper ? "the paper's configuration" : "defaults",
                             training.leaf_accuracy);
    EXPECT_GE(training.leaf_accuracy, 0.99) << (paper ? "paper" : "defaults");
  }
}

TEST_F(TinyCityTrainerTest, VisibilitySoftmaxRangesOverTheImagesChildrenOnly) {
  // One step each, same weights and batch: the masked softmax has fewer classes, so its first loss
  // is lower; with the mask broken (all children, or the true child masked) it would not be.
  TrainerOptions options = QuickOptions(1);
  options.log_every_iterations = 1;
  options.evaluations = 0;
  options.visibility_softmax = false;
  const TrainingResult full = TrainNetwork(Map().scene, Map().tree, options);
  options.visibility_softmax = true;
  const TrainingResult masked = TrainNetwork(Map().scene, Map().tree, options);
  ASSERT_EQ(full.log.size(), 1u);
  ASSERT_EQ(masked.log.size(), 1u);
  EXPECT_TRUE(std::isfinite(masked.log[0].loss));
  EXPECT_LT(masked.log[0].loss, full.log[0].loss - 0.5);
  // A sample without an image (image dropout) is not masked: the loss stays finite.
  options.image_dropout = 1;
  const TrainingResult no_image = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_NEAR(no_image.log[0].loss, full.log[0].loss, 0.5);
}

TEST_F(TinyCityTrainerTest, PooledPointRowsLearnAndAreDecodedWithTheMask) {
  TrainerOptions options = QuickOptions(400);
  options.network.node_output_dim = 32;
  options.network.pooled_point_rows = true;
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_TRUE(result.network.options().masked_decoding);
  const NetworkEvaluation training =
      EvaluateNetwork(result.network, Map().scene, Map().tree,
                      TrainingObservations(Map().scene, options), &Map().visibility);
  std::cout << fmt::format("tiny city, pooled point rows: masked training leaf accuracy {:.4f}\n",
                           training.leaf_accuracy);
  EXPECT_GE(training.leaf_accuracy, 0.99);
  // The visibility softmax alone also asks for masked decoding; the defaults do not.
  options.network.pooled_point_rows = false;
  options.max_iterations = 1;
  EXPECT_FALSE(TrainNetwork(Map().scene, Map().tree, options).network.options().masked_decoding);
  options.visibility_softmax = true;
  EXPECT_TRUE(TrainNetwork(Map().scene, Map().tree, options).network.options().masked_decoding);
}

// Every level's loss trains the one trunk they share, as far as a trunk per level gets.
TEST_F(TinyCityTrainerTest, SharedTrunkLearnsFromEveryLevel) {
  TrainerOptions options = QuickOptions(400);
  options.network.node_output_dim = 32;
  options.network.pooled_point_rows = true;
  options.network.shared_trunk = true;
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_TRUE(result.network.options().shared_trunk);
  const NetworkEvaluation training =
      EvaluateNetwork(result.network, Map().scene, Map().tree,
                      TrainingObservations(Map().scene, options), &Map().visibility);
  std::cout << fmt::format("tiny city, shared trunk: masked training leaf accuracy {:.4f}\n",
                           training.leaf_accuracy);
  EXPECT_GE(training.leaf_accuracy, 0.99);
}

TEST_F(TinyCityTrainerTest, EpochBudgetCountsPassesOverTheTrainingObservations) {
  TrainerOptions options = QuickOptions(0);
  options.epochs = 2;
  options.evaluations = 0;
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  const int64_t expected =
      (2 * static_cast<int64_t>(result.num_training_observations) + options.batch_size - 1) /
      options.batch_size;
  EXPECT_EQ(result.iterations, expected);
}

TEST_F(TinyCityTrainerTest, SameSeedGivesIdenticalWeights) {
  const TrainerOptions options = QuickOptions(30);
  const TrainingResult first = TrainNetwork(Map().scene, Map().tree, options);
  const TrainingResult second = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_TRUE(first.network.HasSameWeights(second.network));
  ASSERT_EQ(first.log.size(), second.log.size());
  for (size_t i = 0; i < first.log.size(); ++i) {
    EXPECT_EQ(first.log[i].loss, second.log[i].loss);
    EXPECT_EQ(first.log[i].level_accuracies, second.log[i].level_accuracies);
  }
  TrainerOptions other_seed = options;
  other_seed.seed = 1;
  const TrainingResult third = TrainNetwork(Map().scene, Map().tree, other_seed);
  EXPECT_FALSE(first.network.HasSameWeights(third.network));
}

TEST_F(TinyCityTrainerTest, ResumedTrainingContinuesExactly) {
  TrainerOptions options = QuickOptions(40);
  // The schedule and the held-out checks follow the budget, which differs below.
  options.schedule = LearningRateSchedule::kHalving;
  options.halving_fractions = {};
  options.evaluations = 0;
  options.image_dropout = 0.1;
  const TrainingResult uninterrupted = TrainNetwork(Map().scene, Map().tree, options);

  options.checkpoint_path = temp_dir_ / "checkpoint.pt";
  options.checkpoint_every_iterations = 7;
  options.max_iterations = 25;
  TrainNetwork(Map().scene, Map().tree, options);
  ASSERT_TRUE(fs::exists(options.checkpoint_path));
  options.max_iterations = 40;
  options.resume = true;
  const TrainingResult resumed = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_EQ(resumed.iterations, 40);
  EXPECT_TRUE(resumed.network.HasSameWeights(uninterrupted.network));
  ASSERT_FALSE(resumed.log.empty());
  EXPECT_EQ(resumed.log.back().iteration, 40);
  EXPECT_EQ(resumed.log.front().iteration, 10);

  std::ofstream(options.checkpoint_path) << "corrupt";
  EXPECT_THROW(TrainNetwork(Map().scene, Map().tree, options), std::invalid_argument);
}

TEST_F(TinyCityTrainerTest, WritesTheNetworkIntoTheBundle) {
  const fs::path bundle_dir = temp_dir_ / "bundle";
  MapBundleWriter writer(bundle_dir);
  writer.AddBlob("scene.bin",
                 [&](std::ostream& stream) { WriteSceneGeometry(stream, Map().scene); });
  writer.metadata()["descriptor_dim"] = Map().scene.Dimension();
  writer.Commit();

  const TrainerOptions options = QuickOptions(20);
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  const NetworkEvaluation held_out =
      EvaluateNetwork(result.network, Map().scene, Map().tree,
                      HeldOutObservations(Map().scene, options.holdout_fraction, 0));
  WriteNetworkToBundle(bundle_dir, result, options, {{"held_out", held_out}});

  const MapBundle bundle = MapBundle::Open(bundle_dir);
  EXPECT_TRUE(bundle.HasBlob("scene.bin"));
  EXPECT_EQ(bundle.metadata()["descriptor_dim"], Map().scene.Dimension());
  const nlohmann::json& metadata = bundle.metadata()["network"];
  EXPECT_EQ(metadata["training"]["iterations"], 20);
  EXPECT_EQ(metadata["options"]["channels"], 128);
  EXPECT_EQ(metadata["evaluations"]["held_out"]["observations"], held_out.num_observations);
  // The held-out curve, check by check.
  const nlohmann::json& checks = metadata["training"]["held_out_checks"];
  ASSERT_EQ(checks.size(), result.held_out_checks.size());
  ASSERT_FALSE(checks.empty());
  EXPECT_EQ(checks.back()["iteration"], result.held_out_checks.back().iteration);
  EXPECT_EQ(checks.back()["point_accuracy"], result.held_out_checks.back().point_accuracy);
  EXPECT_EQ(checks.back()["seconds"], result.held_out_checks.back().seconds);
  EXPECT_THAT(bundle.Blob(map_blobs::kTrainingLog),
              ::testing::StartsWith("iteration,seconds,learning_rate,loss,accuracy_level1"));

  const Network loaded = Network::FromBundle(bundle);
  const Network expected_network = testing_support::AsStoredInABundle(result.network);
  EXPECT_TRUE(loaded.HasSameWeights(expected_network));
  DescriptorMatrix descriptors = Map().scene.observation_descriptors.topRows(50);
  const PointPredictions expected = expected_network.Predict(descriptors, {0, 5}, Map().tree);
  const PointPredictions actual = loaded.Predict(descriptors, {0, 5}, Map().tree);
  EXPECT_EQ(actual.point_indices, expected.point_indices);
  EXPECT_EQ(actual.confidences, expected.confidences);
}

}  // namespace
}  // namespace hscloc
