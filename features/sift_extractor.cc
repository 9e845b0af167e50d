#include "features/sift_extractor.h"

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "util/check.h"

namespace hscloc {

void SiftOptions::Check() const {
  if (max_keypoints <= 0) {
    ThrowInvalidArgument("SiftOptions.max_keypoints must be positive (got {})", max_keypoints);
  }
}

SiftExtractor::SiftExtractor(const SiftOptions& options) : options_(options) { options_.Check(); }

ExtractedFeatures SiftExtractor::Extract(const std::filesystem::path& image_path) {
  const cv::Mat image = cv::imread(image_path.string(), cv::IMREAD_GRAYSCALE);
  if (image.empty()) ThrowInvalidArgument("cannot read the image {}", image_path.string());
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  cv::SIFT::create(options_.max_keypoints)
      ->detectAndCompute(image, cv::noArray(), keypoints, descriptors);
  if (descriptors.rows == 0) {
    ThrowInvalidArgument("SIFT found no keypoint in the image {}", image_path.string());
  }
  ExtractedFeatures extracted;
  extracted.width = image.cols;
  extracted.height = image.rows;
  ImageFeatures& features = extracted.features;
  features.keypoints.resize(descriptors.rows, 2);
  features.descriptors.resize(descriptors.rows, descriptors.cols);
  features.scores.resize(descriptors.rows);
  for (int i = 0; i < descriptors.rows; ++i) {
    // OpenCV puts pixel centres at integers, COLMAP at half-integers.
    features.keypoints(i, 0) = keypoints[i].pt.x + 0.5f;
    features.keypoints(i, 1) = keypoints[i].pt.y + 0.5f;
    features.scores(i) = keypoints[i].response;
    const float* row = descriptors.ptr<float>(i);
    double l1 = 0;
    for (int j = 0; j < descriptors.cols; ++j) l1 += std::abs(row[j]);
    // RootSIFT: the square roots of an L1-normalized vector have unit L2 norm.
    for (int j = 0; j < descriptors.cols; ++j) {
      features.descriptors(i, j) =
          static_cast<float>(std::sqrt(std::abs(row[j]) / std::max(l1, 1e-12)));
    }
  }
  return extracted;
}

}  // namespace hscloc
