// The points a level of a network with pooled point rows (NetworkOptions::pooled_point_rows) pools
// over: the points under a tree node, all of them or those a database image observes. Internal to
// model/.
//
// Points are addressed by leaf rank: every leaf sits at the tree's last depth (map/label_tree.h)
// and the nodes of a depth are numbered in label order, so the leaves under any node form one
// contiguous range of ranks, and the pooled table's row of a point is its leaf rank.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"

namespace hscloc {

// Candidate ranks of one (slot, node): a sorted list of ranks, or the whole range [first, first +
// size) when `ranks` is null.
struct CandidateSpan {
  const uint32_t* ranks = nullptr;
  uint32_t first = 0;
  size_t size = 0;

  uint32_t operator[](size_t i) const {
    return ranks != nullptr ? ranks[i] : first + static_cast<uint32_t>(i);
  }
};

class PointCandidates {
 public:
  // Sorted leaf ranks of the points each of `images` observes, a slot per entry; an entry with no
  // visibility list (visibility null, or an index past its images: the "no image" id) gets no
  // slot and pools over every point.
  PointCandidates(const LabelTree& tree, const Visibility* visibility,
                  const std::vector<uint32_t>& images);

  size_t NumRanks() const { return num_ranks_; }
  // The slot of entry k of the images given, -1 without one.
  int SlotOf(size_t k) const { return slot_of_k_[k]; }
  // The ranks under `node` that slot observes (every rank under it for slot -1).
  CandidateSpan Under(int slot, uint32_t node) const;
  // The label at `level` (0-based) of the point of a rank: the child it falls under there.
  LabelTree::Label LabelOfRank(uint32_t rank, int level) const {
    return tree_.LabelsOfPoint(static_cast<uint32_t>(tree_.PointOfLeaf(first_leaf_ + rank)))[level];
  }
  // The leaf rank of a point.
  uint32_t RankOfPoint(uint32_t point_index) const;

 private:
  uint32_t FirstRankUnder(uint32_t node) const;

  const LabelTree& tree_;
  uint32_t first_leaf_ = 0;  // node id of rank 0
  size_t num_ranks_ = 0;
  std::vector<int> slot_of_k_;
  std::vector<uint64_t> offsets_;  // slot s: ranks_[offsets_[s], offsets_[s + 1])
  std::vector<uint32_t> ranks_;
};

}  // namespace hscloc
