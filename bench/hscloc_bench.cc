// hscloc-bench: how well hscloc localizes and where its time goes, beside the machine's limit and
// the alternatives a user would pick, measured in one run on the same data. Writes a Markdown
// report (default docs/performance.md), its SVG plots beside it, and the raw numbers as JSON.
//
//   hscloc-bench [--quick] [--work DIR] [--data DIR] [--report FILE] [--json FILE]
//   hscloc-bench --scale-only PRESET [--train-minutes M]   one row of the scale table
//   hscloc-bench --from-json                               the report from the JSON alone
//
// Steps: the machine's fp32 GEMM peak (libtorch and hscloc's Eigen kernels); synthetic maps made
// with the `hscloc` tool as a user would (synth, build-map, train; wall time and peak memory of
// each); the network's time against its FLOP floor; end-to-end latency per stage over keypoint
// count, retrieved images and exhaustive vs early exit; the server's throughput over loopback
// against the ideal of its worker pool; HSC beside the nearest-neighbour baseline and COLMAP's
// image_registrator on real and synthetic sets; cost against map size. --quick trains briefly,
// times fewer queries and leaves the aachen preset out (its numbers are carried over from the last
// full run when the JSON file has them).
#include <fmt/format.h>
#include <torch/torch.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "bench/bench_support.h"
#include "bench/performance_report.h"
#include "client/localization_client.h"
#include "scene/colmap_io.h"
#include "model/dense_kernels.h"
#include "scene/feature_io.h"
#include "model/network_module.h"
#include "localization/pose_evaluation.h"
#include "scene/query_io.h"
#include "server/localization_service.h"
#include "localization/localizer.h"
#include "server/wire.h"
#include "util/logging.h"
#include "util/parallel.h"
#include "util/random.h"
#include "util/timer.h"

