#include "retrieval/global_index.h"

#include <faiss/IndexFlat.h>
#include <faiss/IndexIVFPQ.h>
#include <faiss/impl/io.h>
#include <faiss/index_io.h>

#include <algorithm>
#include <array>
#include <istream>
#include <limits>
#include <numeric>
#include <ostream>

#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

using RowMajorMatrixXf = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

constexpr std::array<char, 8> kMagic = {'H', 'S', 'C', 'G', 'I', 'D', 'X', '\0'};
constexpr uint32_t kVersion = 1;

// FAISS's rule of thumb: k-means wants about 39 training points per centroid.
constexpr int64_t kMinTrainingPointsPerList = 39;
// 8-bit product quantizer codes: each sub-quantizer is a k-means with 256 centroids.
constexpr int kPqBitsPerCode = 8;
constexpr int64_t kPqCentroids = int64_t{1} << kPqBitsPerCode;

// Read copies the serialized FAISS index in chunks so that a corrupt length fails on the short
// read instead of allocating the claimed size up front.
constexpr uint64_t kReadChunkBytes = uint64_t{1} << 24;

int TypeCode(GlobalIndexOptions::Type type) {
  return type == GlobalIndexOptions::Type::kFlat ? 0 : 1;
}

// The flat index's search as one matrix-vector product over its stored rows, then the best
// `count`: FAISS's own search of a single query takes an inner product per row in a loop, about
// four times slower at 2,048 dimensions (bench/retrieval_benchmark.cc). Equal scores rank by image
// index, lower first (FAISS's heap returned them in no stated order).
std::vector<RetrievalHit> SearchFlat(const faiss::IndexFlatIP& flat, const Eigen::VectorXf& query,
                                     int64_t count) {
  const Eigen::Map<const RowMajorMatrixXf> database(flat.get_xb(), flat.ntotal, flat.d);
  const Eigen::VectorXf scores = database * query;
  std::vector<uint32_t> order(static_cast<size_t>(flat.ntotal));
  std::iota(order.begin(), order.end(), 0u);
  const auto better = [&](uint32_t a, uint32_t b) {
    return scores[a] != scores[b] ? scores[a] > scores[b] : a < b;
  };
  std::partial_sort(order.begin(), order.begin() + count, order.end(), better);
  std::vector<RetrievalHit> hits;
  hits.reserve(static_cast<size_t>(count));
  for (int64_t i = 0; i < count; ++i) hits.push_back({order[i], scores[order[i]]});
  return hits;
}

}  // namespace

void GlobalIndexOptions::Check() const {
  THROW_CHECK_MSG(type == Type::kFlat || type == Type::kIvfPq, "type must be kFlat or kIvfPq");
  THROW_CHECK_MSG(ivf_lists >= 1, "ivf_lists must be >= 1 (got {})", ivf_lists);
  THROW_CHECK_MSG(pq_subquantizers >= 1, "pq_subquantizers must be >= 1 (got {})",
                  pq_subquantizers);
  THROW_CHECK_MSG(nprobe >= 1, "nprobe must be >= 1 (got {})", nprobe);
}

struct GlobalIndex::Impl {
  GlobalIndexOptions options;
  std::unique_ptr<faiss::Index> index;  // null in an empty GlobalIndex
};

GlobalIndex::GlobalIndex() : impl_(std::make_unique<Impl>()) {}
GlobalIndex::~GlobalIndex() = default;
GlobalIndex::GlobalIndex(GlobalIndex&&) noexcept = default;
GlobalIndex& GlobalIndex::operator=(GlobalIndex&&) noexcept = default;

