// The common interface of local feature extractors and what they return.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "scene/features.h"

namespace hscloc {

// The features of one photo: keypoints in pixels of the photo (COLMAP convention, the centre of
// the top-left pixel at (0.5, 0.5)), a detection score per keypoint (higher is better), and one
// unit-L2-norm descriptor per keypoint.
struct ExtractedFeatures {
  ImageFeatures features;
  int64_t width = 0;   // of the photo, pixels
  int64_t height = 0;  // of the photo, pixels
};

class FeatureExtractor {
 public:
  virtual ~FeatureExtractor() = default;
  // Throws std::invalid_argument naming the file when it cannot be read as an image, or when it
  // yields no keypoint (a map or a query needs at least one).
  virtual ExtractedFeatures Extract(const std::filesystem::path& image_path) = 0;
  // "sift" or "xfeat".
  virtual std::string Name() const = 0;
  // The descriptor dimension (128 for SIFT, 64 for XFeat).
  virtual int Dimension() const = 0;
};

}  // namespace hscloc
