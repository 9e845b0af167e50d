#include "model/network.h"

#include <ATen/Parallel.h>
#include <dlfcn.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <istream>
#include <limits>
#include <ostream>
#include <sstream>
#include <string>
#include <utility>

#include "model/network_decoding.h"
#include "model/network_module.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {
namespace {

constexpr int kMaxNodeOutputDim = 1024;
constexpr int kMaxConditionedLayers = 3;

// Threads of the CPU inference kernels (SetComputeThreads; 0: all cores).
std::atomic<int> compute_threads{0};

torch::Tensor Elu(const torch::Tensor& x) { return torch::elu(x); }

// Rows of unit-variance logits for unit-variance projections; biases start at 0.
void InitializeOutputRows(torch::Tensor& rows, int64_t dim) {
  rows.narrow(1, 0, dim).normal_(0, 1 / std::sqrt(static_cast<double>(dim)));
}

}  // namespace

int ComputeThreads() { return compute_threads.load(); }

// ---------------------------------------------------------------------------------------------
// Devices and small helpers.

ComputeDevice ParseComputeDevice(const std::string& name) {
  if (name == "cpu") return ComputeDevice::kCpu;
  if (name == "cuda") return ComputeDevice::kCuda;
  ThrowInvalidArgument("unknown compute device '{}' (cpu, cuda)", name);
}

std::string ComputeDeviceName(ComputeDevice device) {
  return device == ComputeDevice::kCuda ? "cuda" : "cpu";
}

bool IsComputeDeviceAvailable(ComputeDevice device) {
  return device == ComputeDevice::kCpu || torch::cuda::is_available();
}

void SetComputeThreads(int num_threads) {
  const int threads = ResolveNumThreads(num_threads);
  using SetBlasThreads = void (*)(int);
  const auto set_blas_threads =
      reinterpret_cast<SetBlasThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
  if (set_blas_threads != nullptr) {
    set_blas_threads(threads);
    torch::set_num_threads(1);
  } else {
    torch::set_num_threads(threads);
  }
  compute_threads.store(threads);
}

torch::Device TorchDevice(ComputeDevice device) {
  if (!IsComputeDeviceAvailable(device)) {
    ThrowInvalidArgument("compute device '{}' is not available (libtorch without CUDA or no GPU)",
                         ComputeDeviceName(device));
  }
  return device == ComputeDevice::kCuda ? torch::Device(torch::kCUDA) : torch::Device(torch::kCPU);
}

torch::Tensor NormalizeRows(const torch::Tensor& rows) {
  return rows / rows.norm(2, /*dim=*/1, /*keepdim=*/true).clamp_min(1e-12);
}

NetworkShape NetworkShape::ForTree(int descriptor_dim, const LabelTree& tree, int num_images) {
  NetworkShape shape{descriptor_dim, tree.levels(), tree.branching(), num_images, {}, {}};
  shape.nodes_per_depth = tree.NodesPerLevel();
  return shape;
}

int64_t NetworkShape::FirstNodeOfDepth(int depth) const {
  THROW_CHECK_MSG(depth >= 0 && depth < static_cast<int>(nodes_per_depth.size()),
                  "NetworkShape.nodes_per_depth: no depth {}", depth);
  int64_t first = 0;
  for (int d = 0; d < depth; ++d) first += nodes_per_depth[d];
  return first;
}

bool NetworkShape::FitsTree(const LabelTree& tree) const {
  return nodes_per_depth.empty() ||
         nodes_per_depth == ForTree(descriptor_dim, tree, num_images).nodes_per_depth;
}

int64_t NetworkShape::NumPointRows() const {
  if (!point_row_offsets.empty()) return point_row_offsets.back();
  return nodes_per_depth.empty() ? 0 : nodes_per_depth.back();
}

