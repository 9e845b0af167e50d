// XFeat (Potje et al., "XFeat: Accelerated Features for Lightweight Image Matching", CVPR 2024)
// from its ONNX export through OpenCV DNN: 64-D descriptors, SuperPoint-style keypoints. The
// network has a fixed 640 x 640 input: a photo is scaled with its aspect kept to at most
// max_side_px, padded, and covered by overlapping 640 x 640 tiles (each cell's outputs come from
// the tile where it is most central); keypoints are mapped back to the photo's pixels exactly.
#pragma once

#include <memory>
#include <string>

#include "features/extracted_features.h"

namespace hscloc {

// The model file used when none is given: $HSCLOC_XFEAT_MODEL when set, else the one the
// repository ships, data/weights/xfeat/xfeat.onnx of the source tree the program was built from.
std::string DefaultXFeatModelPath();

struct XFeatOptions {
  // The ONNX export (input `input` 1x3x640x640; outputs `output`, `1266`, `266`).
  std::string model_path = DefaultXFeatModelPath();
  // The longer side of the photo as the network sees it: larger photos are scaled down to it,
  // smaller ones are kept as they are (hloc's resize_max for SuperPoint on Aachen is 1024). 640,
  // the network's input, runs one pass per photo; 1024 runs four on a 4:3 photo.
  int max_side_px = 1024;
  // The best keypoints kept (top-K by score; the paper's 2048).
  int max_keypoints = 2048;
  // Non-maximum suppression window half-size, in network input pixels (SuperPoint's 4).
  int nms_radius_px = 4;
  // Smallest score (keypoint probability x reliability, in [0, 1]) of a keypoint.
  float score_threshold = 0.005f;
  void Check() const;
};

class XFeatExtractor : public FeatureExtractor {
 public:
  // Loads the model; throws std::invalid_argument naming the file when it is missing or is not
  // an XFeat ONNX model.
  explicit XFeatExtractor(const XFeatOptions& options);
  ~XFeatExtractor() override;
  ExtractedFeatures Extract(const std::filesystem::path& image_path) override;
  std::string Name() const override { return "xfeat"; }
  int Dimension() const override { return 64; }

 private:
  struct Network;
  XFeatOptions options_;
  std::unique_ptr<Network> network_;
};

}  // namespace hscloc
