#include "retrieval/vlad.h"

#include <faiss/Clustering.h>
#include <faiss/IndexFlat.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <istream>
#include <ostream>

#include "util/binary_io.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/random.h"

namespace hscloc {
namespace {

using RowMajorMatrixXf = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

constexpr std::array<char, 8> kMagic = {'H', 'S', 'C', 'V', 'L', 'A', 'D', '\0'};
constexpr uint32_t kVersion = 1;

// Bounds on what Read accepts, far beyond any real encoder, so that a corrupt header fails with a
// message instead of an attempt to allocate terabytes.
constexpr int64_t kMaxDescriptorDim = 1 << 16;
constexpr int64_t kMaxVladDim = int64_t{1} << 26;
constexpr int64_t kMaxProjectionSize = int64_t{1} << 30;

// Eigenvalues below this fraction of the largest are rounding noise of a rank-deficient training
// set (duplicate images): their components get a zero row rather than a direction made of noise.
constexpr double kNegligibleEigenvalueRatio = 1e-10;

constexpr uint64_t kStreamCodebookSample = 0x766c6164;  // "vlad"

// The dimension shared by all non-empty images; throws naming the first image that differs.
int CommonDescriptorDim(const std::vector<DescriptorMatrix>& images) {
  int dim = -1;
  size_t first = 0;
  for (size_t i = 0; i < images.size(); ++i) {
    if (images[i].rows() == 0) continue;
    if (dim < 0) {
      dim = static_cast<int>(images[i].cols());
      first = i;
    } else if (images[i].cols() != dim) {
      ThrowInvalidArgument(
          "VLAD training: image {} has descriptors of dimension {} but image {} of dimension {}", i,
          images[i].cols(), first, dim);
    }
  }
  if (dim <= 0) ThrowInvalidArgument("VLAD training: no image has local descriptors");
  return dim;
}

template <typename T>
T ReadChecked(std::istream& stream, const std::string& source, const std::string& field) {
  return ReadBinary<T>(stream, source + ": VLAD encoder " + field);
}

template <typename Matrix>
void ReadMatrix(std::istream& stream, Matrix& matrix, const std::string& source,
                const std::string& field) {
  ReadBinaryArray(stream, matrix.data(), static_cast<size_t>(matrix.size()),
                  source + ": VLAD encoder " + field);
  if (!matrix.allFinite()) {
    ThrowInvalidArgument("{}: VLAD encoder {} holds non-finite values", source, field);
  }
}

}  // namespace

void VladOptions::Check() const {
  THROW_CHECK_MSG(num_words >= 1, "num_words must be >= 1 (got {})", num_words);
  THROW_CHECK_MSG(kmeans_iterations >= 1, "kmeans_iterations must be >= 1 (got {})",
                  kmeans_iterations);
  THROW_CHECK_MSG(max_training_descriptors >= num_words,
                  "max_training_descriptors must be >= num_words (got {} < {})",
                  max_training_descriptors, num_words);
  THROW_CHECK_MSG(whitened_dim >= 0, "whitened_dim must be >= 0 (got {})", whitened_dim);
  THROW_CHECK_MSG(std::isfinite(whitening_regularization) && whitening_regularization >= 0,
                  "whitening_regularization must be finite and >= 0 (got {})",
                  whitening_regularization);
}

VladEncoder VladEncoder::Train(const std::vector<DescriptorMatrix>& images,
                               const VladOptions& options) {
  return Train(
      images, images.size(), [&images](size_t image) { return images[image]; }, options);
}

VladEncoder VladEncoder::Train(const std::vector<DescriptorMatrix>& codebook_images,
                               size_t num_whitening_images, const ImageReader& read_whitening_image,
                               const VladOptions& options) {
  options.Check();
  VladEncoder encoder;
  encoder.options_ = options;
  encoder.TrainCodebook(codebook_images);
  if (options.whitened_dim > 0) encoder.TrainWhitening(num_whitening_images, read_whitening_image);
  return encoder;
}

void VladEncoder::TrainCodebook(const std::vector<DescriptorMatrix>& images) {
  const int dim = CommonDescriptorDim(images);
  int64_t total = 0;
  for (const DescriptorMatrix& image : images) total += image.rows();
  if (total < options_.num_words) {
    ThrowInvalidArgument("VLAD training: {} local descriptors for num_words = {} centroids", total,
                         options_.num_words);
  }

  // Selection sampling (Knuth's Algorithm S): a uniform sample in one pass over all images, in
  // image order, without holding the index list of a city-sized descriptor set.
  const int64_t sample_size = std::min<int64_t>(total, options_.max_training_descriptors);
  RowMajorMatrixXf sample(sample_size, dim);
  Random random(options_.seed, {kStreamCodebookSample});
  int64_t taken = 0;
  int64_t seen = 0;
  for (const DescriptorMatrix& image : images) {
    for (Eigen::Index r = 0; r < image.rows() && taken < sample_size; ++r, ++seen) {
      if (static_cast<double>(total - seen) * random.Uniform() >=
          static_cast<double>(sample_size - taken)) {
        continue;
      }
      const float norm = image.row(r).norm();
      if (!std::isfinite(norm)) {
        ThrowInvalidArgument("VLAD training: a local descriptor of dimension {} is not finite",
                             dim);
      }
      sample.row(taken++) = norm > 0 ? (image.row(r) / norm).eval() : image.row(r);
    }
  }
  sample.conservativeResize(taken, dim);

  faiss::ClusteringParameters params;
  params.niter = options_.kmeans_iterations;
  params.seed = static_cast<int>(MixBits(options_.seed) & 0x7fffffff);
  // The sample size is this encoder's knob: FAISS must neither subsample it again nor warn that
  // it is small (the options already demand one descriptor per centroid).
  params.max_points_per_centroid = static_cast<int>(taken);
  params.min_points_per_centroid = 1;
  faiss::Clustering clustering(dim, options_.num_words, params);
  faiss::IndexFlatL2 assigner(dim);
  clustering.train(taken, sample.data(), assigner);

  centroids_ =
      Eigen::Map<const RowMajorMatrixXf>(clustering.centroids.data(), options_.num_words, dim);
  centroid_half_squared_norms_ = 0.5f * centroids_.rowwise().squaredNorm();
}

RowMajorMatrixXf VladEncoder::UnwhitenedVlads(size_t num_images,
                                              const ImageReader& read_image) const {
  // A batch of images is read, then encoded on every core, then the next is read: only the
  // batch's descriptors and the VLAD vectors are held.
  constexpr size_t kBatchImages = 256;
  RowMajorMatrixXf vlads(static_cast<Eigen::Index>(num_images), centroids_.size());
  Eigen::Index num_nonempty = 0;
  std::vector<DescriptorMatrix> batch;
  for (size_t begin = 0; begin < num_images; begin += kBatchImages) {
    batch.clear();
    for (size_t image = begin; image < std::min(num_images, begin + kBatchImages); ++image) {
      DescriptorMatrix descriptors = read_image(image);
      if (descriptors.rows() > 0) batch.push_back(std::move(descriptors));
    }
    ParallelFor(batch.size(), options_.num_threads, [&](size_t lo, size_t hi) {
      for (size_t i = lo; i < hi; ++i) {
        vlads.row(num_nonempty + static_cast<Eigen::Index>(i)) = EncodeUnwhitened(batch[i]);
      }
    });
    num_nonempty += static_cast<Eigen::Index>(batch.size());
  }
  vlads.conservativeResize(num_nonempty, Eigen::NoChange);
  return vlads;
}

void VladEncoder::TrainWhitening(size_t num_whitening_images, const ImageReader& read_image) {
  RowMajorMatrixXf vlads = UnwhitenedVlads(num_whitening_images, read_image);
  const int64_t num_images = vlads.rows();
  if (num_images < 2) {
    ThrowInvalidArgument(
        "VLAD training: whitening needs at least 2 images with descriptors (got {}); set "
        "whitened_dim = 0",
        num_images);
  }
  const int64_t vlad_dim = centroids_.size();
  pca_mean_ = vlads.colwise().mean().transpose();
  vlads.rowwise() -= pca_mean_.transpose();

  const int64_t out_dim = std::min<int64_t>({options_.whitened_dim, num_images - 1, vlad_dim});
  // Covariance = X^T X / (I - 1) for the centred I x KD matrix X. With fewer images than
  // dimensions, the eigenvectors come from the I x I Gram matrix X X^T instead (same non-zero
  // eigenvalues; eigenvector v = X^T u / sqrt(lambda)), which is what keeps a 16k-dimensional
  // PCA over a few thousand images cheap.
  const bool use_gram = num_images <= vlad_dim;
  Eigen::MatrixXd scatter = use_gram ? (vlads * vlads.transpose()).cast<double>().eval()
                                     : (vlads.transpose() * vlads).cast<double>().eval();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(scatter);
  if (solver.info() != Eigen::Success) {
    ThrowInvalidArgument("VLAD training: the eigen-decomposition for the whitening failed");
  }
  const Eigen::Index n = solver.eigenvalues().size();
  const double largest = std::max(solver.eigenvalues()[n - 1], 0.0);
  const double epsilon = options_.whitening_regularization * largest / (num_images - 1);

  // Row j of the projection maps onto the j-th strongest principal direction, divided by the
  // standard deviation along it (regularized).
  Eigen::MatrixXd basis(out_dim, scatter.rows());
  for (int64_t j = 0; j < out_dim; ++j) {
    const double eigenvalue = solver.eigenvalues()[n - 1 - j];
    if (eigenvalue <= kNegligibleEigenvalueRatio * largest) {
      basis.row(j).setZero();
      continue;
    }
    const double scale = 1.0 / std::sqrt(eigenvalue / (num_images - 1) + epsilon);
    const double to_unit = use_gram ? 1.0 / std::sqrt(eigenvalue) : 1.0;
    basis.row(j) = (scale * to_unit) * solver.eigenvectors().col(n - 1 - j).transpose();
  }
  if (use_gram) {
    projection_ = basis.cast<float>() * vlads;
  } else {
    projection_ = basis.cast<float>();
  }
  // An eigenvector's sign is the solver's choice; fixing it (largest entry positive) makes the
  // encoding the same whichever decomposition or library version produced it.
  for (Eigen::Index j = 0; j < projection_.rows(); ++j) {
    Eigen::Index largest_entry = 0;
    projection_.row(j).cwiseAbs().maxCoeff(&largest_entry);
    if (projection_(j, largest_entry) < 0) projection_.row(j) *= -1.0f;
  }
  half_projection_ =
      vlad_kernels::ToHalfPrecisionRows(projection_.data(), projection_.rows(), projection_.cols());
}

int VladEncoder::descriptor_dim() const { return static_cast<int>(centroids_.cols()); }

int VladEncoder::num_words() const { return static_cast<int>(centroids_.rows()); }

int VladEncoder::output_dim() const {
  return projection_.size() > 0 ? static_cast<int>(projection_.rows())
                                : static_cast<int>(centroids_.size());
}

Eigen::VectorXf VladEncoder::EncodeUnwhitened(const DescriptorMatrix& local_descriptors) const {
  const int dim = descriptor_dim();
  // An image without keypoints may arrive as 0 x 0: it has no dimension to disagree with.
  if (local_descriptors.rows() == 0) return Eigen::VectorXf::Zero(centroids_.size());
  if (local_descriptors.cols() != dim) {
    ThrowInvalidArgument(
        "VLAD: local descriptors have dimension {} but the codebook was trained on dimension {}",
        local_descriptors.cols(), dim);
  }
  // The unit descriptors (a zero one has no direction to contribute), then every one's nearest
  // word in one pass of the kernel.
  RowMajorMatrixXf units(local_descriptors.rows(), dim);
  Eigen::Index num_units = 0;
  for (Eigen::Index r = 0; r < local_descriptors.rows(); ++r) {
    const float norm = local_descriptors.row(r).norm();
    if (!std::isfinite(norm)) ThrowInvalidArgument("VLAD: local descriptor {} is not finite", r);
    if (norm > 0) units.row(num_units++) = local_descriptors.row(r) / norm;
  }
  std::vector<int32_t> words(num_units);
  vlad_kernels::NearestWords(units.data(), num_units, centroids_.data(),
                             centroid_half_squared_norms_.data(), centroids_.rows(), dim,
                             words.data());
  RowMajorMatrixXf residuals = RowMajorMatrixXf::Zero(centroids_.rows(), dim);
  for (Eigen::Index r = 0; r < num_units; ++r) {
    residuals.row(words[r]) += units.row(r) - centroids_.row(words[r]);
  }
  // Intra-normalization (Arandjelovic and Zisserman, "All about VLAD", CVPR 2013) keeps a few
  // bursty words (repeated facades) from dominating the descriptor.
  for (Eigen::Index k = 0; k < residuals.rows(); ++k) {
    const float norm = residuals.row(k).norm();
    if (norm > 0) residuals.row(k) /= norm;
  }
  Eigen::VectorXf vlad = Eigen::Map<const Eigen::VectorXf>(residuals.data(), residuals.size());
  if (options_.power_normalization) {
    vlad = vlad.array().sign() * vlad.array().abs().sqrt();
  }
  const float norm = vlad.norm();
  if (norm > 0) vlad /= norm;
  return vlad;
}

Eigen::VectorXf VladEncoder::Encode(const DescriptorMatrix& local_descriptors,
                                    int num_threads) const {
  Eigen::VectorXf vlad = EncodeUnwhitened(local_descriptors);
  if (projection_.size() == 0) return vlad;
  // Whitening would move the zero vector of an empty image to an arbitrary direction.
  if (vlad.squaredNorm() == 0) return Eigen::VectorXf::Zero(projection_.rows());
  const Eigen::VectorXf centered = vlad - pca_mean_;
  Eigen::VectorXf whitened(projection_.rows());
  // Blocks of rows on the threads: one core alone does not reach the memory's bandwidth.
  constexpr int64_t kRowsPerBlock = 64;
  const int64_t rows = half_projection_.rows;
  ParallelFor((rows + kRowsPerBlock - 1) / kRowsPerBlock, num_threads,
              [&](size_t first, size_t last) {
                const int64_t begin = static_cast<int64_t>(first) * kRowsPerBlock;
                const int64_t end = std::min(rows, static_cast<int64_t>(last) * kRowsPerBlock);
                vlad_kernels::HalfPrecisionRowsTimes(half_projection_, centered.data(), begin, end,
                                                     whitened.data() + begin);
              });
  const float norm = whitened.norm();
  if (norm > 0) whitened /= norm;
  return whitened;
}

void VladEncoder::Write(std::ostream& stream) const {
  WriteBinaryArray(stream, kMagic.data(), kMagic.size());
  WriteBinary(stream, kVersion);
  WriteBinary<int32_t>(stream, options_.num_words);
  WriteBinary<int32_t>(stream, options_.kmeans_iterations);
  WriteBinary<int32_t>(stream, options_.max_training_descriptors);
  WriteBinary<int32_t>(stream, options_.whitened_dim);
  WriteBinary<double>(stream, options_.whitening_regularization);
  WriteBinary<uint8_t>(stream, options_.power_normalization ? 1 : 0);
  WriteBinary<uint64_t>(stream, options_.seed);
  WriteBinary<int32_t>(stream, options_.num_threads);
  WriteBinary<int32_t>(stream, descriptor_dim());
  WriteBinary<int32_t>(stream, static_cast<int32_t>(projection_.rows()));
  WriteBinaryArray(stream, centroids_.data(), static_cast<size_t>(centroids_.size()));
  WriteBinaryArray(stream, pca_mean_.data(), static_cast<size_t>(pca_mean_.size()));
  WriteBinaryArray(stream, projection_.data(), static_cast<size_t>(projection_.size()));
  if (!stream) ThrowInvalidArgument("VLAD encoder: writing failed");
}

VladEncoder VladEncoder::Read(std::istream& stream, const std::string& source) {
  std::array<char, 8> magic{};
  ReadBinaryArray(stream, magic.data(), magic.size(), source + ": VLAD encoder magic");
  if (magic != kMagic) ThrowInvalidArgument("{}: not a VLAD encoder (bad magic)", source);
  const auto version = ReadChecked<uint32_t>(stream, source, "version");
  if (version != kVersion) {
    ThrowInvalidArgument("{}: VLAD encoder version {} is not supported (expected {})", source,
                         version, kVersion);
  }
  VladEncoder encoder;
  VladOptions& options = encoder.options_;
  options.num_words = ReadChecked<int32_t>(stream, source, "num_words");
  options.kmeans_iterations = ReadChecked<int32_t>(stream, source, "kmeans_iterations");
  options.max_training_descriptors =
      ReadChecked<int32_t>(stream, source, "max_training_descriptors");
  options.whitened_dim = ReadChecked<int32_t>(stream, source, "whitened_dim");
  options.whitening_regularization =
      ReadChecked<double>(stream, source, "whitening_regularization");
  options.power_normalization = ReadChecked<uint8_t>(stream, source, "power_normalization") != 0;
  options.seed = ReadChecked<uint64_t>(stream, source, "seed");
  options.num_threads = ReadChecked<int32_t>(stream, source, "num_threads");
  try {
    options.Check();
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: VLAD encoder options: {}", source, error.what());
  }

  const int64_t dim = ReadChecked<int32_t>(stream, source, "descriptor dimension");
  const int64_t out_dim = ReadChecked<int32_t>(stream, source, "output dimension");
  const int64_t vlad_dim = dim * options.num_words;
  if (dim < 1 || dim > kMaxDescriptorDim || vlad_dim > kMaxVladDim) {
    ThrowInvalidArgument("{}: VLAD encoder descriptor dimension {} x {} words is out of range",
                         source, dim, options.num_words);
  }
  if (out_dim < 0 || out_dim > vlad_dim || out_dim > options.whitened_dim ||
      (out_dim > 0) != (options.whitened_dim > 0) || out_dim * vlad_dim > kMaxProjectionSize) {
    ThrowInvalidArgument("{}: VLAD encoder output dimension {} is out of range (whitened_dim {})",
                         source, out_dim, options.whitened_dim);
  }
  encoder.centroids_.resize(options.num_words, dim);
  ReadMatrix(stream, encoder.centroids_, source, "centroids");
  encoder.centroid_half_squared_norms_ = 0.5f * encoder.centroids_.rowwise().squaredNorm();
  if (out_dim > 0) {
    encoder.pca_mean_.resize(vlad_dim);
    ReadMatrix(stream, encoder.pca_mean_, source, "PCA mean");
    encoder.projection_.resize(out_dim, vlad_dim);
    ReadMatrix(stream, encoder.projection_, source, "PCA projection");
    encoder.half_projection_ =
        vlad_kernels::ToHalfPrecisionRows(encoder.projection_.data(), out_dim, vlad_dim);
  }
  return encoder;
}

}  // namespace hscloc
