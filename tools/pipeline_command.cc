#include <fmt/format.h>

#include <iostream>
#include <memory>

#include "pipeline/dataset_pipeline.h"
#include "tools/commands.h"
#include "tools/stop_signal.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct PipelineArguments {
  std::string dataset;
  std::string out;
  std::string feature = "xfeat";
  std::string matcher = "hsc";
  PipelineOptions options;
};

void PrintEvaluation(const PipelineSummary& summary) {
  if (summary.accuracy.empty()) return;
  std::cout << "\nagainst the dataset's ground truth:\n";
  for (const QueryPoseError& error : summary.errors) {
    std::cout << fmt::format("  {:<40} {:>10.3f} m {:>8.2f} deg{}\n", error.name, error.position,
                             error.rotation_deg, error.estimated ? "" : "  (no result)");
  }
  std::cout << FormatAccuracyTable(summary.accuracy);
}

int RunPipeline(PipelineArguments& arguments) {
  PipelineOptions& options = arguments.options;
  options.feature = ParseFeatureType(arguments.feature);
  options.matcher = ParseMatcher(arguments.matcher);
  // Ctrl-C stops at the next safe point (between chunks of photos, after a training step), so
  // that a rerun resumes there.
  options.stop_requested = StopOnFirstSignal();
  const Timer timer;
  const PipelineSummary summary =
      RunDatasetPipeline(arguments.dataset, arguments.out, options, std::cout);
  if (summary.Interrupted()) {
    std::cout << fmt::format("interrupted after {}: rerun the same command to resume\n",
                             FormatDuration(timer.ElapsedSeconds()));
    return 130;
  }
  if (summary.NothingToDo()) {
    std::cout << fmt::format("nothing to do: every step's output is complete in {}\n",
                             arguments.out);
  } else {
    PrintEvaluation(summary);
  }
  std::cout << fmt::format("submission: {} (total {})\n", summary.submission.string(),
                           FormatDuration(timer.ElapsedSeconds()));
  return 0;
}

}  // namespace

void AddPipelineCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<PipelineArguments>();
  PipelineOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand(
      "pipeline",
      "Photos and a COLMAP model to a submission: features, triangulated model, map, network, "
      "localized queries; a rerun resumes where a run stopped");
  command
      ->add_option("--dataset", arguments->dataset,
                   "Dataset folder: the layout of data/ (images/, map/, "
                   "queries_with_intrinsics.txt, queries_gt.txt) or of Aachen Day-Night v1.1 "
                   "(images/images_upright/, 3D-models/<model>/, queries/)")
      ->required();
  command
      ->add_option("--out", arguments->out,
                   "Output folder: features.h5, model/, map/, submission.txt (submission-nn.txt "
                   "with --matcher nn)")
      ->required();
  command->add_option("--feature", arguments->feature, "xfeat or sift, extracted from the photos")
      ->check(CLI::IsMember({"xfeat", "sift"}))
      ->capture_default_str();
  command
      ->add_option("--matcher", arguments->matcher,
                   "hsc (train the network, then localize with it) or nn (the nearest-neighbour "
                   "baseline on the same map, no training)")
      ->check(CLI::IsMember({"hsc", "nn"}))
      ->capture_default_str();
  command
      ->add_option("--iterations", options.max_iterations,
                   "Training iteration budget (0 and no --minutes: `hscloc train`'s default)")
      ->check(CLI::NonNegativeNumber);
  command->add_option("--minutes", options.max_minutes, "Training time budget in minutes")
      ->check(CLI::NonNegativeNumber);
  command->add_option("--seed", options.seed, "Training seed")->capture_default_str();
  command->add_option("--threads", options.num_threads, "Threads (0: all cores)");
  command->add_option("--colmap", options.colmap_executable, "The COLMAP 3.8 executable")
      ->capture_default_str();
  command->callback([&run, arguments] { run = [arguments] { return RunPipeline(*arguments); }; });
}

}  // namespace hscloc
