// Local features of a photo for a query: OpenCV's SIFT, normalized as COLMAP's extractor does
// (RootSIFT: L1-normalize, square root), so that they match maps built from COLMAP databases.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace hscloc {

struct ExtractedFeatures {
  uint32_t width = 0;
  uint32_t height = 0;
  std::vector<float> keypoints_xy;  // N x 2, pixels, centre of the top-left pixel at (0.5, 0.5)
  std::vector<float> descriptors;   // N x 128
};

// Throws std::invalid_argument when the image cannot be read.
ExtractedFeatures ExtractSift(const std::string& image_path, int max_keypoints = 4096);

}  // namespace hscloc