void NetworkShape::Check() const {
  THROW_CHECK_MSG(descriptor_dim > 0, "NetworkShape.descriptor_dim = {}", descriptor_dim);
  THROW_CHECK_MSG(levels > 0, "NetworkShape.levels = {}", levels);
  THROW_CHECK_MSG(branching > 1 && branching <= 256, "NetworkShape.branching = {}", branching);
  THROW_CHECK_MSG(num_images > 0, "NetworkShape.num_images = {}", num_images);
  THROW_CHECK_MSG(
      nodes_per_depth.empty() ||
          (static_cast<int>(nodes_per_depth.size()) == levels + 1 && nodes_per_depth[0] == 1 &&
           std::all_of(nodes_per_depth.begin(), nodes_per_depth.end(),
                       [](int64_t count) { return count > 0; })),
      "NetworkShape.nodes_per_depth: {} entries for {} levels, the root first",
      nodes_per_depth.size(), levels);
  if (point_row_offsets.empty()) return;
  THROW_CHECK_MSG(!nodes_per_depth.empty() &&
                      static_cast<int64_t>(point_row_offsets.size()) == nodes_per_depth.back() + 1,
                  "NetworkShape.point_row_offsets: {} entries for {} points",
                  point_row_offsets.size(), nodes_per_depth.empty() ? 0 : nodes_per_depth.back());
  THROW_CHECK_MSG(point_row_offsets[0] == 0, "NetworkShape.point_row_offsets must start at 0");
  for (size_t i = 1; i < point_row_offsets.size(); ++i) {
    THROW_CHECK_MSG(point_row_offsets[i] > point_row_offsets[i - 1],
                    "NetworkShape.point_row_offsets: point {} has no row", i - 1);
  }
}

bool NetworkShape::operator==(const NetworkShape& other) const {
  return descriptor_dim == other.descriptor_dim && levels == other.levels &&
         branching == other.branching && num_images == other.num_images &&
         nodes_per_depth == other.nodes_per_depth && point_row_offsets == other.point_row_offsets;
}

void NetworkOptions::Check() const {
  THROW_CHECK_MSG(channels > 0, "NetworkOptions.channels = {}", channels);
  THROW_CHECK_MSG(trunk_channels > 0, "NetworkOptions.trunk_channels = {}", trunk_channels);
  THROW_CHECK_MSG(embedding_dim > 0, "NetworkOptions.embedding_dim = {}", embedding_dim);
  THROW_CHECK_MSG(conditioned_layers >= 1 && conditioned_layers <= kMaxConditionedLayers,
                  "NetworkOptions.conditioned_layers = {} (1 .. {})", conditioned_layers,
                  kMaxConditionedLayers);
  THROW_CHECK_MSG(node_output_dim >= 0 && node_output_dim <= kMaxNodeOutputDim,
                  "NetworkOptions.node_output_dim = {} (0 .. {})", node_output_dim,
                  kMaxNodeOutputDim);
  THROW_CHECK_MSG(!descriptor_shortcut || pooled_point_rows,
                  "NetworkOptions.descriptor_shortcut needs pooled_point_rows");
}

NetworkOptions NetworkOptions::PaperFaithful() {
  NetworkOptions options;
  options.node_conditioning = false;
  options.node_output_dim = 0;
  return options;
}

bool NetworkOptions::operator==(const NetworkOptions& other) const {
  return channels == other.channels && trunk_channels == other.trunk_channels &&
         embedding_dim == other.embedding_dim && conditioned_layers == other.conditioned_layers &&
         node_conditioning == other.node_conditioning && node_output_dim == other.node_output_dim &&
         pooled_point_rows == other.pooled_point_rows &&
         descriptor_shortcut == other.descriptor_shortcut &&
         masked_decoding == other.masked_decoding && shared_trunk == other.shared_trunk;
}

