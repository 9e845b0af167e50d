// The hierarchical scene coordinate classification network (Li et al., "Hierarchical Scene
// Coordinate Classification and Regression for Visual Localization", CVPR 2020), in its
// classification-only form for sparse features: for each keypoint descriptor and a database image
// id it predicts the label path of a 3D point in the map's label tree, level by level.
//
// Level j:
//   trunk        t = ELU(Linear_HC(ELU(Linear_DH(x))))              x: L2-normalized descriptor
//                (one trunk per level, or one shared by every level: NetworkOptions::shared_trunk)
//   generator    z = ELU(Linear(ELU(E_id[image] + sum_{k<j} E_k[label_k])))
//                gamma_i = Linear(z), beta_i = Linear(z)           one pair per conditioned layer
//   conditioned  h_i = ELU(gamma_i * (W_i h_{i-1} + b_i) + beta_i)  h_0 = t
//   output       logits = Linear(h_last) over the children of the parent cluster
//
// Three departures measured at city scale (docs/decisions.md, "Training at city scale"), each an
// option, all off in NetworkOptions::PaperFaithful():
//   node conditioning   the generator reads one embedding row per tree node, that of the parent
//                       (the whole label prefix), instead of sum_{k<j} E_k[label_k];
//   node output rows    logits_c = <u_child(c), [P h_last, 1]>: a projection P (C -> r) shared by
//                       the level and one row u (r weights and a bias) per tree node, so every
//                       parent has a classifier of its own over its children (near the leaves a
//                       learned nearest-class-mean matcher). Children a parent does not have get
//                       probability 0.
//   pooled point rows   logits_c = logsumexp_{p in subtree(c), seen} <u_p, [P h_last, 1]>: one
//                       row per point shared by all levels, pooled over each child's points.
//   descriptor shortcut pooled point rows scored against [P h_last + s x, 1], the unit descriptor
//                       added, P from zero, the rows from the points' mean descriptors.
// The paper's 1x1 convolutions over one-hot labels and an encoded image id are embedding lookups;
// the paper's per-position linear modulation is gamma * (W h + b) + beta.
//
// Inference runs the levels in order, each conditioned on the labels predicted before it. The
// trunk and the first conditioned layer's linear part depend on the descriptor only, so they run
// once per query; the image-dependent parts run on all (image, descriptor) pairs as one batch,
// with the generator evaluated once per distinct (image, label prefix).
//
// libtorch stays behind this interface: callers see Eigen matrices and plain structs.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "map/label_tree.h"
#include "map/map_blobs.h"
#include "map/map_bundle.h"
#include "map/visibility.h"
#include "scene/features.h"
#include "util/memory.h"

namespace hscloc {

class PointRowIndex;

// Where tensors live. kCuda needs a libtorch built with CUDA and a visible GPU.
enum class ComputeDevice { kCpu, kCuda };
// "cpu" or "cuda"; throws std::invalid_argument otherwise.
ComputeDevice ParseComputeDevice(const std::string& name);
std::string ComputeDeviceName(ComputeDevice device);
bool IsComputeDeviceAvailable(ComputeDevice device);

// Sets the CPU threads of libtorch and of Predict's CPU kernels for the whole process (<= 0: all
// cores). Where libtorch's
// matrix products run in OpenBLAS's own thread pool (Debian's libtorch), OpenBLAS gets the threads
// and libtorch's OpenMP pool one: both pools spin while waiting, and on shared cores they starve
// each other (training 4 to 25 times slower, docs/decisions.md).
void SetComputeThreads(int num_threads);
// The threads SetComputeThreads set (0: all cores).
int ComputeThreads();

// libtorch's fp32 matrix product of two size x size matrices, in GFLOP/s, over at least
// `min_seconds` (after a warm-up), with the threads SetComputeThreads gave: the machine's peak
// that reports compare against.
double LibtorchMatrixProductGflops(int64_t size, double min_seconds);

// What the map fixes: descriptor dimension, label tree shape and the number of database images.
struct NetworkShape {
  int descriptor_dim = 0;
  int levels = 0;
  int branching = 0;
  // Database images; the image embedding has one more row, index num_images, meaning "no image".
  int num_images = 0;
  // Nodes of the label tree per depth, 0 (the root) .. levels; empty when unknown, which only the
  // paper's configuration (no per-node tables) allows.
  std::vector<int64_t> nodes_per_depth;
  // Pooled point rows with several rows per point (prototypes, TrainerOptions::point_prototypes):
  // the rows of the point of leaf rank l are [point_row_offsets[l], point_row_offsets[l + 1]);
  // empty: one row per point, the row of a point its leaf rank.
  std::vector<int64_t> point_row_offsets;

