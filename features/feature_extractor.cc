#include "features/feature_extractor.h"

#include "util/check.h"

namespace hscloc {

FeatureType ParseFeatureType(const std::string& name) {
  if (name == "sift") return FeatureType::kSift;
  if (name == "xfeat") return FeatureType::kXFeat;
  ThrowInvalidArgument("unknown feature '{}' (sift or xfeat)", name);
}

std::string FeatureTypeName(FeatureType type) {
  return type == FeatureType::kSift ? "sift" : "xfeat";
}

void FeatureExtractorOptions::Check() const {
  if (type == FeatureType::kSift) sift.Check();
  if (type == FeatureType::kXFeat) xfeat.Check();
}

std::unique_ptr<FeatureExtractor> CreateFeatureExtractor(const FeatureExtractorOptions& options) {
  options.Check();
  if (options.type == FeatureType::kXFeat) return std::make_unique<XFeatExtractor>(options.xfeat);
  return std::make_unique<SiftExtractor>(options.sift);
}

}  // namespace hscloc
