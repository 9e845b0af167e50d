#include "bench/measurements.h"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <nlohmann/json.hpp>
#include <numeric>
#include <thread>

#include "bench/bench_support.h"
#include "bench/query_evaluation.h"
#include "client/localization_client.h"
#include "model/dense_kernels.h"
#include "model/network.h"
#include "server/localization_service.h"
#include "server/wire.h"
#include "util/parallel.h"
#include "util/statistics.h"
#include "util/timer.h"

namespace hscloc::bench {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr int64_t kPeakProductSize = 2048;

// hscloc's kernels are single-threaded; Predict splits rows over the threads, and so does this,
// with the packed product the network runs (the weight packed once, as the network's are).
class PackedProductPeak {
 public:
  PackedProductPeak()
      : in_(kPeakProductSize * kPeakProductSize, 0.5f),
        weight_(kPeakProductSize * kPeakProductSize, 0.25f),
        bias_(kPeakProductSize, 0),
        out_(kPeakProductSize * kPeakProductSize),
        packed_(dense_kernels::PackMatrix(weight_.data(), kPeakProductSize, kPeakProductSize)) {}

  // All cores, over at least `seconds` after one product to warm up.
  double Gflops(double seconds) {
    const int64_t size = kPeakProductSize;
    const double flops = 2.0 * size * size * size;
    Multiply();
    Timer timer;
    int runs = 0;
    do {
      Multiply();
      ++runs;
    } while (timer.ElapsedSeconds() < seconds);
    return flops * runs / timer.ElapsedSeconds() / 1e9;
  }

 private:
  void Multiply() {
    const int64_t size = kPeakProductSize;
    ParallelFor(size / kBlock, 0, [&](size_t first, size_t last) {
      for (size_t i = first; i < last; ++i) {
        dense_kernels::Linear(in_.data() + i * kBlock * size, kBlock, packed_, bias_.data(), false,
                              out_.data() + i * kBlock * size);
      }
    });
  }

  static constexpr int64_t kBlock = 256;
  std::vector<float> in_, weight_, bias_, out_;
  dense_kernels::PackedMatrix packed_;
};

}  // namespace

json MeasureGemmPeaks() {
  SetComputeThreads(0);
  const double torch_gflops = LibtorchMatrixProductGflops(kPeakProductSize, 1.5);
  const double kernel_gflops = PackedProductPeak().Gflops(1.5);
  // The arithmetic peak of the same threads: fused multiply-adds on registers alone.
  const int64_t iterations = int64_t{1} << 27;
  const int threads = ResolveNumThreads(0);
  std::vector<float> sinks(threads, 0.0f);
  Timer fma_timer;
  ParallelFor(threads, 0, [&](size_t first, size_t last) {
    for (size_t i = first; i < last; ++i) {
      dense_kernels::FusedMultiplyAddPeakLoop(iterations, &sinks[i]);
    }
  });
  const double fma_gflops = 2.0 * dense_kernels::PacketLanes() * dense_kernels::kPeakLoopChains *
                            static_cast<double>(iterations) * threads / fma_timer.ElapsedSeconds() /
                            1e9;
  return {{"threads", ResolveNumThreads(0)},
          {"libtorch_gflops", torch_gflops},
          {"kernels_gflops", kernel_gflops},
          {"fma_peak_gflops", fma_gflops},
          {"peak_gflops", std::max(torch_gflops, kernel_gflops)},
          {"kernel_instruction_sets", dense_kernels::KernelInstructionSets()}};
}

// Rounds of (peak, Predict) in NetworkAgainstFloor.
constexpr int kFloorRounds = 7;

