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

#include "scene/features.h"

namespace hscloc {

struct VladOptions {
  int num_words = 64;  // k-means codebook size K
  int kmeans_iterations = 25;
  int max_training_descriptors = 100000;  // sample for the codebook
  int whitened_dim = 256;                 // capped by the number of training images - 1; 0: none
  // Whitening scales component i by 1 / sqrt(eigenvalue_i + epsilon) with
  // epsilon = whitening_regularization * (largest eigenvalue): without it the weakest components,
  // estimated from few images, are mostly noise and would be amplified as much as the strongest.
  double whitening_regularization = 0.1;
  bool power_normalization = true;  // signed square root after intra-normalization
  uint64_t seed = 0;                // codebook sample and k-means initialization
  int num_threads = 0;              // encoding the training images; <= 0: all cores
  // Throws std::invalid_argument naming the first field out of range.
  void Check() const;
};

class VladEncoder {
 public:
  // Learns the codebook from local descriptors (rows; L2-normalized internally) sampled from
  // `images` (each image's descriptors), then the PCA whitening from the images' VLAD vectors.
  // Images without descriptors take no part in the whitening. The same images, options and seed
  // give the same encoder, byte for byte. Throws when the images disagree on the descriptor
  // dimension, hold fewer descriptors than num_words, or (whitening on) fewer than two of them
  // have descriptors.
  static VladEncoder Train(const std::vector<DescriptorMatrix>& images, const VladOptions& options);

  int descriptor_dim() const;  // D of the local descriptors
  int num_words() const;
  int output_dim() const;  // whitened dimension, or num_words * D without whitening

  // The global descriptor of one image (unit length). Throws when the descriptor dimension differs
  // from the codebook's or a descriptor is not finite. An image without descriptors (zero rows, of
  // any column count) gives the zero vector. Thread-safe.
  Eigen::VectorXf Encode(const DescriptorMatrix& local_descriptors) const;

  const VladOptions& options() const { return options_; }

  // Binary, little-endian, versioned. Read validates what it reads and names `source` (a file
  // name or a description) in every error.
  void Write(std::ostream& stream) const;
  static VladEncoder Read(std::istream& stream, const std::string& source);

 private:
  // The normalized VLAD vector (K*D) before whitening; zero for an image without descriptors.
  Eigen::VectorXf EncodeUnwhitened(const DescriptorMatrix& local_descriptors) const;
  void TrainCodebook(const std::vector<DescriptorMatrix>& images);
  void TrainWhitening(const std::vector<DescriptorMatrix>& images);

  VladOptions options_;
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> centroids_;  // K x D
  Eigen::VectorXf centroid_half_squared_norms_;  // K; nearest centroid = argmax c.x - |c|^2 / 2
  // Whitening (both empty when off): y = projection_ * (vlad - pca_mean_), then L2.
  Eigen::VectorXf pca_mean_;                                                          // K*D
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> projection_;  // out x K*D
};

}  // namespace hscloc
