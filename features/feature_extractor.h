// Local features of a photo behind one interface, so that maps and queries can be made with any of
// them: OpenCV SIFT (RootSIFT, as COLMAP stores it) or XFeat (Potje et al., "XFeat: Accelerated
// Features for Lightweight Image Matching", CVPR 2024) through OpenCV DNN.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "features/extracted_features.h"
#include "features/sift_extractor.h"
#include "features/xfeat_extractor.h"
#include "scene/features.h"

namespace hscloc {

enum class FeatureType { kSift, kXFeat };

// "sift" or "xfeat"; throws std::invalid_argument naming the value otherwise.
FeatureType ParseFeatureType(const std::string& name);
std::string FeatureTypeName(FeatureType type);

struct FeatureExtractorOptions {
  FeatureType type = FeatureType::kSift;
  SiftOptions sift;
  XFeatOptions xfeat;
  void Check() const;
};

// Builds the extractor `options.type` names (XFeat loads its model here). One extractor serves one
// thread at a time: OpenCV DNN networks are not thread-safe, so give each thread its own.
std::unique_ptr<FeatureExtractor> CreateFeatureExtractor(const FeatureExtractorOptions& options);

}  // namespace hscloc