torch::Tensor ChildNodesOf(const LabelTree& tree, const int64_t* parent_nodes, int64_t rows) {
  const int64_t branching = tree.branching();
  torch::Tensor children = torch::full({rows, branching}, -1, torch::kInt64);
  int64_t* data = children.data_ptr<int64_t>();
  for (int64_t r = 0; r < rows; ++r) {
    const int64_t parent = parent_nodes[r];
    if (parent < 0) continue;
    const int64_t first = tree.FirstChild(static_cast<uint32_t>(parent));
    const int64_t count = tree.NumChildren(static_cast<uint32_t>(parent));
    for (int64_t c = 0; c < count; ++c) data[r * branching + c] = first + c;
  }
  return children;
}

// ---------------------------------------------------------------------------------------------
// Modules.

LevelImpl::LevelImpl(int level, const NetworkShape& shape, const NetworkOptions& options,
                     const LevelImpl* trunk_owner)
    : level_(level) {
  node_output_dim_ = options.node_output_dim;
  pooled_ = options.pooled_point_rows;
  // A level whose parents all have one child never runs (Predict and training take the only
  // child): it holds no weights. Without node counts (archives before version 3) every level runs.
  has_weights_ = shape.nodes_per_depth.empty() ||
                 shape.nodes_per_depth.at(level + 1) > shape.nodes_per_depth.at(level);
  if (!has_weights_) return;
  const int64_t channels = options.channels;
  const int64_t embedding = options.embedding_dim;
  const int64_t trunk_channels = options.trunk_channels;
  borrows_trunk_ = trunk_owner != nullptr;
  if (borrows_trunk_) {
    // The owner's modules, not registered here: the parameters are saved, trained and moved
    // once, as the owner's.
    trunk1_ = trunk_owner->trunk1_;
    trunk2_ = trunk_owner->trunk2_;
  } else {
    trunk1_ = register_module("trunk1", torch::nn::Linear(shape.descriptor_dim, trunk_channels));
    trunk2_ = register_module("trunk2", torch::nn::Linear(trunk_channels, channels));
  }
  image_embedding_ =
      register_module("image_embedding", torch::nn::Embedding(shape.num_images + 1, embedding));
  if (options.node_conditioning) {
    node_embedding_first_ = shape.FirstNodeOfDepth(level);
    node_embedding_ = register_module(
        "node_embedding", torch::nn::Embedding(shape.nodes_per_depth.at(level), embedding));
  } else {
    for (int k = 0; k < level; ++k) {
      label_embeddings_.push_back(register_module(
          "label_embedding" + std::to_string(k), torch::nn::Embedding(shape.branching, embedding)));
    }
  }
  generator_ = register_module("generator", torch::nn::Linear(embedding, embedding));
  for (int i = 0; i < options.conditioned_layers; ++i) {
    const std::string suffix = std::to_string(i);
    gamma_heads_.push_back(
        register_module("gamma" + suffix, torch::nn::Linear(embedding, channels)));
    beta_heads_.push_back(register_module("beta" + suffix, torch::nn::Linear(embedding, channels)));
    conditioned_.push_back(
        register_module("conditioned" + suffix, torch::nn::Linear(channels, channels)));
  }
  if (node_output_dim_ > 0) {
    const int64_t children = shape.nodes_per_depth.at(level + 1);
    node_rows_first_ = shape.FirstNodeOfDepth(level + 1);
    projection_ = register_module("projection", torch::nn::Linear(channels, node_output_dim_));
    if (options.descriptor_shortcut) {
      shortcut_scale_ =
          register_parameter("shortcut_scale", torch::full({1}, kInitialShortcutScale));
    }
    if (!pooled_) {
      node_rows_ = register_parameter("node_rows", torch::zeros({children, node_output_dim_ + 1}));
    }
  } else {
    output_ = register_module("output", torch::nn::Linear(channels, shape.branching));
  }

  // He initialization keeps the activations of the ELU stack at unit scale (libtorch's default
  // shrinks them by about 1/sqrt(3) per layer, leaving an untrained network nearly linear and
  // slow to start). The heads start near gamma = 1, beta = 0 (deviations of about 0.1): every
  // level begins close to a plain MLP and the conditioning grows from there.
  torch::NoGradGuard no_grad;
  const auto he_initialize = [](torch::nn::Linear& linear) {
    torch::nn::init::kaiming_normal_(linear->weight, 0, torch::kFanIn, torch::kReLU);
    linear->bias.zero_();
  };
  if (!borrows_trunk_) {
    he_initialize(trunk1_);
    he_initialize(trunk2_);
  }
  he_initialize(generator_);
  for (int i = 0; i < options.conditioned_layers; ++i) {
    he_initialize(conditioned_[i]);
    const double head_std = 0.1 / std::sqrt(static_cast<double>(embedding));
    torch::nn::init::normal_(gamma_heads_[i]->weight, 0, head_std);
    gamma_heads_[i]->bias.fill_(1.0);
    torch::nn::init::normal_(beta_heads_[i]->weight, 0, head_std);
    beta_heads_[i]->bias.zero_();
  }
  if (node_output_dim_ > 0) {
    // Rows of unit-variance logits for unit-variance projections; biases start at 0. Beside the
    // descriptor shortcut the projection starts at zero: the level starts as the class means.
    if (shortcut_scale_.defined()) {
      projection_->weight.zero_();
    } else {
      torch::nn::init::kaiming_normal_(projection_->weight, 0, torch::kFanIn, torch::kLinear);
    }
    projection_->bias.zero_();
    if (!pooled_) InitializeOutputRows(node_rows_, node_output_dim_);
  } else {
    torch::nn::init::kaiming_normal_(output_->weight, 0, torch::kFanIn, torch::kLinear);
    output_->bias.zero_();
  }
  input_scale_ = std::sqrt(static_cast<double>(shape.descriptor_dim));
}

