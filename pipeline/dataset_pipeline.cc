#include "pipeline/dataset_pipeline.h"

#include <fmt/format.h>

#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <ostream>
#include <unordered_map>

#include "features/image_extraction.h"
#include "localization/localization_map.h"
#include "localization/map_builder.h"
#include "localization/matcher_choice.h"
#include "localization/query_runner.h"
#include "map/map_blobs.h"
#include "map/map_bundle.h"
#include "model/network.h"
#include "model/trainer.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "triangulation/map_triangulation.h"
#include "util/check.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

constexpr char kRecordFile[] = "pipeline.json";
constexpr char kFeaturesFile[] = "features.h5";
constexpr char kModelDir[] = "model";
constexpr char kMapDir[] = "map";
// Photos per extraction call: each call closes the feature file, so an interrupted run loses at
// most one chunk's work.
constexpr size_t kPhotosPerChunk = 32;

// Where a step writes its output until complete: features.partial.h5, model.partial (the
// extension kept, as readers choose the format by it).
fs::path Partial(const fs::path& path) {
  return path.parent_path() / (path.stem().string() + ".partial" + path.extension().string());
}

// Moves a finished step's output under its final name.
void Publish(const fs::path& partial, const fs::path& final_path) {
  fs::remove_all(final_path);
  fs::rename(partial, final_path);
}

// OUT records the dataset and the feature it was made from, so that a rerun never mixes the
// outputs of two datasets or two features.
void CheckOrWriteRecord(const fs::path& dataset, const fs::path& out,
                        const PipelineOptions& options) {
  const nlohmann::json record = {{"dataset", fs::weakly_canonical(dataset).string()},
                                 {"feature", FeatureTypeName(options.feature)}};
  const fs::path path = out / kRecordFile;
  if (fs::exists(path)) {
    std::ifstream file(path);
    nlohmann::json existing;
    try {
      existing = nlohmann::json::parse(file);
    } catch (const nlohmann::json::exception&) {
      ThrowInvalidArgument("{} is not a pipeline record: is {} another tool's folder?",
                           path.string(), out.string());
    }
    if (existing != record) {
      ThrowInvalidArgument(
          "{} was made from {} with {} features, not {} with {}: choose another --out",
          out.string(), existing.value("dataset", "?"), existing.value("feature", "?"),
          record["dataset"].get<std::string>(), record["feature"].get<std::string>());
    }
    return;
  }
  if (fs::exists(out) && !fs::is_empty(out)) {
    ThrowInvalidArgument("{} is not empty and holds no {}: choose an empty or new --out",
                         out.string(), kRecordFile);
  }
  fs::create_directories(out);
  std::ofstream(path) << record.dump(2) << '\n';
}

// Thrown inside a step that stopped at PipelineOptions::stop_requested.
struct StepInterrupted {};

void StopIfRequested(const PipelineOptions& options) {
  if (options.stop_requested != nullptr && options.stop_requested->load()) throw StepInterrupted{};
}

// Runs the steps in order, skipping those whose output is complete, and removes the outputs of
// the steps after one that ran (they were made from what it replaced).
class StepSequence {
 public:
  StepSequence(int num_steps, const PipelineOptions& options, std::ostream& log,
               PipelineSummary& summary)
      : num_steps_(num_steps), options_(options), log_(log), summary_(summary) {}

  // `outputs`: what the step writes (removed when an earlier step ran); `run` returns its detail.
  void Step(const std::string& name, const std::vector<fs::path>& outputs,
            const std::function<bool()>& complete, const std::function<std::string()>& run) {
    if (interrupted_) return;
    ++index_;
    PipelineStepReport report;
    report.name = name;
    if (redo_) {
      for (const fs::path& output : outputs) fs::remove_all(output);
    }
    if (!redo_ && complete()) {
      report.skipped = true;
      log_ << fmt::format("[{}/{}] {}: complete, skipped\n", index_, num_steps_, name)
           << std::flush;
    } else {
      log_ << fmt::format("[{}/{}] {} ...\n", index_, num_steps_, name) << std::flush;
      const Timer timer;
      try {
        StopIfRequested(options_);
        report.detail = run();
      } catch (const StepInterrupted&) {
        report.interrupted = interrupted_ = true;
        report.detail = "interrupted: rerun the same command to resume";
      }
      report.seconds = timer.ElapsedSeconds();
      redo_ = true;
      log_ << fmt::format("[{}/{}] {}: {} ({})\n", index_, num_steps_, name, report.detail,
                          FormatDuration(report.seconds))
           << std::flush;
    }
    summary_.steps.push_back(std::move(report));
  }

