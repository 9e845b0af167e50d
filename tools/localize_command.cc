#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <fstream>
#include <iostream>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_set>
#include <vector>

#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "localization/localizer.h"
#include "tools/commands.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

struct LocalizeArguments {
  std::string map_dir;
  std::vector<std::string> query_lists;
  std::string features;
  std::string global_features;
  std::string out;
  std::string matcher = "hsc";
  std::string device = "cpu";
  bool no_visibility_filter = false;
  bool no_image_id = false;
  bool early_exit = false;
  bool resume = false;
  int num_threads = 0;
  LocalizerOptions options;
};

// Sums of per-stage times, for the summary.
struct StageTotals {
  double retrieval_ms = 0;
  double matching_ms = 0;
  double visibility_ms = 0;
  double pose_ms = 0;
  double total_ms = 0;
  std::vector<double> totals;

  void Add(const StageTimings& timings) {
    retrieval_ms += timings.retrieval_ms;
    matching_ms += timings.matching_ms;
    visibility_ms += timings.visibility_ms;
    pose_ms += timings.pose_ms;
    total_ms += timings.total_ms;
    totals.push_back(timings.total_ms);
  }
};

double Percentile(std::vector<double> values, double fraction) {
  if (values.empty()) return 0;
  const size_t index = std::min(values.size() - 1, static_cast<size_t>(fraction * values.size()));
  std::nth_element(values.begin(), values.begin() + index, values.end());
  return values[index];
}

// Names already in an existing output file (a resumed run skips them).
std::unordered_set<std::string> NamesIn(const fs::path& path) {
  std::unordered_set<std::string> names;
  std::ifstream file(path);
  std::string line;
  while (std::getline(file, line)) {
    const size_t end = line.find(' ');
    if (end != std::string::npos && end > 0) names.insert(line.substr(0, end));
  }
  return names;
}