torch::Tensor LevelImpl::Trunk(const torch::Tensor& descriptors) {
  return Elu(trunk2_(Elu(trunk1_(descriptors * input_scale_))));
}

LevelModulation LevelImpl::Generate(const torch::Tensor& image_indices,
                                    const torch::Tensor& prefix_labels,
                                    const torch::Tensor& parent_nodes) {
  torch::Tensor embedding = image_embedding_(image_indices);
  if (node_embedding_) {
    embedding = embedding +
                torch::nn::functional::embedding(
                    (parent_nodes - node_embedding_first_).clamp_min(0), node_embedding_->weight,
                    torch::nn::functional::EmbeddingFuncOptions().sparse(sparse_node_rows_));
  }
  for (int k = 0; k < static_cast<int>(label_embeddings_.size()); ++k) {
    embedding = embedding + label_embeddings_[k](prefix_labels.select(1, k));
  }
  const torch::Tensor z = Elu(generator_(Elu(embedding)));
  LevelModulation modulation;
  for (size_t i = 0; i < conditioned_.size(); ++i) {
    modulation.gammas.push_back(gamma_heads_[i](z));
    modulation.betas.push_back(beta_heads_[i](z));
  }
  return modulation;
}

torch::Tensor LevelImpl::ConditionedLinear(int layer, const torch::Tensor& features) {
  return conditioned_[layer](features);
}

torch::Tensor LevelImpl::Project(const torch::Tensor& features,
                                 const torch::Tensor& unit_descriptors) {
  torch::Tensor projected = projection_(features);
  if (shortcut_scale_.defined()) projected = projected + shortcut_scale_ * unit_descriptors;
  return torch::cat({projected, torch::ones({projected.size(0), 1}, projected.options())}, 1);
}

