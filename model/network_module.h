// The libtorch modules behind model/network.h, shared by the network's and the trainer's .cc
// files only: nothing outside model/'s network files includes this header.
#pragma once

#include <torch/torch.h>

#include <memory>
#include <vector>

#include "model/dense_kernels.h"
#include "model/network.h"
#include "model/packed_weight_cache.h"
#include "model/point_candidates.h"

namespace hscloc {

// FiLM parameters of one level: a (gamma, beta) pair per conditioned layer, one row per input row.
struct LevelModulation {
  std::vector<torch::Tensor> gammas;
  std::vector<torch::Tensor> betas;
};

// Views of one level's weights, for the CPU inference kernels (model/dense_kernels.h): the Linear
// weights packed for the matrix-product kernel (PackedMatrix), the rest raw. Valid while the module
// lives and its parameters are not replaced.
struct LevelWeights {
  using Packed = std::shared_ptr<const dense_kernels::PackedMatrix>;
  float input_scale = 1;
  Packed trunk1_weight;
  const float* trunk1_bias = nullptr;
  Packed trunk2_weight;
  const float* trunk2_bias = nullptr;
  const float* image_embedding = nullptr;      // [num_images + 1, E]
  std::vector<const float*> label_embeddings;  // one [branching, E] table per coarser level
  // Node conditioning: [nodes at the parents' depth, E], row = node id - node_embedding_first.
  const float* node_embedding = nullptr;
  int64_t node_embedding_first = 0;
  Packed generator_weight;
  const float* generator_bias = nullptr;
  std::vector<Packed> gamma_weights, beta_weights;
  std::vector<const float*> gamma_biases, beta_biases;
  std::vector<Packed> conditioned_weights;
  std::vector<const float*> conditioned_biases;
  Packed output_weight;  // the shared output (node_output_dim == 0)
  const float* output_bias = nullptr;
  // Node output rows: projection [r, C] and [r]; rows [nodes at the children's depth, r + 1]
  // (weights, then the bias), row = node id - node_rows_first.
  int64_t node_output_dim = 0;
  Packed projection_weight;
  const float* projection_bias = nullptr;
  const float* node_rows = nullptr;
  int64_t node_rows_first = 0;
  // Pooled point rows (NetworkOptions::pooled_point_rows): the network's shared table
  // [points, r + 1], row = leaf rank; node_rows is null then.
  const float* point_rows = nullptr;
  // The descriptor shortcut's scale s ([1]); null without the shortcut.
  const float* shortcut_scale = nullptr;
};

// One level of the network (see model/network.h for the equations).
class LevelImpl : public torch::nn::Module {
 public:
  // With `trunk_owner`, the level runs that level's trunk (NetworkOptions::shared_trunk) and
  // registers none of its own: the trunk's parameters belong to the owner alone.
  LevelImpl(int level, const NetworkShape& shape, const NetworkOptions& options,
            const LevelImpl* trunk_owner = nullptr);

  // [N, D] normalized descriptors -> [N, C].
  torch::Tensor Trunk(const torch::Tensor& descriptors);
  // Whether the level's trunk is another level's (a shared trunk, not its first level).
  bool BorrowsTrunk() const { return borrows_trunk_; }
  // image_indices [R], prefix_labels [R, level] and parent_nodes [R] (the tree node of the prefix;
  // int64) -> the modulation of R rows. Label-sum conditioning reads the labels, node
  // conditioning the parent nodes.
  LevelModulation Generate(const torch::Tensor& image_indices, const torch::Tensor& prefix_labels,
                           const torch::Tensor& parent_nodes);
  // W_i h + b_i of conditioned layer i.
  torch::Tensor ConditionedLinear(int layer, const torch::Tensor& features);
  // [R, branching] logits. child_nodes [R, branching] holds each row's children's node ids (-1:
  // no such child); node output rows read them and give -inf where there is no child; the shared
  // output ignores them (the paper: every label has a logit).
  torch::Tensor Logits(const torch::Tensor& features, const torch::Tensor& child_nodes);
  // Throws std::logic_error unless every parameter is a contiguous fp32 CPU tensor. The packed
  // matrices come from `packed` (the network's).
  LevelWeights CpuWeights(PackedWeightCache& packed) const;

