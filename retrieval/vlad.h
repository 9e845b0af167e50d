// A NetVLAD-style global image descriptor computed from local descriptors (Arandjelovic et al.,
// "NetVLAD", CVPR 2016; Jegou et al., "Aggregating local descriptors", CVPR 2010):
// hard-assignment VLAD over a k-means codebook, intra-normalization, signed square-root (power)
// normalization, L2 normalization, then PCA whitening to a chosen dimension and L2 again. The same
// encoder serves database and query images.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "model/features.h"

namespace hscloc {

struct VladOptions {
  int num_words = 64;
  int kmeans_iterations = 25;
  int max_training_descriptors = 100000;  // sample for the codebook
  int whitened_dim = 256;                 // capped by the number of training images - 1; 0: none
  bool power_normalization = true;
  uint64_t seed = 0;
  int num_threads = 0;
  void Check() const;
};

class VladEncoder {
 public:
  // Learns the codebook from local descriptors (rows; L2-normalized internally) sampled from
  // `images` (each image's descriptors), then the PCA whitening from the images' VLAD vectors.
  static VladEncoder Train(const std::vector<DescriptorMatrix>& images, const VladOptions& options);

  int descriptor_dim() const;  // D of the local descriptors
  int num_words() const;
  int output_dim() const;      // whitened dimension, or num_words * D without whitening

  // The global descriptor of one image (unit length). Throws when the descriptor dimension differs
  // from the codebook's. An image without descriptors gives the zero vector.
  Eigen::VectorXf Encode(const DescriptorMatrix& local_descriptors) const;

  void Write(std::ostream& stream) const;
  static VladEncoder Read(std::istream& stream, const std::string& source);

 private:
  Eigen::VectorXf EncodeUnwhitened(const DescriptorMatrix& local_descriptors) const;

  VladOptions options_;
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> centroids_;  // K x D
  Eigen::VectorXf pca_mean_;                                                        // K*D
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> projection_;  // out x K*D
};

}  // namespace hscloc