 private:
  int num_steps_;
  const PipelineOptions& options_;
  int index_ = 0;
  bool redo_ = false;
  bool interrupted_ = false;
  std::ostream& log_;
  PipelineSummary& summary_;
};

std::string ExtractFeatures(const DatasetLayout& layout, const std::vector<std::string>& photos,
                            const fs::path& features, const PipelineOptions& options,
                            std::ostream& log) {
  const fs::path partial = Partial(features);
  if (fs::exists(partial)) {
    try {
      OpenFeatureReader(partial);
      log << fmt::format("  continuing the extraction in {}\n", partial.string());
    } catch (const std::exception& error) {
      log << fmt::format("  {} cannot be read ({}): extracting again\n", partial.string(),
                         error.what());
      fs::remove(partial);
    }
  }
  ImageExtractionOptions extraction;
  extraction.extractor.type = options.feature;
  extraction.num_threads = options.num_threads;
  extraction.show_progress = false;
  ProgressBar progress(
      "extract " + FeatureTypeName(options.feature), photos.size(),
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  int64_t extracted = 0;
  int64_t keypoints = 0;
  for (size_t begin = 0; begin < photos.size(); begin += kPhotosPerChunk) {
    StopIfRequested(options);
    const std::vector<std::string> chunk(
        photos.begin() + begin, photos.begin() + std::min(photos.size(), begin + kPhotosPerChunk));
    const ImageExtractionSummary summary =
        ExtractImagesToH5(layout.images_dir, chunk, partial, extraction);
    extracted += summary.num_extracted;
    keypoints += summary.num_keypoints;
    progress.Advance(chunk.size());
  }
  progress.Finish();
  Publish(partial, features);
  return fmt::format("{} photos, {} extracted by this run ({:.0f} keypoints per photo)",
                     photos.size(), extracted,
                     extracted > 0 ? static_cast<double>(keypoints) / extracted : 0.0);
}

std::string Triangulate(const DatasetLayout& layout, const fs::path& features,
                        const fs::path& model, const PipelineOptions& options) {
  MapTriangulationOptions triangulation;
  triangulation.colmap.colmap_executable = options.colmap_executable;
  triangulation.num_threads = options.num_threads;
  triangulation.show_progress = options.show_progress;
  fs::remove_all(Partial(model));
  const MapTriangulationSummary summary = TriangulateMap(
      {layout.model_dir, features, layout.images_dir}, triangulation, Partial(model));
  Publish(Partial(model), model);
  return fmt::format(
      "{} images, {} verified pairs, {} points, mean track length {:.2f}, reprojection error "
      "{:.2f} px",
      summary.num_registered_images, summary.num_verified_pairs, summary.num_points3D,
      summary.mean_track_length, summary.mean_reprojection_error_px);
}

std::string BuildMapBundle(const fs::path& model, const fs::path& features, const fs::path& map,
                           const PipelineOptions& options) {
  MapBuildOptions build;
  build.label_tree.num_threads = options.num_threads;
  build.vlad.num_threads = options.num_threads;
  build.show_progress = options.show_progress;
  fs::remove_all(Partial(map));
  const MapBuildSummary summary = BuildMap({model, features, std::nullopt}, build, Partial(map));
  Publish(Partial(map), map);
  return fmt::format("{} images, {} points, {} observations, {:.1f} MiB", summary.num_images,
                     summary.num_points, summary.num_observations,
                     summary.bundle_bytes / 1048576.0);
}

bool HasNetwork(const fs::path& map) {
  return fs::exists(map) &&
         MapBundle::Open(map, std::vector<std::string>{}).HasBlob(map_blobs::kNetwork);
}

// `hscloc train --map MAP` with the pipeline's budget and seed, resuming from its checkpoint.
std::string Train(const fs::path& map_dir, const fs::path& checkpoint,
                  const PipelineOptions& options) {
  const auto map = LocalizationMap::Load(map_dir, {.load_observations = true});
  TrainerOptions training;
  training.network =
      DefaultNetworkOptions(map->scene().NumPoints(), static_cast<int>(map->scene().Dimension()));
  training.point_prototypes = DefaultPointPrototypes(training.network);
  training.max_iterations = options.max_iterations;
  training.max_minutes = options.max_minutes;
  training.seed = options.seed;
  training.num_threads = options.num_threads;
  training.checkpoint_path = checkpoint;
  training.resume = true;
  training.show_progress = options.show_progress;
  SetComputeThreads(options.num_threads);
  training.stop_requested = options.stop_requested;
  const TrainingResult result = TrainNetwork(map->scene(), map->label_tree(), training);
  // The trainer checkpointed where it stopped; the network is published only when trained.
  if (result.interrupted) throw StepInterrupted{};
  WriteNetworkToBundle(map_dir, result, training, {},
                       MeasureMatchingCost(*map, result.network).AsNetworkNotes());
  fs::remove(checkpoint);
  return fmt::format("{} iterations, held-out point accuracy {:.1f} %", result.iterations,
                     100 * result.best_held_out_accuracy);
}

std::vector<QueryWithIntrinsics> AllQueries(const DatasetLayout& layout) {
  std::vector<QueryWithIntrinsics> queries;
  for (const auto& [condition, list] : layout.query_lists) {
    for (QueryWithIntrinsics& query : ReadQueryList(list)) queries.push_back(std::move(query));
  }
  return queries;
}

// Publishes the submission with its lines in the query lists' order: queries are written as they
// finish, in an order that varies from run to run.
void PublishInQueryOrder(const fs::path& partial, const std::vector<QueryWithIntrinsics>& queries,
                         const fs::path& submission) {
  std::unordered_map<std::string, std::string> lines;
  std::ifstream in(partial);
  for (std::string line; std::getline(in, line);) {
    lines.emplace(line.substr(0, line.find(' ')), line);
  }
  const fs::path ordered = submission.string() + ".ordered";
  {
    std::ofstream out(ordered);
    for (const QueryWithIntrinsics& query : queries) {
      const auto line = lines.find(ImageBasename(query.name));
      if (line != lines.end()) out << line->second << '\n';
    }
    if (!out) ThrowInvalidArgument("cannot write {}", ordered.string());
  }
  fs::remove(partial);
  Publish(ordered, submission);
}

std::string Localize(const DatasetLayout& layout, const fs::path& map, const fs::path& features,
                     const fs::path& submission, const PipelineOptions& options) {
  LocalizerOptions localizer_options;
  localizer_options.matcher = options.matcher;
  const Localizer localizer = Localizer::FromBundle(map, localizer_options);
  const std::unique_ptr<FeatureReader> reader = OpenFeatureReader(features);
  QueryListRunOptions run;
  run.out = Partial(submission);
  run.resume = true;
  run.num_threads = options.num_threads;
  run.show_progress = options.show_progress;
  const std::vector<QueryWithIntrinsics> queries = AllQueries(layout);
  const QueryListRunSummary summary = RunQueryList(localizer, queries, *reader, nullptr, run);
  const fs::path failures = submission.string() + ".failures.txt";
  fs::remove(failures);
  if (fs::exists(summary.failures_path)) fs::rename(summary.failures_path, failures);
  PublishInQueryOrder(Partial(submission), queries, submission);
  return fmt::format(
      "{} queries, matcher {}: {} posed by this run ({} localized, {} failed), {} kept from before",
      summary.num_queries, MatcherName(options.matcher), summary.num_queries - summary.num_skipped,
      summary.num_localized, summary.num_failed, summary.num_skipped);
}

void Evaluate(const DatasetLayout& layout, PipelineSummary& summary) {
  if (!layout.ground_truth) return;
  summary.errors =
      ComputePoseErrors(ReadPoses(*layout.ground_truth), ReadPoses(summary.submission));
  std::vector<ConditionQueries> conditions;
  for (const auto& [condition, list] : layout.query_lists) {
    conditions.push_back(ConditionFromQueryList(condition, list));
  }
  summary.accuracy = SummarizeAccuracyByCondition(summary.errors, conditions, AachenThresholds());
}

}  // namespace

