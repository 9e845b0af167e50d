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

constexpr int64_t kFormatMagic = 0x4e435348;  // "HSCN"
// Version 2 added the trunk's hidden width; version 1 archives have it equal to the channels.
// Version 3 added node conditioning, node output rows and the tree's node counts; older archives
// are the paper's configuration.
constexpr int64_t kFormatVersion = 3;
constexpr int kMaxNodeOutputDim = 1024;
constexpr int kMaxConditionedLayers = 3;

// Threads of the CPU inference kernels (SetComputeThreads; 0: all cores).
std::atomic<int> compute_threads{0};

torch::Tensor Elu(const torch::Tensor& x) { return torch::elu(x); }

void WriteInt64Vector(torch::serialize::OutputArchive& archive, const std::string& key,
                      const std::vector<int64_t>& values) {
  archive.write(key, torch::tensor(values, torch::kInt64));
}

std::vector<int64_t> ReadInt64Vector(torch::serialize::InputArchive& archive,
                                     const std::string& key, size_t expected_size,
                                     const std::string& source) {
  torch::Tensor tensor;
  if (!archive.try_read(key, tensor) || tensor.scalar_type() != torch::kInt64 ||
      tensor.dim() != 1 || static_cast<size_t>(tensor.numel()) != expected_size) {
    ThrowInvalidArgument("{}: not an hscloc network archive ('{}' missing or malformed)", source,
                         key);
  }
  tensor = tensor.contiguous();
  return std::vector<int64_t>(tensor.data_ptr<int64_t>(),
                              tensor.data_ptr<int64_t>() + tensor.numel());
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
  NetworkShape shape{descriptor_dim, tree.levels(), tree.branching(), num_images, {}};
  shape.nodes_per_depth.assign(tree.levels() + 1, 0);
  for (uint32_t node = 0; node < tree.NumNodes(); ++node) {
    ++shape.nodes_per_depth.at(tree.NodeLevel(node));
  }
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

void NetworkShape::Check() const {
  THROW_CHECK_MSG(descriptor_dim > 0, "NetworkShape.descriptor_dim = {}", descriptor_dim);
  THROW_CHECK_MSG(levels > 0, "NetworkShape.levels = {}", levels);
  THROW_CHECK_MSG(branching > 1 && branching <= 256, "NetworkShape.branching = {}", branching);
  THROW_CHECK_MSG(num_images > 0, "NetworkShape.num_images = {}", num_images);
  THROW_CHECK_MSG(nodes_per_depth.empty() ||
                      (static_cast<int>(nodes_per_depth.size()) == levels + 1 &&
                       nodes_per_depth[0] == 1 &&
                       std::all_of(nodes_per_depth.begin(), nodes_per_depth.end(),
                                   [](int64_t count) { return count > 0; })),
                  "NetworkShape.nodes_per_depth: {} entries for {} levels, the root first",
                  nodes_per_depth.size(), levels);
}

bool NetworkShape::operator==(const NetworkShape& other) const {
  return descriptor_dim == other.descriptor_dim && levels == other.levels &&
         branching == other.branching && num_images == other.num_images &&
         nodes_per_depth == other.nodes_per_depth;
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
         node_conditioning == other.node_conditioning && node_output_dim == other.node_output_dim;
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

LevelImpl::LevelImpl(int level, const NetworkShape& shape, const NetworkOptions& options)
    : level_(level) {
  const int64_t channels = options.channels;
  const int64_t embedding = options.embedding_dim;
  const int64_t trunk_channels = options.trunk_channels;
  trunk1_ = register_module("trunk1", torch::nn::Linear(shape.descriptor_dim, trunk_channels));
  trunk2_ = register_module("trunk2", torch::nn::Linear(trunk_channels, channels));
  image_embedding_ =
      register_module("image_embedding", torch::nn::Embedding(shape.num_images + 1, embedding));
  // A level whose parents all have one child never runs (Predict and training skip it): its
  // per-node tables keep a single row.
  const bool has_choice = !shape.nodes_per_depth.empty() &&
                          shape.nodes_per_depth.at(level + 1) > shape.nodes_per_depth.at(level);
  if (options.node_conditioning) {
    node_embedding_first_ = shape.FirstNodeOfDepth(level);
    node_embedding_ = register_module(
        "node_embedding",
        torch::nn::Embedding(has_choice ? shape.nodes_per_depth.at(level) : 1, embedding));
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
  node_output_dim_ = options.node_output_dim;
  if (node_output_dim_ > 0) {
    const int64_t children = shape.nodes_per_depth.at(level + 1);
    node_rows_first_ = shape.FirstNodeOfDepth(level + 1);
    projection_ = register_module("projection", torch::nn::Linear(channels, node_output_dim_));
    node_rows_ = register_parameter(
        "node_rows", torch::zeros({has_choice ? children : 1, node_output_dim_ + 1}));
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
  he_initialize(trunk1_);
  he_initialize(trunk2_);
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
    // Rows of unit-variance logits for unit-variance projections; biases start at 0.
    torch::nn::init::kaiming_normal_(projection_->weight, 0, torch::kFanIn, torch::kLinear);
    projection_->bias.zero_();
    node_rows_.narrow(1, 0, node_output_dim_)
        .normal_(0, 1 / std::sqrt(static_cast<double>(node_output_dim_)));
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
    embedding = embedding + node_embedding_((parent_nodes - node_embedding_first_).clamp_min(0));
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

torch::Tensor LevelImpl::Logits(const torch::Tensor& features, const torch::Tensor& child_nodes) {
  if (node_output_dim_ == 0) return output_(features);
  const torch::Tensor exists = child_nodes.ge(0);
  const torch::Tensor rows = (child_nodes - node_rows_first_).clamp_min(0);
  // [R, branching, r + 1] rows against [R, r + 1, 1] projections with a constant 1 for the bias.
  const torch::Tensor gathered = torch::nn::functional::embedding(
      rows, node_rows_, torch::nn::functional::EmbeddingFuncOptions().sparse(sparse_node_rows_));
  const torch::Tensor projected = projection_(features);
  const torch::Tensor augmented =
      torch::cat({projected, torch::ones({projected.size(0), 1}, projected.options())}, 1);
  const torch::Tensor logits = torch::bmm(gathered, augmented.unsqueeze(2)).squeeze(2);
  // A row without children (a path that left the tree) keeps finite logits.
  const torch::Tensor absent = exists.logical_not().logical_and(exists.any(1, true));
  return logits.masked_fill(absent, -std::numeric_limits<float>::infinity());
}

LevelWeights LevelImpl::CpuWeights() const {
  const auto data = [](const torch::Tensor& tensor) -> const float* {
    if (!tensor.device().is_cpu() || tensor.scalar_type() != torch::kFloat32 ||
        !tensor.is_contiguous()) {
      throw std::logic_error("network weights are not contiguous fp32 CPU tensors");
    }
    return tensor.data_ptr<float>();
  };
  LevelWeights weights;
  weights.input_scale = static_cast<float>(input_scale_);
  weights.trunk1_weight = data(trunk1_->weight);
  weights.trunk1_bias = data(trunk1_->bias);
  weights.trunk2_weight = data(trunk2_->weight);
  weights.trunk2_bias = data(trunk2_->bias);
  weights.image_embedding = data(image_embedding_->weight);
  for (const torch::nn::Embedding& table : label_embeddings_) {
    weights.label_embeddings.push_back(data(table->weight));
  }
  if (node_embedding_) {
    weights.node_embedding = data(node_embedding_->weight);
    weights.node_embedding_first = node_embedding_first_;
  }
  weights.generator_weight = data(generator_->weight);
  weights.generator_bias = data(generator_->bias);
  for (size_t i = 0; i < conditioned_.size(); ++i) {
    weights.gamma_weights.push_back(data(gamma_heads_[i]->weight));
    weights.gamma_biases.push_back(data(gamma_heads_[i]->bias));
    weights.beta_weights.push_back(data(beta_heads_[i]->weight));
    weights.beta_biases.push_back(data(beta_heads_[i]->bias));
    weights.conditioned_weights.push_back(data(conditioned_[i]->weight));
    weights.conditioned_biases.push_back(data(conditioned_[i]->bias));
  }
  if (node_output_dim_ > 0) {
    weights.node_output_dim = node_output_dim_;
    weights.projection_weight = data(projection_->weight);
    weights.projection_bias = data(projection_->bias);
    weights.node_rows = data(node_rows_);
    weights.node_rows_first = node_rows_first_;
  } else {
    weights.output_weight = data(output_->weight);
    weights.output_bias = data(output_->bias);
  }
  return weights;
}

torch::Tensor LevelImpl::forward(const torch::Tensor& descriptors,
                                 const torch::Tensor& image_indices,
                                 const torch::Tensor& prefix_labels,
                                 const torch::Tensor& parent_nodes,
                                 const torch::Tensor& child_nodes) {
  torch::Tensor features = Trunk(descriptors);
  const LevelModulation modulation = Generate(image_indices, prefix_labels, parent_nodes);
  for (size_t i = 0; i < conditioned_.size(); ++i) {
    features =
        Elu(torch::addcmul(modulation.betas[i], modulation.gammas[i], conditioned_[i](features)));
  }
  return Logits(features, child_nodes);
}

HscNetImpl::HscNetImpl(const NetworkShape& shape, const NetworkOptions& options) {
  for (int level = 0; level < shape.levels; ++level) {
    levels.push_back(
        register_module("level" + std::to_string(level), Level(level, shape, options)));
  }
}

// ---------------------------------------------------------------------------------------------
// Network.

Network::Network(const NetworkShape& shape, const NetworkOptions& options, uint64_t seed) {
  shape.Check();
  options.Check();
  if (options.NeedsNodeCounts() && shape.nodes_per_depth.empty()) {
    ThrowInvalidArgument(
        "NetworkShape.nodes_per_depth is empty, but NetworkOptions.node_conditioning or "
        "node_output_dim need the tree's node counts (NetworkShape::ForTree)");
  }
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
}

void NetworkInternals::SaveTo(const Network& network, torch::serialize::OutputArchive& archive) {
  const NetworkShape& shape = network.shape();
  const NetworkOptions& options = network.options();
  WriteInt64Vector(archive, "format", {kFormatMagic, kFormatVersion});
  WriteInt64Vector(archive, "shape",
                   {shape.descriptor_dim, shape.levels, shape.branching, shape.num_images});
  WriteInt64Vector(archive, "options",
                   {options.channels, options.embedding_dim, options.conditioned_layers,
                    options.trunk_channels, options.node_conditioning ? 1 : 0,
                    options.node_output_dim});
  WriteInt64Vector(archive, "nodes_per_depth", shape.nodes_per_depth);
  torch::serialize::OutputArchive weights;
  network.impl_->module->save(weights);
  archive.write("weights", weights);
}

Network NetworkInternals::LoadFrom(torch::serialize::InputArchive& archive,
                                   const std::string& source, ComputeDevice device) {
  const std::vector<int64_t> format = ReadInt64Vector(archive, "format", 2, source);
  if (format[0] != kFormatMagic || format[1] < 1 || format[1] > kFormatVersion) {
    ThrowInvalidArgument("{}: network archive format {} of version {}, expected version 1 to {}",
                         source, format[0], format[1], kFormatVersion);
  }
  const std::vector<int64_t> s = ReadInt64Vector(archive, "shape", 4, source);
  const size_t option_count = format[1] == 1 ? 3 : format[1] == 2 ? 4 : 6;
  const std::vector<int64_t> o = ReadInt64Vector(archive, "options", option_count, source);
  NetworkShape shape{static_cast<int>(s[0]), static_cast<int>(s[1]), static_cast<int>(s[2]),
                     static_cast<int>(s[3]), {}};
  NetworkOptions options = NetworkOptions::PaperFaithful();
  options.channels = static_cast<int>(o[0]);
  options.embedding_dim = static_cast<int>(o[1]);
  options.conditioned_layers = static_cast<int>(o[2]);
  options.trunk_channels = format[1] == 1 ? options.channels : static_cast<int>(o[3]);
  if (format[1] >= 3) {
    options.node_conditioning = o[4] != 0;
    options.node_output_dim = static_cast<int>(o[5]);
    torch::Tensor nodes;
    if (!archive.try_read("nodes_per_depth", nodes) || nodes.scalar_type() != torch::kInt64 ||
        nodes.dim() != 1) {
      ThrowInvalidArgument("{}: not an hscloc network archive ('nodes_per_depth' malformed)",
                           source);
    }
    nodes = nodes.contiguous();
    shape.nodes_per_depth.assign(nodes.data_ptr<int64_t>(),
                                 nodes.data_ptr<int64_t>() + nodes.numel());
  }
  try {
    shape.Check();
    options.Check();
    if (options.NeedsNodeCounts() && shape.nodes_per_depth.empty()) {
      ThrowInvalidArgument("NetworkShape.nodes_per_depth missing for per-node tables");
    }
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: {}", source, error.what());
  }
  auto impl = std::make_unique<Network::Impl>();
  impl->shape = shape;
  impl->options = options;
  impl->module = HscNet(shape, options);
  torch::serialize::InputArchive weights;
  if (!archive.try_read("weights", weights)) {
    ThrowInvalidArgument("{}: network archive without weights", source);
  }
  try {
    impl->module->load(weights);
  } catch (const c10::Error& error) {
    ThrowInvalidArgument("{}: network weights do not match shape and options: {}", source,
                         error.what_without_backtrace());
  }
  Network network(std::move(impl));
  network.SetDevice(device);
  return network;
}

void Network::Save(std::ostream& stream) const {
  torch::serialize::OutputArchive archive;
  NetworkInternals::SaveTo(*this, archive);
  archive.save_to(stream);
}

Network Network::Load(std::istream& stream, const std::string& source, ComputeDevice device) {
  torch::serialize::InputArchive archive;
  try {
    archive.load_from(stream, torch::Device(torch::kCPU));
  } catch (const c10::Error& error) {
    ThrowInvalidArgument("{}: not a network archive: {}", source, error.what_without_backtrace());
  }
  return NetworkInternals::LoadFrom(archive, source, device);
}

Network Network::FromBundle(const MapBundle& bundle, ComputeDevice device) {
  if (!bundle.HasBlob(network_blobs::kNetwork)) {
    ThrowInvalidArgument("map bundle {} holds no trained network (run `hscloc train`)",
                         bundle.dir().string());
  }
  std::istringstream stream(bundle.Blob(network_blobs::kNetwork));
  return Load(stream, (bundle.dir() / network_blobs::kNetwork).string(), device);
}

bool Network::HasSameWeights(const Network& other) const {
  if (!(shape() == other.shape()) || !(options() == other.options())) return false;
  const auto mine = impl_->module->named_parameters();
  const auto theirs = other.impl_->module->named_parameters();
  if (mine.size() != theirs.size()) return false;
  for (const auto& item : mine) {
    const torch::Tensor* other_parameter = theirs.find(item.key());
    if (other_parameter == nullptr || !torch::equal(item.value().cpu(), other_parameter->cpu())) {
      return false;
    }
  }
  return true;
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
  const double output = r > 0 ? rows * (c * r + (r + 1) * shape().branching)
                              : rows * c * shape().branching;
  const double per_level = n * (d * h + h * c + c * c) + rows * (layers - 1) * c * c +
                           rows * (e * e + 2 * layers * e * c) + output;
  int levels_with_choice = 0;
  for (int level = 0; level < std::min(tree.levels(), shape().levels); ++level) {
    levels_with_choice += tree.LevelHasChoice(level);
  }
  return 2 * per_level * levels_with_choice;
}

PointPredictions Network::Predict(const DescriptorMatrix& descriptors,
                                  const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                                  const Visibility* visibility_mask) const {
  const NetworkShape& s = shape();
  if (descriptors.rows() > 0 && descriptors.cols() != s.descriptor_dim) {
    ThrowInvalidArgument("network: descriptors of dimension {}, the network expects {}",
                         descriptors.cols(), s.descriptor_dim);
  }
  for (const uint32_t image : image_indices) {
    if (image > NoImageIndex()) {
      ThrowInvalidArgument("network: image index {} outside [0, {}]", image, NoImageIndex());
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

  if (impl_->device == ComputeDevice::kCpu) {
    return PredictOnCpu(*this, descriptors, image_indices, tree, visibility_mask);
  }
  return NetworkInternals::PredictWithTorch(*this, descriptors, image_indices, tree,
                                            visibility_mask);
}

PointPredictions NetworkInternals::PredictWithTorch(const Network& network,
                                                    const DescriptorMatrix& descriptors,
                                                    const std::vector<uint32_t>& image_indices,
                                                    const LabelTree& tree,
                                                    const Visibility* visibility_mask) {
  const NetworkShape& s = network.shape();
  Network::Impl* impl = network.impl_.get();
  const int64_t n = descriptors.rows();
  const int64_t k = static_cast<int64_t>(image_indices.size());
  const int64_t rows = n * k;
  PointPredictions result = AllocatePredictions(k, n, s.levels);
  if (rows == 0) return result;

  c10::InferenceMode inference_mode;
  const torch::Device device = TorchDevice(impl->device);
  const auto long_options = torch::TensorOptions().dtype(torch::kInt64).device(device);
  const torch::Tensor x = NormalizeRows(torch::from_blob(const_cast<float*>(descriptors.data()),
                                                         {n, s.descriptor_dim}, torch::kFloat32)
                                            .to(device));
  const std::vector<int64_t> images64(image_indices.begin(), image_indices.end());
  const torch::Tensor row_image =
      torch::tensor(images64, torch::kInt64).to(device).repeat_interleave(n);
  const torch::Tensor row_descriptor = torch::arange(n, long_options).repeat({k});
  const torch::Tensor row_index = torch::arange(rows, long_options);

  std::unique_ptr<NodeVisibilityMasks> masks;
  if (visibility_mask != nullptr) {
    masks = std::make_unique<NodeVisibilityMasks>(image_indices, tree, *visibility_mask);
  }
  // The tree node of every row's label prefix (-1 once a path leaves the tree).
  std::vector<int64_t> parent_node(rows, 0);

  torch::Tensor labels = torch::empty({rows, 0}, long_options);
  torch::Tensor confidence = torch::ones({rows}, torch::TensorOptions().device(device));
  for (Level& level : impl->module->levels) {
    const Timer level_timer;
    const int depth = level->level();
    if (!tree.LevelHasChoice(depth)) {
      // Every parent has a single child: label 0 with certainty, no network to run.
      labels = torch::cat({labels, torch::zeros({rows, 1}, long_options)}, 1);
      for (int64_t& parent : parent_node) parent = ChildNode(parent, 0, tree);
      result.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
      continue;
    }
    const torch::Tensor shared_linear = level->ConditionedLinear(0, level->Trunk(x));

    // Rows with the same image and label prefix share their modulation: evaluate the generator
    // once per distinct key.
    torch::Tensor key = row_image.clone();
    for (int column = 0; column < depth; ++column)
      key = key * s.branching + labels.select(1, column);
    const auto [unique_keys, inverse, counts] =
        at::_unique2(key, /*sorted=*/true, /*return_inverse=*/true, /*return_counts=*/false);
    const torch::Tensor representative =
        torch::empty({unique_keys.size(0)}, long_options).scatter_(0, inverse, row_index);
    const torch::Tensor parents = torch::from_blob(parent_node.data(), {rows}, torch::kInt64);
    const torch::Tensor device_parents = parents.to(device);
    const LevelModulation modulation = level->Generate(
        row_image.index_select(0, representative), labels.index_select(0, representative),
        device_parents.index_select(0, representative));

    torch::Tensor features = Elu(torch::addcmul(modulation.betas[0].index_select(0, inverse),
                                                modulation.gammas[0].index_select(0, inverse),
                                                shared_linear.index_select(0, row_descriptor)));
    for (int layer = 1; layer < level->NumConditionedLayers(); ++layer) {
      features = Elu(torch::addcmul(modulation.betas[layer].index_select(0, inverse),
                                    modulation.gammas[layer].index_select(0, inverse),
                                    level->ConditionedLinear(layer, features)));
    }
    torch::Tensor child_nodes;
    if (level->HasNodeOutput()) {
      child_nodes = ChildNodesOf(tree, parent_node.data(), rows).to(device);
    }
    const torch::Tensor probabilities = torch::softmax(level->Logits(features, child_nodes), 1);

    torch::Tensor chosen;
    torch::Tensor chosen_probability;
    if (masks) {
      const torch::Tensor cpu_probabilities = probabilities.to(torch::kCPU).contiguous();
      const float* p = cpu_probabilities.data_ptr<float>();
      chosen = torch::empty({rows}, torch::kInt64);
      chosen_probability = torch::empty({rows}, torch::kFloat32);
      int64_t* chosen_data = chosen.data_ptr<int64_t>();
      float* probability_data = chosen_probability.data_ptr<float>();
      const int64_t branching = s.branching;
      at::parallel_for(0, rows, 1024, [&](int64_t begin, int64_t end) {
        for (int64_t r = begin; r < end; ++r) {
          const float* row = p + r * branching;
          const int slot = masks->SlotOfK(static_cast<size_t>(r / n));
          const int64_t parent = parent_node[r];
          const int64_t best = ChooseLabel(row, branching, masks.get(), slot, parent, tree);
          chosen_data[r] = best;
          probability_data[r] = row[best];
          parent_node[r] = ChildNode(parent, best, tree);
        }
      });
      chosen = chosen.to(device);
      chosen_probability = chosen_probability.to(device);
    } else {
      std::tie(chosen_probability, chosen) = probabilities.max(1);
      const torch::Tensor cpu_chosen = chosen.to(torch::kCPU).contiguous();
      const int64_t* chosen_data = cpu_chosen.data_ptr<int64_t>();
      for (int64_t r = 0; r < rows; ++r) {
        parent_node[r] = ChildNode(parent_node[r], chosen_data[r], tree);
      }
    }
    labels = torch::cat({labels, chosen.unsqueeze(1)}, 1);
    confidence = confidence * chosen_probability;
    result.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
  }

  const torch::Tensor cpu_labels = labels.to(torch::kCPU).to(torch::kUInt8).contiguous();
  const torch::Tensor cpu_confidence = confidence.to(torch::kCPU).contiguous();
  std::copy_n(cpu_labels.data_ptr<uint8_t>(), rows * s.levels, result.labels.data());
  std::copy_n(cpu_confidence.data_ptr<float>(), rows, result.confidences.data());
  ResolvePointIndices(tree, result);
  return result;
}

}  // namespace hscloc
