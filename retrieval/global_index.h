// Nearest-neighbour search over database images' global descriptors (inner product on unit
// vectors = cosine). FAISS underneath: exact (flat) by default; IVF-PQ for maps beyond a few
// hundred thousand images.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

namespace hscloc {

struct GlobalIndexOptions {
  enum class Type { kFlat, kIvfPq };
  Type type = Type::kFlat;
  // IVF-PQ: coarse cells; capped at (database size / 39) so that k-means has enough points per
  // cell (FAISS's rule of thumb).
  int ivf_lists = 1024;
  int pq_subquantizers = 32;  // IVF-PQ: bytes per vector (must divide the dimension)
  int nprobe = 32;            // IVF-PQ: cells searched per query
  // Throws std::invalid_argument naming the first field out of range.
  void Check() const;
};

struct RetrievalHit {
  uint32_t image_index = 0;  // dense database image index
  float score = 0;           // inner product, higher is closer
};

class GlobalIndex {
 public:
  GlobalIndex();  // empty, of dimension 0: Build or Read one to search
  ~GlobalIndex();
  GlobalIndex(GlobalIndex&&) noexcept;
  GlobalIndex& operator=(GlobalIndex&&) noexcept;

  // descriptors: one row per database image (dense index order), unit length (a zero row, an
  // image without features, is allowed: it scores 0 against every query). IVF-PQ trains on these
  // rows and needs at least 256 of them (8-bit product quantizer codes). Throws on non-finite
  // values or a dimension that pq_subquantizers does not divide.
  static GlobalIndex Build(
      const Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>& descriptors,
      const GlobalIndexOptions& options = {});

  int dimension() const;
  size_t size() const;
  const GlobalIndexOptions& options() const;
  // The k best database images, best first (fewer when the index holds fewer; IVF-PQ may also
  // return fewer when the probed cells hold fewer). Thread-safe. Throws when the query's
  // dimension differs from the index's, the query is not finite, or k < 0.
  std::vector<RetrievalHit> Search(const Eigen::VectorXf& query, int k) const;

  // Binary, versioned: a header, then the FAISS index serialized by FAISS, length-prefixed. Read
  // validates both and names `source` in every error.
  void Write(std::ostream& stream) const;
  static GlobalIndex Read(std::istream& stream, const std::string& source);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hscloc
