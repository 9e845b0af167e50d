// A NetVLAD-style global image descriptor computed from local descriptors (Arandjelovic et al.,
// "NetVLAD", CVPR 2016; Jegou et al., "Aggregating local descriptors", CVPR 2010):
// hard-assignment VLAD over a k-means codebook, intra-normalization, signed square-root (power)
// normalization, L2 normalization, then PCA whitening to a chosen dimension and L2 again. The same
// encoder serves database and query images.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <iosfwd>
#include <string>
#include <vector>

#include "retrieval/vlad_kernels.h"
#include "scene/features.h"

namespace hscloc {

struct VladOptions {
  int num_words = 64;  // k-means codebook size K
  int kmeans_iterations = 25;
  int max_training_descriptors = 100000;  // sample for the codebook
  // Capped by the number of whitening images - 1; 0: none. A city's database needs the
  // dimensions: on a 4,356-image synthetic Aachen, 256 of them placed a right image among the
  // first 10 for 41 of 60 night queries, 2,048 for 56 (docs/decisions.md, "How many dimensions the
  // global descriptor keeps").
  int whitened_dim = 2048;
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
  // Reads one image's local descriptors; called from one thread at a time, in index order.
  using ImageReader = std::function<DescriptorMatrix(size_t image)>;
  // The codebook from `codebook_images` as above, the whitening from the VLAD vectors of
  // `num_whitening_images` images read one at a time: a whitening of thousands of dimensions
  // needs more images than their descriptors would fit in memory at once.
  static VladEncoder Train(const std::vector<DescriptorMatrix>& codebook_images,
                           size_t num_whitening_images, const ImageReader& read_whitening_image,
                           const VladOptions& options);

  int descriptor_dim() const;  // D of the local descriptors
  int num_words() const;
  int output_dim() const;  // whitened dimension, or num_words * D without whitening

  // The global descriptor of one image (unit length). Throws when the descriptor dimension differs
  // from the codebook's or a descriptor is not finite. An image without descriptors (zero rows, of
  // any column count) gives the zero vector. Thread-safe; the whitening runs on up to
  // `num_threads` threads (<= 0: all cores), the same result on any number.
  Eigen::VectorXf Encode(const DescriptorMatrix& local_descriptors, int num_threads = 1) const;

  const VladOptions& options() const { return options_; }

  // Binary, little-endian, versioned. Read validates what it reads and names `source` (a file
  // name or a description) in every error.
  void Write(std::ostream& stream) const;
  static VladEncoder Read(std::istream& stream, const std::string& source);

 private:
  // The normalized VLAD vector (K*D) before whitening; zero for an image without descriptors.
  Eigen::VectorXf EncodeUnwhitened(const DescriptorMatrix& local_descriptors) const;
  void TrainCodebook(const std::vector<DescriptorMatrix>& images);
  // One row per image with descriptors among the `num_images` that `read_image` gives.
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> UnwhitenedVlads(
      size_t num_images, const ImageReader& read_image) const;
  void TrainWhitening(size_t num_images, const ImageReader& read_image);

  VladOptions options_;
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> centroids_;  // K x D
  Eigen::VectorXf centroid_half_squared_norms_;  // K; nearest centroid = argmax c.x - |c|^2 / 2
  // Whitening (both empty when off): y = projection_ * (vlad - pca_mean_), then L2.
  Eigen::VectorXf pca_mean_;                                                          // K*D
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> projection_;  // out x K*D
  // The projection Encode reads, in half precision (vlad_kernels.h); projection_ is what Write
  // saves, so that a map read and written again keeps its bits.
  vlad_kernels::HalfPrecisionRows half_projection_;
};

}  // namespace hscloc