  // The last conditioned layer's features [R, C] of R (descriptor, image, prefix) rows.
  torch::Tensor Features(const torch::Tensor& descriptors, const torch::Tensor& image_indices,
                         const torch::Tensor& prefix_labels, const torch::Tensor& parent_nodes);
  // The same from the rows' trunk output [R, C] (Trunk), computed once for a shared trunk.
  torch::Tensor FeaturesOfTrunk(const torch::Tensor& trunk, const torch::Tensor& image_indices,
                                const torch::Tensor& prefix_labels,
                                const torch::Tensor& parent_nodes);
  // [R, r + 1]: the projection of the features (plus the scaled unit descriptors [R, D] of the
  // same rows, with the descriptor shortcut) with a constant 1 appended (the rows' bias).
  torch::Tensor Project(const torch::Tensor& features, const torch::Tensor& unit_descriptors);
  // Teacher-forced logits [R, branching] of R (descriptor, image, prefix) rows (not for pooled
  // point rows: PooledPointLogits).
  torch::Tensor forward(const torch::Tensor& descriptors, const torch::Tensor& image_indices,
                        const torch::Tensor& prefix_labels, const torch::Tensor& parent_nodes,
                        const torch::Tensor& child_nodes);

  int level() const { return level_; }
  // False for a level whose parents all have one child: it never runs and holds no weights.
  bool HasWeights() const { return has_weights_; }
  bool HasNodeOutput() const { return node_output_dim_ > 0; }
  bool IsPooled() const { return pooled_; }
  // Training gathers the per-node tables (output rows, conditioning embeddings) with sparse
  // gradients (only the rows a batch touches), for row-wise lazy Adam (model/lazy_adam.h).
  void SetSparseNodeRows(bool sparse) { sparse_node_rows_ = sparse; }
  // The node output rows (undefined without them): the table the trainer updates lazily.
  torch::Tensor NodeRows() const { return node_rows_; }
  int NumConditionedLayers() const { return static_cast<int>(conditioned_.size()); }

 private:
  int level_;
  bool has_weights_ = true;
  // Unit-norm descriptors have components of about 1/sqrt(D); the trunk sees them scaled to unit
  // variance, as He initialization assumes, so Adam's steps have the same relative size for any D.
  double input_scale_ = 1;
  torch::nn::Linear trunk1_{nullptr};
  torch::nn::Linear trunk2_{nullptr};
  bool borrows_trunk_ = false;
  torch::nn::Embedding image_embedding_{nullptr};
  std::vector<torch::nn::Embedding> label_embeddings_;
  torch::nn::Linear generator_{nullptr};
  std::vector<torch::nn::Linear> gamma_heads_;
  std::vector<torch::nn::Linear> beta_heads_;
  std::vector<torch::nn::Linear> conditioned_;
  torch::nn::Linear output_{nullptr};
  // Node conditioning and node output rows (NetworkOptions); first node ids of their depths.
  torch::nn::Embedding node_embedding_{nullptr};
  int64_t node_embedding_first_ = 0;
  int64_t node_output_dim_ = 0;
  torch::nn::Linear projection_{nullptr};
  torch::Tensor node_rows_;
  int64_t node_rows_first_ = 0;
  bool sparse_node_rows_ = false;
  bool pooled_ = false;
  // The descriptor shortcut's learned scale s ([1]); undefined without the shortcut.
  torch::Tensor shortcut_scale_;
};
TORCH_MODULE(Level);

// The scale s the descriptor shortcut starts at: cosines of a unit descriptor and unit rows,
// times s, are the logits of a softmax sharp enough to train on (cosine classifiers use 10 to 30).
inline constexpr float kInitialShortcutScale = 16.0f;

// Throws std::invalid_argument when the options need what the shape lacks (node counts for
// per-node tables, rows at the descriptor's width for the descriptor shortcut).
void CheckOptionsFitShape(const NetworkShape& shape, const NetworkOptions& options);

// Per row of a batch, the ids of the children of its parent node [R, branching], -1 past the
// parent's last child or for parents < 0 (a path that left the tree).
torch::Tensor ChildNodesOf(const LabelTree& tree, const int64_t* parent_nodes, int64_t rows);

class HscNetImpl : public torch::nn::Module {
 public:
  HscNetImpl(const NetworkShape& shape, const NetworkOptions& options);

