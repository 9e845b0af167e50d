// The trainer's batches (model/trainer.cc): the order in which the iterations consume the training
// observations, and the assembly of one iteration's batch (descriptor augmentation, image dropout,
// label paths, and the children each level's softmax ranges over). Private to model/: it holds
// libtorch types, and nothing outside model/ includes this header.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <utility>
#include <vector>

#include "map/label_tree.h"
#include "model/network_module.h"
#include "model/trainer.h"
#include "scene/scene.h"

namespace hscloc {

class NodeVisibilityMasks;

// The training observations in the order the iterations consume them: an endless sequence of
// permutations, one per epoch, each drawn from its own stream, so that any iteration's batch can
// be found without replaying the ones before it (resume).
class SampleOrder {
 public:
  SampleOrder(std::vector<uint32_t> samples, uint64_t seed)
      : samples_(std::move(samples)), seed_(seed) {}

  // The observation at `position` of the sequence (batch i, row r: position i * batch_size + r).
  uint32_t At(uint64_t position);
  size_t size() const { return samples_.size(); }

 private:
  void Shuffle(uint64_t epoch);

  std::vector<uint32_t> samples_;
  uint64_t seed_;
  uint64_t epoch_ = ~uint64_t{0};
  std::vector<uint32_t> permutation_;
};

struct Batch {
  torch::Tensor descriptors;  // [B, D], augmented, not yet normalized
  torch::Tensor images;       // [B]
  torch::Tensor labels;       // [B, levels]
  // Per level: the parent node of each row [B]; its children's node ids [B, branching] (-1: no
  // such child; node output rows only); the children its softmax ranges over [B, branching]
  // (visibility softmax only; undefined: every label). With node output rows and the visibility
  // softmax, child_nodes holds only the candidates, [B, K], and targets [B] the true child's
  // column (undefined: the label).
  std::vector<torch::Tensor> parent_nodes, child_nodes, allowed, targets;
  // Pooled point rows, per level: each row's candidate points, those under its parent that its
  // observation's image sees (also when image dropout hid the image from the generator).
  std::vector<FlatCandidates> candidates;
};

// What a batch needs of the tree beyond the labels: node visibility per image for the
// visibility softmax.
struct BatchContext {
  const Scene& scene;
  const LabelTree& tree;
  const TrainerOptions& options;
  const NodeVisibilityMasks* masks = nullptr;  // slot = image index
  bool node_output = false;
  const PointCandidates* point_candidates = nullptr;  // pooled point rows; entry k = image k
};

// The batch of `iteration`: options.batch_size rows taken from `order`, augmented from streams
// addressed by (options.seed, iteration, row), on `device`.
Batch MakeBatch(const BatchContext& context, SampleOrder& order, int64_t iteration,
                torch::Device device);

}  // namespace hscloc