GlobalIndex GlobalIndex::Build(const RowMajorMatrixXf& descriptors,
                               const GlobalIndexOptions& options) {
  options.Check();
  const int64_t num_images = descriptors.rows();
  const int64_t dim = descriptors.cols();
  if (dim < 1) ThrowInvalidArgument("global index: descriptors have dimension 0");
  if (num_images > std::numeric_limits<uint32_t>::max()) {
    ThrowInvalidArgument("global index: {} images exceed the 32-bit image index", num_images);
  }
  if (!descriptors.allFinite()) {
    ThrowInvalidArgument("global index: database descriptors hold non-finite values");
  }

  GlobalIndex result;
  result.impl_->options = options;
  if (options.type == GlobalIndexOptions::Type::kFlat) {
    result.impl_->index = std::make_unique<faiss::IndexFlatIP>(dim);
  } else {
    if (dim % options.pq_subquantizers != 0) {
      ThrowInvalidArgument(
          "global index: pq_subquantizers = {} does not divide the descriptor dimension {}",
          options.pq_subquantizers, dim);
    }
    if (num_images < kPqCentroids) {
      ThrowInvalidArgument(
          "global index: IVF-PQ needs at least {} database images to train its product "
          "quantizer (got {}); use the flat index",
          kPqCentroids, num_images);
    }
    const int64_t lists =
        std::clamp<int64_t>(num_images / kMinTrainingPointsPerList, 1, options.ivf_lists);
    auto quantizer = std::make_unique<faiss::IndexFlatIP>(dim);
    auto ivf =
        std::make_unique<faiss::IndexIVFPQ>(quantizer.get(), dim, lists, options.pq_subquantizers,
                                            kPqBitsPerCode, faiss::METRIC_INNER_PRODUCT);
    quantizer.release();
    ivf->own_fields = true;
    // Unit vectors compared by inner product: the coarse centroids belong on the sphere too.
    ivf->cp.spherical = true;
    // Build already refuses fewer images than PQ centroids; between that and FAISS's 39 points
    // per centroid the codebook is merely coarser, and a library must not print to stderr.
    ivf->pq.cp.min_points_per_centroid = 1;
    ivf->nprobe = std::min<int64_t>(options.nprobe, lists);
    ivf->train(num_images, descriptors.data());
    result.impl_->index = std::move(ivf);
  }
  result.impl_->index->add(num_images, descriptors.data());
  return result;
}

int GlobalIndex::dimension() const {
  return impl_ && impl_->index ? static_cast<int>(impl_->index->d) : 0;
}

size_t GlobalIndex::size() const {
  return impl_ && impl_->index ? static_cast<size_t>(impl_->index->ntotal) : 0;
}

const GlobalIndexOptions& GlobalIndex::options() const { return impl_->options; }

std::vector<RetrievalHit> GlobalIndex::Search(const Eigen::VectorXf& query, int k) const {
  if (query.size() != dimension()) {
    ThrowInvalidArgument("global index: query dimension {} differs from the index dimension {}",
                         query.size(), dimension());
  }
  if (!query.allFinite()) ThrowInvalidArgument("global index: the query holds non-finite values");
  if (k < 0) ThrowInvalidArgument("global index: k must be >= 0 (got {})", k);
  const int64_t count = std::min<int64_t>(k, static_cast<int64_t>(size()));
  if (count == 0) return {};

  if (const auto* flat = dynamic_cast<const faiss::IndexFlatIP*>(impl_->index.get())) {
    return SearchFlat(*flat, query, count);
  }
  std::vector<float> scores(count);
  std::vector<faiss::Index::idx_t> labels(count);
  impl_->index->search(1, query.data(), count, scores.data(), labels.data());
  std::vector<RetrievalHit> hits;
  hits.reserve(count);
  for (int64_t i = 0; i < count; ++i) {
    // FAISS pads with -1 when the probed IVF cells hold fewer than k vectors.
    if (labels[i] < 0) break;
    hits.push_back({static_cast<uint32_t>(labels[i]), scores[i]});
  }
  return hits;
}

void GlobalIndex::Write(std::ostream& stream) const {
  if (!impl_ || !impl_->index) ThrowInvalidArgument("global index: writing an empty index");
  faiss::VectorIOWriter writer;
  faiss::write_index(impl_->index.get(), &writer);
  const GlobalIndexOptions& options = impl_->options;
  WriteBinaryArray(stream, kMagic.data(), kMagic.size());
  WriteBinary(stream, kVersion);
  WriteBinary<int32_t>(stream, TypeCode(options.type));
  WriteBinary<int32_t>(stream, options.ivf_lists);
  WriteBinary<int32_t>(stream, options.pq_subquantizers);
  WriteBinary<int32_t>(stream, options.nprobe);
  WriteBinary<int32_t>(stream, dimension());
  WriteBinary<uint64_t>(stream, size());
  WriteBinary<uint64_t>(stream, writer.data.size());
  WriteBinaryArray(stream, writer.data.data(), writer.data.size());
  if (!stream) ThrowInvalidArgument("global index: writing failed");
}

