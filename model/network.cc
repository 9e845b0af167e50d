#include "model/network.h"

#include <ATen/Parallel.h>
#include <dlfcn.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <istream>
#include <ostream>
#include <sstream>
#include <string>
#include <utility>

#include "model/dense_kernels.h"
#include "model/network_module.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {
namespace {

constexpr int64_t kFormatMagic = 0x4e435348;  // "HSCN"
constexpr int64_t kFormatVersion = 1;
constexpr int kMaxConditionedLayers = 3;

// Threads of the CPU inference kernels (SetComputeThreads; 0: all cores).
std::atomic<int> compute_threads{0};

torch::Tensor Elu(const torch::Tensor& x) { return torch::elu(x); }

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

 private:
  size_t words_;
  std::vector<uint32_t> images_;
  std::vector<int> slot_of_k_;
  std::vector<uint64_t> bits_;
};

// The label a row takes at one level: the most probable child, or with a mask slot (>= 0) and a
// known parent node, the most probable among the children the mask keeps (the plain argmax when it
// keeps none).
int64_t ChooseLabel(const float* probabilities, int64_t branching, const NodeVisibilityMasks* masks,
                    int slot, int64_t parent, const LabelTree& tree) {
  int64_t best = -1;
  if (masks != nullptr && slot >= 0 && parent >= 0) {
    const uint32_t first = tree.FirstChild(static_cast<uint32_t>(parent));
    const int64_t children = tree.NumChildren(static_cast<uint32_t>(parent));
    for (int64_t c = 0; c < children; ++c) {
      if (masks->Contains(slot, first + static_cast<uint32_t>(c)) &&
          (best < 0 || probabilities[c] > probabilities[best])) {
        best = c;
      }
    }
  }
  if (best < 0) best = std::max_element(probabilities, probabilities + branching) - probabilities;
  return best;
}

// The tree node reached from `parent` by `label`; -1 when the path leaves the tree.
int64_t ChildNode(int64_t parent, int64_t label, const LabelTree& tree) {
  return parent >= 0 && label < tree.NumChildren(static_cast<uint32_t>(parent))
             ? tree.FirstChild(static_cast<uint32_t>(parent)) + label
             : -1;
}

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

void NetworkShape::Check() const {
  THROW_CHECK_MSG(descriptor_dim > 0, "NetworkShape.descriptor_dim = {}", descriptor_dim);
  THROW_CHECK_MSG(levels > 0, "NetworkShape.levels = {}", levels);
  THROW_CHECK_MSG(branching > 1 && branching <= 256, "NetworkShape.branching = {}", branching);
  THROW_CHECK_MSG(num_images > 0, "NetworkShape.num_images = {}", num_images);
}

bool NetworkShape::operator==(const NetworkShape& other) const {
  return descriptor_dim == other.descriptor_dim && levels == other.levels &&
         branching == other.branching && num_images == other.num_images;
}

void NetworkOptions::Check() const {
  THROW_CHECK_MSG(channels > 0, "NetworkOptions.channels = {}", channels);
  THROW_CHECK_MSG(embedding_dim > 0, "NetworkOptions.embedding_dim = {}", embedding_dim);
  THROW_CHECK_MSG(conditioned_layers >= 1 && conditioned_layers <= kMaxConditionedLayers,
                  "NetworkOptions.conditioned_layers = {} (1 .. {})", conditioned_layers,
                  kMaxConditionedLayers);
}

bool NetworkOptions::operator==(const NetworkOptions& other) const {
  return channels == other.channels && embedding_dim == other.embedding_dim &&
         conditioned_layers == other.conditioned_layers;
}

// ---------------------------------------------------------------------------------------------
// Modules.