torch::Tensor LevelImpl::Logits(const torch::Tensor& features, const torch::Tensor& child_nodes) {
  if (node_output_dim_ == 0) return output_(features);
  if (pooled_) throw std::logic_error("LevelImpl::Logits on pooled point rows");
  const torch::Tensor exists = child_nodes.ge(0);
  const torch::Tensor rows = (child_nodes - node_rows_first_).clamp_min(0);
  // [R, branching, r + 1] rows against [R, r + 1, 1] projections with a constant 1 for the bias.
  const torch::Tensor gathered = torch::nn::functional::embedding(
      rows, node_rows_, torch::nn::functional::EmbeddingFuncOptions().sparse(sparse_node_rows_));
  const torch::Tensor logits =
      torch::bmm(gathered, Project(features, torch::Tensor()).unsqueeze(2)).squeeze(2);
  // A row without children (a path that left the tree) keeps finite logits.
  const torch::Tensor absent = exists.logical_not().logical_and(exists.any(1, true));
  return logits.masked_fill(absent, -std::numeric_limits<float>::infinity());
}

LevelWeights LevelImpl::CpuWeights(PackedWeightCache& packed) const {
  if (!has_weights_) throw std::logic_error("CpuWeights of a level without a choice");
  const auto data = [](const torch::Tensor& tensor) -> const float* {
    if (!tensor.device().is_cpu() || tensor.scalar_type() != torch::kFloat32 ||
        !tensor.is_contiguous()) {
      throw std::logic_error("network weights are not contiguous fp32 CPU tensors");
    }
    return tensor.data_ptr<float>();
  };
  LevelWeights weights;
  weights.input_scale = static_cast<float>(input_scale_);
  weights.trunk1_weight = packed.Get(trunk1_->weight);
  weights.trunk1_bias = data(trunk1_->bias);
  weights.trunk2_weight = packed.Get(trunk2_->weight);
  weights.trunk2_bias = data(trunk2_->bias);
  weights.image_embedding = data(image_embedding_->weight);
  for (const torch::nn::Embedding& table : label_embeddings_) {
    weights.label_embeddings.push_back(data(table->weight));
  }
  if (node_embedding_) {
    weights.node_embedding = data(node_embedding_->weight);
    weights.node_embedding_first = node_embedding_first_;
  }
  weights.generator_weight = packed.Get(generator_->weight);
  weights.generator_bias = data(generator_->bias);
  for (size_t i = 0; i < conditioned_.size(); ++i) {
    weights.gamma_weights.push_back(packed.Get(gamma_heads_[i]->weight));
    weights.gamma_biases.push_back(data(gamma_heads_[i]->bias));
    weights.beta_weights.push_back(packed.Get(beta_heads_[i]->weight));
    weights.beta_biases.push_back(data(beta_heads_[i]->bias));
    weights.conditioned_weights.push_back(packed.Get(conditioned_[i]->weight));
    weights.conditioned_biases.push_back(data(conditioned_[i]->bias));
  }
  if (node_output_dim_ > 0) {
    weights.node_output_dim = node_output_dim_;
    weights.projection_weight = packed.Get(projection_->weight);
    weights.projection_bias = data(projection_->bias);
    if (shortcut_scale_.defined()) weights.shortcut_scale = data(shortcut_scale_);
    if (!pooled_) weights.node_rows = data(node_rows_);
    weights.node_rows_first = node_rows_first_;
  } else {
    weights.output_weight = packed.Get(output_->weight);
    weights.output_bias = data(output_->bias);
  }
  return weights;
}

torch::Tensor LevelImpl::Features(const torch::Tensor& descriptors,
                                  const torch::Tensor& image_indices,
                                  const torch::Tensor& prefix_labels,
                                  const torch::Tensor& parent_nodes) {
  return FeaturesOfTrunk(Trunk(descriptors), image_indices, prefix_labels, parent_nodes);
}

torch::Tensor LevelImpl::FeaturesOfTrunk(const torch::Tensor& trunk,
                                         const torch::Tensor& image_indices,
                                         const torch::Tensor& prefix_labels,
                                         const torch::Tensor& parent_nodes) {
  torch::Tensor features = trunk;
  const LevelModulation modulation = Generate(image_indices, prefix_labels, parent_nodes);
  for (size_t i = 0; i < conditioned_.size(); ++i) {
    features =
        Elu(torch::addcmul(modulation.betas[i], modulation.gammas[i], conditioned_[i](features)));
  }
  return features;
}

