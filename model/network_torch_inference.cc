// The libtorch inference path of Network::Predict: operator by operator, on any device (the path
// CUDA takes), and the reference the CPU kernels (network_cpu_inference.cc) are tested against.
#include <ATen/Parallel.h>

#include <algorithm>
#include <memory>
#include <tuple>
#include <vector>

#include "model/network.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "util/timer.h"

namespace hscloc {
namespace {

torch::Tensor Elu(const torch::Tensor& x) { return torch::elu(x); }

// The forward pass of one call over every (image, descriptor) row, row k * N + n.
class TorchForwardPass {
 public:
  TorchForwardPass(const Network& network, const DescriptorMatrix& descriptors,
                   const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                   const Visibility* visibility_mask)
      : shape_(network.shape()),
        tree_(tree),
        device_(TorchDevice(network.device())),
        long_options_(torch::TensorOptions().dtype(torch::kInt64).device(device_)),
        num_descriptors_(descriptors.rows()),
        num_rows_(descriptors.rows() * static_cast<int64_t>(image_indices.size())),
        result_(AllocatePredictions(static_cast<int64_t>(image_indices.size()), descriptors.rows(),
                                    shape_.levels)),
        parent_node_(num_rows_, 0) {
    if (num_rows_ == 0) return;
    descriptors_ =
        NormalizeRows(torch::from_blob(const_cast<float*>(descriptors.data()),
                                       {num_descriptors_, shape_.descriptor_dim}, torch::kFloat32)
                          .to(device_));
    const std::vector<int64_t> images64(image_indices.begin(), image_indices.end());
    row_image_ =
        torch::tensor(images64, torch::kInt64).to(device_).repeat_interleave(num_descriptors_);
    row_descriptor_ = torch::arange(num_descriptors_, long_options_)
                          .repeat({static_cast<int64_t>(image_indices.size())});
    labels_ = torch::empty({num_rows_, 0}, long_options_);
    confidence_ = torch::ones({num_rows_}, torch::TensorOptions().device(device_));
    if (visibility_mask != nullptr) {
      masks_ = std::make_unique<NodeVisibilityMasks>(image_indices, tree, *visibility_mask);
    }
    if (network.options().pooled_point_rows) {
      candidates_ = std::make_unique<PointCandidates>(tree, visibility_mask, image_indices,
                                                      &network.shape().point_row_offsets);
      point_rows_ = NetworkInternals::Module(network)->point_rows;
      slot_of_row_.resize(num_rows_);
      for (int64_t row = 0; row < num_rows_; ++row) {
        slot_of_row_[row] = candidates_->SlotOf(static_cast<size_t>(row / num_descriptors_));
      }
    }
  }

  PointPredictions Run(const Network& network) {
    if (num_rows_ == 0) return std::move(result_);
    c10::InferenceMode inference_mode;
    // Level holders are shared pointers: a copy gives the non-const module the forward pass needs.
    for (Level level : NetworkInternals::Module(network)->levels) {
      const Timer level_timer;
      if (tree_.LevelHasChoice(level->level())) {
        RunLevel(level);
      } else {
        SkipLevel();
      }
      result_.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
    }
    const torch::Tensor cpu_labels = labels_.to(torch::kCPU).to(torch::kUInt8).contiguous();
    const torch::Tensor cpu_confidence = confidence_.to(torch::kCPU).contiguous();
    std::copy_n(cpu_labels.data_ptr<uint8_t>(), num_rows_ * shape_.levels, result_.labels.data());
    std::copy_n(cpu_confidence.data_ptr<float>(), num_rows_, result_.confidences.data());
    ResolvePointIndices(tree_, result_);
    return std::move(result_);
  }

 private:
  // Every parent has a single child: label 0 with certainty, no network to run.
  void SkipLevel() {
    labels_ = torch::cat({labels_, torch::zeros({num_rows_, 1}, long_options_)}, 1);
    for (int64_t& parent : parent_node_) parent = ChildNode(parent, 0, tree_);
  }

  void RunLevel(Level level) {
    const torch::Tensor probabilities = torch::softmax(LevelLogits(level), 1);
    const auto [chosen, chosen_probability] =
        masks_ ? ChooseVisible(probabilities) : ChooseAny(probabilities);
    labels_ = torch::cat({labels_, chosen.unsqueeze(1)}, 1);
    confidence_ = confidence_ * chosen_probability;
  }

  // The level's trunk output; a shared trunk runs once, at the first level that borrows it.
  torch::Tensor TrunkOf(LevelImpl& level) {
    if (!level.BorrowsTrunk() || !trunk_.defined()) trunk_ = level.Trunk(descriptors_);
    return trunk_;
  }

