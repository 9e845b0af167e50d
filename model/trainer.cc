#include "model/trainer.h"

#include <ATen/Parallel.h>
#include <fmt/format.h>
#include <malloc.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>

#include "model/map_bundle.h"
#include "model/network_decoding.h"
#include "model/network_module.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/random.h"
#include "util/timer.h"

namespace hscloc {
namespace {

// Random stream keys (util/random.h).
constexpr uint64_t kStreamHoldout = 0x686f6c64;  // "hold"
constexpr uint64_t kStreamShuffle = 0x73687566;  // "shuf"
constexpr uint64_t kStreamAugment = 0x6175676d;  // "augm"
constexpr uint64_t kStreamSiblings = 0x7369626c;  // "sibl"

// Every training step allocates and frees the same few-megabyte activations. glibc's defaults hand
// such blocks back to the kernel on free (mmap'd chunks, heap trimming), so each step page-faulted
// them in again: half of the CPU time went to the kernel, and training ran at less than half speed
// (docs/decisions.md). Freed memory is kept for reuse instead, for the whole process.
void KeepFreedMemoryForReuse() {
  mallopt(M_MMAP_THRESHOLD, 32 << 20);  // glibc's largest: blocks below it come from the heap
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
  mallopt(M_TOP_PAD, 64 << 20);
}

// Checkpoint layout version; the network inside carries its own. Version 2 added the lazy Adam
// state of node output rows and the best network so far.
constexpr int64_t kCheckpointVersion = 2;

// The training observations in the order the iterations consume them: an endless sequence of
// permutations, one per epoch, each drawn from its own stream, so that any iteration's batch can
// be found without replaying the ones before it (resume).
class SampleOrder {
 public:
  SampleOrder(std::vector<uint32_t> samples, uint64_t seed)
      : samples_(std::move(samples)), seed_(seed) {}

  uint32_t At(uint64_t position) {
    const uint64_t epoch = position / samples_.size();
    if (epoch != epoch_) Shuffle(epoch);
    return permutation_[position % samples_.size()];
  }