torch::Tensor LevelImpl::forward(const torch::Tensor& descriptors,
                                 const torch::Tensor& image_indices,
                                 const torch::Tensor& prefix_labels,
                                 const torch::Tensor& parent_nodes,
                                 const torch::Tensor& child_nodes) {
  return Logits(Features(descriptors, image_indices, prefix_labels, parent_nodes), child_nodes);
}

HscNetImpl::HscNetImpl(const NetworkShape& shape, const NetworkOptions& options) {
  // A shared trunk belongs to the first level with weights; the others borrow it.
  const LevelImpl* trunk_owner = nullptr;
  for (int level = 0; level < shape.levels; ++level) {
    levels.push_back(register_module("level" + std::to_string(level),
                                     Level(level, shape, options, trunk_owner)));
    if (options.shared_trunk && trunk_owner == nullptr && levels.back()->HasWeights()) {
      trunk_owner = levels.back().get();
    }
  }
  if (options.pooled_point_rows) {
    point_rows = register_parameter(
        "point_rows",
        torch::zeros({shape.NumPointRows(), static_cast<int64_t>(options.node_output_dim) + 1}));
    torch::NoGradGuard no_grad;
    InitializeOutputRows(point_rows, options.node_output_dim);
  }
}

// ---------------------------------------------------------------------------------------------
// Network.

void CheckOptionsFitShape(const NetworkShape& shape, const NetworkOptions& options) {
  if (options.NeedsNodeCounts() && shape.nodes_per_depth.empty()) {
    ThrowInvalidArgument(
        "NetworkShape.nodes_per_depth is empty, but NetworkOptions.node_conditioning or "
        "node_output_dim need the tree's node counts (NetworkShape::ForTree)");
  }
  if (!shape.point_row_offsets.empty() && !options.pooled_point_rows) {
    ThrowInvalidArgument("NetworkShape.point_row_offsets need NetworkOptions.pooled_point_rows");
  }
  if (options.descriptor_shortcut && options.node_output_dim != shape.descriptor_dim) {
    ThrowInvalidArgument(
        "NetworkOptions.descriptor_shortcut needs node_output_dim ({}) equal to the descriptor "
        "dimension ({})",
        options.node_output_dim, shape.descriptor_dim);
  }
}

Network::Network(const NetworkShape& shape, const NetworkOptions& options, uint64_t seed) {
  shape.Check();
  options.Check();
  CheckOptionsFitShape(shape, options);
  torch::manual_seed(seed);
  impl_ = std::make_unique<Impl>();
  impl_->shape = shape;
  impl_->options = options;
  impl_->module = HscNet(shape, options);
}