namespace hscloc::bench {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct BenchOptions {
  bool quick = false;
  bool from_json = false;    // only rewrite the report from the JSON file's numbers
  std::string scale_only;    // only measure this preset's scale row, into the existing JSON
  double train_minutes = 0;  // training budget of --scale-only (0: the full run's)
  fs::path work = "bench-work";
  fs::path data = HSCLOC_DEFAULT_DATA_DIR;
  fs::path report = "docs/performance.md";
  fs::path json_path;  // default: the report's path with .json
  std::string hscloc = HSCLOC_TOOL_PATH;
  std::string colmap = "colmap";
};

// ---------------------------------------------------------------------------------------------
// The machine's limit.

std::string CpuModel() {
  std::ifstream cpuinfo("/proc/cpuinfo");
  std::string line;
  while (std::getline(cpuinfo, line)) {
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  }
  return "unknown";
}

json MeasureGemmPeaks() {
  const int64_t size = 2048;
  const double flops = 2.0 * size * size * size;
  const auto rate = [&](const std::function<void()>& product) {
    product();  // warm-up
    Timer timer;
    int runs = 0;
    do {
      product();
      ++runs;
    } while (timer.ElapsedSeconds() < 1.5);
    return flops * runs / timer.ElapsedSeconds() / 1e9;
  };
  SetComputeThreads(0);
  torch::manual_seed(0);
  const torch::Tensor a = torch::randn({size, size});
  const torch::Tensor b = torch::randn({size, size});
  torch::Tensor c = torch::empty({size, size});
  const double torch_gflops = rate([&] { torch::mm_out(c, a, b); });
  // hscloc's kernels are single-threaded; Predict splits rows over the threads, and so does this.
  std::vector<float> in(size * size, 0.5f), weight(size * size, 0.25f), bias(size, 0),
      out(size * size);
  const int64_t block = 256;
  const double kernel_gflops = rate([&] {
    ParallelFor(size / block, 0, [&](size_t first, size_t last) {
      for (size_t i = first; i < last; ++i) {
        dense_kernels::Linear(in.data() + i * block * size, block, size, weight.data(), bias.data(),
                              size, false, out.data() + i * block * size);
      }
    });
  });
  return {{"threads", ResolveNumThreads(0)},
          {"libtorch_gflops", torch_gflops},
          {"eigen_kernels_gflops", kernel_gflops},
          {"peak_gflops", std::max(torch_gflops, kernel_gflops)},
          {"kernel_instruction_sets", dense_kernels::KernelInstructionSets()}};
}

// ---------------------------------------------------------------------------------------------
// Maps and queries.

struct SyntheticMap {
  std::string preset;
  fs::path city;  // synth output: COLMAP model, features.h5, queries
  fs::path map;   // trained bundle
  json build;     // times, memory, sizes
};

SyntheticMap MakeSyntheticMap(const BenchOptions& options, const std::string& preset,
                              double train_minutes) {
  SyntheticMap result{preset, options.work / preset / "city", options.work / preset / "map", {}};
  const fs::path logs = options.work / preset / "logs";
  Step(fmt::format("{}: synth", preset));
  const ChildRun synth = RunChild(
      {options.hscloc, "synth", "--preset", preset, "--out", result.city.string(), "--overwrite"},
      logs / "synth.log");
  Step(fmt::format("{}: build-map", preset));
  fs::remove_all(result.map);
  const ChildRun build =
      RunChild({options.hscloc, "build-map", "--model", (result.city / "map").string(),
                "--features", (result.city / "features.h5").string(), "--out", result.map.string()},
               logs / "build_map.log");
  Step(fmt::format("{}: train for {} min", preset, train_minutes));
  const ChildRun train = RunChild({options.hscloc, "train", "--map", result.map.string(),
                                   "--minutes", fmt::format("{}", train_minutes), "--checkpoint",
                                   (options.work / preset / "checkpoint.pt").string()},
                                  logs / "train.log");
  std::ifstream stats_stream(result.city / "stats.json");
  const json stats = json::parse(stats_stream, nullptr, false);
  result.build = {{"synth_s", synth.seconds},
                  {"build_map_s", build.seconds},
                  {"build_map_peak_mb", build.peak_rss_mb},
                  {"train_s", train.seconds},
                  {"train_peak_mb", train.peak_rss_mb},
                  {"city_stats", stats.is_discarded() ? json() : stats}};
  return result;
}

std::vector<LocalizationQuery> LoadQueries(const fs::path& list, const FeatureReader& features,
                                           size_t limit) {
  std::vector<LocalizationQuery> queries;
  for (const QueryWithIntrinsics& query : ReadQueryList(list)) {
    if (queries.size() == limit) break;
    ImageFeatures image = features.Read(query.name);
    queries.push_back({query.name, query.camera, std::move(image.keypoints),
                       std::move(image.descriptors), std::nullopt});
  }
  return queries;
}

// The query with exactly `count` keypoints: its own (the first `count` when it has more), then
// clutter keypoints, uniform in the image with random unit descriptors, as a detector tuned to
// return `count` keypoints would add.
LocalizationQuery WithKeypointCount(const LocalizationQuery& query, int64_t count, uint64_t seed) {
  LocalizationQuery result = query;
  const int64_t own = std::min<int64_t>(count, query.keypoints.rows());
  const int64_t dim = query.descriptors.cols();
  result.keypoints.resize(count, 2);
  result.descriptors.resize(count, dim);
  result.keypoints.topRows(own) = query.keypoints.topRows(own);
  result.descriptors.topRows(own) = query.descriptors.topRows(own);
  Random random(seed);
  for (int64_t i = own; i < count; ++i) {
    result.keypoints(i, 0) = static_cast<float>(random.Uniform(0, query.camera.width));
    result.keypoints(i, 1) = static_cast<float>(random.Uniform(0, query.camera.height));
    for (int64_t j = 0; j < dim; ++j) result.descriptors(i, j) = float(random.Normal());
    result.descriptors.row(i).normalize();
  }
  return result;
}

struct Evaluation {
  ConditionAccuracy accuracy;
  std::vector<PoseResult> results;
};

// Localizes the queries, each on one thread and several at a time (as `hscloc localize` does),
// and scores them against the ground truth.
Evaluation Evaluate(const Localizer& localizer, const LocalizerOptions& options,
                    const std::vector<LocalizationQuery>& queries,
                    const std::vector<NamedPose>& ground_truth, const std::string& condition) {
  SetComputeThreads(1);
  Evaluation evaluation;
  evaluation.results.resize(queries.size());
  ParallelFor(queries.size(), 0, [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      evaluation.results[i] = localizer.Localize(queries[i], options);
    }
  });
  std::vector<NamedPose> estimates;
  std::vector<NamedPose> truth;
  for (size_t i = 0; i < queries.size(); ++i) {
    estimates.push_back({queries[i].name, evaluation.results[i].cam_from_world});
    const std::string basename = ImageBasename(queries[i].name);
    for (const NamedPose& pose : ground_truth) {
      if (ImageBasename(pose.name) == basename) truth.push_back(pose);
    }
  }
  evaluation.accuracy =
      SummarizeAccuracy(condition, ComputePoseErrors(truth, estimates), AachenThresholds());
  return evaluation;
}

