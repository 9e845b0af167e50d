#include <fmt/format.h>

#include <iostream>
#include <memory>

#include "tools/commands.h"
#include "triangulation/map_triangulation.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct TriangulateArguments {
  MapTriangulationInputs inputs;
  std::string out;
  MapTriangulationOptions options;
};

int RunTriangulate(const TriangulateArguments& arguments) {
  const MapTriangulationSummary summary =
      TriangulateMap(arguments.inputs, arguments.options, arguments.out);
  std::cout << fmt::format(
      "model written to {}\n"
      "  images            {:>10}  ({} registered)\n"
      "  pairs             {:>10}  ({} verified, >= {} inliers)\n"
      "  matches           {:>10}  ({} verified, <= {:g} px from their epipolar lines)\n"
      "  points            {:>10}\n"
      "  observations      {:>10}  (mean track length {:.2f})\n"
      "  mean reproj. error{:>10.3f}  px\n"
      "  time              {:>10}  (matching {}, COLMAP {})\n",
      arguments.out, summary.num_images, summary.num_registered_images, summary.num_pairs,
      summary.num_verified_pairs, arguments.options.verification.min_num_inliers,
      summary.num_matches, summary.num_verified_matches,
      arguments.options.verification.max_epipolar_error_px, summary.num_points3D,
      summary.num_observations, summary.mean_track_length, summary.mean_reprojection_error_px,
      FormatDuration(summary.seconds_total), FormatDuration(summary.seconds_matching),
      FormatDuration(summary.seconds_triangulation));
  return 0;
}

}  // namespace

void AddTriangulateCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<TriangulateArguments>();
  MapTriangulationOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand(
      "triangulate",
      "Triangulate a map for new local features from the known poses of a COLMAP model (as hloc)");
  command->add_option("--model", arguments->inputs.model_dir, "COLMAP model with the poses to keep")
      ->required()
      ->check(CLI::ExistingDirectory);
  command
      ->add_option("--features", arguments->inputs.features,
                   "Local features of every model image: hloc features.h5 or COLMAP database.db")
      ->required()
      ->check(CLI::ExistingFile);
  command->add_option("--out", arguments->out, "Directory of the triangulated COLMAP model")
      ->required();
  command
      ->add_option("--images", arguments->inputs.image_dir,
                   "The photos, for the points' colours (optional)")
      ->check(CLI::ExistingDirectory);
  command
      ->add_option("--pairs-per-image", options.pairs.pairs_per_image,
                   "Most co-visible images matched with each image")
      ->capture_default_str();
  command
      ->add_option("--ratio", options.matching.max_ratio,
                   "Ratio test of the mutual nearest neighbours (1: off)")
      ->capture_default_str();
  command
      ->add_option("--max-epipolar-error-px", options.verification.max_epipolar_error_px,
                   "Largest distance of a match from its epipolar lines")
      ->capture_default_str();
  command
      ->add_option("--min-inliers", options.verification.min_num_inliers,
                   "Fewest verified matches a pair keeps")
      ->capture_default_str();
  command->add_option("--colmap", options.colmap.colmap_executable, "The COLMAP 3.8 executable")
      ->capture_default_str();
  command->add_option("--threads", options.num_threads, "Matching threads (0: all cores)");
  command
      ->add_option("--max-images-in-memory", options.max_images_in_memory,
                   "Images whose descriptors are held at once while matching (chunks of pairs)")
      ->check(CLI::Range(2, 1 << 30))
      ->capture_default_str();
  command->callback(
      [&run, arguments] { run = [arguments] { return RunTriangulate(*arguments); }; });
}

}  // namespace hscloc
