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

#include <CLI/CLI.hpp>
#include <algorithm>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "bench/bench_options.h"
#include "bench/bench_support.h"
#include "bench/measurements.h"
#include "bench/peers.h"
#include "bench/performance_report.h"
#include "bench/query_evaluation.h"
#include "client/localization_client.h"
#include "localization/localizer.h"
#include "localization/pose_evaluation.h"
#include "localization/query_runner.h"
#include "map/map_blobs.h"
#include "model/network.h"
#include "model/trainer.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/localization_service.h"
#include "server/wire.h"
#include "util/logging.h"
#include "util/parallel.h"
#include "util/random.h"
#include "util/statistics.h"
#include "util/timer.h"

namespace hscloc::bench {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

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

// ---------------------------------------------------------------------------------------------
// Maps and queries.

// The real sets, in the report's order: kitti-07 ships with the project (data/), the others come
// from the data directory.
const std::vector<std::string> kRealSets = {"fountain-P11", "lund", "kitti-07"};

struct SyntheticMap {
  std::string preset;  // synth's --preset
  std::string label;   // the report's name: the preset, and its appearance when real
  fs::path city;       // synth output: COLMAP model, features.h5, queries
  fs::path map;        // trained bundle
  json build;          // times, memory, sizes
  std::string hscloc;  // the tool that made it, which serves it too
};

// The networks `hscloc train` saved at its held-out checks.
fs::path SnapshotDir(const SyntheticMap& map) { return map.map.parent_path() / "snapshots"; }

// The bank of real XFeat descriptors the real appearance draws from, made from every real set at
// hand on first use (6 minutes for the three sets on 2 cores) and kept under the work folder.
fs::path EnsureDescriptorBank(const BenchOptions& options) {
  const fs::path bank = options.work / "bank" / "real-xfeat.bank";
  if (fs::exists(bank)) return bank;
  std::vector<std::string> command = {
      options.hscloc, "bank",          "--feature",
      "xfeat",        "--xfeat-model", RealDataPath(options, "weights/xfeat/xfeat.onnx").string(),
      "--out",        bank.string()};
  std::vector<std::string> sets;
  for (const std::string& set : kRealSets) {
    const fs::path dir = RealDataPath(options, set);
    if (!fs::is_directory(dir / "images") || !fs::is_directory(dir / "map")) continue;
    command.insert(command.end(), {"--set", dir.string()});
    sets.push_back(set);
  }
  if (sets.empty()) {
    throw std::invalid_argument("--appearance real needs a real set under " +
                                options.data.string() + " to make its descriptor bank");
  }
  Step(fmt::format("descriptor bank from {}", fmt::join(sets, ", ")));
  fs::create_directories(bank.parent_path());
  RunChild(command, bank.parent_path() / "bank.log");
  return bank;
}

SyntheticMap MakeSyntheticMap(const BenchOptions& options, const std::string& preset,
                              double train_minutes) {
  const bool real = options.appearance == "real";
  const std::string label = real ? preset + " (real appearance)" : preset;
  const fs::path dir = options.work / (real ? preset + "-real" : preset);
  SyntheticMap result{preset, label, dir / "city", dir / "map", {}, options.hscloc};
  const fs::path logs = dir / "logs";
  std::vector<std::string> synth_command = {
      options.hscloc, "synth", "--preset", preset, "--out", result.city.string(), "--overwrite"};
  if (real) {
    synth_command.insert(synth_command.end(), {"--appearance", "real", "--bank",
                                               EnsureDescriptorBank(options).string()});
  }
  Step(fmt::format("{}: synth", label));
  const ChildRun synth = RunChild(synth_command, logs / "synth.log");
  Step(fmt::format("{}: build-map", label));
  fs::remove_all(result.map);
  const ChildRun build =
      RunChild({options.hscloc, "build-map", "--model", (result.city / "map").string(),
                "--features", (result.city / "features.h5").string(), "--out", result.map.string()},
               logs / "build_map.log");
  Step(fmt::format("{}: train for {} min", label, train_minutes));
  fs::remove_all(SnapshotDir(result));
  const ChildRun train =
      RunChild({options.hscloc, "train", "--map", result.map.string(), "--minutes",
                fmt::format("{}", train_minutes), "--checkpoint", (dir / "checkpoint.pt").string(),
                "--snapshots", SnapshotDir(result).string()},
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

// Localization accuracy within (0.25 m, 2 deg) of each held-out check's network against its
// training time: the curve a user reads to know how long their map needs.
json LocalizationCurve(
    const SyntheticMap& synthetic, std::shared_ptr<const LocalizationMap> map,
    const json& held_out_curve,
    const std::vector<std::pair<std::string, std::vector<LocalizationQuery>>>& queries_by_condition,
    const std::vector<NamedPose>& ground_truth) {
  json curve = json::array();
  for (const json& check : held_out_curve) {
    const auto iteration = check["iteration"].get<int64_t>();
    const fs::path path = SnapshotDir(synthetic) / SnapshotFileName(iteration);
    if (!fs::exists(path)) continue;
    std::ifstream stream(path, std::ios::binary);
    const auto network = std::make_shared<const Network>(Network::Load(stream, path.string()));
    const Localizer localizer(map, network);
    json point = {{"iteration", iteration}, {"seconds", check["seconds"]}};
    for (const auto& [condition, queries] : queries_by_condition) {
      const Evaluation evaluation =
          Evaluate(localizer, LocalizerOptions{}, queries, ground_truth, condition);
      point[condition] = evaluation.accuracy.localized_fraction.front();
    }
    curve.push_back(point);
  }
  return curve;
}

// Cost of one map: sizes, build, memory of the loaded map, accuracy and latency.
json MeasureMap(const SyntheticMap& synthetic, size_t queries_per_condition, json* city_extras,
                const json& peaks, bool with_grid) {
  json row = synthetic.build;
  row["preset"] = synthetic.label;
  const double rss_before = ResidentMegabytes();
  const auto map = LocalizationMap::Load(synthetic.map, {.load_observations = true});
  row["loaded_map_mb"] = ResidentMegabytes() - rss_before;
  row["points"] = map->scene().NumPoints();
  row["images"] = map->scene().NumImages();
  row["observations"] = map->scene().NumObservations();
  row["sizes"] = BundleSizes(synthetic.map);
  row["held_out_curve"] = map->metadata()
                              .value("network", json::object())
                              .value("training", json::object())
                              .value("held_out_checks", json::array());
  Step(fmt::format("{}: hscloc serve, load time and memory", synthetic.label));
  const ServeRun serve = MeasureServe(synthetic.hscloc, synthetic.map,
                                      synthetic.map.parent_path() / "logs" / "serve.log");
  row["serve_load_s"] = serve.load_seconds;
  row["serve_rss_mb"] = serve.rss_mb;
  row["process_baseline_rss_mb"] = serve.baseline_rss_mb;
  row["features_h5_bytes"] = fs::file_size(synthetic.city / "features.h5");
  const Localizer localizer(map, map->network());
  const auto features = OpenH5Features(synthetic.city / "features.h5");
  const std::vector<NamedPose> ground_truth = ReadPoses(synthetic.city / "queries_gt.txt");
  json conditions;
  std::vector<LocalizationQuery> day;
  std::vector<std::pair<std::string, std::vector<LocalizationQuery>>> queries_for_curve;
  for (const std::string condition : {"day", "night"}) {
    Step(fmt::format("{}: localize {} queries, HSC and nearest neighbours", synthetic.label,
                     condition));
    const std::vector<LocalizationQuery> queries = LoadQueries(
        synthetic.city / "queries" / fmt::format("{}_time_queries_with_intrinsics.txt", condition),
        *features, nullptr, queries_per_condition);
    if (condition == std::string("day")) day = queries;
    queries_for_curve.emplace_back(condition, queries);
    json peers = ComparePeers(synthetic.label + " " + condition, synthetic.map,
                              synthetic.build["train_s"].get<double>(), queries, ground_truth,
                              {{"skipped",
                                "COLMAP matches 128-D SIFT only; the synthetic city's "
                                "descriptors are 256-D floats"}});
    conditions[condition] = peers;
  }
  row["peers"] = conditions;
  Step(fmt::format("{}: localization with the network of each held-out check", synthetic.label));
  const size_t curve_queries = std::max<size_t>(1, queries_per_condition / 4);
  std::vector<std::pair<std::string, std::vector<LocalizationQuery>>> curve_sets;
  for (const auto& [condition, queries] : queries_for_curve) {
    curve_sets.emplace_back(
        condition, std::vector<LocalizationQuery>(
                       queries.begin(), queries.begin() + std::min(curve_queries, queries.size())));
  }
  row["localization_curve"] =
      LocalizationCurve(synthetic, map, row["held_out_curve"], curve_sets, ground_truth);
  // Latency at the queries' own keypoint counts, all cores for one query.
  SetComputeThreads(0);
  std::vector<double> total;
  for (const LocalizationQuery& query : day)
    total.push_back(localizer.Localize(query).timings.total_ms);
  row["query_p50_ms"] = Percentile(total, 0.5);
  if (with_grid) {
    Step(fmt::format("{}: network against its FLOP floor", synthetic.label));
    (*city_extras)["network"] = NetworkAgainstFloor(localizer, day.front(), peaks);
    Step(fmt::format("{}: latency per stage over keypoints, images and mode", synthetic.label));
    const std::vector<LocalizationQuery> grid_queries(
        day.begin(), day.begin() + std::min<size_t>(day.size(), queries_per_condition / 2));
    (*city_extras)["latency"] = LatencyGrid(localizer, grid_queries);
    Step(fmt::format("{}: server throughput over loopback", synthetic.label));
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

// What the full run gives each preset: training minutes, and queries measured per condition.
double FullRunTrainMinutes(const std::string& preset) {
  return preset == "small" ? 3 : preset == "city" ? 8 : 30;
}
size_t FullRunQueriesPerCondition(const std::string& preset) {
  return preset == "aachen" ? 20 : 50;
}

// The peers rows of the real sets, SIFT then XFeat, each over options.seeds training seeds. The
// full run trains as `hscloc train` does by default, the map's own budget (Lund: 844 iterations,
// 2.5 min); --quick cuts it to 20 s and one seed.
json MeasureRealSets(const BenchOptions& options) {
  json rows = json::array();
  for (const LocalFeature feature : {LocalFeature::kSift, LocalFeature::kXFeat}) {
    for (const std::string& set : kRealSets) {
      if (!options.real_sets.empty() &&
          std::find(options.real_sets.begin(), options.real_sets.end(), set) ==
              options.real_sets.end()) {
        continue;
      }
      std::optional<double> minutes;
      if (options.quick) minutes = 0.3;
      if (options.real_train_minutes > 0) minutes = options.real_train_minutes;
      json row = RealSetPeers(options, set, feature, minutes);
      if (options.real_train_minutes > 0) {
        row["set"] = fmt::format("{}, {} min training", row["set"].get<std::string>(),
                                 options.real_train_minutes);
      }
      rows.push_back(row);
    }
  }
  return rows;
}

// `rows` with each of `measured` in place of the row of its set (by "set"), new sets appended.
json MergeRows(json rows, const json& measured) {
  for (const json& row : measured) {
    const auto same = std::find_if(rows.begin(), rows.end(),
                                   [&](const json& old) { return old["set"] == row["set"]; });
    if (same != rows.end()) {
      *same = row;
    } else {
      rows.push_back(row);
    }
  }
  return rows;
}

// Writes the numbers and the report made from them.
void WriteResults(const json& results, const fs::path& json_path, const BenchOptions& options) {
  fs::create_directories(fs::absolute(options.report).parent_path());
  std::ofstream(json_path) << results.dump(2) << '\n';
  std::ofstream(options.report) << WriteReport(results, fs::absolute(options.report));
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
    const SyntheticMap map =
        MakeSyntheticMap(options, options.scale_only,
                         options.train_minutes > 0 ? options.train_minutes
                                                   : FullRunTrainMinutes(options.scale_only));
    // The city's row comes with what the full run measures on it: the network against the
    // machine's floor, the latency grid and the server's throughput.
    // (Of the random appearance: the real one's row stands beside it.)
    const bool city = options.scale_only == "city" && options.appearance == "random";
    json city_extras;
    // The network's floor is this machine's: the report's header may describe another.
    json machine = previous["machine"];
    if (city) {
      Step("fp32 GEMM peak (libtorch, hscloc kernels) of this machine");
      machine = MeasureGemmPeaks();
      machine["cpu"] = CpuModel();
    }
    json row = MeasureMap(map, FullRunQueriesPerCondition(options.scale_only),
                          city ? &city_extras : nullptr, machine, city);
    if (city) {
      city_extras["measured"] = Today();
      city_extras["measured_cpu"] = CpuModel();
      city_extras["machine"] = machine;
      previous["city"] = city_extras;
    }
    row["measured"] = Today();
    row["measured_cpu"] = CpuModel();
    // In its place among the presets (small, city, aachen), or last when it had none.
    json scale = json::array();
    bool replaced = false;
    for (const json& existing : previous["scale"]) {
      const bool same = existing["preset"] == map.label;
      scale.push_back(same ? row : existing);
      replaced = replaced || same;
    }
    if (!replaced) scale.push_back(row);
    previous["scale"] = scale;
    WriteResults(previous, json_path, options);
    Step(fmt::format("added {} to {} and {}", options.scale_only, json_path.string(),
                     options.report.string()));
    return 0;
  }
  if (options.real_sets_only) {
    if (!previous.is_object() || !previous.contains("real_sets")) {
      throw std::invalid_argument("--real-sets-only needs an existing report JSON: " +
                                  json_path.string());
    }
    fs::create_directories(options.work);
    SetupLogging("warn");
    previous["real_sets"] = MergeRows(previous["real_sets"], MeasureRealSets(options));
    // Rows not measured now keep their date: "*" is the whole run's, a set's own replaces it.
    json measured = previous.value("real_sets_measured", json::object());
    if (!measured.is_object()) measured = {{"*", measured}};  // one date for every set
    if (options.real_sets.empty()) measured = {{"*", Today()}};
    for (const std::string& set : options.real_sets) measured[set] = Today();
    previous["real_sets_measured"] = measured;
    WriteResults(previous, json_path, options);
    Step(fmt::format("measured the real sets into {} and {}", json_path.string(),
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

  const double minutes = options.quick ? 1 : FullRunTrainMinutes("city");
  results["real_sets"] = MeasureRealSets(options);

  results["scale"] = json::array();
  json city_extras;
  const size_t queries = options.quick ? 16 : FullRunQueriesPerCondition("city");
  {
    const SyntheticMap small =
        MakeSyntheticMap(options, "small", options.quick ? 0.5 : FullRunTrainMinutes("small"));
    results["scale"].push_back(MeasureMap(small, queries, nullptr, machine, false));
  }
  {
    const SyntheticMap city = MakeSyntheticMap(options, "city", minutes);
    results["scale"].push_back(MeasureMap(city, queries, &city_extras, machine, true));
  }
  if (!options.quick) {
    const SyntheticMap aachen = MakeSyntheticMap(options, "aachen", FullRunTrainMinutes("aachen"));
    results["scale"].push_back(
        MeasureMap(aachen, FullRunQueriesPerCondition("aachen"), nullptr, machine, false));
  } else if (previous.is_object() && previous.contains("scale")) {
    for (json row : previous["scale"]) {
      if (row["preset"] == "aachen") {
        if (!row.contains("measured")) row["measured"] = previous.value("date", "unknown");
        results["scale"].push_back(row);
      }
    }
  }
  results["city"] = city_extras;

  WriteResults(results, json_path, options);
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
  app.add_flag("--real-sets-only", options.real_sets_only,
               "Measure the real sets' peers rows (SIFT and XFeat) into the existing JSON, then "
               "rewrite the report");
  app.add_option("--real-set", options.real_sets,
                 "With --real-sets-only: measure only this set (fountain-P11, lund, kitti-07; "
                 "repeatable), keeping the other rows")
      ->check(CLI::IsMember(hscloc::bench::kRealSets));
  app.add_option("--appearance", options.appearance,
                 "With --scale-only: the city's appearance, random or real (drawn from a bank of "
                 "real XFeat descriptors made from the real sets on first use); a real row sits "
                 "beside the random one")
      ->check(CLI::IsMember({"random", "real"}));
  app.add_option("--train-minutes", options.train_minutes,
                 "Training budget for --scale-only (default: the full run's: small 3, city 8, "
                 "aachen 30)");
  app.add_option("--seeds", options.seeds,
                 "Training seeds of each real set (1 .. N), HSC and the nearest-neighbour "
                 "baseline measured on each (default 5; --quick: 1)")
      ->check(CLI::Range(1, 100));
  app.add_option("--real-train-minutes", options.real_train_minutes,
                 "Training budget of the real sets in minutes (default: `hscloc train`'s own for "
                 "each map); its rows are named after it, beside the default's")
      ->check(CLI::PositiveNumber);
  app.add_option("--work", work, "Scratch directory for maps and logs")
      ->default_str(options.work.string());
  app.add_option("--data", data,
                 "Real test data (fountain-P11, lund; kitti-07 is read from the project's data/ "
                 "when absent there)")
      ->default_str(options.data.string());
  app.add_option("--report", report, "Markdown report to write")
      ->default_str(options.report.string());
  app.add_option("--json", json_path, "Raw numbers (default: the report with .json)");
  app.add_option("--hscloc", options.hscloc, "The hscloc tool")->default_str(options.hscloc);
  app.add_option("--colmap", options.colmap, "The COLMAP binary")->default_str(options.colmap);
  CLI11_PARSE(app, argc, argv);
  if (options.quick && app.count("--seeds") == 0) options.seeds = 1;
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
