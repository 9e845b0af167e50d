#include "bench/peers.h"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "bench/bench_support.h"
#include "bench/query_evaluation.h"
#include "localization/localization_map.h"
#include "localization/matcher_choice.h"
#include "localization/query_runner.h"
#include "map/map_blobs.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "util/statistics.h"
#include "util/timer.h"

namespace hscloc::bench {

namespace fs = std::filesystem;
using nlohmann::json;

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
          {"map_bytes", fs::file_size(set_dir / "database.db") + DirectoryBytes(set_dir / "map")},
          {"per_query", PerQueryErrorsJson(accuracy)}};
}

// HSC needs the bundle without the observations' descriptors; the nearest-neighbour matcher needs
// them and neither the network nor the points' descriptors (the network's last round).
json BundleSizes(const fs::path& bundle) {
  const std::vector<std::string> bookkeeping = {map_blobs::kManifest, map_blobs::kTrainingLog};
  std::vector<std::string> without_descriptors = bookkeeping;
  without_descriptors.push_back(map_blobs::kObservations);
  std::vector<std::string> without_network = bookkeeping;
  without_network.push_back(map_blobs::kNetwork);
  without_network.push_back(map_blobs::kPointDescriptors);
  return {{"hsc_bytes", DirectoryBytes(bundle, without_descriptors)},
          {"nn_bytes", DirectoryBytes(bundle, without_network)},
          {"network_bytes", fs::file_size(bundle / map_blobs::kNetwork)},
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
  // What `--matcher auto` runs on this map, from the timing `hscloc train` recorded.
  if (const std::optional<MatchingCost> cost = MatchingCost::FromMetadata(map->metadata())) {
    peers["auto"] = cost->ToJson();
    peers["auto"]["matcher"] = MatcherName(localizer.ResolvedMatcher(Matcher::kAuto));
  }
  // `hscloc train --eval`'s held-out point accuracy (visibility-masked decoding) beside the
  // nearest-class-mean matcher's on the same observations, when the training wrote them.
  const nlohmann::json evaluations = map->metadata()
                                         .value(map_metadata::kNetwork, json::object())
                                         .value("evaluations", json::object());
  if (evaluations.contains("held_out_masked") &&
      evaluations.contains("held_out_nearest_class_mean")) {
    peers["held_out"] = {
        {"network", evaluations["held_out_masked"]["leaf_accuracy"]},
        {"nearest_class_mean", evaluations["held_out_nearest_class_mean"]["leaf_accuracy"]}};
  }
  return peers;
}

json RealSetPeers(const BenchOptions& options, const std::string& set, LocalFeature feature,
                  std::optional<double> train_minutes) {
  const fs::path set_dir = RealDataPath(options, set);
  const bool xfeat = feature == LocalFeature::kXFeat;
  const std::string name = xfeat ? set + ", XFeat" : set;
  if (!fs::exists(set_dir / "database.db")) {
    return {{"set", name}, {"skipped", fmt::format("{} not found", set_dir.string())}};
  }
  const fs::path work = options.work / (xfeat ? set + "-xfeat" : set);
  const fs::path bundle = work / "map";
  // SIFT comes with the set (its database and map); XFeat is extracted from the photos and its
  // map triangulated from the set map's poses, as a user would make them.
  fs::path model = set_dir / "map";
  fs::path features = set_dir / "database.db";
  if (xfeat) {
    const fs::path weights = RealDataPath(options, "weights/xfeat/xfeat.onnx");
    if (!fs::exists(weights)) {
      return {{"set", name}, {"skipped", fmt::format("{} not found", weights.string())}};
    }
    features = work / "features.h5";
    model = work / "model";
    Step(fmt::format("{}: extract XFeat and triangulate the map", name));
    fs::remove_all(work);
    RunChild({options.hscloc, "extract", "--images", (set_dir / "images").string(), "--feature",
              "xfeat", "--xfeat-model", weights.string(), "--out", features.string()},
             work / "extract.log");
    RunChild(
        {options.hscloc, "triangulate", "--model", (set_dir / "map").string(), "--features",
         features.string(), "--images", (set_dir / "images").string(), "--out", model.string()},
        work / "triangulate.log");
  }
  Step(fmt::format("{}: build-map", name));
  const fs::path untrained = work / "map";
  fs::remove_all(untrained);
  RunChild({options.hscloc, "build-map", "--model", model.string(), "--features", features.string(),
            "--out", untrained.string()},
           work / "build_map.log");
  const auto reader = OpenFeatureReader(features);
  const std::vector<QueryWithIntrinsics> list =
      ReadQueryList(set_dir / "queries_with_intrinsics.txt");
  const std::vector<NamedPose> ground_truth = ReadPoses(set_dir / "queries_gt.txt");
  const std::vector<LocalizationQuery> queries =
      LoadQueries(set_dir / "queries_with_intrinsics.txt", *reader, nullptr, list.size());
  json colmap = {{"skipped", "COLMAP's image_registrator matches SIFT only"}};
  if (!xfeat) {
    Step(fmt::format("{}: COLMAP image_registrator", name));
    try {
      colmap = RunColmapRegistration(options, set_dir, list, ground_truth);
    } catch (const std::exception& error) {
      colmap = {{"skipped", error.what()}};
    }
  }
  // Each seed trains its own copy of the untrained bundle; both matchers run on every copy (the
  // nearest-neighbour baseline retrieves by the network's votes when the global descriptor fails).
  json peers;
  json per_seed = json::array();
  for (int seed = 1; seed <= std::max(options.seeds, 1); ++seed) {
    const fs::path bundle = work / fmt::format("map-seed{}", seed);
    fs::remove_all(bundle);
    fs::copy(untrained, bundle, fs::copy_options::recursive);
    Step(fmt::format("{}: train seed {} of {} ({})", name, seed, options.seeds,
                     train_minutes ? fmt::format("{} min", *train_minutes) : "its own budget"));
    std::vector<std::string> train_command = {
        options.hscloc, "train",
        "--map",        bundle.string(),
        "--checkpoint", (work / fmt::format("checkpoint-seed{}.pt", seed)).string(),
        "--seed",       std::to_string(seed),
        "--eval"};
    if (train_minutes) {
      train_command.insert(train_command.end(), {"--minutes", fmt::format("{}", *train_minutes)});
    }
    const ChildRun train = RunChild(train_command, work / fmt::format("train-seed{}.log", seed));
    Step(fmt::format("{}: HSC and nearest neighbours, seed {}", name, seed));
    json row = ComparePeers(name, bundle, train.seconds, queries, ground_truth, colmap);
    if (seed == 1) peers = row;
    json seed_row = {{"seed", seed},
                     {"train_s", train.seconds},
                     {"hsc", row["hsc"]},
                     {"nn", row["nn"]},
                     {"hsc_bytes", row["sizes"]["hsc_bytes"]},
                     {"nn_bytes", row["sizes"]["nn_bytes"]}};
    if (row.contains("held_out")) seed_row["held_out"] = row["held_out"];
    per_seed.push_back(seed_row);
  }
  peers["seeds"] = per_seed;
  if (!xfeat) peers["sizes"]["colmap_database_bytes"] = fs::file_size(set_dir / "database.db");
  return peers;
}

}  // namespace hscloc::bench