  // The shape of a network over `tree`, with its node counts.
  static NetworkShape ForTree(int descriptor_dim, const LabelTree& tree, int num_images);
  // The first node id of a depth (nodes are numbered breadth-first); needs nodes_per_depth.
  int64_t FirstNodeOfDepth(int depth) const;
  // Whether the tree has the node counts (and points) this shape records.
  bool FitsTree(const LabelTree& tree) const;
  // Rows of the pooled point table: one per point, or the prototypes' count.
  int64_t NumPointRows() const;
  void Check() const;
  bool operator==(const NetworkShape& other) const;
};

struct NetworkOptions {
  int channels = 512;          // C: width of each level's conditioned layers and trunk output
  int embedding_dim = 64;      // width of the image and label embeddings and of the generator
  int conditioned_layers = 1;  // FiLM-modulated layers per level, 1 .. 3
  int trunk_channels = 512;    // H: width of the trunk's hidden layer (runs once per keypoint)
  // The generator reads the parent node's own embedding row (one per tree node) rather than the
  // sum of one row per coarser label (the paper's one-hot labels); needs the shape's node counts.
  bool node_conditioning = true;
  // r > 0: per-node output rows of r weights and a bias after a shared projection C -> r;
  // 0: the paper's Linear(C, branching) shared by every parent of the level.
  int node_output_dim = 64;
  // Pooled point rows (needs node_output_dim > 0): one table of rows, one per point (leaf), shared
  // by every level; a level scores a child by the log-sum-exp of the scores of the points in its
  // subtree that the conditioning image observes (all of them without an image or a mask). Every
  // level is then a classifier with many prototypes per class (Qian et al., "SoftTriple Loss",
  // ICCV 2019), so a coarse cluster of a thousand unrelated descriptors needs no single row that
  // fits them all; off: each node has its own row (docs/decisions.md, "Training at city scale").
  // The trainer starts the rows from the points' descriptors.
  bool pooled_point_rows = false;
  // The descriptor shortcut (needs pooled point rows at the descriptor's width, node_output_dim ==
  // D): a level scores point p by <u_p, P h + s x> + b_p, the unit descriptor x itself added to the
  // projection, with P starting at zero and the rows at the points' mean training descriptors. The
  // untrained network is then the nearest-class-mean matcher among the points each image sees, and
  // training learns a correction. On Lund it reaches the class means' held-out accuracy at a
  // seventh of the bytes of the wider network, and it is the default below
  // kMinPointsForNodeOutputRows points (model/trainer.h; docs/decisions.md, "The network on real
  // photos").
  bool descriptor_shortcut = false;
  // Trained with the visibility softmax: decode with the visibility mask (the Localizer does so on
  // its own for such a network).
  bool masked_decoding = false;
  // One trunk for every level instead of one per level: each level keeps its own conditioned
  // layers, and the trunk, most of a query's work at the default widths (it runs on every
  // keypoint at every level), runs once per keypoint (docs/decisions.md, "Latency at Aachen
  // scale").
  bool shared_trunk = false;

  // The configuration of Li et al. (label-sum conditioning, a shared output layer per level).
  static NetworkOptions PaperFaithful();
  // Whether any per-node table needs the shape's node counts.
  bool NeedsNodeCounts() const { return node_conditioning || node_output_dim > 0; }
  void Check() const;
  bool operator==(const NetworkOptions& other) const;
};

// What the CPU path of Network::Predict computes from the descriptors alone, per level: the
// trunk and the first conditioned layer's W h + b, [N, C] (the per-keypoint part of the work, run
// once however many images condition it). One per query and thread.
struct DescriptorLayerCache {
  const float* descriptors = nullptr;  // the matrix it was filled from, and its size
  int64_t rows = 0;
  int64_t cols = 0;
  std::vector<UninitializedVector<float>> levels;  // empty until that level was computed
  // A shared trunk's output [N, H -> C] and the trunk weights it came from (null: none yet).
  UninitializedVector<float> shared_trunk;
  const void* shared_trunk_weight = nullptr;
};

// Predictions for K conditioning images and N descriptors; (k, n) is row k * N + n of `labels`.
struct PointPredictions {
  int64_t num_images = 0;       // K
  int64_t num_descriptors = 0;  // N
  // Dense point index of the leaf the label path leads to; -1 when the path leads to no point.
  Eigen::Matrix<int64_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> point_indices;  // K x N
  // Product over the levels of the chosen label's softmax probability (not renormalized when a
  // visibility mask excluded other labels), in [0, 1].
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> confidences;  // K x N
  // The predicted label path of every (k, n).
  Eigen::Matrix<uint8_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> labels;  // K*N x levels
  // Wall time of each level of the forward pass, coarsest first (where the time goes).
  std::vector<double> level_milliseconds;
  // The floating-point operations each level's matrix products performed (2 per multiply-add),
  // counting the work done: the modulation once per run of rows that share it, the output only
  // over the children or points a row scores. The CPU path fills it; the honest floor of the
  // pass is their sum at the machine's peak rate.
  std::vector<double> level_flops;
};

class Network {
 public:
  // A network with freshly initialized weights: the same shape, options and seed give the same
  // weights. Seeds libtorch's global generator with `seed`.
  Network(const NetworkShape& shape, const NetworkOptions& options, uint64_t seed);
  ~Network();
  Network(Network&&) noexcept;
  Network& operator=(Network&&) noexcept;
  Network(const Network&) = delete;
  Network& operator=(const Network&) = delete;

