#include <fmt/format.h>

#include <iostream>
#include <memory>

#include "features/image_extraction.h"
#include "tools/commands.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct ExtractArguments {
  std::string image_dir;
  std::string list;
  std::string feature = "xfeat";
  std::string out;
  ImageExtractionOptions options;
  bool float32 = false;
};

int RunExtract(ExtractArguments& arguments) {
  ImageExtractionOptions& options = arguments.options;
  options.extractor.type = ParseFeatureType(arguments.feature);
  options.precision = arguments.float32 ? H5FloatPrecision::kFloat32 : H5FloatPrecision::kFloat16;
  const std::vector<std::string> names =
      arguments.list.empty() ? ListImages(arguments.image_dir) : ReadImageList(arguments.list);
  const ImageExtractionSummary summary =
      ExtractImagesToH5(arguments.image_dir, names, arguments.out, options);
  std::cout << fmt::format(
      "{} features of {} images in {}: {} extracted ({} keypoints, {:.0f} per image), {} already "
      "there, in {} ({:.0f} ms per image)\n",
      arguments.feature, summary.num_images, arguments.out, summary.num_extracted,
      summary.num_keypoints,
      summary.num_extracted > 0 ? double(summary.num_keypoints) / summary.num_extracted : 0.0,
      summary.num_skipped, FormatDuration(summary.seconds),
      summary.num_extracted > 0 ? 1e3 * summary.seconds / summary.num_extracted : 0.0);
  return 0;
}

}  // namespace

void AddExtractCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<ExtractArguments>();
  ImageExtractionOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand(
      "extract", "Extract local features of photos into an hloc .h5 file (resumable)");
  command->add_option("--images", arguments->image_dir, "Folder of photos (searched recursively)")
      ->required();
  command->add_option("--list", arguments->list,
                      "File of image names relative to --images, one per line (default: all "
                      "photos under --images)");
  command->add_option("--feature", arguments->feature, "xfeat or sift")
      ->check(CLI::IsMember({"xfeat", "sift"}))
      ->capture_default_str();
  command->add_option("--out", arguments->out, "hloc feature file; images already in it are kept")
      ->required();
  command->add_option("--xfeat-model", options.extractor.xfeat.model_path, "XFeat ONNX model")
      ->capture_default_str();
  command
      ->add_option("--xfeat-max-keypoints", options.extractor.xfeat.max_keypoints,
                   "XFeat keypoints kept per image (top-K by score)")
      ->capture_default_str();
  command
      ->add_option("--xfeat-max-side", options.extractor.xfeat.max_side_px,
                   "Longer side of a photo as XFeat sees it, in pixels (larger photos are scaled "
                   "down, smaller ones kept; queries must use the map's)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  command
      ->add_option("--sift-max-keypoints", options.extractor.sift.max_keypoints,
                   "SIFT keypoints kept per image")
      ->capture_default_str();
  command->add_option("--threads", options.num_threads, "Threads (0: all cores)");
  command->add_flag("--float32", arguments->float32,
                    "Store descriptors as float32 (default float16, as hloc)");
  command->callback([&run, arguments] { run = [arguments] { return RunExtract(*arguments); }; });
}

}  // namespace hscloc