 private:
  void Shuffle(uint64_t epoch) {
    permutation_ = samples_;
    Random random(seed_, {kStreamShuffle, epoch});
    for (size_t i = permutation_.size(); i > 1; --i) {
      std::swap(permutation_[i - 1], permutation_[random.UniformInt(i)]);
    }
    epoch_ = epoch;
  }

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
};

// What a batch needs of the tree beyond the labels: node visibility per image for the
// visibility softmax.
struct BatchContext {
  const Scene& scene;
  const LabelTree& tree;
  const TrainerOptions& options;
  const NodeVisibilityMasks* masks = nullptr;  // slot = image index
  bool node_output = false;
};

Batch MakeBatch(const BatchContext& context, SampleOrder& order, int64_t iteration,
                torch::Device device) {
  const Scene& scene = context.scene;
  const LabelTree& tree = context.tree;
  const TrainerOptions& options = context.options;
  const int64_t size = options.batch_size;
  const int64_t dim = scene.Dimension();
  const int levels = tree.levels();
  std::vector<uint32_t> observations(size);
  for (int64_t row = 0; row < size; ++row) {
    observations[row] = order.At(static_cast<uint64_t>(iteration * size + row));
  }
  torch::Tensor descriptors = torch::empty({size, dim}, torch::kFloat32);
  torch::Tensor images = torch::empty({size}, torch::kInt64);
  torch::Tensor labels = torch::empty({size, levels}, torch::kInt64);
  float* descriptor_data = descriptors.data_ptr<float>();
  int64_t* image_data = images.data_ptr<int64_t>();
  int64_t* label_data = labels.data_ptr<int64_t>();
  const DescriptorAugmentationOptions& augmentation = options.augmentation;
  const double noise_sigma = augmentation.noise_norm / std::sqrt(static_cast<double>(dim));
  const uint32_t no_image = static_cast<uint32_t>(scene.NumImages());
  at::parallel_for(0, size, 64, [&](int64_t begin, int64_t end) {
    for (int64_t row = begin; row < end; ++row) {
      const uint32_t observation = observations[row];
      Random random(options.seed,
                    {kStreamAugment, static_cast<uint64_t>(iteration), static_cast<uint64_t>(row)});
      Eigen::Map<Eigen::VectorXf> x(descriptor_data + row * dim, dim);
      x = scene.observation_descriptors.row(observation).transpose();
      if (augmentation.enabled) {
        x /= std::max(x.norm(), 1e-12f);
        for (int64_t i = 0; i < dim; ++i) {
          x[i] = random.Bernoulli(augmentation.dimension_dropout)
                     ? 0.0f
                     : x[i] + static_cast<float>(random.Normal(0, noise_sigma));
        }
      }
      const bool drop_image = options.image_dropout > 0 && random.Bernoulli(options.image_dropout);
      image_data[row] = drop_image ? no_image : scene.observation_image_indices[observation];
      const LabelTree::Label* path =
          tree.LabelsOfPoint(scene.observation_point_indices[observation]);
      std::copy(path, path + levels, label_data + row * levels);
    }
  });
  Batch batch{descriptors.to(device), images.to(device), labels.to(device), {}, {}, {}, {}};
  const int64_t branching = tree.branching();
  std::vector<int64_t> node(size, 0);
  for (int level = 0; level < levels; ++level) {
    torch::Tensor parents = torch::from_blob(node.data(), {size}, torch::kInt64).clone();
    torch::Tensor children, allowed, targets;
    if (tree.LevelHasChoice(level) && context.node_output && context.masks != nullptr) {
      // Only the candidates are gathered: the children the image sees (a few of up to
      // `branching`). A row without an image ranges over all children, sampled down to as many as
      // the widest image row has (the true child and random siblings), so that it costs no more.
      std::vector<std::vector<int64_t>> candidates(size);
      std::vector<int64_t> target(size, 0);
      size_t widest = 1;
      bool any_image = false;
      for (int64_t row = 0; row < size; ++row) {
        if (image_data[row] == static_cast<int64_t>(no_image)) continue;
        const uint32_t parent = static_cast<uint32_t>(node[row]);
        const uint32_t first = tree.FirstChild(parent);
        const int64_t truth = first + label_data[row * levels + level];
        for (uint32_t c = 0; c < tree.NumChildren(parent); ++c) {
          if (first + c == truth ||
              context.masks->Contains(static_cast<int>(image_data[row]), first + c)) {
            if (first + c == truth) target[row] = static_cast<int64_t>(candidates[row].size());
            candidates[row].push_back(first + c);
          }
        }
        widest = std::max(widest, candidates[row].size());
        any_image = true;
      }
      if (!any_image) widest = static_cast<size_t>(branching);
      for (int64_t row = 0; row < size; ++row) {
        if (image_data[row] != static_cast<int64_t>(no_image)) continue;
        const uint32_t parent = static_cast<uint32_t>(node[row]);
        const uint32_t first = tree.FirstChild(parent);
        const int64_t truth = first + label_data[row * levels + level];
        std::vector<int64_t> siblings;
        for (uint32_t c = 0; c < tree.NumChildren(parent); ++c) {
          if (first + c != truth) siblings.push_back(first + c);
        }
        Random random(options.seed, {kStreamSiblings, static_cast<uint64_t>(iteration),
                                     static_cast<uint64_t>(row), static_cast<uint64_t>(level)});
        const size_t keep = std::min(siblings.size(), widest - 1);
        for (size_t i = 0; i < keep; ++i) {
          std::swap(siblings[i], siblings[i + random.UniformInt(siblings.size() - i)]);
        }
        candidates[row] = {truth};
        candidates[row].insert(candidates[row].end(), siblings.begin(), siblings.begin() + keep);
      }
      children = torch::full({size, static_cast<int64_t>(widest)}, -1, torch::kInt64);
      int64_t* child_data = children.data_ptr<int64_t>();
      for (int64_t row = 0; row < size; ++row) {
        std::copy(candidates[row].begin(), candidates[row].end(), child_data + row * widest);
      }
      children = children.to(device);
      targets = torch::from_blob(target.data(), {size}, torch::kInt64).clone().to(device);
    } else if (tree.LevelHasChoice(level)) {
      if (context.node_output) children = ChildNodesOf(tree, node.data(), size);
      if (context.masks != nullptr) {
        allowed = torch::zeros({size, branching}, torch::kBool);
        bool* allowed_data = allowed.data_ptr<bool>();
        for (int64_t row = 0; row < size; ++row) {
          const uint32_t parent = static_cast<uint32_t>(node[row]);
          const uint32_t first = tree.FirstChild(parent);
          const int64_t count = tree.NumChildren(parent);
          const bool without_image = image_data[row] == static_cast<int64_t>(no_image);
          for (int64_t c = 0; c < count; ++c) {
            allowed_data[row * branching + c] =
                without_image ||
                context.masks->Contains(static_cast<int>(image_data[row]), first + c);
          }
        }
        allowed = allowed.to(device);
      }
      if (children.defined()) children = children.to(device);
    }
    batch.parent_nodes.push_back(parents.to(device));
    batch.child_nodes.push_back(children);
    batch.allowed.push_back(allowed);
    batch.targets.push_back(targets);
    for (int64_t row = 0; row < size; ++row) {
      node[row] = tree.FirstChild(static_cast<uint32_t>(node[row])) + label_data[row * levels + level];
    }
  }
  return batch;
}

// Adam on the rows of a table that a step's sparse gradient touches (PyTorch's SparseAdam): the
// other rows and their moments stay as they are.
struct LazyAdamTable {
  torch::Tensor parameter, first_moment, second_moment;
  int64_t steps = 0;