// Drops a half-written last line that an interrupted run may have left.
void TruncateToLastFullLine(const fs::path& path) {
  if (!fs::exists(path)) return;
  std::string text;
  {
    std::ifstream file(path, std::ios::binary);
    text.assign(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
  }
  if (text.empty() || text.back() == '\n') return;
  const size_t last_newline = text.rfind('\n');
  text.resize(last_newline == std::string::npos ? 0 : last_newline + 1);
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
}

int RunLocalize(LocalizeArguments& arguments) {
  LocalizerOptions& options = arguments.options;
  options.matcher = ParseMatcher(arguments.matcher);
  options.visibility_filter = !arguments.no_visibility_filter;
  options.use_image_id = !arguments.no_image_id;
  options.exhaustive = !arguments.early_exit;
  options.Check();

  std::vector<QueryWithIntrinsics> queries;
  for (const std::string& list : arguments.query_lists) {
    for (QueryWithIntrinsics& query : ReadQueryList(list)) queries.push_back(std::move(query));
  }
  const std::unique_ptr<FeatureReader> features = OpenFeatureReader(arguments.features);
  std::unordered_map<std::string, Eigen::VectorXf> global_descriptors;
  if (!arguments.global_features.empty()) {
    global_descriptors = ReadH5GlobalDescriptors(arguments.global_features);
  }
  for (const QueryWithIntrinsics& query : queries) {
    if (!features->HasImage(query.name)) {
      ThrowInvalidArgument("{}: no features for query '{}'", arguments.features, query.name);
    }
    if (!arguments.global_features.empty() && !global_descriptors.count(query.name)) {
      ThrowInvalidArgument("{}: no global descriptor for query '{}'", arguments.global_features,
                           query.name);
    }
  }

  Timer timer;
  const Localizer localizer =
      Localizer::FromBundle(arguments.map_dir, options, ParseComputeDevice(arguments.device));
  std::cerr << fmt::format("loaded {} in {}\n", arguments.map_dir,
                           FormatDuration(timer.ElapsedSeconds()));

  const fs::path out = arguments.out;
  const fs::path failures_path = out.string() + ".failures.txt";
  std::unordered_set<std::string> done;
  if (arguments.resume) {
    TruncateToLastFullLine(out);
    TruncateToLastFullLine(failures_path);
    done = NamesIn(out);
  }
  std::vector<size_t> pending;
  for (size_t i = 0; i < queries.size(); ++i) {
    if (!done.count(ImageBasename(queries[i].name))) pending.push_back(i);
  }
  if (arguments.resume) {
    std::cerr << fmt::format("resuming: {} of {} queries already in {}\n",
                             queries.size() - pending.size(), queries.size(), out.string());
  }
  if (!out.parent_path().empty()) fs::create_directories(out.parent_path());
  const auto mode = arguments.resume ? std::ios::app : std::ios::trunc;
  std::ofstream submission(out, std::ios::out | mode);
  std::ofstream failures(failures_path, std::ios::out | mode);
  if (!submission || !failures) ThrowInvalidArgument("cannot write {}", out.string());

  // Queries run in parallel, each on one core: the network's products are too small to split
  // well across cores, while whole queries are independent.
  const int num_threads =
      std::min<int>(ResolveNumThreads(arguments.num_threads), std::max<size_t>(pending.size(), 1));
  SetComputeThreads(1);
  ProgressBar progress("localize", pending.size());
  std::mutex mutex;
  std::atomic<size_t> next{0};
  size_t num_localized = 0;
  size_t num_failed = 0;
  StageTotals totals;
  std::exception_ptr error;
  timer.Restart();
  const auto worker = [&] {
    for (size_t i = next++; i < pending.size(); i = next++) {
      try {
        const QueryWithIntrinsics& entry = queries[pending[i]];
        ImageFeatures query_features = features->Read(entry.name);
        LocalizationQuery query{entry.name, entry.camera, std::move(query_features.keypoints),
                                std::move(query_features.descriptors), std::nullopt};
        if (!global_descriptors.empty())
          query.global_descriptor = global_descriptors.at(entry.name);
        const PoseResult result = localizer.Localize(query);
        const std::string basename = ImageBasename(entry.name);
        std::lock_guard<std::mutex> lock(mutex);
        // A failed query still gets a line (the top-1 retrieved image's pose), so that the
        // submission is complete; the failures file says which and why.
        submission << FormatPoseLine(basename, result.cam_from_world) << std::flush;
        if (result.success) {
          ++num_localized;
        } else {
          ++num_failed;
          failures << basename << ' ' << result.failure_reason << '\n' << std::flush;
        }
        totals.Add(result.timings);
        progress.SetStatus(fmt::format("{} localized, {} failed", num_localized, num_failed));
        progress.Advance();
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        if (!error) error = std::current_exception();
        next = pending.size();
      }
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < num_threads; ++t) threads.emplace_back(worker);
  worker();
  for (std::thread& thread : threads) thread.join();
  progress.Finish();
  if (error) std::rethrow_exception(error);

  const double count = std::max<double>(1, static_cast<double>(totals.totals.size()));
  std::cout << fmt::format(
      "localized {} of {} queries ({} failed, listed in {}) in {}, {} threads, matcher {}\n"
      "per query (ms): retrieval {:.1f}, {} {:.1f}, visibility {:.1f}, pose {:.1f}; total mean "
      "{:.1f}, p50 {:.1f}, p95 {:.1f}\n"
      "submission: {}\n",
      num_localized, pending.size(), num_failed, failures_path.string(),
      FormatDuration(timer.ElapsedSeconds()), num_threads, MatcherName(options.matcher),
      totals.retrieval_ms / count, options.matcher == Matcher::kNetwork ? "network" : "matching",
      totals.matching_ms / count, totals.visibility_ms / count, totals.pose_ms / count,
      totals.total_ms / count, Percentile(totals.totals, 0.5), Percentile(totals.totals, 0.95),
      out.string());
  return 0;
}

}  // namespace

void AddLocalizeCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<LocalizeArguments>();
  LocalizerOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand(
      "localize", "Localize a list of queries offline and write a submission file");
  command->add_option("--map", arguments->map_dir, "Map bundle (hscloc build-map, hscloc train)")
      ->required()
      ->check(CLI::ExistingDirectory);
  command
      ->add_option("--queries", arguments->query_lists,
                   "Query list(s): NAME MODEL WIDTH HEIGHT PARAMS... per line")
      ->required()
      ->check(CLI::ExistingFile);
  command->add_option("--features", arguments->features, "Query features: .h5 or database.db")
      ->required()
      ->check(CLI::ExistingFile);
  command
      ->add_option("--global-features", arguments->global_features,
                   "Query global descriptors (.h5), for maps built with external ones")
      ->check(CLI::ExistingFile);
  command->add_option("--out", arguments->out, "Submission file: NAME QW QX QY QZ TX TY TZ")
      ->required();
  command->add_option("--matcher", arguments->matcher, "hsc (the network) or nn (baseline)")
      ->check(CLI::IsMember({"hsc", "nn"}))
      ->capture_default_str();
  command->add_option("--top-k", options.top_k, "Retrieved database images")->capture_default_str();
  command->add_flag("--no-visibility-filter", arguments->no_visibility_filter,
                    "Keep matches to points the retrieved image does not see");
  command->add_flag("--no-image-id", arguments->no_image_id,
                    "Run the network without the retrieved image's id");
  command->add_flag("--masked-decoding", options.visibility_masked_decoding,
                    "Let the network choose only subtrees the retrieved image sees");
  command->add_flag("--early-exit", arguments->early_exit,
                    "Stop at the first candidate with enough inliers instead of posing all");
  command
      ->add_option("--early-exit-inliers", options.early_exit_inliers,
                   "Inliers that end the search with --early-exit")
      ->capture_default_str();
  command
      ->add_option("--threshold", options.pose.max_reprojection_error_px,
                   "RANSAC inlier threshold in pixels")
      ->capture_default_str();
  command->add_option("--device", arguments->device, "cpu or cuda")
      ->check(CLI::IsMember({"cpu", "cuda"}))
      ->capture_default_str();
  command->add_option("--threads", arguments->num_threads, "Queries in parallel (0: all cores)");
  command->add_flag("--resume", arguments->resume,
                    "Keep the queries already in --out and localize the rest");
  command->callback([&run, arguments] { run = [arguments] { return RunLocalize(*arguments); }; });
}

}  // namespace hscloc
