// hscloc demo: the whole product on an embedded default, end to end, in a few minutes. A synthetic
// city whose points look like real XFeat tracks (or, with --real, the Lund street set under data/:
// XFeat features extracted from its photos and a map triangulated for them from its poses, or
// with --feature sift its SIFT database) is generated, mapped and trained; a server starts on
// loopback; `hscloc-client batch` localizes the day and night queries through it; the accuracy,
// the ablations (nearest-neighbour matching among them) and the latency per stage are printed and
// written, with the error curves, a top view of the map and pictures of inlier matches, into an
// HTML report.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <cstdlib>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "bank/bank_builder.h"
#include "features/image_extraction.h"
#include "localization/ablation.h"
#include "localization/localizer.h"
#include "localization/map_builder.h"
#include "localization/matcher_choice.h"
#include "localization/pose_evaluation.h"
#include "localization/query_runner.h"
#include "model/trainer.h"
#include "report/demo_report.h"
#include "report/error_curves.h"
#include "report/match_picture.h"
#include "report/top_view.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/localization_service.h"
#include "synthetic/synthetic_city.h"
#include "synthetic/synthetic_city_writer.h"
#include "tools/commands.h"
#include "triangulation/map_triangulation.h"
#include "util/check.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

struct DemoArguments {
  bool real = false;
  std::string out = "demo-output";
  std::string data = "data/lund";
  // With --real. XFeat, the learned path, by default: it localizes all of Lund's 5 queries within
  // (0.25 m, 2 deg), SIFT 4 (docs/features.md).
  std::string feature = "xfeat";
  double minutes = 3;
  int64_t iterations = 3000;
  // The synthetic city's appearance. "real": each point's views take the descriptors of a real
  // XFeat track, made from the photo sets below on first use and kept under --out, so that the
  // matchers meet real confusion between points; "random": a random unit vector per point, which
  // every matcher localizes (docs/decisions.md).
  std::string appearance = "real";
  std::vector<std::string> bank_sets = {"data/lund", "data/kitti-07"};
};

// What the demo runs on, and what it promises: the share of queries of the first condition within
// (0.25 m, 2 deg), below which it exits non-zero.
struct DemoInputs {
  std::string description;
  MapBuildInputs map;
  std::vector<std::pair<std::string, fs::path>> lists;  // condition -> query list
  fs::path features;
  fs::path ground_truth;
  fs::path images_dir;  // photos for the match pictures; empty for the synthetic city
  double promised_fine_fraction = 0.9;
};

fs::path ExecutableDir() {
  std::error_code error;
  const fs::path self = fs::read_symlink("/proc/self/exe", error);
  return error ? fs::current_path() : self.parent_path();
}

void Section(const std::string& title, const Timer& total) {
  std::cout << fmt::format("\n== {} ({} so far)\n", title, FormatDuration(total.ElapsedSeconds()))
            << std::flush;
}

// The Lund set with XFeat: features of every photo (map and queries), and a map triangulated
// for them from the set's poses, as `hscloc extract` and `hscloc triangulate` make them.
MapBuildInputs XFeatMapOfRealSet(const fs::path& data, const fs::path& out, const Timer& total) {
  Section("XFeat features of the photos", total);
  ImageExtractionOptions extraction;
  extraction.extractor.type = FeatureType::kXFeat;
  const fs::path features = out / "features.h5";
  fs::remove(features);
  const ImageExtractionSummary extracted =
      ExtractImagesToH5(data / "images", ListImages(data / "images"), features, extraction);
  std::cout << fmt::format("{} photos, {} keypoints, in {}\n", extracted.num_extracted,
                           extracted.num_keypoints, FormatDuration(extracted.seconds));

  Section("map triangulated for them from the set's poses (COLMAP point_triangulator)", total);
  const MapTriangulationSummary triangulated = TriangulateMap(
      {data / "map", features, data / "images"}, MapTriangulationOptions(), out / "model");
  std::cout << fmt::format(
      "{} pairs ({} verified, {} matches), {} points, mean track length {:.2f}, mean reprojection "
      "error {:.2f} px, in {}\n",
      triangulated.num_pairs, triangulated.num_verified_pairs, triangulated.num_verified_matches,
      triangulated.num_points3D, triangulated.mean_track_length,
      triangulated.mean_reprojection_error_px, FormatDuration(triangulated.seconds_total));
  return {out / "model", features, std::nullopt};
}

