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
  int ivf_lists = 1024;         // IVF-PQ: coarse cells
  int pq_subquantizers = 32;    // IVF-PQ: bytes per vector (must divide the dimension)
  int nprobe = 32;              // IVF-PQ: cells searched per query
  void Check() const;
};

struct RetrievalHit {
  uint32_t image_index = 0;  // dense database image index
  float score = 0;           // inner product, higher is closer
};

class GlobalIndex {
 public:
  GlobalIndex();
  ~GlobalIndex();
  GlobalIndex(GlobalIndex&&) noexcept;
  GlobalIndex& operator=(GlobalIndex&&) noexcept;

  // descriptors: one row per database image (dense index order), unit length.
  static GlobalIndex Build(const Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic,
                                               Eigen::RowMajor>& descriptors,
                           const GlobalIndexOptions& options = {});

  int dimension() const;
  size_t size() const;
  // The k best database images, best first (fewer when the index holds fewer). Thread-safe.
  std::vector<RetrievalHit> Search(const Eigen::VectorXf& query, int k) const;

  void Write(std::ostream& stream) const;
  static GlobalIndex Read(std::istream& stream, const std::string& source);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hscloc
