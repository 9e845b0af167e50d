// The trainer's checkpoints (model/trainer.cc): the network, the optimizers' state, the iteration,
// the time trained, the log, the held-out checks and the best network so far, in one libtorch
// archive. Private to model/: it holds libtorch types, and nothing outside model/ includes this
// header.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "model/lazy_adam.h"
#include "model/network.h"
#include "model/trainer.h"

namespace hscloc {

// What a checkpoint keeps of a run besides the network and the optimizers.
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

// Writes the checkpoint to `path` by way of a ".partial" file renamed into place. `seed` is the
// run's, for the warning of a resume with another one.
void SaveCheckpoint(const std::filesystem::path& path, const Network& network,
                    torch::optim::Adam& optimizer, const std::vector<LazyAdamTable>& lazy,
                    const TrainingState& state, uint64_t seed);

// A checkpoint opened to resume from. Each method throws std::invalid_argument naming the file
// when the checkpoint does not hold what it should.
class CheckpointReader {
 public:
  // Loads the file's tensors onto `device`; throws when it is no checkpoint or one of another
  // version.
  CheckpointReader(const std::filesystem::path& path, torch::Device device);

  // Throws when the network has another shape or other options than the run's.
  Network ReadNetwork(const NetworkShape& shape, const NetworkOptions& options,
                      ComputeDevice device);
  // Warns when the checkpoint was trained with another seed than `seed`.
  TrainingState ReadState(int levels, uint64_t seed);
  // Restores the optimizers' state into the run's optimizers, created as the checkpointed run
  // created them (the same parameters, in the same order).
  void RestoreOptimizers(torch::optim::Adam& optimizer, std::vector<LazyAdamTable>& lazy);

 private:
  int64_t ReadScalar(const std::string& key);

  std::string source_;
  torch::serialize::InputArchive archive_;
};

}  // namespace hscloc