json AccuracyJson(const Evaluation& evaluation) {
  std::vector<double> total_ms;
  for (const PoseResult& result : evaluation.results) total_ms.push_back(result.timings.total_ms);
  return {{"queries", evaluation.accuracy.num_queries},
          {"localized_fraction", evaluation.accuracy.localized_fraction},
          {"median_position", evaluation.accuracy.median_position},
          {"median_rotation_deg", evaluation.accuracy.median_rotation_deg},
          {"ms_per_query_one_thread", Mean(total_ms)}};
}

// ---------------------------------------------------------------------------------------------
// COLMAP's image_registrator, as the peer that matches each query against every map image.

json RunColmapRegistration(const BenchOptions& options, const fs::path& set_dir,
                           const std::vector<QueryWithIntrinsics>& queries,
                           const std::vector<NamedPose>& ground_truth) {
  if (!CanRun(options.colmap)) return {{"skipped", "the colmap binary is not installed"}};
  const fs::path dir = options.work / "colmap" / set_dir.filename();
  fs::remove_all(dir);
  fs::create_directories(dir / "registered");
  fs::copy_file(set_dir / "database.db", dir / "database.db");
  const Reconstruction map = ReadColmapModel(set_dir / "map");
  // COLMAP's registration needs every map image in its correspondence graph: the map images are
  // matched among themselves first (a one-off cost of building its map, not timed per query).
  const auto match_pairs = [&](const std::string& name,
                               const std::vector<std::pair<std::string, std::string>>& pairs) {
    {
      std::ofstream list(dir / (name + ".txt"));
      for (const auto& [a, b] : pairs) list << a << ' ' << b << '\n';
    }
    return RunChild(
        {options.colmap, "matches_importer", "--database_path", (dir / "database.db").string(),
         "--match_list_path", (dir / (name + ".txt")).string(), "--match_type", "pairs",
         "--SiftMatching.use_gpu", "0"},
        dir / (name + ".log"));
  };
  std::vector<std::pair<std::string, std::string>> map_pairs;
  std::vector<std::pair<std::string, std::string>> query_pairs;
  for (auto a = map.images.begin(); a != map.images.end(); ++a) {
    for (auto b = std::next(a); b != map.images.end(); ++b) {
      map_pairs.emplace_back(a->second.name, b->second.name);
    }
    for (const QueryWithIntrinsics& query : queries) {
      query_pairs.emplace_back(query.name, a->second.name);
    }
  }
  match_pairs("map_pairs", map_pairs);
  const ChildRun matching = match_pairs("query_pairs", query_pairs);
  const ChildRun registration = RunChild(
      {options.colmap, "image_registrator", "--database_path", (dir / "database.db").string(),
       "--input_path", (set_dir / "map").string(), "--output_path", (dir / "registered").string()},
      dir / "image_registrator.log");
  const Reconstruction registered = ReadColmapModel(dir / "registered");
  std::vector<NamedPose> estimates;
  for (const auto& [id, image] : registered.images) {
    for (const QueryWithIntrinsics& query : queries) {
      if (image.name == query.name) estimates.push_back({image.name, image.cam_from_world});
    }
  }
  const ConditionAccuracy accuracy =
      SummarizeAccuracy("colmap", ComputePoseErrors(ground_truth, estimates), AachenThresholds());
  return {{"queries", accuracy.num_queries},
          {"localized_fraction", accuracy.localized_fraction},
          {"median_position", accuracy.median_position},
          {"median_rotation_deg", accuracy.median_rotation_deg},
          {"ms_per_query", 1000 * (matching.seconds + registration.seconds) / queries.size()},
          {"map_bytes", fs::file_size(set_dir / "database.db") + DirectoryBytes(set_dir / "map")}};
}