  const NetworkShape& shape() const;
  const NetworkOptions& options() const;
  // The image index that stands for "no image" (the id-free ablation): shape().num_images.
  uint32_t NoImageIndex() const { return static_cast<uint32_t>(shape().num_images); }
  int64_t NumParameters() const;

  // Moves the weights; throws std::invalid_argument when the device is not available.
  void SetDevice(ComputeDevice device);
  ComputeDevice device() const;

  // A libtorch archive holding the shape, the options and the weights, every matrix as 8-bit rows
  // with a scale per row: a quarter of the bytes, and no held-out accuracy moved beyond its
  // sampling noise (docs/decisions.md).
  void Save(std::ostream& stream) const;
  // Throws std::invalid_argument naming `source` when the data is not a network archive of this
  // format version.
  static Network Load(std::istream& stream, const std::string& source,
                      ComputeDevice device = ComputeDevice::kCpu);
  // The network of a trained map bundle (blob map_blobs::kNetwork); throws naming the bundle
  // when it has none.
  static Network FromBundle(const MapBundle& bundle, ComputeDevice device = ComputeDevice::kCpu);

  // Predicts the point of every descriptor (N x D, any norm; rows are L2-normalized here) for each
  // of the K image indices (< num_images, or NoImageIndex()). With `visibility_mask`, each level
  // only chooses among children whose subtree holds a point the conditioning image observes (a
  // row falls back to the plain argmax where no child qualifies, and NoImageIndex() rows are never
  // masked). Throws std::invalid_argument when the descriptor dimension, an image index, the tree
  // or the visibility lists do not fit the network. Safe to call concurrently.
  // With `cache`, each level's descriptor-only layers are taken from it, or computed into it on
  // first use, so that Predict calls on the same descriptors (a query's candidates, its votes
  // without an image id, the votes' candidates) run them once; a cache filled from other
  // descriptors throws std::invalid_argument. With `index` (model/point_row_index.h, built from
  // this network), rows without an image score the first level through it: approximate, for the
  // votes. The libtorch path (CUDA) uses neither.
  PointPredictions Predict(const DescriptorMatrix& descriptors,
                           const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                           const Visibility* visibility_mask = nullptr,
                           DescriptorLayerCache* cache = nullptr,
                           const PointRowIndex* index = nullptr) const;

  // Predict through libtorch's operators instead of hscloc's CPU kernels: the path a CUDA device
  // takes, and the reference the CPU kernels are tested against. Same contract as Predict.
  PointPredictions PredictWithLibtorch(const DescriptorMatrix& descriptors,
                                       const std::vector<uint32_t>& image_indices,
                                       const LabelTree& tree,
                                       const Visibility* visibility_mask = nullptr) const;

  // Floating-point operations (2 per multiply-add) of the matrix products of one Predict call,
  // counting the generator once per (image, descriptor) pair, i.e. without the deduplication of
  // identical (image, label prefix) rows that Predict performs. Levels of `tree` that offer no
  // choice cost nothing (Predict skips them).
  double PredictFlops(int64_t num_descriptors, int64_t num_images, const LabelTree& tree) const;

  // The pooled point rows, [NumPointRows() x (width + 1)] row-major (a row's weights, then its
  // bias), with their width; empty without pooled point rows.
  std::vector<float> PointRows(int64_t* width) const;

  // True when both networks have the same shape, options and bit-identical weights.
  bool HasSameWeights(const Network& other) const;

 private:
  struct Impl;
  explicit Network(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
  friend struct NetworkInternals;
};

}  // namespace hscloc