LevelImpl::LevelImpl(int level, const NetworkShape& shape, const NetworkOptions& options)
    : level_(level) {
  const int64_t channels = options.channels;
  const int64_t embedding = options.embedding_dim;
  trunk1_ = register_module("trunk1", torch::nn::Linear(shape.descriptor_dim, channels));
  trunk2_ = register_module("trunk2", torch::nn::Linear(channels, channels));
  image_embedding_ =
      register_module("image_embedding", torch::nn::Embedding(shape.num_images + 1, embedding));
  for (int k = 0; k < level; ++k) {
    label_embeddings_.push_back(register_module("label_embedding" + std::to_string(k),
                                                torch::nn::Embedding(shape.branching, embedding)));
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
  output_ = register_module("output", torch::nn::Linear(channels, shape.branching));

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
  torch::nn::init::kaiming_normal_(output_->weight, 0, torch::kFanIn, torch::kLinear);
  output_->bias.zero_();
  input_scale_ = std::sqrt(static_cast<double>(shape.descriptor_dim));
}

torch::Tensor LevelImpl::Trunk(const torch::Tensor& descriptors) {
  return Elu(trunk2_(Elu(trunk1_(descriptors * input_scale_))));
}

LevelModulation LevelImpl::Generate(const torch::Tensor& image_indices,
                                    const torch::Tensor& prefix_labels) {
  torch::Tensor embedding = image_embedding_(image_indices);
  for (int k = 0; k < level_; ++k) {
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

torch::Tensor LevelImpl::Logits(const torch::Tensor& features) { return output_(features); }

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
  weights.output_weight = data(output_->weight);
  weights.output_bias = data(output_->bias);
  return weights;
}

torch::Tensor LevelImpl::forward(const torch::Tensor& descriptors,
                                 const torch::Tensor& image_indices,
                                 const torch::Tensor& prefix_labels) {
  torch::Tensor features = Trunk(descriptors);
  const LevelModulation modulation = Generate(image_indices, prefix_labels);
  for (size_t i = 0; i < conditioned_.size(); ++i) {
    features =
        Elu(torch::addcmul(modulation.betas[i], modulation.gammas[i], conditioned_[i](features)));
  }
  return output_(features);
}

HscNetImpl::HscNetImpl(const NetworkShape& shape, const NetworkOptions& options) {
  for (int level = 0; level < shape.levels; ++level) {
    levels.push_back(
        register_module("level" + std::to_string(level), Level(level, shape, options)));
  }
}

std::vector<torch::Tensor> HscNetImpl::forward(const torch::Tensor& descriptors,
                                               const torch::Tensor& image_indices,
                                               const torch::Tensor& labels) {
  std::vector<torch::Tensor> logits;
  for (size_t level = 0; level < levels.size(); ++level) {
    logits.push_back(levels[level]->forward(descriptors, image_indices,
                                            labels.narrow(1, 0, static_cast<int64_t>(level))));
  }
  return logits;
}

// ---------------------------------------------------------------------------------------------
// Network.

Network::Network(const NetworkShape& shape, const NetworkOptions& options, uint64_t seed) {
  shape.Check();
  options.Check();
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
                   {options.channels, options.embedding_dim, options.conditioned_layers});
  torch::serialize::OutputArchive weights;
  network.impl_->module->save(weights);
  archive.write("weights", weights);
}

Network NetworkInternals::LoadFrom(torch::serialize::InputArchive& archive,
                                   const std::string& source, ComputeDevice device) {
  const std::vector<int64_t> format = ReadInt64Vector(archive, "format", 2, source);
  if (format[0] != kFormatMagic || format[1] != kFormatVersion) {
    ThrowInvalidArgument("{}: network archive format {} of version {}, expected version {}", source,
                         format[0], format[1], kFormatVersion);
  }
  const std::vector<int64_t> s = ReadInt64Vector(archive, "shape", 4, source);
  const std::vector<int64_t> o = ReadInt64Vector(archive, "options", 3, source);
  NetworkShape shape{static_cast<int>(s[0]), static_cast<int>(s[1]), static_cast<int>(s[2]),
                     static_cast<int>(s[3])};
  NetworkOptions options{static_cast<int>(o[0]), static_cast<int>(o[1]), static_cast<int>(o[2])};
  try {
    shape.Check();
    options.Check();
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

double Network::PredictFlops(int64_t num_descriptors, int64_t num_images) const {
  const double n = static_cast<double>(num_descriptors);
  const double rows = n * static_cast<double>(num_images);
  const double d = shape().descriptor_dim;
  const double c = options().channels;
  const double e = options().embedding_dim;
  const double layers = options().conditioned_layers;
  const double per_level = n * (d * c + c * c + c * c) + rows * (layers - 1) * c * c +
                           rows * (e * e + 2 * layers * e * c) + rows * c * shape().branching;
  return 2 * per_level * shape().levels;
}

// ---------------------------------------------------------------------------------------------
// CPU inference: the forward pass of Predict on the dense kernels, row block by row block. A block
// of FiLM features, its logits and its softmax stay in cache from modulation to label choice,
// where libtorch's operator-at-a-time path wrote and reread each [rows, C] intermediate.

namespace {

constexpr int64_t kRowBlock = 128;

// body(begin, end) over blocks of kRowBlock rows, on the compute threads.
void ForEachRowBlock(int64_t rows, const std::function<void(int64_t begin, int64_t end)>& body) {
  const int64_t blocks = (rows + kRowBlock - 1) / kRowBlock;
  ParallelFor(static_cast<size_t>(blocks), compute_threads.load(), [&](size_t first, size_t last) {
    for (size_t block = first; block < last; ++block) {
      const int64_t begin = static_cast<int64_t>(block) * kRowBlock;
      body(begin, std::min(rows, begin + kRowBlock));
    }
  });
}

// Per-thread buffers of one row block, kept between blocks and calls: fresh allocations of this
// size would each be zeroed and page-faulted in.
struct BlockScratch {
  std::vector<float> embedding, generator, features, linear, logits;
  std::vector<std::vector<float>> gammas, betas;
  std::vector<int32_t> run_of_row;
  std::vector<int64_t> descriptor_of_row;

  void Reserve(int64_t rows, int64_t channels, int64_t embedding_dim, int64_t branching,
               int layers) {
    const auto grow = [](auto& buffer, int64_t size) {
      if (static_cast<int64_t>(buffer.size()) < size) buffer.resize(size);
    };
    grow(embedding, rows * embedding_dim);
    grow(generator, rows * embedding_dim);
    grow(features, rows * channels);
    grow(linear, rows * channels);
    grow(logits, rows * branching);
    grow(run_of_row, rows);
    grow(descriptor_of_row, rows);
    if (static_cast<int>(gammas.size()) < layers) {
      gammas.resize(layers);
      betas.resize(layers);
    }
    for (int layer = 0; layer < layers; ++layer) {
      grow(gammas[layer], rows * channels);
      grow(betas[layer], rows * channels);
    }
  }
};

PointPredictions PredictOnCpu(const Network& network, const DescriptorMatrix& descriptors,
                              const std::vector<uint32_t>& image_indices, const LabelTree& tree,
                              const Visibility* visibility_mask) {
  namespace dk = dense_kernels;
  const NetworkShape& s = network.shape();
  const int64_t n = descriptors.rows();
  const int64_t k = static_cast<int64_t>(image_indices.size());
  const int64_t rows = n * k;
  const int64_t d = s.descriptor_dim;
  const int64_t c = network.options().channels;
  const int64_t e = network.options().embedding_dim;
  const int64_t branching = s.branching;
  PointPredictions result;
  result.num_images = k;
  result.num_descriptors = n;
  result.point_indices.resize(k, n);
  result.confidences.setOnes(k, n);
  result.labels.resize(rows, s.levels);
  if (rows == 0) return result;

  DescriptorMatrix normalized = descriptors;
  for (int64_t i = 0; i < n; ++i) {
    normalized.row(i) /= std::max(normalized.row(i).norm(), 1e-12f);
  }
  std::unique_ptr<NodeVisibilityMasks> masks;
  std::vector<int64_t> parent_node;
  if (visibility_mask != nullptr) {
    masks = std::make_unique<NodeVisibilityMasks>(image_indices, tree, *visibility_mask);
    parent_node.assign(rows, 0);
  }

  uint8_t* labels = result.labels.data();
  float* confidences = result.confidences.data();
  std::vector<float> scaled(n * d);
  std::vector<float> shared(n * c);
  std::vector<std::pair<int64_t, int64_t>> keyed_rows(rows);  // (image and label prefix, row)
  for (const Level& level : NetworkInternals::Module(network)->levels) {
    const Timer level_timer;
    const int depth = level->level();
    const LevelWeights w = level->CpuWeights();
    const int layers = level->NumConditionedLayers();

    // Descriptor-only part, once per keypoint: trunk and the first conditioned layer's W h + b.
    Eigen::Map<Eigen::ArrayXf>(scaled.data(), n * d) =
        Eigen::Map<const Eigen::ArrayXf>(normalized.data(), n * d) * w.input_scale;
    ForEachRowBlock(n, [&](int64_t begin, int64_t end) {
      const int64_t m = end - begin;
      thread_local BlockScratch scratch;
      scratch.Reserve(m, c, e, branching, layers);
      dk::Linear(scaled.data() + begin * d, m, d, w.trunk1_weight, w.trunk1_bias, c, true,
                 scratch.features.data());
      dk::Linear(scratch.features.data(), m, c, w.trunk2_weight, w.trunk2_bias, c, true,
                 scratch.linear.data());
      dk::Linear(scratch.linear.data(), m, c, w.conditioned_weights[0], w.conditioned_biases[0], c,
                 false, shared.data() + begin * c);
    });

    // Rows with the same image and label prefix share their modulation. Rows are visited in the
    // order of that key, so a block holds runs of equal keys and evaluates the generator once per
    // run, and a block's modulation never leaves the cache.
    for (int64_t r = 0; r < rows; ++r) {
      int64_t key = image_indices[r / n];
      for (int column = 0; column < depth; ++column) {
        key = key * branching + labels[r * s.levels + column];
      }
      keyed_rows[r] = {key, r};
    }
    std::sort(keyed_rows.begin(), keyed_rows.end());

    ForEachRowBlock(rows, [&](int64_t begin, int64_t end) {
      const int64_t m = end - begin;
      thread_local BlockScratch scratch;
      scratch.Reserve(m, c, e, branching, layers);
      int64_t runs = 0;
      for (int64_t i = begin; i < end; ++i) {
        if (i == begin || keyed_rows[i].first != keyed_rows[i - 1].first) {
          // The generator input of the run: image embedding plus the coarser labels' embeddings.
          const int64_t r = keyed_rows[i].second;
          auto sum = Eigen::Map<Eigen::VectorXf>(scratch.embedding.data() + runs * e, e);
          sum = Eigen::Map<const Eigen::VectorXf>(w.image_embedding + image_indices[r / n] * e, e);
          for (int column = 0; column < depth; ++column) {
            sum += Eigen::Map<const Eigen::VectorXf>(
                w.label_embeddings[column] + labels[r * s.levels + column] * e, e);
          }
          ++runs;
        }
        scratch.run_of_row[i - begin] = static_cast<int32_t>(runs - 1);
        scratch.descriptor_of_row[i - begin] = keyed_rows[i].second % n;
      }
      dk::EluInPlace(scratch.embedding.data(), runs * e);
      dk::Linear(scratch.embedding.data(), runs, e, w.generator_weight, w.generator_bias, e, true,
                 scratch.generator.data());
      for (int layer = 0; layer < layers; ++layer) {
        dk::Linear(scratch.generator.data(), runs, e, w.gamma_weights[layer], w.gamma_biases[layer],
                   c, false, scratch.gammas[layer].data());
        dk::Linear(scratch.generator.data(), runs, e, w.beta_weights[layer], w.beta_biases[layer],
                   c, false, scratch.betas[layer].data());
      }

      dk::ModulateElu(shared.data(), scratch.descriptor_of_row.data(), scratch.gammas[0].data(),
                      scratch.betas[0].data(), scratch.run_of_row.data(), m, c,
                      scratch.features.data());
      for (int layer = 1; layer < layers; ++layer) {
        dk::Linear(scratch.features.data(), m, c, w.conditioned_weights[layer],
                   w.conditioned_biases[layer], c, false, scratch.linear.data());
        dk::ModulateElu(scratch.linear.data(), nullptr, scratch.gammas[layer].data(),
                        scratch.betas[layer].data(), scratch.run_of_row.data(), m, c,
                        scratch.features.data());
      }
      dk::Linear(scratch.features.data(), m, c, w.output_weight, w.output_bias, branching, false,
                 scratch.logits.data());
      dk::SoftmaxRowsInPlace(scratch.logits.data(), m, branching);
      for (int64_t i = begin; i < end; ++i) {
        const int64_t r = keyed_rows[i].second;
        const float* probabilities = scratch.logits.data() + (i - begin) * branching;
        const int slot = masks ? masks->SlotOfK(static_cast<size_t>(r / n)) : -1;
        const int64_t parent = masks ? parent_node[r] : -1;
        const int64_t best = ChooseLabel(probabilities, branching, masks.get(), slot, parent, tree);
        labels[r * s.levels + depth] = static_cast<uint8_t>(best);
        confidences[r] *= probabilities[best];
        if (masks) parent_node[r] = ChildNode(parent, best, tree);
      }
    });
    result.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
  }
  for (int64_t r = 0; r < rows; ++r) {
    result.point_indices.data()[r] = tree.PointOfLabels(labels + r * s.levels);
  }
  return result;
}

}  // namespace

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
  PointPredictions result;
  result.num_images = k;
  result.num_descriptors = n;
  result.point_indices.resize(k, n);
  result.confidences.resize(k, n);
  result.labels.resize(rows, s.levels);
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
  std::vector<int64_t> parent_node;
  if (visibility_mask != nullptr) {
    masks = std::make_unique<NodeVisibilityMasks>(image_indices, tree, *visibility_mask);
    parent_node.assign(rows, 0);
  }

  torch::Tensor labels = torch::empty({rows, 0}, long_options);
  torch::Tensor confidence = torch::ones({rows}, torch::TensorOptions().device(device));
  for (Level& level : impl->module->levels) {
    const Timer level_timer;
    const int depth = level->level();
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
    const LevelModulation modulation = level->Generate(row_image.index_select(0, representative),
                                                       labels.index_select(0, representative));

    torch::Tensor features = Elu(torch::addcmul(modulation.betas[0].index_select(0, inverse),
                                                modulation.gammas[0].index_select(0, inverse),
                                                shared_linear.index_select(0, row_descriptor)));
    for (int layer = 1; layer < level->NumConditionedLayers(); ++layer) {
      features = Elu(torch::addcmul(modulation.betas[layer].index_select(0, inverse),
                                    modulation.gammas[layer].index_select(0, inverse),
                                    level->ConditionedLinear(layer, features)));
    }
    const torch::Tensor probabilities = torch::softmax(level->Logits(features), 1);

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
    }
    labels = torch::cat({labels, chosen.unsqueeze(1)}, 1);
    confidence = confidence * chosen_probability;
    result.level_milliseconds.push_back(level_timer.ElapsedMilliseconds());
  }

  const torch::Tensor cpu_labels = labels.to(torch::kCPU).to(torch::kUInt8).contiguous();
  const torch::Tensor cpu_confidence = confidence.to(torch::kCPU).contiguous();
  std::copy_n(cpu_labels.data_ptr<uint8_t>(), rows * s.levels, result.labels.data());
  std::copy_n(cpu_confidence.data_ptr<float>(), rows, result.confidences.data());
  for (int64_t r = 0; r < rows; ++r) {
    result.point_indices.data()[r] = tree.PointOfLabels(result.labels.data() + r * s.levels);
  }
  return result;
}

}  // namespace hscloc