json NetworkAgainstFloor(const Localizer& localizer, const LocalizationQuery& query,
                         const json& peaks) {
  const Network& network = *localizer.network();
  const LocalizationQuery padded = WithKeypointCount(query, 2000, 1);
  std::vector<uint32_t> images;
  for (uint32_t k = 0; k < 10; ++k) {
    images.push_back(k * 97 % static_cast<uint32_t>(localizer.map().scene().NumImages()));
  }
  // Decoded as the localizer decodes it: a network trained for the visibility mask (pooled point
  // rows) chooses among the children the image sees; without the mask the libtorch path would
  // score every point under every parent.
  const Visibility* mask =
      network.options().masked_decoding ? &localizer.map().visibility() : nullptr;
  SetComputeThreads(0);
  const auto time_ms = [&](const std::function<void()>& run) {
    run();
    std::vector<double> runs;
    for (int i = 0; i < 5; ++i) {
      Timer timer;
      run();
      runs.push_back(timer.ElapsedMilliseconds());
    }
    return Percentile(runs, 0.5);
  };
  // The kernels' peak is measured between the network's runs, so that the ratio compares the two
  // at the same moments: this machine's speed drifts by 10-20 % from one minute to the next, and a
  // peak measured minutes apart moved the ratio from 1.37x to 1.58x between runs of one code.
  PackedProductPeak packed_product;
  std::vector<double> level_ms;
  std::vector<double> level_flops;
  std::vector<double> predict_runs;
  std::vector<double> peak_runs;
  network.Predict(padded.descriptors, images, localizer.map().label_tree(), mask);  // warm-up
  for (int i = 0; i < kFloorRounds; ++i) {
    peak_runs.push_back(packed_product.Gflops(0.3));
    Timer timer;
    PointPredictions predictions =
        network.Predict(padded.descriptors, images, localizer.map().label_tree(), mask);
    predict_runs.push_back(timer.ElapsedMilliseconds());
    level_ms = std::move(predictions.level_milliseconds);
    level_flops = std::move(predictions.level_flops);
  }
  const double kernels_ms = Percentile(predict_runs, 0.5);
  const double kernels_peak = Percentile(peak_runs, 0.5);
  const double torch_ms = time_ms([&] {
    network.PredictWithLibtorch(padded.descriptors, images, localizer.map().label_tree(), mask);
  });
  // The floor counts the work the kernels did (modulation once per run of rows that share it,
  // node outputs over a parent's children only), so the rate can never pass the peak; the count
  // from the shapes (every row does everything) is kept beside it.
  const double shape_flops = network.PredictFlops(2000, 10, localizer.map().label_tree());
  const double flops = std::accumulate(level_flops.begin(), level_flops.end(), 0.0);
  std::vector<double> level_gflop;
  for (const double level : level_flops) level_gflop.push_back(level / 1e9);
  // The best rate measured: the packed product's beside the network, or libtorch's.
  const double peak = std::max(kernels_peak, peaks["libtorch_gflops"].get<double>());
  const double floor_ms = flops / (peak * 1e9) * 1000;
  return {{"keypoints", 2000},
          {"images", 10},
          {"gflop", flops / 1e9},
          {"shape_gflop", shape_flops / 1e9},
          {"level_gflop", level_gflop},
          {"floor_ms", floor_ms},
          {"floor_peak_gflops", peak},
          {"kernels_gflops_beside", kernels_peak},
          {"floor_rounds", kFloorRounds},
          {"predict_ms", kernels_ms},
          {"level_ms", level_ms},
          {"predict_libtorch_operators_ms", torch_ms},
          {"times_floor", kernels_ms / floor_ms},
          {"achieved_gflops", flops / 1e9 / (kernels_ms / 1000)}};
}