void PipelineOptions::Check() const {
  THROW_CHECK_MSG(max_iterations >= 0, "PipelineOptions.max_iterations must be >= 0");
  THROW_CHECK_MSG(max_minutes >= 0, "PipelineOptions.max_minutes must be >= 0");
  THROW_CHECK_MSG(!colmap_executable.empty(), "PipelineOptions.colmap_executable is empty");
}

bool PipelineSummary::NothingToDo() const {
  for (const PipelineStepReport& step : steps) {
    if (!step.skipped) return false;
  }
  return true;
}

bool PipelineSummary::Interrupted() const {
  for (const PipelineStepReport& step : steps) {
    if (step.interrupted) return true;
  }
  return false;
}

std::string SubmissionFileName(Matcher matcher) {
  return matcher == Matcher::kNetwork ? "submission.txt" : "submission-nn.txt";
}

PipelineSummary RunDatasetPipeline(const fs::path& dataset, const fs::path& out,
                                   const PipelineOptions& options, std::ostream& log) {
  options.Check();
  const DatasetLayout layout = FindDatasetLayout(dataset);
  const std::vector<std::string> photos = DatasetPhotos(layout);
  CheckOrWriteRecord(dataset, out, options);
  log << fmt::format("dataset {} ({} layout): {} photos, {} query list(s); output {}\n",
                     dataset.string(), layout.kind, photos.size(), layout.query_lists.size(),
                     out.string());

  const fs::path features = out / kFeaturesFile;
  const fs::path model = out / kModelDir;
  const fs::path map = out / kMapDir;
  const fs::path checkpoint = out / "map.checkpoint.pt";
  PipelineSummary summary;
  summary.submission = out / SubmissionFileName(options.matcher);
  const bool trains = options.matcher == Matcher::kNetwork;
  StepSequence steps(trains ? 5 : 4, options, log, summary);
  steps.Step(
      "features", {features, Partial(features)}, [&] { return fs::exists(features); },
      [&] { return ExtractFeatures(layout, photos, features, options, log); });
  steps.Step(
      "model", {model}, [&] { return fs::exists(model); },
      [&] { return Triangulate(layout, features, model, options); });
  steps.Step(
      "map", {map, checkpoint}, [&] { return fs::exists(map); },
      [&] { return BuildMapBundle(model, features, map, options); });
  // The other matcher's submission, from an earlier run, is stale once the map or the network
  // it was made with is replaced.
  const fs::path other_submission =
      out / SubmissionFileName(trains ? Matcher::kNearestNeighbor : Matcher::kNetwork);
  if (trains) {
    steps.Step(
        "network", {other_submission}, [&] { return HasNetwork(map); },
        [&] { return Train(map, checkpoint, options); });
  }
  std::vector<fs::path> submission_outputs = {summary.submission, Partial(summary.submission)};
  if (!trains) submission_outputs.push_back(other_submission);
  steps.Step(
      "submission", submission_outputs, [&] { return fs::exists(summary.submission); },
      [&] { return Localize(layout, map, features, summary.submission, options); });
  if (!summary.Interrupted()) Evaluate(layout, summary);
  return summary;
}

}  // namespace hscloc
