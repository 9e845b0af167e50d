// Early stopping: the best held-out network kept, patience, and the convergence verdict.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "model/network.h"
#include "model/trainer.h"
#include "model/trainer_test_support.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using trainer_testing::QuickOptions;
using trainer_testing::ShortcutOptions;
using trainer_testing::TinyCityTrainerTest;

TEST(TrainerTest, ConvergenceLooksAtWhatTheLastQuarterGained) {
  EXPECT_FALSE(HeldOutConverged({0.5, 0.6, 0.8}, {0.1, 0.5, 0.9}));
  EXPECT_TRUE(HeldOutConverged({0.5, 0.79, 0.8}, {0.1, 0.5, 0.9}));
  EXPECT_TRUE(HeldOutConverged({0.98, 0.90, 0.91}, {0.0, 0.5, 0.9}));
  EXPECT_TRUE(HeldOutConverged({0.5, 0.8}, {0.1, 0.75}));  // nothing in the last quarter
  EXPECT_FALSE(HeldOutConverged({0.5, 0.8}, {0.1, 0.76}));
  EXPECT_FALSE(HeldOutConverged({0.8}, {1.0}));
}

// The last network comes back unless its check is measurably below the best (two standard errors:
// 4.6 points at 80 % on 301 observations), or the best is the untrained start and no later check
// reached it.
TEST(TrainerTest, TheBestNetworkComesBackOnlyForAMeasurableDropOrAnUnreachedStart) {
  const auto checks = [](std::vector<double> accuracies) {
    std::vector<HeldOutCheck> result;
    for (size_t i = 0; i < accuracies.size(); ++i) {
      result.push_back({static_cast<int64_t>(10 * i), 0.0, accuracies[i]});
    }
    return result;
  };
  EXPECT_TRUE(MeasurablyBelow(0.72, 0.80, 301));
  EXPECT_FALSE(MeasurablyBelow(0.76, 0.80, 301));
  EXPECT_TRUE(MeasurablyBelow(0.76, 0.80, 3000));
  // A trained best, the last within noise of it: the last stays.
  EXPECT_FALSE(ReturnsBestNetwork(checks({0.70, 0.80, 0.76}), 301));
  // ... or measurably below it: the best comes back.
  EXPECT_TRUE(ReturnsBestNetwork(checks({0.70, 0.80, 0.72}), 301));
  // The start unreached, however close the last came: the start comes back.
  EXPECT_TRUE(ReturnsBestNetwork(checks({0.80, 0.77, 0.72, 0.79}), 301));
  // The start reached again later: the last stays.
  EXPECT_FALSE(ReturnsBestNetwork(checks({0.80, 0.77, 0.80, 0.79}), 301));
  EXPECT_FALSE(ReturnsBestNetwork(checks({0.80}), 301));
  EXPECT_FALSE(ReturnsBestNetwork({}, 301));
}

