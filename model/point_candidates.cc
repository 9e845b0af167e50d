#include "model/point_candidates.h"

#include <algorithm>
#include <unordered_map>

#include "util/check.h"

namespace hscloc {

PointCandidates::PointCandidates(const LabelTree& tree, const Visibility* visibility,
                                 const std::vector<uint32_t>& images,
                                 const std::vector<int64_t>* row_offsets)
    : tree_(tree),
      row_offsets_(row_offsets != nullptr && !row_offsets->empty() ? row_offsets : nullptr) {
  for (int depth = 0; depth < tree.levels(); ++depth) first_leaf_ = tree.FirstChild(first_leaf_);
  num_ranks_ = tree.NumNodes() - first_leaf_;
  num_rows_ = num_ranks_;
  if (row_offsets_ != nullptr) {
    THROW_CHECK_MSG(row_offsets_->size() == num_ranks_ + 1,
                    "PointCandidates: {} row offsets for {} points", row_offsets_->size(),
                    num_ranks_);
    num_rows_ = static_cast<size_t>(row_offsets_->back());
  }
  slot_of_k_.assign(images.size(), -1);
  offsets_.push_back(0);
  std::unordered_map<uint32_t, int> slot_of_image;
  for (size_t k = 0; k < images.size(); ++k) {
    const uint32_t image = images[k];
    if (visibility == nullptr || image >= visibility->NumImages()) continue;
    const auto [known, inserted] =
        slot_of_image.emplace(image, static_cast<int>(offsets_.size()) - 1);
    slot_of_k_[k] = known->second;
    if (!inserted) continue;
    const size_t begin = rows_.size();
    for (const uint32_t* point = visibility->PointsBegin(image);
         point != visibility->PointsEnd(image); ++point) {
      const auto [first, end] = RowsOfPoint(*point);
      for (uint32_t row = first; row < end; ++row) rows_.push_back(row);
    }
    std::sort(rows_.begin() + static_cast<std::ptrdiff_t>(begin), rows_.end());
    offsets_.push_back(rows_.size());
  }
}

uint32_t PointCandidates::RankOfPoint(uint32_t point_index) const {
  return static_cast<uint32_t>(
             tree_.NodeOfLabels(tree_.LabelsOfPoint(point_index), tree_.levels())) -
         first_leaf_;
}

uint32_t PointCandidates::FirstRankUnder(uint32_t node) const {
  for (int depth = tree_.NodeLevel(node); depth < tree_.levels(); ++depth) {
    node = tree_.FirstChild(node);
  }
  return node - first_leaf_;
}

CandidateSpan PointCandidates::Under(int slot, uint32_t node) const {
  const uint32_t first_rank = FirstRankUnder(node);
  const bool last_of_depth =
      node + 1 >= tree_.NumNodes() || tree_.NodeLevel(node + 1) != tree_.NodeLevel(node);
  const uint32_t end_rank =
      last_of_depth ? static_cast<uint32_t>(num_ranks_) : FirstRankUnder(node + 1);
  const uint32_t first = FirstRowOfRank(first_rank);
  const uint32_t end = FirstRowOfRank(end_rank);
  if (slot < 0) return {nullptr, first, static_cast<size_t>(end - first)};
  const uint32_t* begin = rows_.data() + offsets_[slot];
  const uint32_t* stop = rows_.data() + offsets_[slot + 1];
  const uint32_t* lower = std::lower_bound(begin, stop, first);
  const uint32_t* upper = std::lower_bound(lower, stop, end);
  return {lower, 0, static_cast<size_t>(upper - lower)};
}

}  // namespace hscloc
