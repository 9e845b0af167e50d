#include "model/trainer.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <iostream>
#include <memory>

#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "map/map_bundle.h"
#include "scene/scene_io.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// A synthetic city on disk and the map parts the trainer needs, built as `hscloc build-map` does.
struct CityMap {
  std::unique_ptr<SyntheticCity> city;
  fs::path dir;
  Scene scene;
  LabelTree tree;
  Visibility visibility;
};

std::unique_ptr<CityMap> MakeCityMap(const std::string& preset, const fs::path& dir) {
  auto map = std::make_unique<CityMap>();
  map->city = std::make_unique<SyntheticCity>(SyntheticCityOptions::Preset(preset));
  map->dir = dir;
  SyntheticCityWriteOptions write_options;
  write_options.show_progress = false;
  WriteSyntheticCity(*map->city, dir, write_options);
  const Reconstruction reconstruction = ReadColmapModel(dir / "map");
  const auto features = OpenH5Features(dir / "features.h5");
  map->scene =
      Scene::FromReconstruction(reconstruction, JoinObservations(reconstruction, *features));
  LabelTreeOptions tree_options;
  tree_options.show_progress = false;
  map->tree = LabelTree::Build(map->scene.points, tree_options);
  map->visibility = Visibility::FromObservations(map->scene.NumImages(), map->scene.NumPoints(),
                                                 map->scene.observation_image_indices,
                                                 map->scene.observation_point_indices);
  return map;
}

TrainerOptions QuickOptions(int64_t iterations) {
  TrainerOptions options;
  options.network.channels = 128;
  options.network.embedding_dim = 64;
  options.max_iterations = iterations;
  options.batch_size = 256;
  options.image_dropout = 0;
  options.show_progress = false;
  options.log_every_iterations = 10;
  return options;
}

std::vector<uint32_t> TrainingObservations(const Scene& scene, const TrainerOptions& options) {
  std::vector<uint32_t> training;
  for (uint32_t i = 0; i < scene.NumObservations(); ++i) {
    if (!IsHeldOutObservation(i, options.holdout_fraction, options.holdout_seed)) {
      training.push_back(i);
    }
  }
  return training;
}

class TinyCityTrainerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    temp_ = new testing::TempDir();
    map_ = MakeCityMap("tiny", temp_->path() / "tiny").release();
  }
  static void TearDownTestSuite() {
    delete map_;
    delete temp_;
  }
  static const CityMap& Map() { return *map_; }

  testing::TempDir temp_dir_;

 private:
  static testing::TempDir* temp_;
  static CityMap* map_;
};
testing::TempDir* TinyCityTrainerTest::temp_ = nullptr;
CityMap* TinyCityTrainerTest::map_ = nullptr;

TEST(TrainerOptionsTest, ChecksNameTheField) {
  TrainerOptions options;
  EXPECT_NO_THROW(options.Check());
  options.max_iterations = 0;
  EXPECT_THROW(options.Check(), std::invalid_argument);
  options.max_minutes = 1;
  EXPECT_NO_THROW(options.Check());
  options.halving_fractions = {0.5, 1.5};
  EXPECT_THROW(options.Check(), std::invalid_argument);
  options = TrainerOptions();
  options.augmentation.dimension_dropout = 1;
  EXPECT_THROW(options.Check(), std::invalid_argument);
}

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

TEST_F(TinyCityTrainerTest, ReachesNinetyNinePercentOnItsTrainingObservations) {
  TrainerOptions options = QuickOptions(400);
  const TrainingResult result = TrainNetwork(Map().scene, Map().tree, options);
  EXPECT_EQ(result.iterations, 400);
  EXPECT_EQ(result.num_training_observations + result.num_held_out_observations,
            Map().scene.NumObservations());
  const NetworkEvaluation training = EvaluateNetwork(result.network, Map().scene, Map().tree,
                                                     TrainingObservations(Map().scene, options));
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
  EXPECT_DOUBLE_EQ(result.log.back().learning_rate, options.learning_rate / 8);
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
  options.halving_fractions = {};  // the schedule follows the budget, which differs below
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
  EXPECT_THAT(bundle.Blob(map_blobs::kTrainingLog),
              ::testing::StartsWith("iteration,seconds,learning_rate,loss,accuracy_level1"));

  const Network loaded = Network::FromBundle(bundle);
  EXPECT_TRUE(loaded.HasSameWeights(result.network));
  DescriptorMatrix descriptors = Map().scene.observation_descriptors.topRows(50);
  const PointPredictions expected = result.network.Predict(descriptors, {0, 5}, Map().tree);
  const PointPredictions actual = loaded.Predict(descriptors, {0, 5}, Map().tree);
  EXPECT_EQ(actual.point_indices, expected.point_indices);
  EXPECT_EQ(actual.confidences, expected.confidences);
}

}  // namespace
}  // namespace hscloc
