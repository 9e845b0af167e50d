#include "model/training_checkpoint.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>

#include "model/network_module.h"
#include "util/check.h"

namespace hscloc {
namespace {

// Checkpoint layout version; the network inside carries its own. Version 2 added the lazy Adam
// state of node output rows and the best network so far. Version 3: levels without a choice hold no
// weights, so the optimizers' state has fewer tensors than version 2's.
constexpr int64_t kCheckpointVersion = 3;

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

}  // namespace

void SaveCheckpoint(const std::filesystem::path& path, const Network& network,
                    torch::optim::Adam& optimizer, const std::vector<LazyAdamTable>& lazy,
                    const TrainingState& state, uint64_t seed) {
  torch::serialize::OutputArchive archive;
  archive.write("checkpoint_version", torch::tensor({kCheckpointVersion}, torch::kInt64));
  torch::serialize::OutputArchive network_archive;
  NetworkInternals::SaveTo(network, network_archive, WeightStorage::kFloat32);
  archive.write("network", network_archive);
  torch::serialize::OutputArchive optimizer_archive;
  optimizer.save(optimizer_archive);
  archive.write("optimizer", optimizer_archive);
  archive.write("iteration", torch::tensor({state.iteration}, torch::kInt64));
  archive.write("seconds", torch::tensor({state.seconds_before}, torch::kFloat64));
  archive.write("seed", torch::tensor({static_cast<int64_t>(seed)}, torch::kInt64));
  archive.write("log", LogToTensor(state.log, network.shape().levels));
  archive.write("checks", ChecksToTensor(state.checks));
  for (size_t i = 0; i < lazy.size(); ++i) {
    archive.write(fmt::format("lazy_adam{}_m", i), lazy[i].first_moment);
    archive.write(fmt::format("lazy_adam{}_v", i), lazy[i].second_moment);
    archive.write(fmt::format("lazy_adam{}_steps", i),
                  torch::tensor({lazy[i].steps}, torch::kInt64));
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

CheckpointReader::CheckpointReader(const std::filesystem::path& path, torch::Device device)
    : source_(path.string()) {
  try {
    archive_.load_from(source_, device);
  } catch (const c10::Error& error) {
    ThrowInvalidArgument("{}: not a training checkpoint: {}", source_,
                         error.what_without_backtrace());
  }
  if (ReadScalar("checkpoint_version") != kCheckpointVersion) {
    ThrowInvalidArgument("{}: checkpoint of another version", source_);
  }
}

Network CheckpointReader::ReadNetwork(const NetworkShape& shape, const NetworkOptions& options,
                                      ComputeDevice device) {
  torch::serialize::InputArchive network_archive;
  if (!archive_.try_read("network", network_archive)) {
    ThrowInvalidArgument("{}: checkpoint without a network", source_);
  }
  Network network = NetworkInternals::LoadFrom(network_archive, source_, device);
  if (!(network.shape() == shape) || !(network.options() == options)) {
    ThrowInvalidArgument("{}: the checkpoint's network has another shape or other options",
                         source_);
  }
  return network;
}

TrainingState CheckpointReader::ReadState(int levels, uint64_t seed) {
  if (ReadScalar("seed") != static_cast<int64_t>(seed)) {
    spdlog::warn("{}: resuming with another seed than the checkpoint was trained with", source_);
  }
  TrainingState state;
  state.iteration = ReadScalar("iteration");
  torch::Tensor seconds;
  torch::Tensor log;
  torch::Tensor checks;
  torch::Tensor best_accuracy;
  archive_.read("seconds", seconds);
  archive_.read("log", log);
  archive_.read("checks", checks);
  archive_.read("best_accuracy", best_accuracy);
  state.seconds_before = seconds.to(torch::kCPU).item<double>();
  state.log = LogFromTensor(log, levels);
  state.checks = ChecksFromTensor(checks);
  state.best_iteration = ReadScalar("best_iteration");
  state.best_accuracy = best_accuracy.to(torch::kCPU).item<double>();
  for (size_t i = 0;; ++i) {
    torch::Tensor parameter;
    if (!archive_.try_read(fmt::format("best{}", i), parameter)) break;
    state.best_parameters.push_back(parameter);
  }
  spdlog::info("resuming from {} at iteration {}", source_, state.iteration);
  return state;
}

void CheckpointReader::RestoreOptimizers(torch::optim::Adam& optimizer,
                                         std::vector<LazyAdamTable>& lazy) {
  torch::serialize::InputArchive optimizer_archive;
  if (!archive_.try_read("optimizer", optimizer_archive)) {
    ThrowInvalidArgument("{}: checkpoint without optimizer state", source_);
  }
  // A checkpoint of another build may split the parameters between dense and lazy Adam otherwise
  // (the conditioning embeddings moved to lazy Adam): that is named, not a libtorch trace.
  try {
    optimizer.load(optimizer_archive);
    for (size_t i = 0; i < lazy.size(); ++i) {
      archive_.read(fmt::format("lazy_adam{}_m", i), lazy[i].first_moment);
      archive_.read(fmt::format("lazy_adam{}_v", i), lazy[i].second_moment);
      lazy[i].steps = ReadScalar(fmt::format("lazy_adam{}_steps", i));
    }
  } catch (const c10::Error& error) {
    ThrowInvalidArgument(
        "{}: the optimizer state does not fit this network's training (a checkpoint of another "
        "hscloc version? train without --resume): {}",
        source_, error.what_without_backtrace());
  }
}

int64_t CheckpointReader::ReadScalar(const std::string& key) {
  torch::Tensor tensor;
  if (!archive_.try_read(key, tensor) || tensor.numel() != 1) {
    ThrowInvalidArgument("{}: not a training checkpoint ('{}' missing)", source_, key);
  }
  return tensor.to(torch::kCPU).to(torch::kInt64).item<int64_t>();
}

}  // namespace hscloc