json LatencyGrid(const Localizer& localizer, const std::vector<LocalizationQuery>& queries) {
  SetComputeThreads(0);
  json rows = json::array();
  for (const int64_t keypoints : {1000, 2000, 4000}) {
    std::vector<LocalizationQuery> sized;
    for (size_t i = 0; i < queries.size(); ++i) {
      sized.push_back(WithKeypointCount(queries[i], keypoints, i + 1));
    }
    for (const int top_k : {1, 10}) {
      for (const CandidateSearch search :
           {CandidateSearch::kAll, CandidateSearch::kUntilAccepted}) {
        // One candidate: nothing to stop early from.
        if (top_k == 1 && search == CandidateSearch::kUntilAccepted) continue;
        LocalizerOptions options;
        options.top_k = top_k;
        options.candidate_search = search;
        options.max_matched_keypoints = 0;  // each row's N keypoints all go through the network
        const bool exhaustive = search == CandidateSearch::kAll;
        std::vector<double> retrieval, matching, visibility, pose, total;
        int localized = 0;
        localizer.Localize(sized.front(), options);  // warm-up
        for (const LocalizationQuery& query : sized) {
          const PoseResult result = localizer.Localize(query, options);
          localized += result.success;
          retrieval.push_back(result.timings.retrieval_ms);
          matching.push_back(result.timings.match_ms);
          visibility.push_back(result.timings.visibility_ms);
          pose.push_back(result.timings.pose_ms);
          total.push_back(result.timings.total_ms);
        }
        const auto stage = [](const std::vector<double>& ms) {
          return json{{"p50", Percentile(ms, 0.5)}, {"p95", Percentile(ms, 0.95)}};
        };
        rows.push_back({{"keypoints", keypoints},
                        {"top_k", top_k},
                        {"mode", exhaustive ? "exhaustive" : "early exit"},
                        {"queries", sized.size()},
                        {"localized", localized},
                        {"retrieval", stage(retrieval)},
                        {"network", stage(matching)},
                        {"visibility", stage(visibility)},
                        {"pose", stage(pose)},
                        {"total", stage(total)}});
      }
    }
  }
  return rows;
}

json ServerThroughput(const fs::path& bundle, const std::vector<LocalizationQuery>& queries) {
  SetComputeThreads(1);
  std::vector<wire::LocalizeRequest> requests;
  for (size_t i = 0; i < queries.size(); ++i) {
    requests.push_back(QueryToWire(WithKeypointCount(queries[i], 2000, i + 1), true));
  }
  ServiceOptions options;
  options.bind = "tcp://127.0.0.1:0";
  options.admin_bind = "";  // no reloads, no probes in process
  options.workers = ResolveNumThreads(0);
  options.max_queue = 1024;
  LocalizationService service(bundle, options);
  ClientOptions client_options;
  client_options.servers = {service.Start()};
  client_options.timeout_ms = 600000;
  const auto run = [&](int clients, size_t per_client) {
    std::vector<double> latencies;
    std::string error;
    std::mutex mutex;
    Timer wall;
    std::vector<std::thread> threads;
    for (int c = 0; c < clients; ++c) {
      threads.emplace_back([&, c] {
        LocalizationClient client(client_options);
        for (size_t r = 0; r < per_client; ++r) {
          Timer timer;
          const wire::LocalizeResponse response =
              client.Localize(requests[(c * 5 + r) % requests.size()]);
          const double ms = timer.ElapsedMilliseconds();
          std::lock_guard<std::mutex> lock(mutex);
          if (response.status() != wire::OK && response.status() != wire::NOT_LOCALIZED) {
            error = response.error_message();
          }
          latencies.push_back(ms);
        }
      });
    }
    for (std::thread& thread : threads) thread.join();
    if (!error.empty()) throw std::runtime_error("server: " + error);
    return std::make_pair(latencies, latencies.size() / wall.ElapsedSeconds());
  };
  run(1, requests.size());  // warm-up: first-touch costs stay out of the numbers
  const auto [single_latencies, single_throughput] = run(1, requests.size());
  const double single_ms = Mean(single_latencies);
  // Ideal: every worker as busy as one client alone keeps one, i.e. workers / single latency.
  const double ideal = options.workers * 1000 / single_ms;
  json load = json::array();
  json headline;
  for (const int clients : {1, 2, 4, 8}) {
    const auto [latencies, throughput] = run(clients, requests.size());
    json row = {{"clients", clients},
                {"requests_per_s", throughput},
                {"p50_ms", Percentile(latencies, 0.5)},
                {"p95_ms", Percentile(latencies, 0.95)},
                {"p99_ms", Percentile(latencies, 0.99)},
                {"of_ideal", throughput / ideal}};
    if (clients == 2 * options.workers) headline = row;
    load.push_back(row);
  }
  service.Stop();
  headline["workers"] = options.workers;
  headline["keypoints"] = 2000;
  headline["single_query_ms"] = single_ms;
  headline["ideal_requests_per_s"] = ideal;
  headline["load"] = load;
  return headline;
}

}  // namespace hscloc::bench
