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
constexpr int kBins = kCellSize * kCellSize + 1;
// Neighbouring tiles share at least this much, so that a cell's outputs come from a tile where it
// lies at least half of it from the tile's border (or at the photo's own border).
constexpr int kTileOverlap = 128;
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

// The network's outputs over the whole scaled photo, one value per 8 x 8 cell, channel-major:
// each cell's from the tile that gives it the most context.
struct CellMaps {
  CellMaps(int cells_x, int cells_y)
      : cells_x(cells_x),
        cells_y(cells_y),
        descriptors(static_cast<size_t>(kDimension) * cells_x * cells_y),
        logits(static_cast<size_t>(kBins) * cells_x * cells_y),
        reliability(static_cast<size_t>(cells_x) * cells_y) {}
  int cells_x;
  int cells_y;
  std::vector<float> descriptors;  // kDimension x cells_y x cells_x
  std::vector<float> logits;       // kBins x cells_y x cells_x
  std::vector<float> reliability;  // cells_y x cells_x
};

// Cells [begin, end) along an axis of the canvas.
struct CellRange {
  int begin = 0;
  int end = 0;
};

// For each tile along an axis, the cells that take their outputs from it: those nearest to its
// centre, one contiguous range per tile since the tiles are in order.
std::vector<CellRange> OwnedCells(const std::vector<int>& origins, int cells) {
  std::vector<CellRange> owned(origins.size());
  for (int c = 0; c < cells; ++c) {
    CellRange& range = owned[NearestTile(origins, kInputSize, (c + 0.5f) * kCellSize)];
    if (range.begin == range.end) range.begin = c;
    range.end = c + 1;
  }
  return owned;
}

// Copies the cells `columns` x `rows` (canvas cells) of `tile_output` (channels x kCells x kCells,
// the tile at canvas pixel origin_x, origin_y) into `canvas` (channels x cells_y x cells_x).
void CopyOwnedCells(const cv::Mat& tile_output, int channels, int origin_x, int origin_y,
                    CellRange columns, CellRange rows, int cells_x, int cells_y, float* canvas) {
  const float* tile = tile_output.ptr<float>();
  const int tile_cx = origin_x / kCellSize, tile_cy = origin_y / kCellSize;
  for (int channel = 0; channel < channels; ++channel) {
    for (int cy = rows.begin; cy < rows.end; ++cy) {
      const float* from = tile + (static_cast<int64_t>(channel) * kCells + cy - tile_cy) * kCells +
                          (columns.begin - tile_cx);
      float* to = canvas + (static_cast<int64_t>(channel) * cells_y + cy) * cells_x;
      std::copy(from, from + (columns.end - columns.begin), to + columns.begin);
    }
  }
}

// Keypoint probability x reliability (upsampled) per canvas pixel, zero beyond the scaled photo.
ScoreMap KeypointScores(const CellMaps& maps, const Letterbox& letterbox) {
  ScoreMap scores = KeypointHeatmap(maps.logits.data(), maps.cells_y, maps.cells_x);
  const int width = maps.cells_x * kCellSize, height = maps.cells_y * kCellSize;
  cv::Mat reliability;
  cv::resize(
      cv::Mat(maps.cells_y, maps.cells_x, CV_32F, const_cast<float*>(maps.reliability.data())),
      reliability, cv::Size(width, height), 0, 0, cv::INTER_LINEAR);
  scores.array() *= Eigen::Map<const ScoreMap>(reliability.ptr<float>(), height, width).array();
  scores.rightCols(width - letterbox.scaled_width).setZero();
  scores.bottomRows(height - letterbox.scaled_height).setZero();
  return scores;
}