TEST_F(TinyCityTrainerTest, KeepsTheBestNetworkOnTheHeldOutObservations) {
  // A rate too high for a constant schedule makes the held-out accuracy rise, then fall (0.23 at
  // iteration 40, 0.13 at 60, far more than two standard errors): the returned network is the
  // best checked one, and it scores what that check scored.
  TrainerOptions options = QuickOptions(60);
  options.learning_rate = 0.03;
  options.schedule = LearningRateSchedule::kHalving;
  options.halving_fractions = {};
  options.evaluations = 6;
  options.evaluation_observations = 1 << 20;  // every held-out observation
  options.snapshot_dir = temp_dir_ / "snapshots";
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  ASSERT_EQ(result.held_out_checks.size(), 6u);
  double best = 0;
  int64_t best_iteration = 0;
  for (const HeldOutCheck& check : result.held_out_checks) {
    if (check.point_accuracy > best) {
      best = check.point_accuracy;
      best_iteration = check.iteration;
    }
  }
  EXPECT_EQ(result.best_held_out_accuracy, best);
  EXPECT_EQ(result.best_iteration, best_iteration);
  const NetworkEvaluation evaluation = EvaluateNetwork(
      result.network, Map().scene, Map().tree,
      HeldOutObservations(Map().scene, options.holdout_fraction, 0), &Map().visibility);
  EXPECT_DOUBLE_EQ(evaluation.leaf_accuracy, best);

  // Each check left the network as it stood then (not the best one), in the bundle's format
  // (matrices as 8-bit rows, so within a few observations of the check).
  size_t snapshots = 0;
  for (const auto& entry : fs::directory_iterator(options.snapshot_dir)) {
    snapshots += entry.path().extension() == ".pt";
  }
  EXPECT_EQ(snapshots, result.held_out_checks.size());
  for (const HeldOutCheck& check : {result.held_out_checks.back(), result.held_out_checks[1]}) {
    std::ifstream stream(options.snapshot_dir / SnapshotFileName(check.iteration),
                         std::ios::binary);
    const Network snapshot = Network::Load(stream, "snapshot");
    EXPECT_NEAR(EvaluateNetwork(snapshot, Map().scene, Map().tree,
                                HeldOutObservations(Map().scene, options.holdout_fraction, 0),
                                &Map().visibility)
                    .leaf_accuracy,
                check.point_accuracy, 0.01)
        << "iteration " << check.iteration;
  }
  // Without keep_best the last network comes back.
  options.keep_best = false;
  const TrainingResult last = TrainNetwork(Map().scene, Map().tree, options);
  const NetworkEvaluation last_evaluation = EvaluateNetwork(
      last.network, Map().scene, Map().tree,
      HeldOutObservations(Map().scene, options.holdout_fraction, 0), &Map().visibility);
  EXPECT_DOUBLE_EQ(last_evaluation.leaf_accuracy, last.held_out_checks.back().point_accuracy);
}

// A rate that wrecks the class means the shortcut starts as: every check after the start falls
// far below it, so training ends once the start is a quarter of the budget behind, with the
// start's network; without patience the whole budget is spent.
TEST_F(TinyCityTrainerTest, EndsOnceTheBestCheckIsThePatienceBehind) {
  TrainerOptions options = ShortcutOptions(120, Map().scene);
  options.learning_rate = 0.3;
  options.schedule = LearningRateSchedule::kHalving;
  options.halving_fractions = {};
  options.evaluations = 12;
  options.evaluation_observations = 1 << 20;  // every held-out observation
  ASSERT_DOUBLE_EQ(options.patience, 0.25);
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_TRUE(result.stopped_early);
  EXPECT_EQ(result.best_iteration, 0);
  // Checks every 10 iterations: the first at or past 30 ends it.
  EXPECT_EQ(result.iterations, 30);
  ASSERT_EQ(result.held_out_checks.size(), 4u);
  const NetworkEvaluation evaluation = EvaluateNetwork(
      result.network, Map().scene, Map().tree,
      HeldOutObservations(Map().scene, options.holdout_fraction, 0), &Map().visibility);
  EXPECT_DOUBLE_EQ(evaluation.leaf_accuracy, result.held_out_checks.front().point_accuracy);

  options.patience = 0;
  const TrainingResult whole = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_FALSE(whole.stopped_early);
  EXPECT_EQ(whole.iterations, 120);
  EXPECT_EQ(whole.best_iteration, 0);
}

// A check within two standard errors of the best is no reason to stop: sampling noise.
TEST_F(TinyCityTrainerTest, PatienceWaitsOutChecksWithinNoiseOfTheBest) {
  TrainerOptions options = ShortcutOptions(60, Map().scene);
  options.learning_rate = 1e-6;  // the network stays the class means
  options.evaluations = 6;
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_FALSE(result.stopped_early);
  EXPECT_EQ(result.iterations, 60);
}

}  // namespace
}  // namespace hscloc