  std::vector<Level> levels;
  // Pooled point rows: [points, r + 1], one row per leaf rank (weights, then the bias); undefined
  // otherwise.
  torch::Tensor point_rows;
};
TORCH_MODULE(HscNet);

// The candidate point rows of R rows at one level, flattened: table row ranks[i] (a point's row,
// PointCandidates) belongs to row rows[i] and falls under child groups[i] of that row's parent.
// CPU int64 tensors [T].
struct FlatCandidates {
  // Candidate i: table row ranks[i] for row rows[i], under child groups[i] (its point's label at
  // the level).
  torch::Tensor ranks{}, rows{}, groups{};
  // Training only: the table rows of each row's observed point, true_ranks[i] of row
  // true_rows[i] ([T']; true_rows may be left undefined when there is one per row, in row
  // order), and the child it falls under, [R]. The true child then scores that point alone (the
  // log-sum-exp of its rows), so that every level is pulled towards the point itself rather than
  // towards all the points of its child (which an untrained level cannot tell apart); the other
  // children still pool all their candidates.
  torch::Tensor true_ranks{}, true_groups{}, true_rows{};
  // The dense form, for a log-sum-exp where most rows share their candidates (GatherCandidates
  // with `allow_dense`; ranks, rows and groups are then undefined): the distinct table rows [U],
  // the child of each [U], and whether each is a candidate of each row, [U, R].
  torch::Tensor dense_table_rows{}, dense_children{}, dense_mask{};
  // The flat lists' leaf rank of each candidate's point, [T] (kBestPoint pools a point's rows).
  torch::Tensor points{};
};
// The candidates of rows [begin, end): row r pools over the points under parent_nodes[r] that
// slot slots[r] observes (PointCandidates::Under); rows whose parent is < 0 get none. Row ids in
// the result count from 0 at `begin`. With `allow_dense` (training's log-sum-exp), the dense form
// where it is the cheaper one.
FlatCandidates GatherCandidates(const PointCandidates& candidates, const int* slots,
                                const int64_t* parent_nodes, int64_t begin, int64_t end, int level,
                                bool allow_dense = false);

// How a child pools the scores <point_rows[rank], projected[r]> of its candidates. Training takes
// their log-sum-exp. Decoding takes the child's best point (kBestPoint), a point scoring its row
// or, with several rows per point, their log-sum-exp. Each row's bias starts at -log of its
// point's rows, so that a point starts as the log of its views' mean exponential: a soft vote of
// its views, which on real maps ranks the true point first more often than its best view
// (nearest-neighbour matching) or its views' mean (docs/decisions.md, "Pooling a point's views").
enum class Pooling { kLogSumExp, kBestPoint };
// Logits [R, branching] of pooled point rows, each child pooling its candidates' scores; -inf
// where a child has none (a row with no candidate at all gets 0 everywhere). The score of a row's
// true point (FlatCandidates' true_ranks) is the log-sum-exp of the point's own rows. With
// `sparse_gradient` the table's gradient is sparse (for lazy Adam): only the finest level with a
// choice trains the rows, and its candidates are a few points per row, a sliver of a large map's
// table.
torch::Tensor PooledPointLogits(const torch::Tensor& projected, const torch::Tensor& point_rows,
                                const FlatCandidates& candidates, int64_t branching,
                                Pooling pooling, bool sparse_gradient = false);

torch::Device TorchDevice(ComputeDevice device);
// Rows scaled to unit L2 norm (zero rows stay zero).
torch::Tensor NormalizeRows(const torch::Tensor& rows);

struct Network::Impl {
  NetworkShape shape;
  NetworkOptions options;
  HscNet module{nullptr};
  ComputeDevice device = ComputeDevice::kCpu;
  // The CPU kernels' layout of the module's matrices (mutable: Predict is const).
  mutable PackedWeightCache packed_weights;
};

// How an archive stores the weights: as trained (checkpoints), or with every matrix as 8-bit rows
// and a scale per row (bundles), a quarter of the bytes; the largest error, half a row's step
// (its largest magnitude / 254), moved no held-out accuracy beyond its sampling noise
// (docs/decisions.md).
enum class WeightStorage { kFloat32, kInt8Rows };

// A matrix [rows, cols] as int8 values and fp32 scales [rows]: row i is values[i] * scales[i], the
// scale being the row's largest magnitude / 127 (0 for a zero row).
struct Int8Rows {
  torch::Tensor values;
  torch::Tensor scales;
};
Int8Rows QuantizeRows(const torch::Tensor& matrix);
torch::Tensor DequantizeRows(const Int8Rows& rows);

// The trainer's access to the modules behind a Network.
struct NetworkInternals {
  static HscNet& Module(Network& network) { return network.impl_->module; }
  static const HscNet& Module(const Network& network) { return network.impl_->module; }
  static PackedWeightCache& PackedWeights(const Network& network) {
    return network.impl_->packed_weights;
  }
  // Saves into / restores from an archive nested in a larger one (checkpoints keep every weight
  // as trained).
  static void SaveTo(const Network& network, torch::serialize::OutputArchive& archive,
                     WeightStorage storage);
  static Network LoadFrom(torch::serialize::InputArchive& archive, const std::string& source,
                          ComputeDevice device);
  // Predict through libtorch operators (the CUDA path), whatever the device: the reference the
  // CPU kernels are tested against.
  static PointPredictions PredictWithTorch(const Network& network,
                                           const DescriptorMatrix& descriptors,
                                           const std::vector<uint32_t>& image_indices,
                                           const LabelTree& tree,
                                           const Visibility* visibility_mask);
};

}  // namespace hscloc