DemoInputs RealInputs(const DemoArguments& arguments, const fs::path& out, const Timer& total) {
  const fs::path data = fs::absolute(arguments.data);
  if (!fs::exists(data / "database.db")) {
    ThrowInvalidArgument(
        "demo --real: {} holds no database.db (run from the repository root, or pass --data)",
        data.string());
  }
  Section(fmt::format("Lund street set (Mapillary photos, CC BY-SA 4.0), {} features",
                      arguments.feature),
          total);
  const MapBuildInputs map = arguments.feature == "xfeat"
                                 ? XFeatMapOfRealSet(data, out, total)
                                 : MapBuildInputs{data / "map", data / "database.db", std::nullopt};
  return {fmt::format("Lund street set, {} features", arguments.feature),
          map,
          {{"all", data / "queries_with_intrinsics.txt"}},
          map.features,
          data / "queries_gt.txt",
          data / "images",
          0.8};
}

// The descriptor bank of the real appearance: reused when the one under `out` was made from the
// same sets, made otherwise (an interrupted run resumes from its work folder).
std::shared_ptr<const DescriptorBank> DemoBank(const DemoArguments& arguments, const fs::path& out,
                                               const Timer& total) {
  std::vector<fs::path> sets;
  std::vector<std::string> names;
  for (const std::string& set : arguments.bank_sets) {
    sets.push_back(fs::absolute(set));
    names.push_back(BankSetName(set));
    if (!fs::is_directory(sets.back() / "images") || !fs::is_directory(sets.back() / "map")) {
      ThrowInvalidArgument(
          "demo: the real appearance draws from the photo set {}, which has no images/ and map/ "
          "(run from the repository root, pass --bank-set, or --appearance random)",
          sets.back().string());
    }
  }
  const fs::path path = out / "bank" / "real-xfeat.bank";
  if (fs::exists(path)) {
    auto bank = std::make_shared<const DescriptorBank>(DescriptorBank::Load(path));
    if (bank->sources() == names) return bank;
  }
  Section(fmt::format("descriptor bank of real XFeat tracks from {} (made once, kept in {})",
                      fmt::join(names, ", "), path.string()),
          total);
  BankSetOptions options;
  options.extractor.type = FeatureType::kXFeat;
  const auto report_set = [](const fs::path& set, const DescriptorBank& bank, double seconds) {
    std::cout << fmt::format("{}: {} tracks, {} views, {:.1f} % found again at night, in {}\n",
                             set.filename().string(), bank.NumTracks(), bank.NumViews(),
                             100.0 * static_cast<double>(bank.NumNightViews()) /
                                 static_cast<double>(std::max<size_t>(1, bank.NumViews())),
                             FormatDuration(seconds));
  };
  const DescriptorBank bank = BankFromSets(sets, path.string() + ".work", options, report_set);
  bank.Save(path);
  return std::make_shared<const DescriptorBank>(bank);
}

DemoInputs SyntheticInputs(const DemoArguments& arguments, const fs::path& out,
                           const Timer& total) {
  std::shared_ptr<const DescriptorBank> bank;
  if (arguments.appearance == "real") bank = DemoBank(arguments, out, total);
  const std::string description =
      bank == nullptr ? "synthetic city 'small'"
                      : fmt::format(
                            "synthetic city 'small' with the appearance of real XFeat "
                            "tracks from {}",
                            fmt::join(bank->sources(), ", "));
  Section(description, total);
  SyntheticCityWriteOptions write_options;
  write_options.overwrite = true;
  const SyntheticCityStats stats = WriteSyntheticCity(
      SyntheticCity(SyntheticCityOptions::Preset("small"), bank), out / "city", write_options);
  std::cout << fmt::format("{} database images, {} map points, {} day + {} night queries\n",
                           stats.num_database_images, stats.num_map_points, stats.num_day_queries,
                           stats.num_night_queries);
  const fs::path city = out / "city";
  return {description,
          {city / "map", city / "features.h5", std::nullopt},
          {{"day", city / "queries" / "day_time_queries_with_intrinsics.txt"},
           {"night", city / "queries" / "night_time_queries_with_intrinsics.txt"}},
          city / "features.h5",
          city / "queries_gt.txt",
          {},
          0.9};
}

void TrainDemoNetwork(const DemoArguments& arguments, const fs::path& bundle) {
  const auto map = LocalizationMap::Load(bundle, {.load_observations = true});
  TrainerOptions train_options;
  // The widths `hscloc train` chooses for this map.
  train_options.network =
      DefaultNetworkOptions(map->scene().NumPoints(), static_cast<int>(map->scene().Dimension()));
  train_options.point_prototypes = DefaultPointPrototypes(train_options.network);
  train_options.max_iterations = arguments.iterations;
  train_options.max_minutes = arguments.minutes;
  train_options.holdout_fraction = arguments.real ? 0 : 0.05;
  // The random appearance's night queries carry descriptor noise of norm 0.8 (docs/decisions.md);
  // the real appearance's night is the bank's night photos, and trains as `hscloc train` does.
  if (!arguments.real && arguments.appearance == "random") {
    train_options.augmentation.noise_norm = 0.8;
  }
  const TrainingResult result = TrainNetwork(map->scene(), map->label_tree(), train_options);
  std::cout << fmt::format("{} iterations in {}, final loss {:.3f}\n", result.iterations,
                           FormatDuration(result.seconds), result.final_loss);
  WriteNetworkToBundle(bundle, result, train_options, {},
                       MeasureMatchingCost(*map, result.network).AsNetworkNotes());
}

