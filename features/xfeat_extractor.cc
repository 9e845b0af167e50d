#include "features/xfeat_extractor.h"

#include <algorithm>
#include <cstdlib>
#include <opencv2/dnn.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "features/keypoint_detection.h"
#include "util/check.h"

namespace hscloc {
namespace {

constexpr int kInputSize = 640;
constexpr int kCellSize = 8;
constexpr int kCells = kInputSize / kCellSize;
constexpr int kDimension = 64;
// The export names its outputs by graph node: descriptors, keypoint logits, reliability.
const std::vector<std::string> kOutputNames = {"output", "1266", "266"};

void CheckShape(const cv::Mat& blob, const std::vector<int>& expected, const std::string& name,
                const std::string& model_path) {
  const std::vector<int> shape(blob.size.p, blob.size.p + blob.dims);
  if (shape != expected) {
    ThrowInvalidArgument("XFeat model {}: output '{}' has shape {}, expected {}", model_path, name,
                         fmt::join(shape, "x"), fmt::join(expected, "x"));
  }
}

// The photo scaled into the top-left corner of the zero-padded square input, as a 1x3xSxS blob.
cv::Mat NetworkInput(const cv::Mat& image, const Letterbox& letterbox) {
  cv::Mat input = cv::Mat::zeros(kInputSize, kInputSize, image.type());
  const cv::Size scaled(letterbox.scaled_width, letterbox.scaled_height);
  cv::resize(image, input(cv::Rect(cv::Point(0, 0), scaled)), scaled, 0, 0,
             scaled.width < image.cols ? cv::INTER_AREA : cv::INTER_LINEAR);
  return cv::dnn::blobFromImage(input, 1.0 / 255, cv::Size(), cv::Scalar(), /*swapRB=*/true);
}

// Keypoint probability x reliability (upsampled) per input pixel, zero over the padding.
ScoreMap KeypointScores(const cv::Mat& logits, const cv::Mat& reliability_cells,
                        const Letterbox& letterbox) {
  ScoreMap scores = KeypointHeatmap(logits.ptr<float>(), kCells, kCells);
  cv::Mat reliability;
  cv::resize(reliability_cells.reshape(1, std::vector<int>{kCells, kCells}), reliability,
             cv::Size(kInputSize, kInputSize), 0, 0, cv::INTER_LINEAR);
  scores.array() *=
      Eigen::Map<const ScoreMap>(reliability.ptr<float>(), kInputSize, kInputSize).array();
  scores.rightCols(kInputSize - letterbox.scaled_width).setZero();
  scores.bottomRows(kInputSize - letterbox.scaled_height).setZero();
  return scores;
}

// Keypoints in the photo's pixels, their scores, and descriptors sampled at them.
ImageFeatures FeaturesAtPeaks(const std::vector<Peak>& peaks, const cv::Mat& descriptor_map,
                              const Letterbox& letterbox) {
  const auto count = static_cast<Eigen::Index>(peaks.size());
  ImageFeatures features;
  KeypointMatrix in_cells(count, 2);
  features.keypoints.resize(count, 2);
  features.scores.resize(count);
  for (Eigen::Index i = 0; i < count; ++i) {
    const Eigen::Vector2f in_input(peaks[i].x + 0.5f, peaks[i].y + 0.5f);
    in_cells.row(i) = in_input.transpose() / kCellSize;
    features.keypoints.row(i) = letterbox.ToPhoto(in_input).transpose();
    features.scores(i) = peaks[i].score;
  }
  features.descriptors =
      SampleDescriptors(descriptor_map.ptr<float>(), kDimension, kCells, kCells, in_cells);
  return features;
}

}  // namespace

std::string DefaultXFeatModelPath() {
  const char* path = std::getenv("HSCLOC_XFEAT_MODEL");
  return path != nullptr ? path : HSCLOC_DEFAULT_XFEAT_MODEL;
}

void XFeatOptions::Check() const {
  if (model_path.empty()) {
    ThrowInvalidArgument(
        "XFeatOptions.model_path is empty: give the XFeat ONNX file (weights/xfeat/xfeat.onnx of "
        "the shared data, or set HSCLOC_XFEAT_MODEL)");
  }
  if (max_keypoints <= 0) {
    ThrowInvalidArgument("XFeatOptions.max_keypoints must be positive (got {})", max_keypoints);
  }
  if (nms_radius_px < 0) {
    ThrowInvalidArgument("XFeatOptions.nms_radius_px must be >= 0 (got {})", nms_radius_px);
  }
  if (!(score_threshold >= 0 && score_threshold < 1)) {
    ThrowInvalidArgument("XFeatOptions.score_threshold must be in [0, 1) (got {})",
                         score_threshold);
  }
}

struct XFeatExtractor::Network {
  cv::dnn::Net net;
};

XFeatExtractor::XFeatExtractor(const XFeatOptions& options)
    : options_(options), network_(std::make_unique<Network>()) {
  options_.Check();
  const std::string& path = options_.model_path;
  if (!std::filesystem::is_regular_file(path)) {
    ThrowInvalidArgument(
        "XFeat model {} does not exist or is not a file (give --xfeat-model, or set "
        "HSCLOC_XFEAT_MODEL)",
        path);
  }
  try {
    network_->net = cv::dnn::readNetFromONNX(path);
  } catch (const cv::Exception& error) {
    ThrowInvalidArgument("XFeat model {} is not a valid ONNX model: {}", path, error.what());
  }
  if (network_->net.empty()) ThrowInvalidArgument("XFeat model {} holds no network", path);
  const std::vector<std::string> names = network_->net.getUnconnectedOutLayersNames();
  for (const std::string& name : kOutputNames) {
    if (std::find(names.begin(), names.end(), name) == names.end()) {
      ThrowInvalidArgument("XFeat model {} has no output '{}' (outputs: {})", path, name,
                           fmt::join(names, ", "));
    }
  }
}

XFeatExtractor::~XFeatExtractor() = default;

ExtractedFeatures XFeatExtractor::Extract(const std::filesystem::path& image_path) {
  // The network averages the colour channels itself; a grey photo is read as three equal ones.
  const cv::Mat image = cv::imread(image_path.string(), cv::IMREAD_COLOR);
  if (image.empty()) ThrowInvalidArgument("cannot read the image {}", image_path.string());
  const Letterbox letterbox(image.cols, image.rows, kInputSize);
  network_->net.setInput(NetworkInput(image, letterbox));
  std::vector<cv::Mat> outputs;
  try {
    network_->net.forward(outputs, kOutputNames);
  } catch (const cv::Exception& error) {
    ThrowInvalidArgument("XFeat model {} failed on the image {}: {}", options_.model_path,
                         image_path.string(), error.what());
  }
  CheckShape(outputs[0], {1, kDimension, kCells, kCells}, kOutputNames[0], options_.model_path);
  CheckShape(outputs[1], {1, 65, kCells, kCells}, kOutputNames[1], options_.model_path);
  CheckShape(outputs[2], {1, 1, kCells, kCells}, kOutputNames[2], options_.model_path);

  const std::vector<Peak> peaks = NonMaximumSuppression(
      KeypointScores(outputs[1], outputs[2], letterbox), options_.nms_radius_px,
      options_.score_threshold, options_.max_keypoints);
  if (peaks.empty()) {
    ThrowInvalidArgument("XFeat found no keypoint (score > {}) in the image {}",
                         options_.score_threshold, image_path.string());
  }
  ExtractedFeatures extracted;
  extracted.width = image.cols;
  extracted.height = image.rows;
  extracted.features = FeaturesAtPeaks(peaks, outputs[0], letterbox);
  return extracted;
}

}  // namespace hscloc