// Keypoints in the photo's pixels, their scores, and descriptors sampled at them.
ImageFeatures FeaturesAtPeaks(const std::vector<Peak>& peaks, const CellMaps& maps,
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
      SampleDescriptors(maps.descriptors.data(), kDimension, maps.cells_y, maps.cells_x, in_cells);
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
        "XFeatOptions.model_path is empty: give the XFeat ONNX file (data/weights/xfeat/xfeat.onnx "
        "of the repository, or set HSCLOC_XFEAT_MODEL)");
  }
  if (max_keypoints <= 0) {
    ThrowInvalidArgument("XFeatOptions.max_keypoints must be positive (got {})", max_keypoints);
  }
  if (max_side_px <= 0) {
    ThrowInvalidArgument("XFeatOptions.max_side_px must be positive (got {})", max_side_px);
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

namespace {

// The photo scaled as `letterbox` says, padded to whole cells and to at least the network's input,
// and covered by overlapping tiles of the network's input, each one forward pass.
CellMaps RunOnTiles(cv::dnn::Net& net, const std::string& model_path, const cv::Mat& image,
                    const Letterbox& letterbox, const std::string& image_name) {
  const auto canvas_side = [](int scaled) {
    return std::max(kInputSize, (scaled + kCellSize - 1) / kCellSize * kCellSize);
  };
  cv::Mat canvas = cv::Mat::zeros(canvas_side(letterbox.scaled_height),
                                  canvas_side(letterbox.scaled_width), image.type());
  const cv::Size scaled(letterbox.scaled_width, letterbox.scaled_height);
  cv::resize(image, canvas(cv::Rect(cv::Point(0, 0), scaled)), scaled, 0, 0,
             scaled.width < image.cols ? cv::INTER_AREA : cv::INTER_LINEAR);

  CellMaps maps(canvas.cols / kCellSize, canvas.rows / kCellSize);
  const std::vector<int> origins_x = TileOrigins(canvas.cols, kInputSize, kTileOverlap, kCellSize);
  const std::vector<int> origins_y = TileOrigins(canvas.rows, kInputSize, kTileOverlap, kCellSize);
  const std::vector<CellRange> owned_columns = OwnedCells(origins_x, maps.cells_x);
  const std::vector<CellRange> owned_rows = OwnedCells(origins_y, maps.cells_y);
  for (size_t ty = 0; ty < origins_y.size(); ++ty) {
    for (size_t tx = 0; tx < origins_x.size(); ++tx) {
      const cv::Rect tile(origins_x[tx], origins_y[ty], kInputSize, kInputSize);
      net.setInput(cv::dnn::blobFromImage(canvas(tile), 1.0 / 255, cv::Size(), cv::Scalar(),
                                          /*swapRB=*/true));
      std::vector<cv::Mat> outputs;
      try {
        net.forward(outputs, kOutputNames);
      } catch (const cv::Exception& error) {
        ThrowInvalidArgument("XFeat model {} failed on the image {}: {}", model_path, image_name,
                             error.what());
      }
      CheckShape(outputs[0], {1, kDimension, kCells, kCells}, kOutputNames[0], model_path);
      CheckShape(outputs[1], {1, kBins, kCells, kCells}, kOutputNames[1], model_path);
      CheckShape(outputs[2], {1, 1, kCells, kCells}, kOutputNames[2], model_path);
      const auto copy = [&](const cv::Mat& output, int channels, std::vector<float>* into) {
        CopyOwnedCells(output, channels, tile.x, tile.y, owned_columns[tx], owned_rows[ty],
                       maps.cells_x, maps.cells_y, into->data());
      };
      copy(outputs[0], kDimension, &maps.descriptors);
      copy(outputs[1], kBins, &maps.logits);
      copy(outputs[2], 1, &maps.reliability);
    }
  }
  return maps;
}

}  // namespace

ExtractedFeatures XFeatExtractor::Extract(const std::filesystem::path& image_path) {
  // The network averages the colour channels itself; a grey photo is read as three equal ones.
  const cv::Mat image = cv::imread(image_path.string(), cv::IMREAD_COLOR);
  if (image.empty()) ThrowInvalidArgument("cannot read the image {}", image_path.string());
  const Letterbox letterbox(image.cols, image.rows,
                            std::min(options_.max_side_px, std::max(image.cols, image.rows)));
  const CellMaps maps =
      RunOnTiles(network_->net, options_.model_path, image, letterbox, image_path.string());
  const std::vector<Peak> peaks =
      NonMaximumSuppression(KeypointScores(maps, letterbox), options_.nms_radius_px,
                            options_.score_threshold, options_.max_keypoints);
  if (peaks.empty()) {
    ThrowInvalidArgument("XFeat found no keypoint (score > {}) in the image {}",
                         options_.score_threshold, image_path.string());
  }
  ExtractedFeatures extracted;
  extracted.width = image.cols;
  extracted.height = image.rows;
  extracted.features = FeaturesAtPeaks(peaks, maps, letterbox);
  return extracted;
}

}  // namespace hscloc