// HSC needs the bundle without the observations' descriptors; the nearest-neighbour matcher needs
// them and not the network.
json BundleSizes(const fs::path& bundle) {
  const std::vector<std::string> bookkeeping = {"manifest.json", "training_log.csv"};
  std::vector<std::string> without_descriptors = bookkeeping;
  without_descriptors.push_back(map_blobs::kObservations);
  std::vector<std::string> without_network = bookkeeping;
  without_network.push_back(network_blobs::kNetwork);
  return {{"hsc_bytes", DirectoryBytes(bundle, without_descriptors)},
          {"nn_bytes", DirectoryBytes(bundle, without_network)},
          {"network_bytes", fs::file_size(bundle / network_blobs::kNetwork)},
          {"descriptor_bytes", fs::file_size(bundle / map_blobs::kObservations)}};
}

// HSC and the nearest-neighbour baseline (and COLMAP on real photos) on one query set.
json ComparePeers(const std::string& name, const fs::path& bundle, double train_seconds,
                  const std::vector<LocalizationQuery>& queries,
                  const std::vector<NamedPose>& ground_truth, const json& colmap) {
  const auto map = LocalizationMap::Load(bundle, {.load_observations = true});
  const Localizer localizer(map, map->network());
  json peers = {{"set", name},
                {"queries", queries.size()},
                {"train_s", train_seconds},
                {"sizes", BundleSizes(bundle)}};
  for (const Matcher matcher : {Matcher::kNetwork, Matcher::kNearestNeighbor}) {
    LocalizerOptions localizer_options;
    localizer_options.matcher = matcher;
    peers[MatcherName(matcher)] =
        AccuracyJson(Evaluate(localizer, localizer_options, queries, ground_truth, name));
  }
  peers["colmap"] = colmap;
  return peers;
}