  // The level's logits of every row. Rows with the same image and label prefix share their
  // modulation: the generator runs once per distinct key.
  torch::Tensor LevelLogits(Level level) {
    const int depth = level->level();
    const torch::Tensor shared_linear = level->ConditionedLinear(0, TrunkOf(*level));
    torch::Tensor key = row_image_.clone();
    for (int column = 0; column < depth; ++column) {
      key = key * shape_.branching + labels_.select(1, column);
    }
    const auto [unique_keys, inverse, counts] =
        at::_unique2(key, /*sorted=*/true, /*return_inverse=*/true, /*return_counts=*/false);
    const torch::Tensor representative =
        torch::empty({unique_keys.size(0)}, long_options_)
            .scatter_(0, inverse, torch::arange(num_rows_, long_options_));
    const torch::Tensor parents =
        torch::from_blob(parent_node_.data(), {num_rows_}, torch::kInt64).to(device_);
    const LevelModulation modulation = level->Generate(row_image_.index_select(0, representative),
                                                       labels_.index_select(0, representative),
                                                       parents.index_select(0, representative));

    torch::Tensor features = Elu(torch::addcmul(modulation.betas[0].index_select(0, inverse),
                                                modulation.gammas[0].index_select(0, inverse),
                                                shared_linear.index_select(0, row_descriptor_)));
    for (int layer = 1; layer < level->NumConditionedLayers(); ++layer) {
      features = Elu(torch::addcmul(modulation.betas[layer].index_select(0, inverse),
                                    modulation.gammas[layer].index_select(0, inverse),
                                    level->ConditionedLinear(layer, features)));
    }
    if (level->IsPooled()) return PooledLogits(level, features, depth);
    torch::Tensor child_nodes;
    if (level->HasNodeOutput()) {
      child_nodes = ChildNodesOf(tree_, parent_node_.data(), num_rows_).to(device_);
    }
    return level->Logits(features, child_nodes);
  }

  // Pooled point rows, over chunks of rows with at most kMaxCandidates candidates between them
  // (a row without a mask ranges over every point under its parent).
  torch::Tensor PooledLogits(Level level, const torch::Tensor& features, int depth) {
    constexpr size_t kMaxCandidates = size_t{1} << 21;
    const torch::Tensor projected =
        level->Project(features, descriptors_.index_select(0, row_descriptor_));
    std::vector<torch::Tensor> chunks;
    for (int64_t begin = 0; begin < num_rows_;) {
      int64_t end = begin;
      size_t total = 0;
      while (end < num_rows_ && (end == begin || total < kMaxCandidates)) {
        if (parent_node_[end] >= 0) {
          total +=
              candidates_->Under(slot_of_row_[end], static_cast<uint32_t>(parent_node_[end])).size;
        }
        ++end;
      }
      const FlatCandidates flat = GatherCandidates(*candidates_, slot_of_row_.data(),
                                                   parent_node_.data(), begin, end, depth);
      chunks.push_back(PooledPointLogits(projected.narrow(0, begin, end - begin), point_rows_, flat,
                                         shape_.branching, Pooling::kBestPoint));
      begin = end;
    }
    return torch::cat(chunks, 0);
  }

  // The most probable child among those whose subtree the row's image observes.
  std::pair<torch::Tensor, torch::Tensor> ChooseVisible(const torch::Tensor& probabilities) {
    const torch::Tensor cpu_probabilities = probabilities.to(torch::kCPU).contiguous();
    const float* all_probabilities = cpu_probabilities.data_ptr<float>();
    torch::Tensor chosen = torch::empty({num_rows_}, torch::kInt64);
    torch::Tensor chosen_probability = torch::empty({num_rows_}, torch::kFloat32);
    int64_t* chosen_data = chosen.data_ptr<int64_t>();
    float* probability_data = chosen_probability.data_ptr<float>();
    const int64_t branching = shape_.branching;
    at::parallel_for(0, num_rows_, 1024, [&](int64_t begin, int64_t end) {
      for (int64_t row = begin; row < end; ++row) {
        const float* row_probabilities = all_probabilities + row * branching;
        const int slot = masks_->SlotOfK(static_cast<size_t>(row / num_descriptors_));
        const int64_t parent = parent_node_[row];
        const int64_t best =
            ChooseLabel(row_probabilities, branching, masks_.get(), slot, parent, tree_);
        chosen_data[row] = best;
        probability_data[row] = row_probabilities[best];
        parent_node_[row] = ChildNode(parent, best, tree_);
      }
    });
    return {chosen.to(device_), chosen_probability.to(device_)};
  }

  std::pair<torch::Tensor, torch::Tensor> ChooseAny(const torch::Tensor& probabilities) {
    const auto [chosen_probability, chosen] = probabilities.max(1);
    const torch::Tensor cpu_chosen = chosen.to(torch::kCPU).contiguous();
    const int64_t* chosen_data = cpu_chosen.data_ptr<int64_t>();
    for (int64_t row = 0; row < num_rows_; ++row) {
      parent_node_[row] = ChildNode(parent_node_[row], chosen_data[row], tree_);
    }
    return {chosen, chosen_probability};
  }

  const NetworkShape& shape_;
  const LabelTree& tree_;
  const torch::Device device_;
  const torch::TensorOptions long_options_;
  const int64_t num_descriptors_;
  const int64_t num_rows_;
  PointPredictions result_;
  // The tree node of every row's label prefix (-1 once a path leaves the tree).
  std::vector<int64_t> parent_node_;
  torch::Tensor descriptors_;     // [N, D], unit rows
  torch::Tensor row_image_;       // [rows]
  torch::Tensor row_descriptor_;  // [rows]
  torch::Tensor labels_;          // [rows, levels so far]
  torch::Tensor trunk_;           // [N, C]: the last owned trunk's output
  torch::Tensor confidence_;      // [rows]
  std::unique_ptr<NodeVisibilityMasks> masks_;
  // Pooled point rows: the candidates of the call's images, each row's slot, the table.
  std::unique_ptr<PointCandidates> candidates_;
  std::vector<int> slot_of_row_;
  torch::Tensor point_rows_;
};

}  // namespace

PointPredictions NetworkInternals::PredictWithTorch(const Network& network,
                                                    const DescriptorMatrix& descriptors,
                                                    const std::vector<uint32_t>& image_indices,
                                                    const LabelTree& tree,
                                                    const Visibility* visibility_mask) {
  return TorchForwardPass(network, descriptors, image_indices, tree, visibility_mask).Run(network);
}

}  // namespace hscloc
