// Label decoding shared by the network's two inference paths (libtorch operators, and the CPU
// kernels of network_cpu_inference.cc): visibility masks over the label tree and the choice of a
// row's label at one level. Internal to the network's files.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"
#include "model/network.h"

namespace hscloc {

// Per distinct conditioning image, a bit per label tree node: set when the node's subtree holds a
// point the image observes. One pass over the image's visible points marks their ancestors.
class NodeVisibilityMasks {
 public:
  NodeVisibilityMasks(const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                      const Visibility& visibility)
      : words_((tree.NumNodes() + 63) / 64) {
    slot_of_k_.assign(image_indices.size(), -1);
    for (size_t k = 0; k < image_indices.size(); ++k) {
      const uint32_t image = image_indices[k];
      if (image >= visibility.NumImages()) continue;  // the "no image" index is never masked
      const auto known = std::find(images_.begin(), images_.end(), image);
      if (known != images_.end()) {
        slot_of_k_[k] = static_cast<int>(known - images_.begin());
        continue;
      }
      slot_of_k_[k] = static_cast<int>(images_.size());
      images_.push_back(image);
      bits_.resize(bits_.size() + words_, 0);
      uint64_t* bits = bits_.data() + bits_.size() - words_;
      for (const uint32_t* point = visibility.PointsBegin(image);
           point != visibility.PointsEnd(image); ++point) {
        const LabelTree::Label* labels = tree.LabelsOfPoint(*point);
        uint32_t node = 0;
        for (int level = 0; level < tree.levels(); ++level) {
          node = tree.FirstChild(node) + labels[level];
          bits[node / 64] |= uint64_t{1} << (node % 64);
        }
      }
    }
  }

  // -1 when the k-th conditioning image has no mask.
  int SlotOfK(size_t k) const { return slot_of_k_[k]; }
  bool Contains(int slot, uint32_t node) const {
    return (bits_[slot * words_ + node / 64] >> (node % 64)) & 1;
  }
  // The bits of nodes [first, first + count), count <= 64, the first node's in bit 0.
  uint64_t Bits(int slot, uint32_t first, int count) const {
    const uint64_t* words = bits_.data() + slot * words_;
    const size_t word = first / 64;
    const int shift = static_cast<int>(first % 64);
    uint64_t bits = words[word] >> shift;
    if (shift != 0 && shift + count > 64) bits |= words[word + 1] << (64 - shift);
    return count == 64 ? bits : bits & ((uint64_t{1} << count) - 1);
  }
  // Of the `children` nodes from `first` on, the index of the only one the mask keeps; -1 when
  // it keeps none or several.
  int64_t OnlyKeptChild(int slot, uint32_t first, int64_t children) const {
    int64_t only_child = -1;
    for (int64_t base = 0; base < children; base += 64) {
      const int count = static_cast<int>(std::min<int64_t>(64, children - base));
      const uint64_t bits = Bits(slot, first + static_cast<uint32_t>(base), count);
      if (bits == 0) continue;
      if (only_child >= 0 || (bits & (bits - 1)) != 0) return -1;
      only_child = base + __builtin_ctzll(bits);
    }
    return only_child;
  }

 private:
  size_t words_;
  std::vector<uint32_t> images_;
  std::vector<int> slot_of_k_;
  std::vector<uint64_t> bits_;
};

// The label a row takes at one level: the most probable child, or with a mask slot (>= 0) and a
// known parent node, the most probable among the children the mask keeps (the plain argmax when it
// keeps none). `scores` are the children's probabilities or their logits, in the same order.
inline int64_t ChooseLabel(const float* scores, int64_t branching, const NodeVisibilityMasks* masks,
                           int slot, int64_t parent, const LabelTree& tree) {
  int64_t best = -1;
  if (masks != nullptr && slot >= 0 && parent >= 0) {
    const uint32_t first = tree.FirstChild(static_cast<uint32_t>(parent));
    const int64_t children = tree.NumChildren(static_cast<uint32_t>(parent));
    // The kept children only, in order: a branch per child on its mask bit mispredicted often
    // enough to cost more than the comparisons.
    for (int64_t base = 0; base < children; base += 64) {
      const int count = static_cast<int>(std::min<int64_t>(64, children - base));
      for (uint64_t bits = masks->Bits(slot, first + static_cast<uint32_t>(base), count); bits != 0;
           bits &= bits - 1) {
        const int64_t c = base + __builtin_ctzll(bits);
        if (best < 0 || scores[c] > scores[best]) best = c;
      }
    }
  }
  if (best < 0) best = std::max_element(scores, scores + branching) - scores;
  return best;
}

// The tree node reached from `parent` by `label`; -1 when the path leaves the tree.
inline int64_t ChildNode(int64_t parent, int64_t label, const LabelTree& tree) {
  return parent >= 0 && label < tree.NumChildren(static_cast<uint32_t>(parent))
             ? tree.FirstChild(static_cast<uint32_t>(parent)) + label
             : -1;
}

// Predictions of K images x N descriptors with room for every level's label; confidences start
// at 1 (each level multiplies its choice in).
inline PointPredictions AllocatePredictions(int64_t num_images, int64_t num_descriptors,
                                            int levels) {
  PointPredictions result;
  result.num_images = num_images;
  result.num_descriptors = num_descriptors;
  result.point_indices.resize(num_images, num_descriptors);
  result.confidences.setOnes(num_images, num_descriptors);
  result.labels.resize(num_images * num_descriptors, levels);
  return result;
}

// Fills point_indices from the complete label paths.
inline void ResolvePointIndices(const LabelTree& tree, PointPredictions& result) {
  const int64_t levels = result.labels.cols();
  for (int64_t r = 0; r < result.labels.rows(); ++r) {
    result.point_indices.data()[r] = tree.PointOfLabels(result.labels.data() + r * levels);
  }
}

// Network::Predict on the CPU kernels (model/dense_kernels.h); inputs already checked.
PointPredictions PredictOnCpu(const Network& network, const DescriptorMatrix& descriptors,
                              const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                              const Visibility* visibility_mask, DescriptorLayerCache* cache,
                              const PointRowIndex* index);

}  // namespace hscloc
