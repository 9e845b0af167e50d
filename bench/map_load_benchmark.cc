// Loading a trained map bundle: reading and verifying every blob (SHA-256) and deserializing the
// scene, label tree, visibility, retrieval index and network, with and without the observations'
// descriptors (the nearest-neighbour matcher's). The bundle comes from the environment variable
// HSCLOC_BENCH_MAP, else the test suite's trained small city.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>

#include "localization/localization_map.h"

namespace hscloc {
namespace {

std::filesystem::path BundleDir() {
  const char* dir = std::getenv("HSCLOC_BENCH_MAP");
  return dir != nullptr ? dir : HSCLOC_DEFAULT_BENCH_MAP;
}

void BM_LoadMap(benchmark::State& state) {
  const std::filesystem::path dir = BundleDir();
  if (!std::filesystem::exists(dir / "manifest.json")) {
    state.SkipWithError(("no map bundle at " + dir.string() +
                         " (set HSCLOC_BENCH_MAP or run the test suite's fixture)")
                            .c_str());
    return;
  }
  const bool observations = state.range(0) != 0;
  uint64_t bytes = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.is_regular_file() &&
        (observations || entry.path().filename() != map_blobs::kObservations)) {
      bytes += entry.file_size();
    }
  }
  // Warm-up: the first load also pays libtorch's one-time initialization and a cold page cache.
  LocalizationMap::Load(dir, {.load_observations = observations});
  for (auto _ : state) {
    benchmark::DoNotOptimize(LocalizationMap::Load(dir, {.load_observations = observations}));
  }
  state.SetBytesProcessed(static_cast<int64_t>(bytes) * state.iterations());
}
BENCHMARK(BM_LoadMap)
    ->ArgName("observations")
    ->Arg(0)
    ->Arg(1)
    ->MinTime(2)
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace hscloc