// Serves the bundle on loopback and localizes every query list through `hscloc-client batch`;
// returns the submission it wrote.
fs::path LocalizeThroughServer(const DemoInputs& inputs, const fs::path& bundle,
                               const fs::path& out) {
  // The server's per-request log lines would bury the demo's output.
  spdlog::set_level(spdlog::level::warn);
  ServiceOptions service_options;
  service_options.bind = "tcp://127.0.0.1:0";
  service_options.admin_bind = "";  // no reloads, no probes in process
  SetComputeThreads(1);
  LocalizationService service(bundle, service_options);
  const std::string endpoint = service.Start();
  const fs::path submission = out / "submission.txt";
  std::string lists;
  for (const auto& [condition, list] : inputs.lists) lists += " --queries " + list.string();
  const std::string command =
      fmt::format("{} --server {} batch{} --features {} --out {} --inflight 4",
                  (ExecutableDir() / "hscloc-client").string(), endpoint, lists,
                  inputs.features.string(), submission.string());
  std::cout << command << '\n' << std::flush;
  if (std::system(command.c_str()) != 0) ThrowInvalidArgument("hscloc-client batch failed");
  service.Stop();
  spdlog::set_level(spdlog::level::info);
  return submission;
}

// The ablations on the in-process Localizer (printed as text), the match pictures of the paper
// configuration's first queries and the top view of the server's estimates.
DemoReport InProcessReport(const DemoInputs& inputs, const fs::path& bundle,
                           const std::vector<NamedPose>& ground_truth,
                           const std::vector<NamedPose>& estimates) {
  // With the observations too, so that nearest-neighbour matching runs beside the network.
  const auto map = LocalizationMap::Load(bundle, {.load_observations = true});
  const Localizer localizer(map, map->network());
  std::cout << fmt::format("the server ran {}\n",
                           DescribeMatcher(localizer, ServiceOptions().localizer.matcher));
  const std::unique_ptr<FeatureReader> features = OpenFeatureReader(inputs.features);
  std::vector<AblationQuerySet> query_sets;
  for (const auto& [condition, list] : inputs.lists) {
    query_sets.push_back({condition, LoadQueries(list, *features)});
  }
  std::vector<AblationVariant> variants = StandardAblationVariants();
  // The default pipeline with nearest-neighbour matching in place of the network: on the real
  // appearance the two part ways, on the random one both localize every query.
  AblationVariant nearest_neighbor = variants.back();
  nearest_neighbor.name = "nearest-neighbour matching instead of the network (default otherwise)";
  nearest_neighbor.options.matcher = Matcher::kNearestNeighbor;
  variants.push_back(nearest_neighbor);
  AblationOptions ablation_options;
  ablation_options.keep_results = true;
  DemoReport report;
  report.ablations = RunAblations(localizer, query_sets, ground_truth, variants, ablation_options);
  report.latency_variant = variants.front().name;
  std::cout << FormatAblationTable(report.ablations)
            << "\nlatency per stage, exhaustive top-10 (one core per query):\n"
            << FormatLatencyTable(report.ablations, report.latency_variant);

  const Scene& scene = localizer.map().scene();
  for (const AblationQuerySet& set : query_sets) {
    const AblationCell& cell = report.ablations.At(report.latency_variant, set.condition);
    for (size_t q = 0; q < std::min<size_t>(2, set.queries.size()); ++q) {
      std::string picture =
          MatchPictureSvg(set.queries[q], cell.results[q], scene, inputs.images_dir);
      if (!picture.empty()) report.match_pictures.push_back(std::move(picture));
    }
  }
  report.top_view = TopViewOf(scene, ground_truth, estimates);
  return report;
}

void WriteFile(const fs::path& path, const std::string& text) {
  std::ofstream file(path);
  file << text;
  if (!file) ThrowInvalidArgument("cannot write {}", path.string());
}