json RealSetPeers(const BenchOptions& options, const std::string& set, double train_minutes) {
  const fs::path set_dir = options.data / set;
  if (!fs::exists(set_dir / "database.db")) {
    return {{"set", set}, {"skipped", fmt::format("{} not found", set_dir.string())}};
  }
  const fs::path bundle = options.work / set / "map";
  Step(fmt::format("{}: build-map and train for {} min", set, train_minutes));
  fs::remove_all(bundle);
  RunChild({options.hscloc, "build-map", "--model", (set_dir / "map").string(), "--features",
            (set_dir / "database.db").string(), "--out", bundle.string()},
           options.work / set / "build_map.log");
  const ChildRun train = RunChild({options.hscloc, "train", "--map", bundle.string(), "--minutes",
                                   fmt::format("{}", train_minutes), "--checkpoint",
                                   (options.work / set / "checkpoint.pt").string()},
                                  options.work / set / "train.log");
  const auto features = OpenColmapDatabaseFeatures(set_dir / "database.db");
  const std::vector<QueryWithIntrinsics> list =
      ReadQueryList(set_dir / "queries_with_intrinsics.txt");
  const std::vector<NamedPose> ground_truth = ReadPoses(set_dir / "queries_gt.txt");
  const std::vector<LocalizationQuery> queries =
      LoadQueries(set_dir / "queries_with_intrinsics.txt", *features, list.size());
  Step(fmt::format("{}: COLMAP image_registrator", set));
  json colmap;
  try {
    colmap = RunColmapRegistration(options, set_dir, list, ground_truth);
  } catch (const std::exception& error) {
    colmap = {{"skipped", error.what()}};
  }
  Step(fmt::format("{}: HSC and nearest neighbours", set));
  json peers = ComparePeers(set, bundle, train.seconds, queries, ground_truth, colmap);
  peers["sizes"]["colmap_database_bytes"] = fs::file_size(set_dir / "database.db");
  return peers;
}

// ---------------------------------------------------------------------------------------------
// Latency, the network's floor, and the server.