Network::Network(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Network::~Network() = default;
Network::Network(Network&&) noexcept = default;
Network& Network::operator=(Network&&) noexcept = default;

const NetworkShape& Network::shape() const { return impl_->shape; }
const NetworkOptions& Network::options() const { return impl_->options; }
ComputeDevice Network::device() const { return impl_->device; }

int64_t Network::NumParameters() const {
  int64_t count = 0;
  for (const torch::Tensor& parameter : impl_->module->parameters()) count += parameter.numel();
  return count;
}

void Network::SetDevice(ComputeDevice device) {
  impl_->module->to(TorchDevice(device));
  impl_->device = device;
  impl_->packed_weights.Clear();
}

double Network::PredictFlops(int64_t num_descriptors, int64_t num_images,
                             const LabelTree& tree) const {
  const double n = static_cast<double>(num_descriptors);
  const double rows = n * static_cast<double>(num_images);
  const double d = shape().descriptor_dim;
  const double c = options().channels;
  const double h = options().trunk_channels;
  const double e = options().embedding_dim;
  const double layers = options().conditioned_layers;
  const double r = options().node_output_dim;
  const double output =
      r > 0 ? rows * (c * r + (r + 1) * shape().branching) : rows * c * shape().branching;
  const double trunk = n * (d * h + h * c);
  const double per_level =
      n * c * c + rows * (layers - 1) * c * c + rows * (e * e + 2 * layers * e * c) + output;
  int levels_with_choice = 0;
  for (int level = 0; level < std::min(tree.levels(), shape().levels); ++level) {
    levels_with_choice += tree.LevelHasChoice(level);
  }
  const double trunks =
      options().shared_trunk ? std::min(levels_with_choice, 1) : levels_with_choice;
  return 2 * (per_level * levels_with_choice + trunk * trunks);
}

// The contract of Predict and PredictWithLibtorch.
void CheckPredictInputs(const Network& network, const DescriptorMatrix& descriptors,
                        const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                        const Visibility* visibility_mask) {
  const NetworkShape& s = network.shape();
  if (descriptors.rows() > 0 && descriptors.cols() != s.descriptor_dim) {
    ThrowInvalidArgument("network: descriptors of dimension {}, the network expects {}",
                         descriptors.cols(), s.descriptor_dim);
  }
  for (const uint32_t image : image_indices) {
    if (image > network.NoImageIndex()) {
      ThrowInvalidArgument("network: image index {} outside [0, {}]", image,
                           network.NoImageIndex());
    }
  }
  if (tree.levels() != s.levels || tree.branching() != s.branching) {
    ThrowInvalidArgument("network: label tree of {} levels x {} children, the network has {} x {}",
                         tree.levels(), tree.branching(), s.levels, s.branching);
  }
  if (!s.FitsTree(tree)) {
    ThrowInvalidArgument("network: the label tree's node counts differ from the network's");
  }
  if (visibility_mask != nullptr &&
      (visibility_mask->NumImages() != static_cast<size_t>(s.num_images) ||
       visibility_mask->NumPoints() != tree.NumPoints())) {
    ThrowInvalidArgument("network: visibility lists of {} images and {} points, expected {} and {}",
                         visibility_mask->NumImages(), visibility_mask->NumPoints(), s.num_images,
                         tree.NumPoints());
  }
}

PointPredictions Network::Predict(const DescriptorMatrix& descriptors,
                                  const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                                  const Visibility* visibility_mask, DescriptorLayerCache* cache,
                                  const PointRowIndex* index) const {
  CheckPredictInputs(*this, descriptors, image_indices, tree, visibility_mask);
  if (impl_->device == ComputeDevice::kCpu) {
    return PredictOnCpu(*this, descriptors, image_indices, tree, visibility_mask, cache, index);
  }
  return NetworkInternals::PredictWithTorch(*this, descriptors, image_indices, tree,
                                            visibility_mask);
}

PointPredictions Network::PredictWithLibtorch(const DescriptorMatrix& descriptors,
                                              const std::vector<uint32_t>& image_indices,
                                              const LabelTree& tree,
                                              const Visibility* visibility_mask) const {
  CheckPredictInputs(*this, descriptors, image_indices, tree, visibility_mask);
  return NetworkInternals::PredictWithTorch(*this, descriptors, image_indices, tree,
                                            visibility_mask);
}

double LibtorchMatrixProductGflops(int64_t size, double min_seconds) {
  torch::NoGradGuard no_grad;
  torch::manual_seed(0);
  const torch::Tensor a = torch::randn({size, size});
  const torch::Tensor b = torch::randn({size, size});
  torch::Tensor c = torch::empty({size, size});
  torch::mm_out(c, a, b);  // warm-up
  const Timer timer;
  int runs = 0;
  do {
    torch::mm_out(c, a, b);
    ++runs;
  } while (timer.ElapsedSeconds() < min_seconds);
  return 2.0 * size * size * size * runs / timer.ElapsedSeconds() / 1e9;
}

}  // namespace hscloc