int RunDemo(const DemoArguments& arguments) {
  const Timer total;
  const fs::path out = fs::absolute(arguments.out);
  fs::create_directories(out);
  const DemoInputs inputs =
      arguments.real ? RealInputs(arguments, out, total) : SyntheticInputs(arguments, out, total);

  Section("map", total);
  const MapBuildSummary summary = BuildMap(inputs.map, MapBuildOptions(), out / "map");
  std::cout << fmt::format("{} images, {} points, {} observations, {:.1f} MiB\n",
                           summary.num_images, summary.num_points, summary.num_observations,
                           summary.bundle_bytes / 1048576.0);

  Section(fmt::format("training (at most {} iterations or {:g} minutes)", arguments.iterations,
                      arguments.minutes),
          total);
  TrainDemoNetwork(arguments, out / "map");

  Section("server on loopback, queries through hscloc-client batch", total);
  const fs::path submission = LocalizeThroughServer(inputs, out / "map", out);

  Section("accuracy", total);
  const std::vector<NamedPose> ground_truth = ReadPoses(inputs.ground_truth);
  const std::vector<NamedPose> estimates = ReadPoses(submission);
  std::vector<ConditionQueries> conditions;
  for (const auto& [condition, list] : inputs.lists) {
    conditions.push_back(ConditionFromQueryList(condition, list));
  }
  const std::vector<ConditionAccuracy> accuracy = SummarizeAccuracyByCondition(
      ComputePoseErrors(ground_truth, estimates), conditions, AachenThresholds());
  std::cout << FormatAccuracyTable(accuracy);

  Section("ablations and latency per stage (in-process Localizer)", total);
  DemoReport report = InProcessReport(inputs, out / "map", ground_truth, estimates);
  report.accuracy = accuracy;
  report.summary =
      fmt::format("{}, total time {}.", inputs.description, FormatDuration(total.ElapsedSeconds()));
  const fs::path plot = out / "errors.svg";
  const fs::path top_view = out / "top_view.svg";
  const fs::path page = out / "report.html";
  WriteFile(plot, CumulativeErrorSvg(report.accuracy, "hscloc demo: cumulative pose errors"));
  WriteFile(top_view, TopViewSvg(report.top_view));
  WriteFile(page, RenderDemoReport(report));
  std::cout << fmt::format("\nreport: {}\nplot: {}\ntop view: {}\ntotal time: {}\n", page.string(),
                           plot.string(), top_view.string(),
                           FormatDuration(total.ElapsedSeconds()));

  const double fine = report.accuracy.front().localized_fraction.front();
  if (fine < inputs.promised_fine_fraction) {
    std::cerr << fmt::format(
        "demo: only {:.0f}% of the {} queries within (0.25 m, 2 deg); the demo promises {:.0f}%\n",
        100 * fine, report.accuracy.front().condition, 100 * inputs.promised_fine_fraction);
    return 1;
  }
  return 0;
}

}  // namespace

void AddDemoCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<DemoArguments>();
  CLI::App* command =
      app.add_subcommand("demo", "Run the whole pipeline on an embedded demo map, with a report");
  command->add_flag("--real", arguments->real,
                    "Use the Lund street photos instead of a synthetic city");
  command->add_option("--data", arguments->data, "The Lund set (with --real)")
      ->capture_default_str();
  command
      ->add_option("--feature", arguments->feature,
                   "With --real: xfeat (extracted from the photos, the map triangulated for them) "
                   "or sift (the set's database.db)")
      ->check(CLI::IsMember({"xfeat", "sift"}))
      ->capture_default_str();
  command
      ->add_option("--appearance", arguments->appearance,
                   "The synthetic city's appearance: real (descriptors of real XFeat tracks from "
                   "--bank-set) or random")
      ->check(CLI::IsMember({"real", "random"}))
      ->capture_default_str();
  command
      ->add_option("--bank-set", arguments->bank_sets,
                   "A real photo set (images/ and map/) the real appearance draws from; "
                   "repeatable")
      ->capture_default_str();
  command->add_option("--out", arguments->out, "Output directory")->capture_default_str();
  command->add_option("--minutes", arguments->minutes, "Training time budget")
      ->capture_default_str();
  CLI::Option* iterations =
      command
          ->add_option("--iterations", arguments->iterations,
                       "Training iteration budget (400 with --real unless given)")
          ->capture_default_str();
  command->callback([&run, arguments, iterations, command] {
    if (arguments->real &&
        (command->count("--appearance") > 0 || command->count("--bank-set") > 0)) {
      throw CLI::ValidationError(
          "--appearance and --bank-set are the synthetic city's, not --real's");
    }
    // Lund's few views per point over-fit with longer training (docs/decisions.md).
    if (arguments->real && iterations->count() == 0) arguments->iterations = 400;
    run = [arguments] { return RunDemo(*arguments); };
  });
}

}  // namespace hscloc
