// The trainer tests' synthetic maps and options, shared by trainer_test.cc and
// trainer_early_stopping_test.cc: one fixture class for the suite whichever file a test is in.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"
#include "model/trainer.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "scene/scene.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc::trainer_testing {

namespace fs = std::filesystem;

// A synthetic city on disk and the map parts the trainer needs, built as `hscloc build-map` does.
struct CityMap {
  std::unique_ptr<SyntheticCity> city;
  fs::path dir;
  Scene scene;
  LabelTree tree;
  Visibility visibility;
};

inline std::unique_ptr<CityMap> MakeCityMap(const std::string& preset, const fs::path& dir) {
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

inline TrainerOptions QuickOptions(int64_t iterations) {
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

// The small maps' network: pooled point rows at the descriptor's width with the shortcut.
inline TrainerOptions ShortcutOptions(int64_t iterations, const Scene& scene) {
  TrainerOptions options = QuickOptions(iterations);
  options.network.node_conditioning = false;
  options.network.node_output_dim = static_cast<int>(scene.Dimension());
  options.network.pooled_point_rows = true;
  options.network.descriptor_shortcut = true;
  return options;
}

inline std::vector<uint32_t> TrainingObservations(const Scene& scene,
                                                  const TrainerOptions& options) {
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
  static inline testing::TempDir* temp_ = nullptr;
  static inline CityMap* map_ = nullptr;
};

}  // namespace hscloc::trainer_testing