  void Step(double learning_rate) {
    const torch::Tensor gradient = parameter.grad();
    if (!gradient.defined()) return;
    torch::NoGradGuard no_grad;
    ++steps;
    constexpr double kBeta1 = 0.9, kBeta2 = 0.999, kEpsilon = 1e-8;
    torch::Tensor rows, values;
    if (gradient.is_sparse()) {
      const torch::Tensor coalesced = gradient.coalesce();
      rows = coalesced.indices().select(0, 0);
      values = coalesced.values();
    } else {
      rows = gradient.abs().sum(1).nonzero().squeeze(1);
      values = gradient.index_select(0, rows);
    }
    const torch::Tensor m =
        first_moment.index_select(0, rows).mul_(kBeta1).add_(values, 1 - kBeta1);
    const torch::Tensor v =
        second_moment.index_select(0, rows).mul_(kBeta2).addcmul_(values, values, 1 - kBeta2);
    first_moment.index_copy_(0, rows, m);
    second_moment.index_copy_(0, rows, v);
    const double correction1 = 1 - std::pow(kBeta1, static_cast<double>(steps));
    const double correction2 = 1 - std::pow(kBeta2, static_cast<double>(steps));
    const torch::Tensor update =
        m / (v / correction2).sqrt_().add_(kEpsilon) * (learning_rate / correction1);
    parameter.index_add_(0, rows, update.neg_());
    parameter.mutable_grad() = torch::Tensor();
  }
};

// The learning rate at `progress` (fraction of the budget) of the schedule.
double ScheduledLearningRate(const TrainerOptions& options, double progress) {
  if (options.schedule == LearningRateSchedule::kOneCycle) {
    const double peak = options.learning_rate;
    const double warmup = options.warmup_fraction;
    if (progress < warmup) return peak * (0.1 + 0.9 * progress / warmup);
    const double t = std::min(1.0, (progress - warmup) / std::max(1e-9, 1 - warmup));
    const double low = peak * options.final_rate_fraction;
    return low + (peak - low) * 0.5 * (1 + std::cos(M_PI * t));
  }
  double rate = options.learning_rate;
  for (const double fraction : options.halving_fractions) {
    if (progress >= fraction) rate *= 0.5;
  }
  return rate;
}

void SetLearningRate(torch::optim::Adam& optimizer, double rate) {
  for (torch::optim::OptimizerParamGroup& group : optimizer.param_groups()) {
    static_cast<torch::optim::AdamOptions&>(group.options()).lr(rate);
  }
}

std::string FormatAccuracies(const std::vector<double>& accuracies) {
  std::string text;
  for (const double accuracy : accuracies) {
    text += fmt::format("{}{:.3f}", text.empty() ? "" : "/", accuracy);
  }
  return text;
}

torch::Tensor LogToTensor(const std::vector<TrainingLogEntry>& log, int levels) {
  const int64_t columns = 4 + levels;
  torch::Tensor tensor = torch::zeros({static_cast<int64_t>(log.size()), columns}, torch::kFloat64);
  for (size_t i = 0; i < log.size(); ++i) {
    double* row = tensor.data_ptr<double>() + i * columns;
    row[0] = static_cast<double>(log[i].iteration);
    row[1] = log[i].seconds;
    row[2] = log[i].learning_rate;
    row[3] = log[i].loss;
    std::copy(log[i].level_accuracies.begin(), log[i].level_accuracies.end(), row + 4);
  }
  return tensor;
}

std::vector<TrainingLogEntry> LogFromTensor(const torch::Tensor& tensor, int levels) {
  const torch::Tensor cpu = tensor.to(torch::kCPU).to(torch::kFloat64).contiguous();
  std::vector<TrainingLogEntry> log(cpu.size(0));
  for (size_t i = 0; i < log.size(); ++i) {
    const double* row = cpu.data_ptr<double>() + i * (4 + levels);
    log[i] = {static_cast<int64_t>(row[0]), row[1], row[2], row[3],
              std::vector<double>(row + 4, row + 4 + levels)};
  }
  return log;
}

struct TrainingState {
  int64_t iteration = 0;
  double seconds_before = 0;
  std::vector<TrainingLogEntry> log;
  std::vector<HeldOutCheck> checks;
  // The best network so far on the held-out sample (keep_best), as parameter copies.
  std::vector<torch::Tensor> best_parameters;
  int64_t best_iteration = 0;
  double best_accuracy = -1;
};

torch::Tensor ChecksToTensor(const std::vector<HeldOutCheck>& checks) {
  torch::Tensor tensor = torch::zeros({static_cast<int64_t>(checks.size()), 3}, torch::kFloat64);
  for (size_t i = 0; i < checks.size(); ++i) {
    double* row = tensor.data_ptr<double>() + i * 3;
    row[0] = static_cast<double>(checks[i].iteration);
    row[1] = checks[i].seconds;
    row[2] = checks[i].point_accuracy;
  }
  return tensor;
}

std::vector<HeldOutCheck> ChecksFromTensor(const torch::Tensor& tensor) {
  const torch::Tensor cpu = tensor.to(torch::kCPU).to(torch::kFloat64).contiguous();
  std::vector<HeldOutCheck> checks(cpu.size(0));
  for (size_t i = 0; i < checks.size(); ++i) {
    const double* row = cpu.data_ptr<double>() + i * 3;
    checks[i] = {static_cast<int64_t>(row[0]), row[1], row[2]};
  }
  return checks;
}

void SaveCheckpoint(const std::filesystem::path& path, const Network& network,
                    torch::optim::Adam& optimizer, const std::vector<LazyAdamTable>& lazy,
                    const TrainingState& state, const TrainerOptions& options) {
  torch::serialize::OutputArchive archive;
  archive.write("checkpoint_version", torch::tensor({kCheckpointVersion}, torch::kInt64));
  torch::serialize::OutputArchive network_archive;
  NetworkInternals::SaveTo(network, network_archive);
  archive.write("network", network_archive);
  torch::serialize::OutputArchive optimizer_archive;
  optimizer.save(optimizer_archive);
  archive.write("optimizer", optimizer_archive);
  archive.write("iteration", torch::tensor({state.iteration}, torch::kInt64));
  archive.write("seconds", torch::tensor({state.seconds_before}, torch::kFloat64));
  archive.write("seed", torch::tensor({static_cast<int64_t>(options.seed)}, torch::kInt64));
  archive.write("log", LogToTensor(state.log, network.shape().levels));
  archive.write("checks", ChecksToTensor(state.checks));
  for (size_t i = 0; i < lazy.size(); ++i) {
    archive.write(fmt::format("lazy_adam{}_m", i), lazy[i].first_moment);
    archive.write(fmt::format("lazy_adam{}_v", i), lazy[i].second_moment);
    archive.write(fmt::format("lazy_adam{}_steps", i), torch::tensor({lazy[i].steps}, torch::kInt64));
  }
  archive.write("best_iteration", torch::tensor({state.best_iteration}, torch::kInt64));
  archive.write("best_accuracy", torch::tensor({state.best_accuracy}, torch::kFloat64));
  for (size_t i = 0; i < state.best_parameters.size(); ++i) {
    archive.write(fmt::format("best{}", i), state.best_parameters[i]);
  }
  // A crash while writing must not destroy the previous checkpoint.
  const std::filesystem::path partial = path.string() + ".partial";
  archive.save_to(partial.string());
  std::filesystem::rename(partial, path);
}

int64_t ReadScalar(torch::serialize::InputArchive& archive, const char* key,
                   const std::string& source) {
  torch::Tensor tensor;
  if (!archive.try_read(key, tensor) || tensor.numel() != 1) {
    ThrowInvalidArgument("{}: not a training checkpoint ('{}' missing)", source, key);
  }
  return tensor.to(torch::kCPU).to(torch::kInt64).item<int64_t>();
}

}  // namespace

void DescriptorAugmentationOptions::Check() const {
  THROW_CHECK_MSG(noise_norm >= 0 && std::isfinite(noise_norm),
                  "DescriptorAugmentationOptions.noise_norm = {}", noise_norm);
  THROW_CHECK_MSG(dimension_dropout >= 0 && dimension_dropout < 1,
                  "DescriptorAugmentationOptions.dimension_dropout = {}", dimension_dropout);
}

void TrainerOptions::Check() const {
  network.Check();
  augmentation.Check();
  THROW_CHECK_MSG(max_iterations >= 0, "TrainerOptions.max_iterations = {}", max_iterations);
  THROW_CHECK_MSG(max_minutes >= 0 && std::isfinite(max_minutes), "TrainerOptions.max_minutes = {}",
                  max_minutes);
  THROW_CHECK_MSG(epochs >= 0 && std::isfinite(epochs), "TrainerOptions.epochs = {}", epochs);
  THROW_CHECK_MSG(warmup_fraction >= 0 && warmup_fraction < 1,
                  "TrainerOptions.warmup_fraction = {}", warmup_fraction);
  THROW_CHECK_MSG(final_rate_fraction > 0 && final_rate_fraction <= 1,
                  "TrainerOptions.final_rate_fraction = {}", final_rate_fraction);
  THROW_CHECK_MSG(evaluations >= 0, "TrainerOptions.evaluations = {}", evaluations);
  THROW_CHECK_MSG(evaluation_observations > 0, "TrainerOptions.evaluation_observations = {}",
                  evaluation_observations);
  THROW_CHECK_MSG(batch_size > 0, "TrainerOptions.batch_size = {}", batch_size);
  THROW_CHECK_MSG(learning_rate > 0 && std::isfinite(learning_rate),
                  "TrainerOptions.learning_rate = {}", learning_rate);
  for (const double fraction : halving_fractions) {
    THROW_CHECK_MSG(fraction > 0 && fraction < 1, "TrainerOptions.halving_fractions: {}", fraction);
  }
  THROW_CHECK_MSG(image_dropout >= 0 && image_dropout <= 1, "TrainerOptions.image_dropout = {}",
                  image_dropout);
  THROW_CHECK_MSG(holdout_fraction >= 0 && holdout_fraction < 1,
                  "TrainerOptions.holdout_fraction = {}", holdout_fraction);
  THROW_CHECK_MSG(checkpoint_every_iterations > 0,
                  "TrainerOptions.checkpoint_every_iterations = {}", checkpoint_every_iterations);
  THROW_CHECK_MSG(log_every_iterations > 0, "TrainerOptions.log_every_iterations = {}",
                  log_every_iterations);
}

std::string TrainingResult::LogCsv() const {
  std::string csv = "iteration,seconds,learning_rate,loss";
  const size_t levels = log.empty() ? 0 : log.front().level_accuracies.size();
  for (size_t level = 1; level <= levels; ++level) csv += fmt::format(",accuracy_level{}", level);
  csv += '\n';
  for (const TrainingLogEntry& entry : log) {
    csv += fmt::format("{},{:.3f},{:.3g},{:.6f}", entry.iteration, entry.seconds,
                       entry.learning_rate, entry.loss);
    for (const double accuracy : entry.level_accuracies) csv += fmt::format(",{:.6f}", accuracy);
    csv += '\n';
  }
  return csv;
}

double DefaultEpochs(size_t num_training_observations) {
  // Small maps need many passes (few views per point); large ones fewer, each pass being longer.
  const double n = std::max<double>(1, static_cast<double>(num_training_observations));
  return std::clamp(12.0 * std::sqrt(1e6 / n), 10.0, 400.0);
}

NetworkOptions DefaultNetworkOptions(size_t num_points) {
  // The node output rows are most of the network's bytes: at most about 6 M numbers (24 MB), so
  // that the HSC bundle stays under a fifth of the nearest-neighbour map (docs/decisions.md).
  NetworkOptions options;
  int rows = 64;
  while (rows > 16 && static_cast<double>(num_points) * (rows + 1) > 6e6) rows /= 2;
  options.node_output_dim = rows;
  return options;
}

bool IsHeldOutObservation(uint64_t index, double fraction, uint64_t seed) {
  const uint64_t hash = MixBits(MixBits(seed ^ kStreamHoldout) ^ MixBits(index));
  return static_cast<double>(hash >> 11) * 0x1.0p-53 < fraction;
}

std::vector<uint32_t> HeldOutObservations(const Scene& scene, double fraction, uint64_t seed) {
  std::vector<uint32_t> held_out;
  for (uint32_t i = 0; i < scene.NumObservations(); ++i) {
    if (IsHeldOutObservation(i, fraction, seed)) held_out.push_back(i);
  }
  return held_out;
}

TrainingResult TrainNetwork(const Scene& scene, const LabelTree& tree,
                            const TrainerOptions& options) {
  options.Check();
  if (tree.NumPoints() != scene.NumPoints()) {
    ThrowInvalidArgument("train: label tree of {} points, scene of {}", tree.NumPoints(),
                         scene.NumPoints());
  }
  std::vector<uint32_t> training;
  for (uint32_t i = 0; i < scene.NumObservations(); ++i) {
    if (!IsHeldOutObservation(i, options.holdout_fraction, options.holdout_seed)) {
      training.push_back(i);
    }
  }
  if (training.empty()) ThrowInvalidArgument("train: the scene has no training observations");
  const size_t num_training = training.size();
  const size_t num_held_out = scene.NumObservations() - num_training;

  SetComputeThreads(options.num_threads);
  KeepFreedMemoryForReuse();
  const torch::Device device = TorchDevice(options.device);
  const NetworkShape shape =
      NetworkShape::ForTree(static_cast<int>(scene.Dimension()), tree,
                            static_cast<int>(scene.NumImages()));
  const int levels = shape.levels;

  // The budget: iterations, minutes, epochs, or (none given) the automatic epochs.
  double epochs = options.epochs;
  if (options.max_iterations == 0 && options.max_minutes == 0 && epochs == 0) {
    epochs = DefaultEpochs(num_training);
  }
  int64_t budget_iterations = options.max_iterations;
  if (epochs > 0) {
    const auto from_epochs = static_cast<int64_t>(
        std::ceil(epochs * static_cast<double>(num_training) / options.batch_size));
    budget_iterations =
        budget_iterations > 0 ? std::min(budget_iterations, from_epochs) : from_epochs;
  }

  TrainingState state;
  std::optional<Network> network;
  torch::serialize::InputArchive checkpoint;
  const std::string checkpoint_source = options.checkpoint_path.string();
  const bool resuming = options.resume && !options.checkpoint_path.empty() &&
                        std::filesystem::exists(options.checkpoint_path);
  if (resuming) {
    try {
      checkpoint.load_from(checkpoint_source, device);
    } catch (const c10::Error& error) {
      ThrowInvalidArgument("{}: not a training checkpoint: {}", checkpoint_source,
                           error.what_without_backtrace());
    }
    if (ReadScalar(checkpoint, "checkpoint_version", checkpoint_source) != kCheckpointVersion) {
      ThrowInvalidArgument("{}: checkpoint of another version", checkpoint_source);
    }
    torch::serialize::InputArchive network_archive;
    if (!checkpoint.try_read("network", network_archive)) {
      ThrowInvalidArgument("{}: checkpoint without a network", checkpoint_source);
    }
    network.emplace(NetworkInternals::LoadFrom(network_archive, checkpoint_source, options.device));
    if (!(network->shape() == shape) || !(network->options() == options.network)) {
      ThrowInvalidArgument("{}: the checkpoint's network has another shape or other options",
                           checkpoint_source);
    }
    if (ReadScalar(checkpoint, "seed", checkpoint_source) != static_cast<int64_t>(options.seed)) {
      spdlog::warn("{}: resuming with another seed than the checkpoint was trained with",
                   checkpoint_source);
    }
    state.iteration = ReadScalar(checkpoint, "iteration", checkpoint_source);
    torch::Tensor seconds;
    torch::Tensor log;
    torch::Tensor checks;
    torch::Tensor best_accuracy;
    checkpoint.read("seconds", seconds);
    checkpoint.read("log", log);
    checkpoint.read("checks", checks);
    checkpoint.read("best_accuracy", best_accuracy);
    state.seconds_before = seconds.to(torch::kCPU).item<double>();
    state.log = LogFromTensor(log, levels);
    state.checks = ChecksFromTensor(checks);
    state.best_iteration = ReadScalar(checkpoint, "best_iteration", checkpoint_source);
    state.best_accuracy = best_accuracy.to(torch::kCPU).item<double>();
    spdlog::info("resuming from {} at iteration {}", checkpoint_source, state.iteration);
  } else {
    network.emplace(shape, options.network, options.seed);
    network->SetDevice(options.device);
  }

  HscNet& module = NetworkInternals::Module(*network);
  module->train();
  // Node output rows go to lazy Adam (sparse gradients), everything else to dense Adam.
  std::vector<torch::Tensor> dense_parameters;
  std::vector<LazyAdamTable> lazy;
  std::vector<const torch::Tensor*> sparse_tables;
  for (Level& level : module->levels) {
    level->SetSparseNodeRows(options.sparse_node_updates && level->HasNodeOutput());
  }
  for (const auto& item : module->named_parameters()) {
    const bool node_rows = item.key().find("node_rows") != std::string::npos;
    if (node_rows && options.sparse_node_updates) {
      lazy.push_back({item.value(), torch::zeros_like(item.value()),
                      torch::zeros_like(item.value()), 0});
    } else {
      dense_parameters.push_back(item.value());
    }
  }
  torch::optim::Adam optimizer(dense_parameters, torch::optim::AdamOptions(options.learning_rate));
  if (resuming) {
    torch::serialize::InputArchive optimizer_archive;
    if (!checkpoint.try_read("optimizer", optimizer_archive)) {
      ThrowInvalidArgument("{}: checkpoint without optimizer state", checkpoint_source);
    }
    optimizer.load(optimizer_archive);
    for (size_t i = 0; i < lazy.size(); ++i) {
      checkpoint.read(fmt::format("lazy_adam{}_m", i), lazy[i].first_moment);
      checkpoint.read(fmt::format("lazy_adam{}_v", i), lazy[i].second_moment);
      lazy[i].steps = ReadScalar(checkpoint, fmt::format("lazy_adam{}_steps", i).c_str(),
                                 checkpoint_source);
    }
    for (size_t i = 0;; ++i) {
      torch::Tensor parameter;
      if (!checkpoint.try_read(fmt::format("best{}", i), parameter)) break;
      state.best_parameters.push_back(parameter);
    }
  }

  // The visibility of every database image, per tree node, for the visibility softmax and the
  // held-out checks (masked decoding, as the localizer's visibility filter sees it).
  const Visibility visibility =
      Visibility::FromObservations(scene.NumImages(), scene.NumPoints(),
                                   scene.observation_image_indices,
                                   scene.observation_point_indices);
  std::unique_ptr<NodeVisibilityMasks> node_masks;
  if (options.visibility_softmax) {
    std::vector<uint32_t> all_images(scene.NumImages());
    std::iota(all_images.begin(), all_images.end(), 0u);
    node_masks = std::make_unique<NodeVisibilityMasks>(all_images, tree, visibility);
  }
  const BatchContext context{scene, tree, options, node_masks.get(),
                             options.network.node_output_dim > 0};
  // The held-out sample of the checks: evenly spaced over the held-out observations.
  std::vector<uint32_t> check_sample;
  {
    const std::vector<uint32_t> held_out =
        HeldOutObservations(scene, options.holdout_fraction, options.holdout_seed);
    const size_t wanted = std::min<size_t>(held_out.size(), options.evaluation_observations);
    for (size_t i = 0; i < wanted; ++i) check_sample.push_back(held_out[i * held_out.size() / wanted]);
  }
  const bool checking = options.evaluations > 0 && !check_sample.empty();

  SampleOrder order(std::move(training), options.seed);
  const double max_seconds = options.max_minutes * 60;
  const int64_t max_iterations =
      budget_iterations > 0 ? budget_iterations : std::numeric_limits<int64_t>::max();
  const auto progress_of = [&](int64_t iteration, double seconds) {
    double progress = 0;
    if (budget_iterations > 0) {
      progress = static_cast<double>(iteration) / static_cast<double>(budget_iterations);
    }
    if (max_seconds > 0) progress = std::max(progress, seconds / max_seconds);
    return progress;
  };

  // The bar counts this run's steps (a resumed run's rate and ETA would otherwise include the
  // steps before the resume).
  ProgressBar progress(
      "train",
      budget_iterations > 0 ? budget_iterations - std::min(state.iteration, budget_iterations) : 0,
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  Timer timer;
  const auto elapsed = [&] { return state.seconds_before + timer.ElapsedSeconds(); };
  // Sums since the last log entry, kept on the device so that no iteration waits for a copy.
  torch::Tensor sums = torch::zeros({1 + levels}, torch::TensorOptions().device(device));
  int64_t iterations_in_sums = 0;
  double learning_rate = ScheduledLearningRate(options, progress_of(state.iteration, elapsed()));
  std::string check_status;

  const auto flush_log = [&](int64_t iteration) {
    if (iterations_in_sums == 0) return;
    const torch::Tensor means = (sums / static_cast<double>(iterations_in_sums)).to(torch::kCPU);
    TrainingLogEntry entry{iteration, elapsed(), learning_rate, means[0].item<double>(), {}};
    for (int level = 0; level < levels; ++level) {
      entry.level_accuracies.push_back(means[1 + level].item<double>());
    }
    progress.SetStatus(fmt::format("loss {:.3f} acc {}{}", entry.loss,
                                   FormatAccuracies(entry.level_accuracies), check_status));
    state.log.push_back(std::move(entry));
    sums.zero_();
    iterations_in_sums = 0;
  };
  // A held-out check: masked point accuracy on the sample; keeps the best parameters.
  const auto check_held_out = [&] {
    if (!checking) return;
    if (!state.checks.empty() && state.checks.back().iteration == state.iteration) return;
    const double seconds_before_check = elapsed();
    module->eval();
    const NetworkEvaluation evaluation =
        EvaluateNetwork(*network, scene, tree, check_sample, &visibility);
    module->train();
    state.checks.push_back({state.iteration, seconds_before_check, evaluation.leaf_accuracy});
    if (evaluation.leaf_accuracy > state.best_accuracy) {
      state.best_accuracy = evaluation.leaf_accuracy;
      state.best_iteration = state.iteration;
      if (options.keep_best) {
        torch::NoGradGuard no_grad;
        state.best_parameters.clear();
        for (const torch::Tensor& parameter : module->parameters()) {
          state.best_parameters.push_back(parameter.detach().clone());
        }
      }
    }
    check_status = fmt::format(" held-out {:.1f}% (best {:.1f}%)", 100 * evaluation.leaf_accuracy,
                               100 * state.best_accuracy);
    progress.SetStatus(check_status);
  };
  const auto next_check_due = [&] {
    const double next = static_cast<double>(state.checks.size() + 1) / options.evaluations;
    return checking && next < 1 && progress_of(state.iteration, elapsed()) >= next;
  };

  while (state.iteration < max_iterations && !(max_seconds > 0 && elapsed() >= max_seconds)) {
    learning_rate = ScheduledLearningRate(options, progress_of(state.iteration, elapsed()));
    SetLearningRate(optimizer, learning_rate);
    const Batch batch = MakeBatch(context, order, state.iteration, device);
    const torch::Tensor descriptors = NormalizeRows(batch.descriptors);
    torch::Tensor loss = torch::zeros({}, torch::TensorOptions().device(device));
    std::vector<torch::Tensor> statistics;
    for (int level = 0; level < levels; ++level) {
      if (!tree.LevelHasChoice(level)) {
        // Nothing to learn: Predict takes the only child without running this level.
        statistics.push_back(torch::ones({}, torch::TensorOptions().device(device)));
        continue;
      }
      torch::Tensor logits = module->levels[level]->forward(
          descriptors, batch.images, batch.labels.narrow(1, 0, static_cast<int64_t>(level)),
          batch.parent_nodes[level], batch.child_nodes[level]);
      if (batch.allowed[level].defined()) {
        logits = logits.masked_fill(batch.allowed[level].logical_not(),
                                    -std::numeric_limits<float>::infinity());
      }
      const torch::Tensor target =
          batch.targets[level].defined() ? batch.targets[level] : batch.labels.select(1, level);
      loss = loss + torch::nn::functional::cross_entropy(logits, target);
      statistics.push_back(logits.detach().argmax(1).eq(target).to(torch::kFloat32).mean());
    }
    optimizer.zero_grad();
    loss.backward();
    optimizer.step();
    for (LazyAdamTable& table : lazy) table.Step(learning_rate);
    statistics.insert(statistics.begin(), loss.detach());
    sums += torch::stack(statistics);
    ++iterations_in_sums;
    ++state.iteration;
    progress.Advance();
    if (state.iteration % options.log_every_iterations == 0) flush_log(state.iteration);
    if (next_check_due()) check_held_out();
    if (!options.checkpoint_path.empty() &&
        state.iteration % options.checkpoint_every_iterations == 0) {
      state.seconds_before = elapsed();
      timer.Restart();
      SaveCheckpoint(options.checkpoint_path, *network, optimizer, lazy, state, options);
    }
  }
  flush_log(state.iteration);
  check_held_out();
  progress.Finish();
  state.seconds_before = elapsed();
  timer.Restart();
  if (!options.checkpoint_path.empty()) {
    SaveCheckpoint(options.checkpoint_path, *network, optimizer, lazy, state, options);
  }
  module->eval();
  for (Level& level : module->levels) level->SetSparseNodeRows(false);

  // Early stopping: the best held-out network, where a later one was worse.
  const bool restore = options.keep_best && !state.best_parameters.empty() &&
                       !state.checks.empty() &&
                       state.checks.back().point_accuracy < state.best_accuracy;
  if (restore) {
    torch::NoGradGuard no_grad;
    const std::vector<torch::Tensor> parameters = module->parameters();
    for (size_t i = 0; i < parameters.size(); ++i) parameters[i].copy_(state.best_parameters[i]);
  }

  TrainingResult result{std::move(*network), state.iteration, state.seconds_before, 0, {},
                        num_training,        num_held_out,    std::move(state.log)};
  if (!result.log.empty()) {
    result.final_loss = result.log.back().loss;
    result.final_level_accuracies = result.log.back().level_accuracies;
  }
  result.held_out_checks = state.checks;
  if (!state.checks.empty()) {
    result.best_iteration = restore ? state.best_iteration : state.checks.back().iteration;
    result.best_held_out_accuracy =
        restore ? state.best_accuracy : state.checks.back().point_accuracy;
    // Converged: the last quarter of the budget gained less than 5 % of the accuracy reached.
    const double final_progress = progress_of(state.iteration, state.seconds_before);
    double at_three_quarters = state.checks.front().point_accuracy;
    for (const HeldOutCheck& check : state.checks) {
      if (progress_of(check.iteration, check.seconds) <= 0.75 * final_progress) {
        at_three_quarters = check.point_accuracy;
      }
    }
    result.converged = state.checks.size() >= 2 &&
                       state.best_accuracy - at_three_quarters < 0.05 * state.best_accuracy;
  }
  return result;
}

NetworkEvaluation EvaluateNetwork(const Network& network, const Scene& scene, const LabelTree& tree,
                                  const std::vector<uint32_t>& observation_indices,
                                  const Visibility* visibility_mask) {
  Timer timer;
  const int levels = tree.levels();
  std::vector<std::vector<uint32_t>> by_image(scene.NumImages());
  for (const uint32_t observation : observation_indices) {
    THROW_CHECK_LT(size_t{observation}, scene.NumObservations());
    by_image[scene.observation_image_indices[observation]].push_back(observation);
  }
  NetworkEvaluation evaluation;
  evaluation.num_observations = observation_indices.size();
  std::vector<size_t> correct_levels(levels, 0);
  size_t correct_points = 0;
  for (uint32_t image = 0; image < by_image.size(); ++image) {
    const std::vector<uint32_t>& observations = by_image[image];
    if (observations.empty()) continue;
    DescriptorMatrix descriptors(observations.size(), scene.Dimension());
    for (size_t i = 0; i < observations.size(); ++i) {
      descriptors.row(i) = scene.observation_descriptors.row(observations[i]);
    }
    const PointPredictions predictions =
        network.Predict(descriptors, {image}, tree, visibility_mask);
    for (size_t i = 0; i < observations.size(); ++i) {
      const uint32_t point = scene.observation_point_indices[observations[i]];
      const LabelTree::Label* truth = tree.LabelsOfPoint(point);
      for (int level = 0; level < levels && predictions.labels(i, level) == truth[level]; ++level) {
        ++correct_levels[level];
      }
      if (predictions.point_indices(0, i) == point) ++correct_points;
    }
  }
  const double count = std::max<double>(1, evaluation.num_observations);
  for (const size_t correct : correct_levels)
    evaluation.level_accuracies.push_back(correct / count);
  evaluation.leaf_accuracy = correct_points / count;
  evaluation.seconds = timer.ElapsedSeconds();
  return evaluation;
}

void WriteNetworkToBundle(
    const std::filesystem::path& bundle_dir, const TrainingResult& result,
    const TrainerOptions& options,
    const std::vector<std::pair<std::string, NetworkEvaluation>>& evaluations) {
  MapBundleWriter writer = MapBundleWriter::Update(bundle_dir);
  writer.AddBlob(network_blobs::kNetwork,
                 [&](std::ostream& stream) { result.network.Save(stream); });
  const std::string csv = result.LogCsv();
  writer.AddBlob(network_blobs::kTrainingLog,
                 [&](std::ostream& stream) { stream.write(csv.data(), csv.size()); });

  const NetworkShape& shape = result.network.shape();
  const NetworkOptions& network_options = result.network.options();
  nlohmann::json json;
  json["shape"] = {{"descriptor_dim", shape.descriptor_dim},
                   {"levels", shape.levels},
                   {"branching", shape.branching},
                   {"num_images", shape.num_images}};
  json["options"] = {{"channels", network_options.channels},
                     {"trunk_channels", network_options.trunk_channels},
                     {"embedding_dim", network_options.embedding_dim},
                     {"conditioned_layers", network_options.conditioned_layers},
                     {"node_conditioning", network_options.node_conditioning},
                     {"node_output_dim", network_options.node_output_dim}};
  json["parameters"] = result.network.NumParameters();
  json["training"] = {{"iterations", result.iterations},
                      {"seconds", result.seconds},
                      {"final_loss", result.final_loss},
                      {"final_level_accuracies", result.final_level_accuracies},
                      {"batch_size", options.batch_size},
                      {"learning_rate", options.learning_rate},
                      {"halving_fractions", options.halving_fractions},
                      {"schedule", options.schedule == LearningRateSchedule::kOneCycle
                                       ? "one_cycle"
                                       : "halving"},
                      {"visibility_softmax", options.visibility_softmax},
                      {"best_iteration", result.best_iteration},
                      {"best_held_out_accuracy", result.best_held_out_accuracy},
                      {"converged", result.converged},
                      {"augmentation",
                       {{"enabled", options.augmentation.enabled},
                        {"noise_norm", options.augmentation.noise_norm},
                        {"dimension_dropout", options.augmentation.dimension_dropout}}},
                      {"image_dropout", options.image_dropout},
                      {"seed", options.seed},
                      {"holdout_fraction", options.holdout_fraction},
                      {"holdout_seed", options.holdout_seed},
                      {"training_observations", result.num_training_observations},
                      {"held_out_observations", result.num_held_out_observations},
                      {"device", ComputeDeviceName(options.device)}};
  nlohmann::json evaluation_json = nlohmann::json::object();
  for (const auto& [name, evaluation] : evaluations) {
    evaluation_json[name] = {{"observations", evaluation.num_observations},
                             {"level_accuracies", evaluation.level_accuracies},
                             {"leaf_accuracy", evaluation.leaf_accuracy}};
  }
  json["evaluations"] = evaluation_json;
  writer.metadata()["network"] = json;
  writer.Commit();
}

}  // namespace hscloc
