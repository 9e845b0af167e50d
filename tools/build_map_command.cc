#include <fmt/format.h>

#include <iostream>
#include <memory>

#include "localization/map_builder.h"
#include "tools/commands.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct BuildMapArguments {
  MapBuildInputs inputs;
  std::string global_features;
  std::string output_dir;
  std::string index_type = "flat";
  MapBuildOptions options;
  int num_threads = 0;
};

int RunBuildMap(BuildMapArguments& arguments) {
  if (!arguments.global_features.empty())
    arguments.inputs.global_features = arguments.global_features;
  MapBuildOptions& options = arguments.options;
  options.global_index.type = arguments.index_type == "ivfpq" ? GlobalIndexOptions::Type::kIvfPq
                                                              : GlobalIndexOptions::Type::kFlat;
  options.label_tree.num_threads = arguments.num_threads;
  options.vlad.num_threads = arguments.num_threads;
  const MapBuildSummary summary = BuildMap(arguments.inputs, options, arguments.output_dir);
  std::cout << fmt::format(
      "map written to {}\n"
      "  database images   {:>10}\n"
      "  points            {:>10}\n"
      "  observations      {:>10}  (descriptor dim {})\n"
      "  label tree nodes  {:>10}  ({} levels, branching {})\n"
      "  global descriptor {:>10}  dims ({})\n"
      "  bundle size       {:>10.1f}  MiB\n"
      "  time              {:>10}  (join {}, tree {}, retrieval {}, write {})\n",
      arguments.output_dir, summary.num_images, summary.num_points, summary.num_observations,
      summary.descriptor_dim, summary.num_tree_nodes, options.label_tree.levels,
      options.label_tree.branching, summary.global_descriptor_dim,
      arguments.inputs.global_features ? "external" : "VLAD", summary.bundle_bytes / 1048576.0,
      FormatDuration(summary.seconds_total), FormatDuration(summary.seconds_join),
      FormatDuration(summary.seconds_label_tree), FormatDuration(summary.seconds_retrieval),
      FormatDuration(summary.seconds_write));
  return 0;
}

}  // namespace

void AddBuildMapCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<BuildMapArguments>();
  MapBuildOptions& options = arguments->options;
  CLI::App* command =
      app.add_subcommand("build-map", "Build a map bundle from a COLMAP model and its features");
  command->add_option("--model", arguments->inputs.model_dir, "COLMAP model directory (bin or txt)")
      ->required()
      ->check(CLI::ExistingDirectory);
  command
      ->add_option("--features", arguments->inputs.features,
                   "Local features: COLMAP database.db or hloc features.h5")
      ->required()
      ->check(CLI::ExistingFile);
  command
      ->add_option("--global-features", arguments->global_features,
                   "hloc global descriptors .h5 (default: VLAD from the local features)")
      ->check(CLI::ExistingFile);
  command->add_option("--out", arguments->output_dir, "Map bundle directory to write")->required();
  command->add_option("--levels", options.label_tree.levels, "Label tree levels")
      ->capture_default_str();
  command->add_option("--branching", options.label_tree.branching, "Label tree branching")
      ->capture_default_str();
  command->add_option("--seed", options.label_tree.seed, "Seed of the tree and codebook k-means")
      ->capture_default_str();
  command->add_option("--vlad-words", options.vlad.num_words, "VLAD codebook size")
      ->capture_default_str();
  command
      ->add_option("--whitened-dim", options.vlad.whitened_dim,
                   "Global descriptor dimension after PCA whitening (0: none)")
      ->capture_default_str();
  command->add_option("--index", arguments->index_type, "Retrieval index: flat or ivfpq")
      ->check(CLI::IsMember({"flat", "ivfpq"}))
      ->capture_default_str();
  command
      ->add_option("--max-keypoint-mismatch-px", options.join.max_keypoint_mismatch_px,
                   "Largest distance between a model 2D point and its keypoint")
      ->capture_default_str();
  command->add_option("--threads", arguments->num_threads, "Threads (0: all cores)");
  command->callback([&run, arguments] {
    arguments->options.vlad.seed = arguments->options.label_tree.seed;
    run = [arguments] { return RunBuildMap(*arguments); };
  });
}

}  // namespace hscloc
