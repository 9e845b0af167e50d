// Retrieval at Aachen's shape: VLAD encoding of a query's local descriptors (D = 256, 64 words,
// whitened to the maps' 2,048 dimensions, which takes 2,049 images or more) and the search of the
// top 10 among 4,000 database images (flat and IVF-PQ), and the two together.
#include <benchmark/benchmark.h>

#include <vector>

#include "retrieval/global_index.h"
#include "retrieval/vlad.h"
#include "util/random.h"

namespace hscloc {
namespace {

constexpr int kDescriptorDim = 256;
constexpr int kDatabaseImages = 4000;

DescriptorMatrix RandomUnitRows(int64_t rows, Random& random) {
  DescriptorMatrix matrix(rows, kDescriptorDim);
  for (int64_t i = 0; i < matrix.size(); ++i) matrix.data()[i] = float(random.Normal());
  matrix.rowwise().normalize();
  return matrix;
}

struct RetrievalSetup {
  VladEncoder encoder;
  GlobalIndex flat;
  GlobalIndex ivfpq;

  RetrievalSetup() {
    Random random(1);
    std::vector<DescriptorMatrix> training;
    VladOptions options;
    options.kmeans_iterations = 10;
    for (int image = 0; image <= options.whitened_dim; ++image) {
      training.push_back(RandomUnitRows(64, random));
    }
    encoder = VladEncoder::Train(training, options);
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> database(
        kDatabaseImages, encoder.output_dim());
    for (int64_t i = 0; i < database.size(); ++i) database.data()[i] = float(random.Normal());
    database.rowwise().normalize();
    flat = GlobalIndex::Build(database);
    GlobalIndexOptions ivfpq_options;
    ivfpq_options.type = GlobalIndexOptions::Type::kIvfPq;
    ivfpq = GlobalIndex::Build(database, ivfpq_options);
  }
};

const RetrievalSetup& Setup() {
  static const auto* setup = new RetrievalSetup();
  return *setup;
}

void BM_VladEncode(benchmark::State& state) {
  const RetrievalSetup& setup = Setup();
  Random random(2);
  const DescriptorMatrix query = RandomUnitRows(state.range(0), random);
  for (auto _ : state) benchmark::DoNotOptimize(setup.encoder.Encode(query));
}
BENCHMARK(BM_VladEncode)
    ->ArgName("keypoints")
    ->Arg(1000)
    ->Arg(2000)
    ->Arg(4000)
    ->Unit(benchmark::kMillisecond);

void BM_IndexSearch(benchmark::State& state) {
  const RetrievalSetup& setup = Setup();
  const GlobalIndex& index = state.range(0) == 0 ? setup.flat : setup.ivfpq;
  Random random(3);
  Eigen::VectorXf query(index.dimension());
  for (int i = 0; i < query.size(); ++i) query[i] = float(random.Normal());
  query.normalize();
  for (auto _ : state) benchmark::DoNotOptimize(index.Search(query, 10));
}
BENCHMARK(BM_IndexSearch)->ArgName("ivfpq")->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

void BM_VladAndSearch(benchmark::State& state) {
  const RetrievalSetup& setup = Setup();
  Random random(4);
  const DescriptorMatrix query = RandomUnitRows(2000, random);
  for (auto _ : state) benchmark::DoNotOptimize(setup.flat.Search(setup.encoder.Encode(query), 10));
}
BENCHMARK(BM_VladAndSearch)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace hscloc
