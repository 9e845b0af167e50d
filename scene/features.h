// Local and global features of images, in memory.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "util/types.h"

namespace hscloc {

using KeypointMatrix = Eigen::Matrix<float, Eigen::Dynamic, 2, Eigen::RowMajor>;
using DescriptorMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// Scales every row to unit L2 norm (zero rows stay zero), so that dot products are cosines.
void NormalizeRows(DescriptorMatrix& rows);
DescriptorMatrix UnitRows(DescriptorMatrix rows);

// The local features of one image: N keypoints in pixels (COLMAP convention, the centre of the
// top-left pixel at (0.5, 0.5)) and N descriptors of dimension D, one per row.
struct ImageFeatures {
  KeypointMatrix keypoints;
  DescriptorMatrix descriptors;
  Eigen::VectorXf scores;  // detection scores, N or empty

  int64_t NumKeypoints() const { return keypoints.rows(); }
  int64_t Dimension() const { return descriptors.cols(); }
};

// Observations of a map: one row per (image, keypoint) that sees a 3D point, with the keypoint's
// descriptor. The training set of the network and the input of the retrieval codebook.
struct Observations {
  std::vector<image_t> image_ids;
  std::vector<point2D_t> keypoint_indices;
  std::vector<point3D_t> point3D_ids;
  DescriptorMatrix descriptors;  // one row per observation

  size_t size() const { return image_ids.size(); }
  int64_t Dimension() const { return descriptors.cols(); }
};

}  // namespace hscloc
