#include "features/feature_extraction.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>

namespace hscloc {

ExtractedFeatures ExtractSift(const std::string& image_path, int max_keypoints) {
  const cv::Mat image = cv::imread(image_path, cv::IMREAD_GRAYSCALE);
  if (image.empty()) {
    throw std::invalid_argument(fmt::format("cannot read the image {}", image_path));
  }
  cv::Ptr<cv::SIFT> sift = cv::SIFT::create(max_keypoints);
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  sift->detectAndCompute(image, cv::noArray(), keypoints, descriptors);
  ExtractedFeatures features;
  features.width = static_cast<uint32_t>(image.cols);
  features.height = static_cast<uint32_t>(image.rows);
  for (int i = 0; i < descriptors.rows; ++i) {
    // OpenCV puts pixel centres at integers, COLMAP at half-integers.
    features.keypoints_xy.push_back(keypoints[i].pt.x + 0.5f);
    features.keypoints_xy.push_back(keypoints[i].pt.y + 0.5f);
    const float* row = descriptors.ptr<float>(i);
    double l1 = 0;
    for (int j = 0; j < descriptors.cols; ++j) l1 += std::abs(row[j]);
    for (int j = 0; j < descriptors.cols; ++j) {
      // RootSIFT scaled to COLMAP's stored range (unit L2 norm x 512).
      features.descriptors.push_back(
          static_cast<float>(512.0 * std::sqrt(std::abs(row[j]) / std::max(l1, 1e-12))));
    }
  }
  return features;
}

}  // namespace hscloc