json NetworkAgainstFloor(const Localizer& localizer, const LocalizationQuery& query,
                         const json& peaks) {
  const Network& network = *localizer.network();
  const LocalizationQuery padded = WithKeypointCount(query, 2000, 1);
  std::vector<uint32_t> images;
  for (uint32_t k = 0; k < 10; ++k) {
    images.push_back(k * 97 % static_cast<uint32_t>(localizer.map().scene().NumImages()));
  }
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
  std::vector<double> level_ms;
  const double kernels_ms = time_ms([&] {
    level_ms = network.Predict(padded.descriptors, images, localizer.map().label_tree())
                   .level_milliseconds;
  });
  const double torch_ms = time_ms([&] {
    NetworkInternals::PredictWithTorch(network, padded.descriptors, images,
                                       localizer.map().label_tree(), nullptr);
  });
  const double flops = network.PredictFlops(2000, 10, localizer.map().label_tree());
  const double peak = peaks["peak_gflops"].get<double>();
  const double floor_ms = flops / (peak * 1e9) * 1000;
  return {{"keypoints", 2000},
          {"images", 10},
          {"gflop", flops / 1e9},
          {"floor_ms", floor_ms},
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
      for (const CandidateSearch search : {CandidateSearch::kAll, CandidateSearch::kUntilAccepted}) {
        // One candidate: nothing to stop early from.
        if (top_k == 1 && search == CandidateSearch::kUntilAccepted) continue;
        LocalizerOptions options;
        options.top_k = top_k;
        options.candidate_search = search;
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
  options.workers = ResolveNumThreads(0);
  options.max_queue = 1024;
  LocalizationService service(bundle, options);
  ClientOptions client_options;
  client_options.server = service.Start();
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

// Cost of one map: sizes, build, memory of the loaded map, accuracy and latency.
json MeasureMap(const SyntheticMap& synthetic, size_t queries_per_condition, json* city_extras,
                const json& peaks, bool with_grid) {
  json row = synthetic.build;
  row["preset"] = synthetic.preset;
  const double rss_before = ResidentMegabytes();
  const auto map = LocalizationMap::Load(synthetic.map, {.load_observations = true});
  row["loaded_map_mb"] = ResidentMegabytes() - rss_before;
  row["points"] = map->scene().NumPoints();
  row["images"] = map->scene().NumImages();
  row["observations"] = map->scene().NumObservations();
  row["sizes"] = BundleSizes(synthetic.map);
  row["features_h5_bytes"] = fs::file_size(synthetic.city / "features.h5");
  const Localizer localizer(map, map->network());
  const auto features = OpenH5Features(synthetic.city / "features.h5");
  const std::vector<NamedPose> ground_truth = ReadPoses(synthetic.city / "queries_gt.txt");
  json conditions;
  std::vector<LocalizationQuery> day;
  for (const std::string condition : {"day", "night"}) {
    Step(fmt::format("{}: localize {} queries, HSC and nearest neighbours", synthetic.preset,
                     condition));
    const std::vector<LocalizationQuery> queries = LoadQueries(
        synthetic.city / "queries" / fmt::format("{}_time_queries_with_intrinsics.txt", condition),
        *features, queries_per_condition);
    if (condition == std::string("day")) day = queries;
    json peers = ComparePeers(synthetic.preset + " " + condition, synthetic.map,
                              synthetic.build["train_s"].get<double>(), queries, ground_truth,
                              {{"skipped",
                                "COLMAP matches 128-D SIFT only; the synthetic city's "
                                "descriptors are 256-D floats"}});
    conditions[condition] = peers;
  }
  row["peers"] = conditions;
  // Latency at the queries' own keypoint counts, all cores for one query.
  SetComputeThreads(0);
  std::vector<double> total;
  for (const LocalizationQuery& query : day)
    total.push_back(localizer.Localize(query).timings.total_ms);
  row["query_p50_ms"] = Percentile(total, 0.5);
  if (with_grid) {
    Step(fmt::format("{}: network against its FLOP floor", synthetic.preset));
    (*city_extras)["network"] = NetworkAgainstFloor(localizer, day.front(), peaks);
    Step(fmt::format("{}: latency per stage over keypoints, images and mode", synthetic.preset));
    const std::vector<LocalizationQuery> grid_queries(
        day.begin(), day.begin() + std::min<size_t>(day.size(), queries_per_condition / 2));
    (*city_extras)["latency"] = LatencyGrid(localizer, grid_queries);
    Step(fmt::format("{}: server throughput over loopback", synthetic.preset));
    (*city_extras)["server"] = ServerThroughput(synthetic.map, grid_queries);
  }
  return row;
}

std::string Today() {
  const std::time_t now = std::time(nullptr);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  return text;
}

int Run(const BenchOptions& options) {
  const fs::path json_path = options.json_path.empty()
                                 ? fs::path(options.report).replace_extension(".json")
                                 : options.json_path;
  if (options.from_json) {
    std::ifstream stream(json_path);
    if (!stream) throw std::invalid_argument("cannot read " + json_path.string());
    const json results = json::parse(stream);
    fs::create_directories(fs::absolute(options.report).parent_path());
    std::ofstream(options.report) << WriteReport(results, fs::absolute(options.report));
    Step(fmt::format("wrote {} from {}", options.report.string(), json_path.string()));
    return 0;
  }
  json previous;
  if (fs::exists(json_path)) {
    std::ifstream stream(json_path);
    previous = json::parse(stream, nullptr, false);
  }
  if (!options.scale_only.empty()) {
    // One preset's row of the scale table, measured now and put into the existing numbers.
    if (!previous.is_object() || !previous.contains("scale")) {
      throw std::invalid_argument("--scale-only needs an existing report JSON: " +
                                  json_path.string());
    }
    fs::create_directories(options.work);
    SetupLogging("warn");
    const SyntheticMap map = MakeSyntheticMap(
        options, options.scale_only, options.train_minutes > 0 ? options.train_minutes : 30);
    json row = MeasureMap(map, 20, nullptr, previous["machine"], false);
    row["measured"] = Today();
    json scale = json::array();
    for (const json& existing : previous["scale"]) {
      if (existing["preset"] != options.scale_only) scale.push_back(existing);
    }
    scale.push_back(row);
    previous["scale"] = scale;
    std::ofstream(json_path) << previous.dump(2) << '\n';
    std::ofstream(options.report) << WriteReport(previous, fs::absolute(options.report));
    Step(fmt::format("added {} to {} and {}", options.scale_only, json_path.string(),
                     options.report.string()));
    return 0;
  }
  fs::create_directories(options.work);
  SetupLogging("warn");
  json results = {
      {"quick", options.quick}, {"date", Today()}, {"json_name", json_path.filename().string()}};

  Step("fp32 GEMM peak (libtorch, hscloc kernels)");
  json machine = MeasureGemmPeaks();
  machine["cpu"] = CpuModel();
  results["machine"] = machine;

  const double minutes = options.quick ? 1 : 8;
  results["real_sets"] = json::array();
  for (const std::string set : {"fountain-P11", "lund"}) {
    results["real_sets"].push_back(RealSetPeers(options, set, options.quick ? 0.3 : 3));
  }

  results["scale"] = json::array();
  json city_extras;
  const size_t queries = options.quick ? 16 : 50;
  {
    const SyntheticMap small = MakeSyntheticMap(options, "small", options.quick ? 0.5 : 3);
    results["scale"].push_back(MeasureMap(small, queries, nullptr, machine, false));
  }
  {
    const SyntheticMap city = MakeSyntheticMap(options, "city", minutes);
    results["scale"].push_back(MeasureMap(city, queries, &city_extras, machine, true));
  }
  if (!options.quick) {
    const SyntheticMap aachen = MakeSyntheticMap(options, "aachen", 30);
    results["scale"].push_back(MeasureMap(aachen, 20, nullptr, machine, false));
  } else if (previous.is_object() && previous.contains("scale")) {
    for (json row : previous["scale"]) {
      if (row["preset"] == "aachen") {
        if (!row.contains("measured")) row["measured"] = previous.value("date", "unknown");
        results["scale"].push_back(row);
      }
    }
  }
  results["city"] = city_extras;

  fs::create_directories(fs::absolute(options.report).parent_path());
  std::ofstream(json_path) << results.dump(2) << '\n';
  std::ofstream(options.report) << WriteReport(results, fs::absolute(options.report));
  Step(fmt::format("wrote {} and {}", options.report.string(), json_path.string()));
  return 0;
}

}  // namespace
}  // namespace hscloc::bench

int main(int argc, char** argv) {
  hscloc::bench::BenchOptions options;
  std::string work, data, report, json_path;
  CLI::App app{"Benchmarks hscloc against the machine's limit and its peers; writes a report"};
  app.add_flag("--quick", options.quick,
               "Brief training, fewer queries, no aachen preset (under 5 minutes)");
  app.add_flag("--from-json", options.from_json,
               "Measure nothing: rewrite the report from the JSON file's numbers");
  app.add_option("--scale-only", options.scale_only,
                 "Measure one preset's row of the scale table (e.g. aachen) into the existing "
                 "JSON, then rewrite the report")
      ->check(CLI::IsMember({"small", "city", "aachen"}));
  app.add_option("--train-minutes", options.train_minutes,
                 "Training budget for --scale-only (default: the full run's, 30 for aachen)");
  app.add_option("--work", work, "Scratch directory for maps and logs")
      ->default_str(options.work.string());
  app.add_option("--data", data, "Real test data (fountain-P11, lund)")
      ->default_str(options.data.string());
  app.add_option("--report", report, "Markdown report to write")
      ->default_str(options.report.string());
  app.add_option("--json", json_path, "Raw numbers (default: the report with .json)");
  app.add_option("--hscloc", options.hscloc, "The hscloc tool")->default_str(options.hscloc);
  app.add_option("--colmap", options.colmap, "The COLMAP binary")->default_str(options.colmap);
  CLI11_PARSE(app, argc, argv);
  if (!work.empty()) options.work = work;
  if (!data.empty()) options.data = data;
  if (!report.empty()) options.report = report;
  if (!json_path.empty()) options.json_path = json_path;
  try {
    return hscloc::bench::Run(options);
  } catch (const std::exception& error) {
    std::cerr << "error: " << error.what() << '\n';
    return 1;
  }
}
