// The rows a level of a network with pooled point rows (NetworkOptions::pooled_point_rows) pools
// over: the rows of the points under a tree node, all of them or those a database image observes.
// Internal to model/.
//
// Points are addressed by leaf rank: every leaf sits at the tree's last depth (map/label_tree.h)
// and the nodes of a depth are numbered in label order, so the leaves under any node form one
// contiguous range of ranks. The pooled table holds a point's rows side by side in rank order
// (one row per point, or its prototypes: NetworkShape::point_row_offsets), so the rows under any
// node are one contiguous range of the table too.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"

namespace hscloc {

// Candidate rows of one (slot, node): a sorted list of table rows, or the whole range [first,
// first + size) when `rows` is null.
struct CandidateSpan {
  const uint32_t* rows = nullptr;
  uint32_t first = 0;
  size_t size = 0;

  uint32_t operator[](size_t i) const {
    return rows != nullptr ? rows[i] : first + static_cast<uint32_t>(i);
  }
};

class PointCandidates {
 public:
  // Sorted table rows of the points each of `images` observes, a slot per entry; an entry with no
  // visibility list (visibility null, or an index past its images: the "no image" id) gets no
  // slot and pools over every point. `row_offsets`: NetworkShape::point_row_offsets, read in place
  // (it must outlive the candidates, which are made per query); null or empty: one row per point.
  PointCandidates(const LabelTree& tree, const Visibility* visibility,
                  const std::vector<uint32_t>& images,
                  const std::vector<int64_t>* row_offsets = nullptr);

  size_t NumRows() const { return num_rows_; }
  // The slot of entry k of the images given, -1 without one.
  int SlotOf(size_t k) const { return slot_of_k_[k]; }
  // The rows of the points under `node` that slot observes (every row under it for slot -1).
  CandidateSpan Under(int slot, uint32_t node) const;
  // The label at `level` (0-based) of the point of a table row: the child it falls under there.
  LabelTree::Label LabelOfRow(uint32_t row, int level) const {
    return tree_.LabelsOfPoint(
        static_cast<uint32_t>(tree_.PointOfLeaf(first_leaf_ + RankOfRow(row))))[level];
  }
  // The leaf rank of the point of a table row.
  uint32_t RankOfRow(uint32_t row) const {
    if (row_offsets_ == nullptr) return row;
    return static_cast<uint32_t>(
        std::upper_bound(row_offsets_->begin(), row_offsets_->end(), int64_t{row}) -
        row_offsets_->begin() - 1);
  }
  // The leaf rank of a point.
  uint32_t RankOfPoint(uint32_t point_index) const;
  // The first table row of leaf rank `rank` (rank = the number of points: the table's end).
  uint32_t FirstRowOfRank(uint32_t rank) const {
    return row_offsets_ == nullptr ? rank : static_cast<uint32_t>((*row_offsets_)[rank]);
  }
  // The table rows of a point: [first, end).
  std::pair<uint32_t, uint32_t> RowsOfPoint(uint32_t point_index) const {
    const uint32_t rank = RankOfPoint(point_index);
    return {FirstRowOfRank(rank), FirstRowOfRank(rank + 1)};
  }

 private:
  uint32_t FirstRankUnder(uint32_t node) const;

  const LabelTree& tree_;
  uint32_t first_leaf_ = 0;  // node id of rank 0
  size_t num_ranks_ = 0;
  size_t num_rows_ = 0;
  const std::vector<int64_t>* row_offsets_ = nullptr;  // null with one row per point
  std::vector<int> slot_of_k_;
  std::vector<uint64_t> offsets_;  // slot s: rows_[offsets_[s], offsets_[s + 1])
  std::vector<uint32_t> rows_;
};

}  // namespace hscloc