GlobalIndex GlobalIndex::Read(std::istream& stream, const std::string& source) {
  const auto what = [&source](const char* field) { return source + ": global index " + field; };
  std::array<char, 8> magic{};
  ReadBinaryArray(stream, magic.data(), magic.size(), what("magic"));
  if (magic != kMagic) ThrowInvalidArgument("{}: not a global index (bad magic)", source);
  const auto version = ReadBinary<uint32_t>(stream, what("version"));
  if (version != kVersion) {
    ThrowInvalidArgument("{}: global index version {} is not supported (expected {})", source,
                         version, kVersion);
  }
  GlobalIndexOptions options;
  const auto type_code = ReadBinary<int32_t>(stream, what("type"));
  if (type_code != 0 && type_code != 1) {
    ThrowInvalidArgument("{}: unknown global index type {}", source, type_code);
  }
  options.type =
      type_code == 0 ? GlobalIndexOptions::Type::kFlat : GlobalIndexOptions::Type::kIvfPq;
  options.ivf_lists = ReadBinary<int32_t>(stream, what("ivf_lists"));
  options.pq_subquantizers = ReadBinary<int32_t>(stream, what("pq_subquantizers"));
  options.nprobe = ReadBinary<int32_t>(stream, what("nprobe"));
  try {
    options.Check();
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: global index options: {}", source, error.what());
  }
  const auto dim = ReadBinary<int32_t>(stream, what("dimension"));
  const auto num_images = ReadBinary<uint64_t>(stream, what("size"));
  const auto num_bytes = ReadBinary<uint64_t>(stream, what("FAISS index length"));

  faiss::VectorIOReader reader;
  while (reader.data.size() < num_bytes) {
    const size_t offset = reader.data.size();
    const size_t chunk = std::min<uint64_t>(kReadChunkBytes, num_bytes - offset);
    reader.data.resize(offset + chunk);
    ReadBinaryArray(stream, reader.data.data() + offset, chunk, what("FAISS index"));
  }
  std::unique_ptr<faiss::Index> index;
  try {
    index.reset(faiss::read_index(&reader));
  } catch (const std::exception& error) {
    ThrowInvalidArgument("{}: global index: FAISS could not read its index: {}", source,
                         error.what());
  }
  if (reader.rp != reader.data.size()) {
    ThrowInvalidArgument("{}: global index: {} bytes after the FAISS index", source,
                         reader.data.size() - reader.rp);
  }
  const bool type_matches = options.type == GlobalIndexOptions::Type::kFlat
                                ? dynamic_cast<faiss::IndexFlatIP*>(index.get()) != nullptr
                                : dynamic_cast<faiss::IndexIVFPQ*>(index.get()) != nullptr;
  if (!type_matches || index->metric_type != faiss::METRIC_INNER_PRODUCT) {
    ThrowInvalidArgument(
        "{}: global index: the FAISS index is not the {} inner-product index its "
        "header names",
        source, type_code == 0 ? "flat" : "IVF-PQ");
  }
  if (index->d != dim || static_cast<uint64_t>(index->ntotal) != num_images) {
    ThrowInvalidArgument(
        "{}: global index: the FAISS index holds {} vectors of dimension {}, the header says {} "
        "of dimension {}",
        source, index->ntotal, index->d, num_images, dim);
  }
  if (auto* ivf = dynamic_cast<faiss::IndexIVFPQ*>(index.get())) {
    ivf->nprobe = std::min<size_t>(options.nprobe, ivf->nlist);
  }
  GlobalIndex result;
  result.impl_->options = options;
  result.impl_->index = std::move(index);
  return result;
}

}  // namespace hscloc
