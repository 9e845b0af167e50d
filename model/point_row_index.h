// An inverted-file index over a network's pooled point rows (NetworkOptions::pooled_point_rows),
// for the one pass that scores every point of the map: the first level of a prediction without an
// image id (the votes' retrieval), where each child's logit is its best point's score. On the
// aachen preset that pass scored 1.5 M points per keypoint, most of a night query's time
// (docs/decisions.md, "Latency at Aachen scale").
//
// The rows [w_p, b_p] are clustered by k-means into lists; a keypoint's projection q probes the
// lists whose mean row scores highest, <w_c, q> + b_c, and scores only their points exactly. A
// child none of whose points was probed gets no probability: the first level becomes an
// approximate maximum inner product search, which only ranks images for the votes. Predictions
// conditioned on an image never use it.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "map/label_tree.h"
#include "model/dense_kernels.h"

namespace hscloc {

class Network;

struct PointRowIndexOptions {
  int lists = 0;                    // 0: about the square root of the points
  int probes = 32;                  // lists scored per keypoint
  int kmeans_iterations = 8;        // Lloyd iterations on the training sample
  int64_t training_sample = 65536;  // rows k-means learns the lists from (evenly spaced)
  void Check() const;
};

class PointRowIndex {
 public:
  // Maps with fewer points score them all: the exact pass is then cheap (on the 148 k-point city
  // it took 32 ms at p50 of a votes query on one core, the index 16 ms; docs/decisions.md).
  static constexpr int64_t kMinPoints = 100000;

  PointRowIndex() = default;
  // The index of `network`'s point rows over `tree` (the tree the network was trained on); the
  // rows are copied, so the index stays valid without the network. Throws std::invalid_argument
  // when the network has no pooled point rows or they do not fit the tree. Uses the compute
  // threads (SetComputeThreads).
  static PointRowIndex Build(const Network& network, const LabelTree& tree,
                             const PointRowIndexOptions& options = {});

  bool empty() const { return offsets_.empty(); }
  int64_t NumLists() const { return empty() ? 0 : static_cast<int64_t>(offsets_.size()) - 1; }
  int64_t NumPoints() const { return static_cast<int64_t>(ranks_.size()); }
  int64_t RowWidth() const { return row_width_; }
  int probes() const { return probes_; }

  // List l holds points [ListBegin(l), ListEnd(l)) of the index's order: their rows (RowWidth()
  // floats each, contiguous), their leaf ranks, and their first-level labels in segments of one
  // label each (Segments).
  int64_t ListBegin(int64_t list) const { return static_cast<int64_t>(offsets_[list]); }
  int64_t ListEnd(int64_t list) const { return static_cast<int64_t>(offsets_[list + 1]); }
  const float* Rows(int64_t list) const { return rows_.data() + ListBegin(list) * row_width_; }
  const uint32_t* Ranks() const { return ranks_.data(); }
  // Segment k of list l: points [starts[k], starts[k + 1]) from the list's begin, label labels[k];
  // starts has one entry more than labels.
  struct Segments {
    const uint32_t* starts = nullptr;
    const uint8_t* labels = nullptr;
    int64_t count = 0;
  };
  Segments SegmentsOf(int64_t list) const;
  // The lists' mean rows, as weights [lists, RowWidth() - 1] (packed for the matrix-product
  // kernel) and biases [lists]: a list's probe score is its mean row's score.
  const dense_kernels::PackedMatrix& CentroidWeights() const { return centroid_weights_; }
  const float* CentroidBiases() const { return centroid_biases_.data(); }

  // The first level's logits [rows, branching] of `rows` projections [rows, RowWidth() - 1]: each
  // row probes probes() lists and keeps, per child, the best score of the points it scored there
  // (-inf for a child none of whose points it scored). All rows at once, so that each list streams
  // from memory once for every row that probes it; the lists are split among the compute threads,
  // and the result does not depend on their number. Adds the multiply-adds done to
  // *multiply_adds.
  std::vector<float> PooledLogits(const float* projected, int64_t rows, int64_t branching,
                                  int64_t* multiply_adds) const;

 private:
  // (list, row) for every list each row probes, sorted.
  std::vector<std::pair<uint32_t, uint32_t>> ProbeLists(const float* projected, int64_t rows,
                                                        int64_t* multiply_adds) const;
  // The probes [first, last) (whole lists), each list's probing rows gathered side by side and
  // pooled over its points into logits [rows, branching]; returns the multiply-adds done.
  int64_t ScanProbedLists(const float* projected, const std::pair<uint32_t, uint32_t>* first,
                          const std::pair<uint32_t, uint32_t>* last, int64_t branching,
                          float* logits) const;

  int64_t row_width_ = 0;
  int probes_ = 0;
  dense_kernels::PackedMatrix centroid_weights_;
  std::vector<float> centroid_biases_;
  std::vector<uint64_t> offsets_;  // per list, into the points
  std::vector<float> rows_;
  std::vector<uint32_t> ranks_;
  // List l's segments are labels [segment_offsets_[l], segment_offsets_[l + 1]) and starts from
  // segment_offsets_[l] + l (one more than its labels: the last is the list's size).
  std::vector<uint64_t> segment_offsets_;
  std::vector<uint32_t> segment_starts_;
  std::vector<uint8_t> segment_labels_;
};

}  // namespace hscloc
