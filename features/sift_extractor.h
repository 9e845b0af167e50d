// OpenCV's SIFT, normalized as COLMAP's extractor does (RootSIFT: L1-normalize, square root), so
// that its descriptors match maps built from COLMAP databases.
#pragma once

#include "features/extracted_features.h"

namespace hscloc {

struct SiftOptions {
  // The strongest keypoints kept (OpenCV's nfeatures).
  int max_keypoints = 4096;
  void Check() const;
};

class SiftExtractor : public FeatureExtractor {
 public:
  explicit SiftExtractor(const SiftOptions& options);
  ExtractedFeatures Extract(const std::filesystem::path& image_path) override;
  std::string Name() const override { return "sift"; }
  int Dimension() const override { return 128; }

 private:
  SiftOptions options_;
};

}  // namespace hscloc
