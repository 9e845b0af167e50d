// The hierarchical classification network at Aachen's shape: D = 256 descriptors, a label tree of
// 4 levels with branching 100, 4,000 database images, default widths. Reports the query path
// (N = 2000 keypoints, K = 10 retrieved images; plain and visibility-masked decoding) beside the
// FLOPs of that forward pass, the training throughput, and the fp32 matrix-product rate that
// libtorch reaches on this machine (torch::mm of 2048 x 2048), so the network's rate can be read
// as a fraction of the machine's.
#include <benchmark/benchmark.h>
#include <torch/torch.h>

#include <memory>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"
#include "model/network.h"
#include "model/trainer.h"
#include "scene/scene.h"
#include "util/random.h"

namespace hscloc {
namespace {

constexpr int kDescriptorDim = 256;
constexpr int kNumImages = 4000;
constexpr int kNumPoints = 60000;
constexpr int kPointsPerImage = 2000;
constexpr int64_t kQueryKeypoints = 2000;
constexpr int kRetrievedImages = 10;

DescriptorMatrix RandomUnitRows(int64_t rows, uint64_t seed) {
  Random random(seed);
  DescriptorMatrix matrix(rows, kDescriptorDim);
  for (int64_t i = 0; i < matrix.size(); ++i) matrix.data()[i] = float(random.Normal());
  matrix.rowwise().normalize();
  return matrix;
}

// A random map of the benchmark's shape; the label tree is real (hierarchical k-means).
struct BenchmarkMap {
  Scene scene;
  LabelTree tree;
  Visibility visibility;

  BenchmarkMap() {
    SetComputeThreads(0);
    Random random(1);
    scene.images.resize(kNumImages);
    for (int image = 0; image < kNumImages; ++image) scene.images[image].image_id = image + 1;
    for (int point = 0; point < kNumPoints; ++point) {
      scene.point3D_ids.push_back(point + 1);
      scene.points.emplace_back(random.Uniform(0, 500), random.Uniform(0, 500),
                                random.Uniform(0, 20));
    }
    scene.RebuildIndex();
    std::vector<uint32_t> image_of_entry;
    std::vector<uint32_t> point_of_entry;
    for (uint32_t image = 0; image < kNumImages; ++image) {
      const uint32_t first = static_cast<uint32_t>(random.UniformInt(kNumPoints - kPointsPerImage));
      for (uint32_t i = 0; i < kPointsPerImage; ++i) {
        image_of_entry.push_back(image);
        point_of_entry.push_back(first + i);
      }
    }
    visibility =
        Visibility::FromObservations(kNumImages, kNumPoints, image_of_entry, point_of_entry);
    // Training samples: a share of the visibility entries, as observations.
    for (size_t entry = 0; entry < image_of_entry.size(); entry += 40) {
      scene.observation_image_indices.push_back(image_of_entry[entry]);
      scene.observation_point_indices.push_back(point_of_entry[entry]);
    }
    scene.observation_descriptors =
        RandomUnitRows(static_cast<int64_t>(scene.observation_image_indices.size()), 2);
    LabelTreeOptions tree_options;
    tree_options.show_progress = false;
    tree = LabelTree::Build(scene.points, tree_options);
  }

  NetworkShape Shape() const { return NetworkShape::ForTree(kDescriptorDim, tree, kNumImages); }
};

const BenchmarkMap& Map() {
  static const auto* map = new BenchmarkMap();
  return *map;
}

void BM_Predict(benchmark::State& state) {
  const bool masked = state.range(0) != 0;
  const BenchmarkMap& map = Map();
  const Network network(map.Shape(), NetworkOptions(), 3);
  const DescriptorMatrix descriptors = RandomUnitRows(kQueryKeypoints, 4);
  std::vector<uint32_t> images;
  for (int k = 0; k < kRetrievedImages; ++k) images.push_back(static_cast<uint32_t>(k * 397));
  std::vector<double> level_ms(network.shape().levels, 0.0);
  for (auto _ : state) {
    const PointPredictions predictions =
        network.Predict(descriptors, images, map.tree, masked ? &map.visibility : nullptr);
    for (size_t level = 0; level < level_ms.size(); ++level) {
      level_ms[level] += predictions.level_milliseconds[level];
    }
  }
  // Forward time per level: the coarse levels condition on few distinct (image, prefix) keys, the
  // fine ones on nearly one per row.
  for (size_t level = 0; level < level_ms.size(); ++level) {
    state.counters["level" + std::to_string(level) + "_ms"] =
        level_ms[level] / double(state.iterations());
  }
  const double flops = network.PredictFlops(kQueryKeypoints, kRetrievedImages, map.tree);
  state.counters["GFLOP_per_query"] = flops / 1e9;
  state.counters["GFLOPS"] =
      benchmark::Counter(flops / 1e9 * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["parameters"] = double(network.NumParameters());
}
BENCHMARK(BM_Predict)
    ->ArgName("masked")
    ->Arg(0)
    ->Arg(1)
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

void BM_Train(benchmark::State& state) {
  const BenchmarkMap& map = Map();
  TrainerOptions options;
  options.batch_size = static_cast<int>(state.range(0));
  options.max_iterations = 20;
  options.holdout_fraction = 0;
  options.show_progress = false;
  options.log_every_iterations = 1000;
  int64_t observations = 0;
  for (auto _ : state) {
    const TrainingResult result = TrainNetwork(map.scene, map.tree, options);
    observations += result.iterations * options.batch_size;
  }
  state.counters["observations_per_s"] =
      benchmark::Counter(double(observations), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_Train)->ArgName("batch")->Arg(256)->Arg(1024)->UseRealTime()->Unit(benchmark::kSecond);

void BM_MatmulPeak(benchmark::State& state) {
  SetComputeThreads(0);
  const int64_t size = state.range(0);
  torch::manual_seed(0);
  const torch::Tensor a = torch::randn({size, size});
  const torch::Tensor b = torch::randn({size, size});
  torch::Tensor c = torch::empty({size, size});
  for (auto _ : state) torch::mm_out(c, a, b);
  state.counters["GFLOPS"] = benchmark::Counter(
      2.0 * size * size * size / 1e9 * double(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_MatmulPeak)->ArgName("size")->Arg(2048)->UseRealTime()->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace hscloc
