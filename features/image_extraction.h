// Extraction of local features from a folder of photos into an hloc feature file (.h5), on all
// cores, resumable: images already in the file are kept and skipped.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "features/feature_extractor.h"
#include "scene/feature_io.h"

namespace hscloc {

// The photos under `image_dir` (recursively; .jpg, .jpeg, .png, .bmp, .tif, .tiff, any case) as
// names relative to it with '/' separators, sorted. Throws std::invalid_argument naming the folder
// when it is missing or holds no photo.
std::vector<std::string> ListImages(const std::filesystem::path& image_dir);

// Image names, one per line (relative to the image folder; blank lines skipped). Throws
// std::invalid_argument naming the file when it cannot be read or names no image.
std::vector<std::string> ReadImageList(const std::filesystem::path& list_path);

struct ImageExtractionOptions {
  FeatureExtractorOptions extractor;
  // Threads, each with its own extractor (<= 0: all cores).
  int num_threads = 0;
  // Of descriptors and scores (hloc's default is half precision).
  H5FloatPrecision precision = H5FloatPrecision::kFloat16;
  // A progress bar on stderr.
  bool show_progress = true;
  void Check() const;
};

struct ImageExtractionSummary {
  int64_t num_images = 0;     // asked for
  int64_t num_skipped = 0;    // already in the file
  int64_t num_extracted = 0;  // extracted by this run
  int64_t num_keypoints = 0;  // over the images extracted by this run
  double seconds = 0;
};

// Extracts the features of `image_names` (relative to `image_dir`) into `out_path` (hloc layout,
// image groups named as the images), adding to the file when it exists. The first image that
// cannot be read or yields no keypoint stops the run with std::invalid_argument naming it; the
// images written before it stay in the file, so the next run resumes after them.
ImageExtractionSummary ExtractImagesToH5(const std::filesystem::path& image_dir,
                                         const std::vector<std::string>& image_names,
                                         const std::filesystem::path& out_path,
                                         const ImageExtractionOptions& options);

}  // namespace hscloc
